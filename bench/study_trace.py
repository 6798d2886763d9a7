"""The cold default study against naive bare-Sionna tracing of its links, in one run.

Prints, from one run on this machine:

1. the whole default study from an empty propagation cache (``rfidstudy run`` in a
   subprocess, a fresh temporary cache and run directory), once per tracing setting
   (default: chains shared between positions within 1 m, 3,000 rays each; direct: every
   antenna position shoots 30,000 rays alone with Sionna's PathSolver, ``tracing.method =
   "direct"``, no completion), with its wall time, the stages' times and
   the peak memory of its stages;
2. the *naive* tracing of the same links with bare Sionna RT (the tours, the truth's tag
   sites and free-space view; not the RSSI field maps, which are radio maps, nor the
   opt-in oracle): every antenna position of
   the two tours a transmitter and every tag a receiver, batches of 50 positions; the
   truth stage's tag-site and free-space links one antenna pose per call, as the study
   traces them (kinder to the naive side than a batch against the union); depth 5, 3e4
   rays, the paths' ``a`` fetched to NumPy;
3. the ratio study / naive, the links per second of both, and the seed-to-seed noise of
   the truth on the evaluation tour (seeds 1 and 2 of ``trace_links`` with the study's
   tracing options, completion included, per setting): p50 /
   p95 |delta gain| over readable links (either seed >= the budget's minimum readable
   gain), p95 over weak links (within 30 dB below it) and the flipped read decisions;
   the default against direct (same seed).

Where a CUDA device is usable, a GPU section follows with the same measurements on it
(``--backend cuda``; ``--backend llvm`` for the CPU section alone). Every study and naive
trace runs in its own process with an empty Dr.Jit kernel cache
(a fresh ``$HOME``: Dr.Jit keeps compiled kernels in ``~/.drjit``), as on a new machine;
``--warm-kernels`` keeps this machine's. The naive tracing is run twice: devices placed
as Sionna's API documents (positions as lists of numbers) and as the study places them
(kinder: fewer kernels to compile).

Takes about 20 minutes on 2 cores. Usage::

    .venv/bin/python bench/study_trace.py [--skip-study] [--skip-noise]
        [--config configs/paper_scale.toml] [--naive arrays]
    # the warehouse-scale case, from a finished run; naive time scaled from 12 calls per tour
    .venv/bin/python bench/study_trace.py --config configs/warehouse_large.toml --skip-study \
        --run RUN_DIR --skip-noise --naive arrays --naive-calls 12 [--naive-cap sionna] \
        [--naive-rays 30000]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import runfiles

ROOT = Path(__file__).resolve().parents[1]


#: Tracing settings compared: label -> config overrides (``--set``).
DIRECT = {"tracing.method": "direct"}


def settings(direct: bool = True) -> dict:
    out = {"default (shared 1 m, 3e3 rays)": {}}
    if direct:
        out["direct (3e4 rays, PathSolver alone)"] = DIRECT
    return out


def run_study(out: Path, cache: Path, overrides: dict, home: Path | None = None,
              config: Path | None = None) -> dict:
    """One cold study (the default, or ``config``); wall time, stage times and peak stage
    memory. ``home``: run with this ``$HOME``, i.e. an empty Dr.Jit kernel cache as on a
    new machine."""
    cmd = [sys.executable, "-m", "pipeline", "run"]  # no entry-point script needed
    if config is not None:
        cmd.append(str(Path(config).resolve()))
    cmd += ["--out", str(out), "--no-progress"]
    for k, v in overrides.items():
        cmd += ["--set", f"{k}={v}"]
    env = {**os.environ, "RFIDSTUDY_CACHE": str(cache)}
    if home is not None:
        env.update(_empty_kernel_cache(home))
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"study failed ({' '.join(cmd)}):\n{proc.stderr[-3000:]}")
    stages = {p.stem: json.loads(p.read_text()) for p in sorted((out / "stages").glob("*.json"))}
    return {"wall_s": wall,
            "stages_s": {k: v.get("elapsed_s", 0.0) for k, v in stages.items()},
            "peak_gb": max(v.get("peak_rss_mib", 0.0) for v in stages.values()) / 1024}


def study_links(run: Path) -> list[tuple[str, np.ndarray, np.ndarray, int]]:
    """The link groups the study traced: (name, antenna positions (k, 3), receivers
    (r, 3), positions per solver call)."""
    tags = pd.read_parquet(run / runfiles.SCENE_TAGS).set_index("tag_id")
    groups = []
    for name, fname in (("train tour", runfiles.TRAIN_READS), ("eval tour", runfiles.EVAL_READS)):
        r = pd.read_parquet(run / fname)
        r = r[r["in_range"]]
        pos = np.unique(r[["true_ant_x_m", "true_ant_y_m", "true_ant_z_m"]].to_numpy(float), axis=0)
        ids = sorted(r["tag_id"].unique())
        groups.append((name, pos, tags.loc[ids, ["x_m", "y_m", "z_m"]].to_numpy(float), 50))
    st = np.load(run / runfiles.SITE_TRUTH)
    for i, pose in enumerate(st["antenna_poses"]):
        cols = st["traced"][i]
        if cols.any():
            groups.append(("tag sites", pose[None, :3], st["positions_m"][cols], 1))
    for f in sorted((run / "truth").glob("rho_points_*.npz")):
        z = np.load(f)
        free = np.isfinite(z["gain_db"])
        groups.append(("free-space view", z["antenna_pose"][None, :3], z["points_m"][free], 1))
    return groups


def naive_trace(scene, groups, max_depth: int, samples: int, placement: str = "api",
                max_calls: int | None = None, cap: str = "rays") -> dict:
    """Bare Sionna PathSolver over the link groups; seconds and links per group name.

    ``placement="api"`` places devices as Sionna's documentation does (positions as
    lists of numbers, Sionna's own endpoint arrays: Dr.Jit compiles kernels per position
    and per device index on an empty kernel cache); ``"arrays"`` as the study does
    (:func:`propagation.sionna_scene.device_point`, endpoints built in one go), kinder
    to the naive side.

    ``max_calls``: trace at most this many calls of each tour group, spread evenly along
    it, and scale its seconds by the positions of all its calls over those traced (a
    warehouse-scale study's naive tracing takes hours on 2 cores; a call's time grows
    with its positions, the receivers being the group's). The result says so:
    ``{name: (seconds, links, calls traced, calls)}``.

    ``cap``: ``PathSolver``'s ``max_num_paths_per_src``: ``"rays"`` ``samples * (max_depth
    + 1)`` (a smaller buffer, kinder to the naive side; with hundreds of receivers per call Sionna drops the candidates beyond it
    without a word, docs/physics.md), or ``"sionna"`` PathSolver's documented default (1e6,
    what a call that leaves it out gets)."""

    from propagation.sionna_scene import load_sionna_scene

    rt_scene = load_sionna_scene(scene, 865e6, public_api=placement == "api")
    return _naive_calls(rt_scene, groups, max_depth, samples, placement, max_calls, cap)


def _naive_calls(rt_scene, groups, max_depth: int, samples: int, placement: str,
                 max_calls: int | None = None, cap: str = "rays") -> dict:
    import sionna.rt as rt

    from propagation.sionna_scene import clear_devices, place_devices

    def place(src, tgt):
        if placement != "api":
            place_devices(rt_scene, src, tgt, polarization="V")
            return
        clear_devices(rt_scene)
        rt_scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
        rt_scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
        for k, p in enumerate(src):
            rt_scene.add(rt.Transmitter(f"tx{k}", position=[float(v) for v in p]))
        for k, p in enumerate(tgt):
            rt_scene.add(rt.Receiver(f"rx{k}", position=[float(v) for v in p]))

    solver = rt.PathSolver()
    caps = {} if cap == "sionna" else {"max_num_paths_per_src": samples * (max_depth + 1)}
    out: dict = {}
    for name, pos, rx, per_call in groups:
        starts = np.arange(0, len(pos), per_call)
        picked = starts
        if max_calls and per_call > 1 and len(starts) > max_calls:
            picked = starts[np.unique(np.linspace(0, len(starts) - 1, max_calls).round().astype(int))]
        sizes = [len(pos[c0:c0 + per_call]) for c0 in picked]
        times = []
        for c0 in picked:
            t0 = time.perf_counter()
            place(pos[c0:c0 + per_call], rx)
            paths = solver(rt_scene, max_depth=max_depth, samples_per_src=samples, **caps,
                           synthetic_array=True, los=True, specular_reflection=True, diffuse_reflection=False,
                           refraction=True, diffraction=False, seed=1)
            _ = paths.a[0].numpy()
            times.append(time.perf_counter() - t0)
        clear_devices(rt_scene)
        secs = sum(times)
        if len(picked) < len(starts) and len(picked) > 1:
            # the first call compiles the kernels (an empty cache): counted once; the
            # others scaled by positions to the calls not traced
            secs = times[0] + sum(times[1:]) * (len(pos) - sizes[0]) / sum(sizes[1:])
        s, n, k, c = out.get(name, (0.0, 0, 0, 0))
        out[name] = (s + secs, n + len(pos) * len(rx), k + len(picked), c + len(starts))
    return out


def _empty_kernel_cache(home: Path) -> dict:
    """Environment of a process starting from an empty Dr.Jit kernel cache in ``home``:
    Dr.Jit reads ``DRJIT_CACHE_DIR``, else ``$HOME/.drjit``; a fresh ``$HOME`` also
    empties matplotlib's font cache, as on a new machine."""
    home.mkdir(parents=True, exist_ok=True)
    return {"HOME": str(home), "DRJIT_CACHE_DIR": str(home / ".drjit")}


