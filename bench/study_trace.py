"""The cold default study against naive bare-Sionna tracing of its links, in one run.

Prints, from one run on this machine:

1. the whole default study from an empty propagation cache (``rfidstudy run`` in a
   subprocess, a fresh temporary cache and run directory), once per tracing setting
   (default: chains shared between positions within 1 m, 3,000 rays each; direct: every
   antenna position shoots 30,000 rays alone, the default before sharing; pooled, with
   ``--lattice``: rays shot from a lattice), with its wall time, the stages' times and
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
   pooled against direct (same seed) as its extrapolation error.

Takes about 20 minutes on 2 cores. Usage::

    .venv/bin/python bench/study_trace.py [--lattice 0.25] [--skip-study] [--skip-noise]
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

ROOT = Path(__file__).resolve().parents[1]


#: Tracing settings compared: label -> config overrides (``--set``).
DIRECT = {"tracing.share_radius_m": 0.0}


def settings(lattice_m: float | None, direct: bool = True) -> dict:
    out = {"default (shared 1 m, 3e3 rays)": {}}
    if direct:
        out["direct (3e4 rays)"] = DIRECT
    if lattice_m:
        out[f"pooled {lattice_m:g} m"] = {**DIRECT, "tracing.lattice_spacing_m": lattice_m}
    return out


def run_study(out: Path, cache: Path, overrides: dict) -> dict:
    """One cold default study; wall time, stage times and peak stage memory."""
    cmd = [str(Path(sys.executable).with_name("rfidstudy")), "run", "--out", str(out), "--no-progress"]
    for k, v in overrides.items():
        cmd += ["--set", f"{k}={v}"]
    env = {**os.environ, "RFIDSTUDY_CACHE": str(cache)}
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
    tags = pd.read_parquet(run / "scene" / "tags.parquet").set_index("tag_id")
    groups = []
    for name, fname in (("train tour", "reads.parquet"), ("eval tour", "eval_reads.parquet")):
        r = pd.read_parquet(run / fname)
        r = r[r["in_range"]]
        pos = np.unique(r[["true_ant_x_m", "true_ant_y_m", "true_ant_z_m"]].to_numpy(float), axis=0)
        ids = sorted(r["tag_id"].unique())
        groups.append((name, pos, tags.loc[ids, ["x_m", "y_m", "z_m"]].to_numpy(float), 50))
    st = np.load(run / "truth" / "site_truth.npz")
    for i, pose in enumerate(st["antenna_poses"]):
        cols = st["traced"][i]
        if cols.any():
            groups.append(("tag sites", pose[None, :3], st["positions_m"][cols], 1))
    for f in sorted((run / "truth").glob("rho_points_*.npz")):
        z = np.load(f)
        free = np.isfinite(z["gain_db"])
        groups.append(("free-space view", z["antenna_pose"][None, :3], z["points_m"][free], 1))
    return groups


def naive_trace(scene, groups, max_depth: int, samples: int) -> dict:
    """Bare Sionna PathSolver over the link groups; seconds and links per group name."""
    import sionna.rt as rt

    from propagation.sionna_scene import clear_devices, load_sionna_scene, place_devices

    rt_scene = load_sionna_scene(scene, 865e6)
    solver = rt.PathSolver()
    out: dict = {}
    for name, pos, rx, per_call in groups:
        t0 = time.perf_counter()
        for c0 in range(0, len(pos), per_call):
            place_devices(rt_scene, pos[c0:c0 + per_call], rx, polarization="V")
            paths = solver(rt_scene, max_depth=max_depth, samples_per_src=samples,
                           max_num_paths_per_src=samples * (max_depth + 1), synthetic_array=True,
                           los=True, specular_reflection=True, diffuse_reflection=False,
                           refraction=True, diffraction=False, seed=1)
            _ = paths.a[0].numpy()
        clear_devices(rt_scene)
        s, n = out.get(name, (0.0, 0))
        out[name] = (s + time.perf_counter() - t0, n + len(pos) * len(rx))
    return out


def seed_noise(scene, run: Path, overrides: dict) -> tuple[dict, np.ndarray, float]:
    """trace_links on the evaluation tour with the study's tracing options (patterns,
    depth, rays, completion), seeds 1 and 2 (fresh caches). Poses are (x, y, z, yaw): the
    default antennas are not tilted."""
    import propagation as P
    from pipeline.config import config_from_mapping
    from pipeline.stages.common import trace_options

    cfg = config_from_mapping(_nested(overrides))
    tags = pd.read_parquet(run / "scene" / "tags.parquet").set_index("tag_id")
    r = pd.read_parquet(run / "eval_reads.parquet")
    ids = sorted(r["tag_id"].unique())
    tpos = tags.loc[ids, ["x_m", "y_m", "z_m"]].to_numpy(float)
    nrm = tags.loc[ids, ["nx", "ny", "nz"]].to_numpy(float)
    cols = ["true_ant_x_m", "true_ant_y_m", "true_ant_z_m", "true_ant_yaw_rad"]
    poses = r.drop_duplicates(cols[:3])[cols].to_numpy(float)
    gains, secs = {}, []
    for seed in (1, 2):
        with tempfile.TemporaryDirectory() as cd:
            t0 = time.perf_counter()
            opts = trace_options(cfg)
            links = P.trace_links(scene, poses, tpos, tag_normals=nrm, seed=seed, cache_dir=cd,
                                  frequency_hz=cfg.frequency_hz, **opts)
            secs.append(time.perf_counter() - t0)
        gains[seed] = links.gain_db
    return gains, np.asarray(secs), len(poses) * len(tpos)


def _nested(overrides: dict) -> dict:
    out: dict = {}
    for key, value in overrides.items():
        section, name = key.split(".")
        out.setdefault(section, {})[name] = value
    return out


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
    ap.add_argument("--lattice", type=float, default=None, help="also a pooled study at this lattice spacing [m]")
    ap.add_argument("--skip-study", action="store_true", help="reuse --run instead of running studies")
    ap.add_argument("--run", type=Path, default=None, help="a finished default run (with --skip-study)")
    ap.add_argument("--skip-noise", action="store_true")
    ap.add_argument("--skip-direct", action="store_true",
                    help="leave out the direct 3e4-ray study (the old default; ~6 min on 2 cores)")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    import propagation as P
    import scenes
    from pipeline.config import StudyConfig

    print("backend:", P.select_variant(), P.backend_info(), flush=True)
    tmp = Path(tempfile.mkdtemp(prefix="study_trace_"))
    studies = {}
    runs = settings(args.lattice, direct=not args.skip_direct)
    if not args.skip_study:
        for label, overrides in runs.items():
            s = run_study(tmp / f"run_{len(studies)}", tmp / f"cache_{len(studies)}", overrides)
            studies[label] = s
            st = ", ".join(f"{k} {v:.0f}" for k, v in s["stages_s"].items() if v >= 1.0)
            print(f"cold default study, {label}: {s['wall_s']:.0f} s wall (stages [s]: {st}); "
                  f"peak stage memory {s['peak_gb']:.1f} GB", flush=True)
        run = tmp / "run_0"
    else:
        run = args.run or ROOT / "runs" / "default"
    scene = scenes.load("corridor_lab")
    cfg = StudyConfig()
    groups = study_links(run)
    naive = naive_trace(scene, groups, cfg.tracing.max_depth, 30_000)
    t_naive = sum(s for s, _ in naive.values())
    n_links = sum(n for _, n in naive.values())
    for name, (s, n) in naive.items():
        print(f"naive bare Sionna, {name}: {n} links in {s:.1f} s ({n / s:.0f} links/s)")
    print(f"naive bare Sionna, all: {n_links} links in {t_naive:.1f} s ({n_links / t_naive:.0f} links/s)")
    for label, s in studies.items():
        print(f"RATIO cold study ({label}) / naive tracing of its links: {s['wall_s'] / t_naive:.2f} "
              f"({s['wall_s']:.0f} s / {t_naive:.0f} s)")
    if not args.skip_noise:
        thr = cfg.reader.link_budget(cfg.frequency_hz).min_gain_db()
        gains = {}
        print("evaluation tour; readable: gain >= %.2f dB" % thr)
        for label, overrides in runs.items():
            g, secs, n = seed_noise(scene, run, overrides)
            gains[label] = g
            print(f"  {label}, seed 1 vs 2 ({secs.mean():.0f} s per trace, {n / secs.mean():.0f} links/s): "
                  f"{noise_row(g[1], g[2], thr)}", flush=True)
        ref = gains.get("direct (3e4 rays)")
        for label, g in gains.items() if ref is not None else ():
            if g is not ref:
                print(f"  {label} vs direct, seed 1: {noise_row(g[1], ref[1], thr)}")


if __name__ == "__main__":
    main()
