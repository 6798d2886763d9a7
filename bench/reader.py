"""Tracing cost of the hopping reader: one trace per position against a trace per channel.

On ``corridor_lab``, the same antenna poses x the scene's tags are traced three ways, each
into a fresh, empty path cache:

(a) one carrier (865 MHz), no channel, no gradient: a reader that does not hop;
(b) the ETSI hopping reader as ``pipeline.acquisition`` traces it: one trace at 865 MHz
    per position, each pose's coherent sum at its channel (865.7 / 866.3 / 866.9 /
    867.5 MHz in turn) with the position gradient (Doppler);
(c) the naive alternative: each channel traced on its own at that frequency (materials
    evaluated there), only the poses on it.

(a) and (b) run twice, interleaved (the machine may be shared), then from their warm
caches (no tracing: the part hopping adds, free of the tracer's noise). Prints wall times,
the ratios (b)/(a) and (c)/(a), and how far (b)'s gain at a channel is from (c)'s direct
trace at that channel. (c) traces other batches of sources than (b), hence other rays, so
that difference is mostly ray-sampling noise; (d), every pose traced directly at
867.5 MHz in (b)'s batch, separates the channel sum's own error (materials at 865 MHz,
Sionna's free-space amplitude at the carrier's wavelength) from it. Numbers, no timed
assertions.

Usage: .venv/bin/python bench/reader.py [--poses 40] [--samples 30000] [--depth 5]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from route_poses import route_poses  # bench/ is the script's own folder

ETSI_HZ = (865.7e6, 866.3e6, 866.9e6, 867.5e6)
CARRIER_HZ = 865e6


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=40, help="antenna poses")
    ap.add_argument("--samples", type=int, default=None, help="rays per source (default: the library's)")
    ap.add_argument("--depth", type=int, default=None, help="max depth (default: the library's)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    import propagation as P
    import scenes
    from propagation.tracing import DEFAULT_MAX_DEPTH, DEFAULT_SAMPLES_PER_SRC

    spp = DEFAULT_SAMPLES_PER_SRC if args.samples is None else args.samples
    depth = DEFAULT_MAX_DEPTH if args.depth is None else args.depth
    print("backend:", P.select_variant())
    scene = scenes.load("corridor_lab")
    tags, normals = scene.tags.positions_m, scene.tags.normals
    poses = route_poses(scene, args.poses)
    channel = np.asarray(ETSI_HZ)[np.arange(len(poses)) % len(ETSI_HZ)]
    print(f"scene {scene.name}: {len(tags)} tags x {len(poses)} antenna poses, depth {depth}, "
          f"{spp} rays/source, carrier {CARRIER_HZ / 1e6:g} MHz")
    # direct tracing (Sionna's PathSolver alone): the channel sums, not the tracer, are measured
    opts = dict(options=P.TraceOptions(method="direct", max_depth=depth, samples_per_src=spp),
                tag_normals=normals)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # warm-up (kernel compilation at this depth, both channel paths) on its own cache
        for grad in (False, True):
            P.trace_links(scene, poses[:2], tags[:2],
                          P.TraceOptions(method="direct", max_depth=depth, samples_per_src=1000),
                          channel_hz=channel[:2], channel_gradient=grad, cache_dir=tmp / f"warm{grad}")

        def timed(**kw):
            t0 = time.perf_counter()
            out = P.trace_links(scene, poses, tags, frequency_hz=CARRIER_HZ, **opts, **kw)
            return out, time.perf_counter() - t0

        # (a) and (b) twice, interleaved, each into a fresh cache: the machine is shared
        a, t_a1 = timed(cache_dir=tmp / "a1")
        b, t_b1 = timed(channel_hz=channel, channel_gradient=True, cache_dir=tmp / "b1")
        _, t_a2 = timed(cache_dir=tmp / "a2")
        _, t_b2 = timed(channel_hz=channel, channel_gradient=True, cache_dir=tmp / "b2")
        # from the warm caches: no ray tracing, only the path load and the coherent sums
        # (with the gradient for (b)): the part the hopping reader adds, free of tracing noise
        w_a = min(timed(cache_dir=tmp / "a1")[1] for _ in range(3))
        w_b = min(timed(channel_hz=channel, channel_gradient=True, cache_dir=tmp / "b1")[1]
                  for _ in range(3))
        t0 = time.perf_counter()
        direct = np.full(b.gain_db.shape, -np.inf)
        for f in ETSI_HZ:
            on = channel == f
            c = P.trace_links(scene, poses[on], tags, frequency_hz=f, cache_dir=tmp / "c", **opts)
            direct[on] = c.gain_db
        t_c = time.perf_counter() - t0
        # (d) every pose traced directly at the last channel: the same batch of sources as
        # (b), so the same rays; (b) against it is the channel sum's own error
        last = ETSI_HZ[-1]
        d = P.trace_links(scene, poses, tags, frequency_hz=last, cache_dir=tmp / "d", **opts)
    t_a, t_b = min(t_a1, t_a2), min(t_b1, t_b2)
    print(f"\nlinks traced: {int(a.traced.sum())} (a), {int(b.traced.sum())} (b); "
          f"solver calls {a.n_solver_calls} (a), {b.n_solver_calls} (b)")
    print(f"\n{'way':<58} {'wall_s':>13} {'/ (a)':>6}")
    for label, t, runs in (("(a) one carrier, no gradient", t_a, (t_a1, t_a2)),
                           ("(b) ETSI hopping: one trace, channel sums + gradient", t_b, (t_b1, t_b2)),
                           ("(c) naive: each of the 4 channels traced on its own", t_c, (t_c,))):
        each = " ".join(f"{v:.1f}" for v in runs)
        print(f"{label:<58} {each:>13} {t / t_a:>6.2f}")
    print("(ratios of the faster run of each; (c) traces each position once too, on its channel)")
    print(f"warm cache (no tracing), best of 3: (a) {w_a:.2f} s, (b) {w_b:.2f} s: the channel sums and "
          f"gradient add {w_b - w_a:.2f} s = {(w_b - w_a) / t_a * 100:.1f} % of (a)'s cold trace")
    thr = P.LinkBudget().min_gain_db()

    def compare(label, x, y, rows):
        both = np.isfinite(x) & np.isfinite(y)
        both[~rows] = False
        only = int(np.sum((np.isfinite(x) != np.isfinite(y))[rows]))
        e = np.abs(x - y)[both]
        near = both & (np.maximum(x, y) >= thr - 10.0)
        en = np.abs(x - y)[near]
        print(f"{label:<44} {both.sum():>6} {only:>5} {np.percentile(e, 50):>7.3f} "
              f"{np.percentile(e, 95):>7.3f} {e.max():>7.2f} {near.sum():>6} "
              f"{np.percentile(en, 50):>7.3f} {np.percentile(en, 95):>7.3f} {en.max():>7.2f}")

    on_last = channel == last
    allrows = np.ones(len(poses), bool)
    print(f"\n|gain difference| [dB]; 'near': links within 10 dB of the read threshold "
          f"({thr:.1f} dB) or above")
    print(f"{'':<44} {'links':>6} {'1-way':>5} {'p50':>7} {'p95':>7} {'max':>7} {'near':>6} "
          f"{'p50':>7} {'p95':>7} {'max':>7}")
    compare("(b) vs (c), every pose at its channel", b.gain_db, direct, allrows)
    compare(f"(b) vs (d), poses on {last / 1e6:g} MHz", b.gain_db, d.gain_db, on_last)
    compare(f"(c) vs (d), poses on {last / 1e6:g} MHz", direct, d.gain_db, on_last)
    compare(f"(a) {CARRIER_HZ / 1e6:g} vs (d) {last / 1e6:g} MHz, those poses", a.gain_db, d.gain_db, on_last)
    print("(b)-(d): same rays, the channel sum's own error (materials at 865 MHz, the carrier's\n"
          "wavelength in Sionna's free-space amplitude); (c)-(d): both direct at the channel but\n"
          "traced in other batches of sources, so other rays: the ray-sampling noise, which is\n"
          "what (b)-(c) is made of; (a)-(d): what the channel itself changes (2.5 MHz).")
    dh = b.dh_dpos
    print(f"(b) gradient: {int(np.isfinite(np.abs(dh)).all(axis=-1).sum())} of "
          f"{dh.shape[0] * dh.shape[1]} links with a finite dh/dpos")

if __name__ == "__main__":
    main()