def naive_in_subprocess(run: Path, placement: str, home: Path | None, backend: str = "auto",
                        max_calls: int | None = None, rays: int | None = None,
                        cap: str = "rays") -> dict:
    """:func:`naive_trace` in a fresh process; ``home``: from an empty kernel cache there;
    ``backend``: the Dr.Jit backend there (``--backend``); ``max_calls``, ``cap``: see
    there; ``rays``: rays per source (default: the run's ``tracing.samples_per_src``)."""
    env = dict(os.environ)
    if home is not None:
        env.update(_empty_kernel_cache(home))
    proc = subprocess.run([sys.executable, __file__, "--naive-only", placement, "--backend", backend,
                           "--run", str(Path(run).resolve()),
                           *(["--naive-calls", str(max_calls)] if max_calls else []),
                           *(["--naive-rays", str(rays)] if rays else []), "--naive-cap", cap],
                          cwd=ROOT, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"naive tracing failed:\n{proc.stderr[-3000:]}")
    return {k: tuple(v) for k, v in json.loads(proc.stdout.strip().splitlines()[-1]).items()}


def seed_noise(scene, run: Path, overrides: dict, config: Path | None) -> tuple[dict, np.ndarray, float]:
    """trace_links on the evaluation tour with the study's tracing options (patterns,
    depth, rays, completion; the study ``config`` with ``overrides``, as ``rfidstudy run
    CONFIG --set KEY=VALUE`` resolves them), seeds 1 and 2 (fresh caches). Poses are
    (x, y, z, yaw): the default antennas are not tilted."""
    import propagation as P
    from pipeline.apps.cli import resolve_target
    from pipeline.studyscene import trace_options

    cfg = resolve_target(None if config is None else str(config),
                         [f"{k}={v}" for k, v in overrides.items()])
    tags = pd.read_parquet(run / runfiles.SCENE_TAGS).set_index("tag_id")
    r = pd.read_parquet(run / runfiles.EVAL_READS)
    ids = sorted(r["tag_id"].unique())
    tpos = tags.loc[ids, ["x_m", "y_m", "z_m"]].to_numpy(float)
    nrm = tags.loc[ids, ["nx", "ny", "nz"]].to_numpy(float)
    cols = ["true_ant_x_m", "true_ant_y_m", "true_ant_z_m", "true_ant_yaw_rad"]
    poses = r.drop_duplicates(cols[:3])[cols].to_numpy(float)
    gains, secs = {}, []
    for seed in (1, 2):
        with tempfile.TemporaryDirectory() as cd:
            t0 = time.perf_counter()
            opts = trace_options(cfg).replace(seed=seed)
            links = P.trace_links(scene, poses, tpos, opts, tag_normals=nrm, cache_dir=cd,
                                  frequency_hz=cfg.frequency_hz)
            secs.append(time.perf_counter() - t0)
        gains[seed] = links.gain_db
    return gains, np.asarray(secs), len(poses) * len(tpos)


