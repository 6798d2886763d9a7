"""Benchmark of propagation.trace_links / rssi_field on corridor_lab, with the convergence check.

Prints, from one run: links/s of trace_links (``method="direct"``) at the default ray budget, field cells/s of rssi_field,
peak memory (ru_maxrss: Dr.Jit allocates outside Python, tracemalloc would not see it),
the overhead of trace_links over a bare Sionna PathSolver call doing the same work, and the
convergence table (rays per source and depth vs error percentiles against a reference).

Usage: .venv/bin/python bench/trace.py [--quick]
"""

from __future__ import annotations

import argparse
import resource
import time
import warnings
from pathlib import Path

import numpy as np
from route_poses import route_poses  # bench/ is the script's own folder


def _scene():
    import scenes

    try:
        return scenes.load("corridor_lab")
    except Exception as exc:  # noqa: BLE001 - fall back to a plain corridor
        print(f"corridor_lab unavailable ({exc}); using a generated corridor")
        return scenes.corridor(length_m=25.0, width_m=2.4, height_m=3.0)


def _maxrss_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="8 antenna positions instead of 20")
    ap.add_argument("--full", action="store_true", help="reference with 1e6 rays/source (~5 min)")
    ap.add_argument("--cache-positions", type=int, default=100,
                    help="antenna positions traced cold then loaded warm for the cache line")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    import propagation as P

    # the convergence check and the overhead are those of Sionna's PathSolver alone (the
    # public-API tracer); the study's shared tracer is measured by bench/study_trace.py
    DIRECT = P.TraceOptions(method="direct")  # noqa: N806 - a constant of this run
    from propagation.tracing import DEFAULT_MAX_DEPTH, DEFAULT_SAMPLES_PER_SRC

    print("backend:", P.select_variant(), P.backend_info())
    scene = _scene()
    tags = scene.tags.positions_m
    normals = scene.tags.normals
    n_src = 8 if args.quick else 20
    poses = route_poses(scene, n_src)
    print(f"scene {scene.name}: {len(tags)} tags, {n_src} antenna positions, bounds {scene.bounds_m.round(2).tolist()}")

    # warm-up (JIT compilation of the kernels) so that timings below are steady-state
    P.trace_links(scene, poses[:2], tags[:2], DIRECT.replace(max_depth=1, samples_per_src=1000))

    # --- convergence check ------------------------------------------------------------
    ref_depth, ref_spp = (6, 1_000_000) if args.full else (6, 300_000)
    t0 = time.perf_counter()
    ref = P.trace_links(scene, poses, tags, DIRECT.replace(max_depth=ref_depth, samples_per_src=ref_spp,
                                                           memory_budget_bytes=6 * 1024**3),
                        tag_normals=normals)
    t_ref = time.perf_counter() - t0
    print(f"\nreference: depth {ref_depth}, {ref_spp:.0e} rays/source, {t_ref:.1f} s, "
          f"mean paths/link {ref.n_paths.mean():.0f}, maxrss {_maxrss_gb():.2f} GB")
    # "relevant" links: reference gain > -55 dB, i.e. within 13 dB of the default tag
    # threshold (-42.15 dB); elsewhere errors sit in deep multipath fades that decide nothing.
    # "flips": links whose detection (gain >= -42.15 dB) differs from the reference.
    rel = ref.gain_db > -55.0
    thr = P.LinkBudget().min_gain_db()

    def row(label, ls, dt):
        err = np.abs(ls.gain_db - ref.gain_db).ravel()
        e_rel = np.abs(ls.gain_db - ref.gain_db)[rel]
        p50, p95, p99 = np.percentile(err, [50, 95, 99])
        flips = int(np.sum((ls.gain_db >= thr) != (ref.gain_db >= thr)))
        rate = ls.gain.size / dt if dt > 0 else float("nan")
        print(f"{label:>15} {dt:>7.2f} {rate:>8.1f} {p50:>7.2f} {p95:>7.2f} {p99:>7.2f} "
              f"{np.percentile(e_rel, 50):>7.2f} {np.percentile(e_rel, 95):>7.2f} {e_rel.max():>7.2f} {flips:>5}")

    print(f"relevant links (ref > -55 dB): {rel.sum()} of {rel.size}")
    print(f"{'depth/rays':>15} {'time_s':>7} {'links/s':>8} {'p50_dB':>7} {'p95_dB':>7} {'p99_dB':>7} "
          f"{'rel_p50':>7} {'rel_p95':>7} {'rel_max':>7} {'flips':>5}")
    t0 = time.perf_counter()
    ref7 = P.trace_links(scene, poses, tags, DIRECT.replace(max_depth=ref_depth, samples_per_src=ref_spp,
                                                            memory_budget_bytes=6 * 1024**3, seed=7),
                         tag_normals=normals)
    row("ref, seed 7", ref7, time.perf_counter() - t0)
    depths = (3, 4, 5, 6)
    spps = (10_000, 30_000, 100_000)
    for depth in depths:
        for spp in spps:
            t0 = time.perf_counter()
            ls = P.trace_links(scene, poses, tags, DIRECT.replace(max_depth=depth, samples_per_src=spp),
                               tag_normals=normals)
            dt = time.perf_counter() - t0
            row(f"{depth} / {spp:.0e}", ls, dt)
    # refraction off (paths through walls dropped): every ray then reflects, so more
    # specular paths are found per ray -- it is slower, not faster, and not the same gains
    for depth, spp in ((DEFAULT_MAX_DEPTH, DEFAULT_SAMPLES_PER_SRC), (6, ref_spp)):
        t0 = time.perf_counter()
        ls = P.trace_links(scene, poses, tags, DIRECT.replace(max_depth=depth, samples_per_src=spp,
                                                              refraction=False, memory_budget_bytes=6 * 1024**3),
                           tag_normals=normals)
        row(f"{depth}/{spp:.0e} no-refr", ls, time.perf_counter() - t0)

    # --- throughput and overhead at the defaults -------------------------------------------
    import sionna.rt as rt

    from propagation.sionna_scene import load_sionna_scene

    t0 = time.perf_counter()
    ls = P.trace_links(scene, poses, tags, DIRECT, tag_normals=normals)
    t_ours = time.perf_counter() - t0
    s = load_sionna_scene(scene, 865e6, public_api=True)
    s.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="VH")
    s.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="VH")
    for k, p in enumerate(poses):
        s.add(rt.Transmitter(f"tx{k}", position=[float(v) for v in p[:3]]))
    for k, p in enumerate(tags):
        s.add(rt.Receiver(f"rx{k}", position=[float(v) for v in p]))
    t0 = time.perf_counter()
    paths = rt.PathSolver()(s, max_depth=DEFAULT_MAX_DEPTH, samples_per_src=DEFAULT_SAMPLES_PER_SRC,
                            max_num_paths_per_src=DEFAULT_SAMPLES_PER_SRC * (DEFAULT_MAX_DEPTH + 1))
    a = paths.a[0].numpy()
    _ = paths.tau.numpy(), paths.theta_t.numpy(), paths.phi_t.numpy(), paths.theta_r.numpy(), paths.phi_r.numpy()
    t_bare = time.perf_counter() - t0
    print(f"\ndefaults depth {DEFAULT_MAX_DEPTH}, {DEFAULT_SAMPLES_PER_SRC:.0e} rays/source: "
          f"{ls.gain.size} links in {t_ours:.2f} s = {ls.gain.size / t_ours:.1f} links/s "
          f"(Sionna part {ls.trace_s:.2f} s); bare PathSolver + numpy() {t_bare:.2f} s "
          f"(max paths {a.shape[-1]}); overhead ratio ours/bare = {t_ours / t_bare:.2f}")
    # receivers per call: the same sources against 4x the receivers (tags moved 5-30 cm
    # into the corridor); the cost ratio tells whether receivers or rays dominate
    rng = np.random.default_rng(0)
    more = np.concatenate([tags] + [tags + normals * rng.uniform(0.05, 0.3, (len(tags), 1)) for _ in range(3)])
    t0 = time.perf_counter()
    P.trace_links(scene, poses, more, DIRECT)
    t_more = time.perf_counter() - t0
    print(f"receivers per call: {len(tags)} -> {len(more)} receivers, {t_ours:.2f} s -> {t_more:.2f} s "
          f"(cost ratio {t_more / t_ours:.2f} for {len(more) / len(tags):.0f}x receivers)")
    # pattern re-application alone (cache hit path): orientation sweep
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        P.trace_links(scene, poses, tags, DIRECT, tag_normals=normals, cache_dir=tmp)
        rot = poses.copy()
        rot[:, 3] += 0.5
        t0 = time.perf_counter()
        hit = P.trace_links(scene, rot, tags, DIRECT, tag_normals=normals, cache_dir=tmp)
        t_hit = time.perf_counter() - t0
    print(f"cache hit with new orientations: {hit.gain.size} links in {t_hit:.3f} s "
          f"({hit.gain.size / t_hit:.0f} links/s, solver calls {hit.n_solver_calls})")
    # cache load alone (packed cache: one NPZ + JSON index per solver call), more positions
    from propagation.pathcache import PathCache, settings_key

    many = route_poses(scene, args.cache_positions)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        cold = P.trace_links(scene, many, tags, DIRECT, tag_normals=normals, cache_dir=tmp)
        t_cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        warm = P.trace_links(scene, many, tags, DIRECT, tag_normals=normals, cache_dir=tmp)
        t_warm = time.perf_counter() - t0
        sub = next(p for p in Path(tmp).iterdir() if p.is_dir())
        assert sub.name == settings_key(scene.content_hash(), {k: cold.settings[k] for k in (
            "frequency_hz", "max_depth", "samples_per_src", "seed", "los", "specular_reflection",
            "refraction", "diffuse_reflection", "diffraction", "direct_algorithm")})
        uniq = np.unique(many[:, :3], axis=0)
        t0 = time.perf_counter()
        loaded = PathCache(sub).load(uniq)
        t_load = time.perf_counter() - t0
        n_files = len(list(sub.iterdir()))
    assert all(sp is not None for sp in loaded) and warm.n_solver_calls == 0
    print(f"cache ({len(uniq)} positions x {len(tags)} tags, {n_files} files): cold trace_links "
          f"{t_cold:.1f} s, warm trace_links {t_warm:.2f} s ({len(uniq) / t_warm:.0f} positions/s); "
          f"cache load positions/s {len(uniq) / t_load:.0f} ({1e3 * t_load / len(uniq):.2f} ms/position)")

    # --- rssi_field ----------------------------------------------------------------------
    t0 = time.perf_counter()
    f = P.rssi_field(scene, poses[n_src // 2], cell_size_m=0.1, samples_per_tx=1_000_000, max_depth=5,
                     include_walls=False)
    t_plane = time.perf_counter() - t0
    t0 = time.perf_counter()
    fw = P.rssi_field(scene, poses[n_src // 2], cell_size_m=0.5, samples_per_tx=100_000, max_depth=5,
                      include_walls=True, wall_samples_per_tx=10_000_000)
    t_wall = time.perf_counter() - t0
    print(f"rssi_field plane: {f.plane_gain.size} cells (0.1 m, 1e6 rays, depth 5) in {t_plane:.2f} s = "
          f"{f.plane_gain.size / t_plane:.0f} cells/s; walls: {fw.wall_gain.size} triangles "
          f"(1e7 rays) in {t_wall:.2f} s = {fw.wall_gain.size / t_wall:.0f} triangles/s")
    print(f"peak memory (ru_maxrss): {_maxrss_gb():.2f} GB")


if __name__ == "__main__":
    main()
