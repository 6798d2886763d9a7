"""What the seed-to-seed |dgain| of the study's truth on sparse poses is made of, path by path.

Traces ``bench/seed_noise.py``'s sparse poses of ``corridor_lab`` (96 poses, 48
positions, each with one neighbour within the sharing radius) with the study's tracing
options and two seeds, matches the paths of the two traces link by link (same tag,
length within 1e-4 m, departure and arrival directions within 1e-4: merge_paths' test)
and prints, over the readable links (either seed's gain >= the read threshold):

1. p50 / p95 |gain seed a - gain seed b| with all paths, with only the paths both seeds
   found (if the paths themselves are seed-independent, this is ~0 and all the noise is
   which paths each seed found), and of each seed against the union of both;
2. for the paths one seed found and the other did not: how many, their power relative to
   the link's coherent power, their excess length over the direct path, and whether the
   completion's enumeration (specular reflections off the large planes, up to order 3)
   holds them;
3. the per-link |dgain| of the largest links, with the strongest missed path of each;
4. near-copies inside one seed's link (same length and directions within 1e-3): paths
   counted twice.

Usage::

    .venv/bin/python bench/seed_noise_paths.py [--seeds 1 2] [--set key=value ...]

``--set`` replaces TraceOptions fields (e.g. ``--set samples_per_src=60000``).
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from seed_noise import sparse_poses  # bench/ is the script's own folder


def per_path_amplitudes(sp, tags, tag_index, pose, opts, tag_axes, frequency_hz):
    """Complex amplitude of each path of link (sp, tag) with the study's patterns
    (propagation.channels.link_channels' algebra, path by path)."""
    from propagation.patterns import dipole_rotation, pattern_field_world, pose_rotation

    row = int(sp.index_of(tags[tag_index][None])[0])
    if row < 0:
        return np.zeros(0, complex), slice(0, 0)
    sl = slice(int(sp.offsets[row]), int(sp.offsets[row + 1]))
    n = sl.stop - sl.start
    if n == 0:
        return np.zeros(0, complex), sl
    r_reader = np.repeat(pose_rotation(pose[None]), n, axis=0)
    r_tag = np.repeat(dipole_rotation(tag_axes[tag_index][None]), n, axis=0)
    c_tx = pattern_field_world(opts.reader_pattern, opts.reader_polarization, r_reader, sp.k_tx[sl])
    g_rx = pattern_field_world(opts.tag_pattern, "V", r_tag, sp.k_rx[sl])
    amp = np.einsum("pr,prt,pt->p", np.conj(g_rx), sp.transfer[sl], c_tx)
    return amp * np.exp(-2j * np.pi * frequency_hz * sp.tau_s[sl]), sl


def match(la, ka, ra, lb, kb, rb, tol=1e-4):
    """For each path of a, the index of its copy in b (-1: none)."""
    out = np.full(len(la), -1, np.int64)
    for i in range(len(la)):
        ok = (np.abs(lb - la[i]) < tol) & np.all(np.abs(kb - ka[i]) < tol, axis=1) & \
             np.all(np.abs(rb - ra[i]) < tol, axis=1)
        j = np.flatnonzero(ok)
        if len(j):
            out[i] = j[0]
    return out


def db(x):
    with np.errstate(divide="ignore"):
        return 10 * np.log10(np.abs(x) ** 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs=2, default=[1, 2])
    ap.add_argument("--set", action="append", default=[], help="TraceOptions field=value")
    ap.add_argument("--top", type=int, default=15)
    ap.add_argument("--label-order", type=int, default=None,
                    help="label one-seed paths against the completion of this order (default: the tracer's)")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    import propagation as P
    import scenes
    from pipeline.apps.cli import resolve_target
    from pipeline.studyscene import trace_options
    from propagation.completion import complete_specular, large_planes
    from propagation.constants import SPEED_OF_LIGHT
    from propagation.pathsolve import trace_paths
    from propagation.patterns import as_pose6
    from propagation.sionna_scene import load_sionna_scene
    from propagation.tracing import tag_dipole_axes

    P.select_variant("llvm")
    cfg = resolve_target(None)
    scene = scenes.load(cfg.scene)
    opts = trace_options(cfg)
    for kv in args.set:
        k, v = kv.split("=", 1)
        cur = getattr(opts, k)
        opts = opts.replace(**{k: (v if isinstance(cur, str) else type(cur or 0)(float(v)) if not isinstance(cur, bool)
                                   else v.lower() in ("1", "true"))})
    f = cfg.frequency_hz
    thr = cfg.reader.link_budget(f).min_gain_db()
    poses = as_pose6(sparse_poses())
    tags, normals = scene.tags.positions_m, scene.tags.normals
    axes = tag_dipole_axes(normals, len(tags))
    uniq, inv = np.unique(poses[:, :3], axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    print(f"options: {opts}", flush=True)
    ps = {}
    for s in args.seeds:
        t0 = time.perf_counter()
        ps[s] = trace_paths(scene, uniq, tags, None, opts.replace(seed=s), frequency_hz=f).paths
        print(f"seed {s}: traced in {time.perf_counter() - t0:.1f} s", flush=True)
    # the completion's paths alone (deterministic): which missed paths it enumerates
    rt_scene = load_sionna_scene(scene, f, public_api=False)
    planes = large_planes(rt_scene, opts.completion_min_area_m2)
    order = min(opts.completion_order, opts.max_depth) if args.label_order is None else args.label_order
    t0 = time.perf_counter()
    comp = complete_specular(rt_scene, uniq, tags, order, planes, buffer_depth=max(order, opts.max_depth),
                             los=True) if order else None
    print(f"completion of order {order} ({len(planes)} planes): {time.perf_counter() - t0:.1f} s", flush=True)
    sa, sb = args.seeds
    rows = []
    missed = []  # (link, seed that has it, rel power dB, excess length m, in completion)
    copies = 0
    for i in range(len(poses)):
        u = inv[i]
        for j in range(len(tags)):
            amp, sl = {}, {}
            for s in args.seeds:
                amp[s], sl[s] = per_path_amplitudes(ps[s][u], tags, j, poses[i], opts, axes, f)
            ga, gb = (db(amp[s].sum()) for s in args.seeds)
            if max(ga, gb) < thr:
                continue
            A, B = ps[sa][u], ps[sb][u]
            la, lb = A.tau_s[sl[sa]] * SPEED_OF_LIGHT, B.tau_s[sl[sb]] * SPEED_OF_LIGHT
            mab = match(la, A.k_tx[sl[sa]], A.k_rx[sl[sa]], lb, B.k_tx[sl[sb]], B.k_rx[sl[sb]])
            mba = match(lb, B.k_tx[sl[sb]], B.k_rx[sl[sb]], la, A.k_tx[sl[sa]], A.k_rx[sl[sa]])
            for s, L in ((sa, la), (sb, lb)):
                K = (A if s == sa else B).k_tx[sl[s]]
                for p in range(len(L)):
                    d = (np.abs(L - L[p]) < 1e-3) & np.all(np.abs(K - K[p]) < 1e-3, axis=1)
                    copies += int(d.sum() - 1)
            common_a = amp[sa][mab >= 0].sum()
            common_b = amp[sb][mba >= 0].sum()
            union = amp[sa].sum() + amp[sb][mba < 0].sum()
            d_los = np.linalg.norm(tags[j] - uniq[u])
            tot = max(np.abs(amp[sa].sum()) ** 2, np.abs(amp[sb].sum()) ** 2)
            strongest = -np.inf
            if comp is not None:
                C = comp[u]
                cs_amp, cs_sl = per_path_amplitudes(C, tags, j, poses[i], opts, axes, f)
                lc = C.tau_s[cs_sl] * SPEED_OF_LIGHT
            for s, m_, L in ((sa, mab, la), (sb, mba, lb)):
                X = A if s == sa else B
                for p in np.flatnonzero(m_ < 0):
                    rel = 10 * np.log10(np.abs(amp[s][p]) ** 2 / tot)
                    inc = False
                    if comp is not None and len(lc):
                        inc = bool(match(L[p:p + 1], X.k_tx[sl[s]][p:p + 1], X.k_rx[sl[s]][p:p + 1], lc,
                                         C.k_tx[cs_sl], C.k_rx[cs_sl])[0] >= 0)
                    missed.append((len(rows), s, rel, L[p] - d_los, inc))
                    strongest = max(strongest, rel)
            rows.append((i, j, ga, gb, db(common_a), db(common_b), db(union), len(la), len(lb),
                         int((mab < 0).sum()), int((mba < 0).sum()), strongest))
    r = np.array(rows, float)
    ga, gb, ca, cb, un = r[:, 2], r[:, 3], r[:, 4], r[:, 5], r[:, 6]
    d_all, d_common = np.abs(ga - gb), np.abs(ca - cb)

    def pp(x):
        x = x[np.isfinite(x)] if np.any(~np.isfinite(x)) else x
        return f"p50 {np.percentile(x, 50):.3f} p95 {np.percentile(x, 95):.3f} max {x.max():.2f} dB"

    print(f"readable links: {len(r)} (threshold {thr:.2f} dB)")
    print(f"|gain a - gain b|, all paths:          {pp(d_all)}")
    print(f"|gain a - gain b|, common paths only:  {pp(d_common)}")
    print(f"|gain a - union|:                      {pp(np.abs(ga - un))}")
    print(f"|gain b - union|:                      {pp(np.abs(gb - un))}")
    print(f"paths per link: mean {r[:, 7].mean():.1f} / {r[:, 8].mean():.1f}; found by one seed only: "
          f"mean {r[:, 9].mean():.2f} / {r[:, 10].mean():.2f} per link")
    print(f"near-copies inside one seed's link (1e-3 m / 1e-3): {copies}")
    mm = np.array([(k, s, rel, ex, inc) for k, s, rel, ex, inc in missed], float).reshape(-1, 5)
    if len(mm):
        for lo, hi in ((-np.inf, -30), (-30, -20), (-20, -10), (-10, np.inf)):
            sel = (mm[:, 2] >= lo) & (mm[:, 2] < hi)
            print(f"one-seed paths with power {lo:>5} .. {hi:>4} dB of the link: {int(sel.sum()):5d}, "
                  f"in the completion's set {int(mm[sel, 4].sum())}, excess length median "
                  f"{np.median(mm[sel, 3]) if sel.any() else np.nan:.2f} m")
    big = np.argsort(-d_all)[:args.top]
    print("largest |dgain| links: pose tag | gain a, b | common a, b | union | paths a, b | one-seed a, b | "
          "strongest one-seed path rel. dB")
    for k in big:
        i, j = int(r[k, 0]), int(r[k, 1])
        ms = mm[mm[:, 0] == k]
        desc = "; ".join(f"s{int(s)} {rel:.1f} dB +{ex:.2f} m{' C' if inc else ''}"
                         for _, s, rel, ex, inc in ms[np.argsort(-ms[:, 2])][:3])
        print(f"  {i:3d} {j:3d} | {ga[k]:7.2f} {gb[k]:7.2f} | {ca[k]:7.2f} {cb[k]:7.2f} | {un[k]:7.2f} | "
              f"{int(r[k, 7])} {int(r[k, 8])} | {int(r[k, 9])} {int(r[k, 10])} | {desc}")
    # the p95 if the one-seed paths weaker than X dB were dropped from both: which paths matter
    print(f"p95 |dgain| of all links: {np.percentile(d_all, 95):.3f} dB; links with no one-seed path: "
          f"{int(((r[:, 9] + r[:, 10]) == 0).sum())}, their p95 "
          f"{np.percentile(d_all[(r[:, 9] + r[:, 10]) == 0], 95) if ((r[:, 9] + r[:, 10]) == 0).any() else np.nan:.3f} dB")


if __name__ == "__main__":
    main()