def noise_row(a: np.ndarray, b: np.ndarray, threshold_db: float) -> str:
    top = np.maximum(a, b)
    readable = top >= threshold_db
    weak = (top >= threshold_db - 30.0) & ~readable
    with np.errstate(invalid="ignore"):
        d = np.abs(a - b)
    flips = int(((a >= threshold_db) != (b >= threshold_db)).sum())
    return (f"readable n={int(readable.sum())}: p50 {np.percentile(d[readable], 50):.2f} dB, "
            f"p95 {np.percentile(d[readable], 95):.2f} dB; weak n={int(weak.sum())}: "
            f"p95 {np.percentile(d[weak], 95):.1f} dB; flipped read decisions {flips}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-study", action="store_true", help="reuse --run instead of running studies")
    ap.add_argument("--run", type=Path, default=None, help="a finished default run (with --skip-study)")
    ap.add_argument("--skip-noise", action="store_true")
    ap.add_argument("--skip-direct", action="store_true",
                    help="leave out the direct 3e4-ray study (the old default; ~6 min on 2 cores)")
    ap.add_argument("--warm-kernels", action="store_true",
                    help="keep this machine's Dr.Jit kernel cache (~/.drjit); default: every "
                         "study and naive trace starts from an empty one, as on a new machine")
    ap.add_argument("--config", type=Path, default=None,
                    help="a study config (e.g. configs/paper_scale.toml) instead of the default")
    ap.add_argument("--naive", choices=("both", "api", "arrays"), default="both",
                    help="naive placements to trace (default both; one halves a long bench)")
    ap.add_argument("--backend", choices=("auto", "llvm", "cuda"), default="auto",
                    help="Dr.Jit backend of the studies and the naive tracing (auto: the CPU, "
                         "then the GPU in a section of its own where a CUDA device is usable)")
    ap.add_argument("--naive-calls", type=int, default=None,
                    help="trace at most this many naive calls per tour, spread along it, and "
                         "scale their time to the whole tour (warehouse scale: hours otherwise)")
    ap.add_argument("--naive-rays", type=int, default=None,
                    help="rays per source of the naive tracing (default: the study's "
                         "tracing.samples_per_src, 3e4 for the default study)")
    ap.add_argument("--naive-cap", choices=("rays", "sionna"), default="rays",
                    help="PathSolver's max_num_paths_per_src on the naive side: rays x "
                         "(depth + 1) (default; drops paths with hundreds of tags per call) "
                         "or Sionna's documented default, 1e6 (drops none at warehouse scale)")
    ap.add_argument("--naive-only", choices=("api", "arrays"), default=None,
                    help=argparse.SUPPRESS)  # internal: one naive trace, JSON on stdout
    args = ap.parse_args()
    if args.naive_rays is not None and args.naive_rays < 1:
        ap.error(f"--naive-rays must be >= 1, got {args.naive_rays}")
    warnings.simplefilter("ignore")
    import propagation as P
    import scenes
    from pipeline.apps.cli import resolve_target
    from pipeline.config import load_config

    if args.naive_only:
        if args.run is None:
            ap.error("--naive-only needs --run")
        P.select_variant(prefer=args.backend)
        # the run's own scene, depth and lone-position rays (3e4 for the default study)
        cfg = load_config(args.run / "config.toml")
        out = naive_trace(scenes.load(cfg.scene), study_links(args.run), cfg.tracing.max_depth,
                          args.naive_rays or cfg.tracing.samples_per_src, placement=args.naive_only,
                          max_calls=args.naive_calls, cap=args.naive_cap)
        print(json.dumps(out))
        return

    # select_variant finds libLLVM before Dr.Jit is imported: nothing imports it earlier
    variant = P.select_variant(prefer=args.backend)
    if args.backend == "auto" and variant == P.backend.CUDA_VARIANT:
        # the CPU section, then the GPU section, each in its own process (one variant each)
        failed = []
        for b, title in (("llvm", "CPU section (LLVM)"), ("cuda", "GPU section (CUDA)")):
            print(f"== {title} ==", flush=True)
            if subprocess.run([sys.executable, __file__, *sys.argv[1:], "--backend", b]).returncode:
                failed.append(title)
        if failed:
            raise SystemExit(f"failed: {', '.join(failed)}")
        return
    args.backend = "cuda" if variant == P.backend.CUDA_VARIANT else "llvm"
    print("backend:", variant, P.backend_info(), flush=True)
    backend = {"tracing.backend": args.backend}
    tmp = Path(tempfile.mkdtemp(prefix="study_trace_"))
    studies = {}
    runs = settings(direct=not args.skip_direct)
    what = "default study" if args.config is None else f"study {args.config.name}"
    if not args.skip_study:
        for label, overrides in runs.items():
            i = len(studies)
            s = run_study(tmp / f"run_{i}", tmp / f"cache_{i}", {**backend, **overrides},
                          home=None if args.warm_kernels else tmp / f"home_{i}", config=args.config)
            studies[label] = s
            st = ", ".join(f"{k} {v:.0f}" for k, v in s["stages_s"].items() if v >= 1.0)
            print(f"cold {what}, {label}: {s['wall_s']:.0f} s wall (stages [s]: {st}); "
                  f"peak stage memory {s['peak_gb']:.1f} GB", flush=True)
        run = tmp / "run_0"
    else:
        run = args.run or ROOT / "runs" / "default"
        man_path = run / "manifest.json"
        man = json.loads(man_path.read_text()) if man_path.is_file() else {}
        stages = man.get("stages") or {}
        ran_all = bool(stages) and all((v or {}).get("status") == "ran" for v in stages.values())
        if man.get("status") == "complete" and ran_all and man.get("elapsed_s"):
            # the finished run's own wall time: every stage ran in that invocation (its
            # propagation cache and Dr.Jit kernel cache as they were then)
            studies[f"the run in {run}, from its manifest"] = {"wall_s": float(man["elapsed_s"])}
            print(f"study {run}: {man['elapsed_s']:.0f} s wall, peak {man.get('peak_rss_mib', 0) / 1024:.1f} GiB "
                  "(its manifest; its kernel cache as it was)", flush=True)
        else:
            print(f"no ratio: {run} is not one complete invocation that ran every stage "
                  f"(status {man.get('status')!r})", flush=True)
    cfg = resolve_target(None if args.config is None else str(args.config))
    scene = scenes.load(cfg.scene)
    kernels = "this machine's kernel cache" if args.warm_kernels else "an empty kernel cache"
    for placement, how in (("api", "devices placed as Sionna's API documents"),
                           ("arrays", "devices placed as the study places them")):
        if args.naive not in ("both", placement):
            continue
        naive = naive_in_subprocess(run, placement,
                                    None if args.warm_kernels else tmp / f"home_naive_{placement}",
                                    args.backend, args.naive_calls, args.naive_rays, args.naive_cap)
        t_naive = sum(v[0] for v in naive.values())
        n_links = sum(v[1] for v in naive.values())
        traced = load_config(Path(run) / "config.toml").tracing  # what the naive side read
        rays = args.naive_rays or traced.samples_per_src
        cap = ("Sionna's default cap, 1e6" if args.naive_cap == "sionna"
               else f"cap {rays * (traced.max_depth + 1):,} per source")
        print(f"naive bare Sionna ({how}, {kernels}; {rays:,} rays, depth {traced.max_depth}, {cap}):")
        for name, (s, n, k, c) in naive.items():
            part = f", scaled from {k} of its {c} calls" if k < c else ""
            print(f"  {name}: {n} links in {s:.1f} s ({n / s:.0f} links/s{part})")
        scaled = any(v[2] < v[3] for v in naive.values())
        print(f"  all: {n_links} links in {t_naive:.1f} s ({n_links / t_naive:.0f} links/s)"
              f"{', scaled from the calls traced' if scaled else ''}", flush=True)
        for label, s in studies.items():
            print(f"RATIO study ({label}) / naive tracing of its links ({placement}"
                  f"{', naive scaled' if scaled else ''}): "
                  f"{s['wall_s'] / t_naive:.2f} ({s['wall_s']:.0f} s / {t_naive:.0f} s)", flush=True)
    if not args.skip_noise:
        thr = cfg.reader.link_budget(cfg.frequency_hz).min_gain_db()
        gains = {}
        print("evaluation tour; readable: gain >= %.2f dB" % thr)
        for label, overrides in runs.items():
            g, secs, n = seed_noise(scene, run, {**backend, **overrides}, args.config)
            gains[label] = g
            print(f"  {label}, seed 1 vs 2 ({secs.mean():.0f} s per trace, {n / secs.mean():.0f} links/s): "
                  f"{noise_row(g[1], g[2], thr)}", flush=True)
        ref = gains.get("direct (3e4 rays, PathSolver alone)")
        for label, g in gains.items() if ref is not None else ():
            if g is not ref:
                print(f"  {label} vs direct, seed 1: {noise_row(g[1], ref[1], thr)}")


if __name__ == "__main__":
    main()
