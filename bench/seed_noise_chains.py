# ruff: noqa: E402  (a measurement script: imports after the warnings filter and the path)
"""Which chains one seed finds and the other not, on bench/seed_noise.py's sparse poses.

Per sparse position of corridor_lab: Sionna's shoot-and-bounce alone (N rays, default
30,000, no sharing, no completion), seeds 1 and 2, every valid path with its chain
(interaction types, shapes); paths matched across the seeds by length and directions
(1e-4). Prints the p95 of |dgain| over readable links if the one-seed paths of a class
were found by both seeds (what a deterministic enumeration of that class would leave),
for classes of the completion (pure reflections up to order k on planes of at least some
area) and chains with refractions; then the one-seed paths by depth and refractions,
the shapes of the strong ones (> -20 dB of the link) and the strongest.

Usage::

    .venv/bin/python bench/seed_noise_chains.py [N]
"""
import sys
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

warnings.simplefilter("ignore")
sys.path.insert(0, str(Path(__file__).resolve().parent))
from seed_noise import sparse_poses

import propagation as P
import scenes
from pipeline.apps.cli import resolve_target
from pipeline.studyscene import trace_options
from propagation.completion import large_planes, plane_lookup
from propagation.constants import SPEED_OF_LIGHT
from propagation.patterns import as_pose6, dipole_rotation, pattern_field_world, pose_rotation
from propagation.sionna_internals import (
    collect_paths,
    shape_pointers,
    shoot_candidates,
    solve_paths,
)
from propagation.sionna_paths import points
from propagation.sionna_scene import clear_devices, load_sionna_scene, place_devices
from propagation.tracing import tag_dipole_axes

N = int(sys.argv[1]) if len(sys.argv) > 1 else 30000
seeds = (1, 2)
P.select_variant("llvm")
cfg = resolve_target(None)
scene = scenes.load(cfg.scene)
opts = trace_options(cfg)
f = cfg.frequency_hz
thr = cfg.reader.link_budget(f).min_gain_db()
poses = as_pose6(sparse_poses())
tags, normals = scene.tags.positions_m, scene.tags.normals
axes = tag_dipole_axes(normals, len(tags))
uniq, inv = np.unique(poses[:, :3], axis=0, return_inverse=True)
inv = inv.reshape(-1)
rt = load_sionna_scene(scene, f, public_api=False)
ptrs = shape_pointers(rt.mi_scene)
names = {int(p): s.id() for p, s in zip(ptrs, rt.mi_scene.shapes(), strict=True)}
areas = {int(p): s.surface_area() for p, s in zip(ptrs, rt.mi_scene.shapes(), strict=True)}
print("shapes:", {names[p]: round(float(areas[p][0] if hasattr(areas[p], '__len__') else areas[p]), 1) for p in names})


def trace(u, seed):
    place_devices(rt)
    pos_mi, tgt_mi = points(uniq[u:u + 1]), points(tags)
    cand = shoot_candidates(rt.mi_scene, pos_mi, tgt_mi, samples_per_src=N, max_depth=opts.max_depth,
                            refraction=True, seed=seed)
    keys, tgt = cand.keys, cand.target
    out = {k: [] for k in ("src", "tgt", "a", "tau", "k_tx", "k_rx")}
    buf, valid = solve_paths(rt, cand.take(np.arange(cand.n_rows)), pos_mi, tgt_mi, 1, len(tags), validity=True)
    collect_paths(buf, out)
    clear_devices(rt)
    o = {k: np.concatenate(v) for k, v in out.items()}
    o["keys"] = keys[valid]
    assert np.array_equal(o["tgt"], tgt[valid])
    return o


def amp(o, sel, pose, j):
    n = len(sel)
    c = pattern_field_world(opts.reader_pattern, opts.reader_polarization,
                            np.repeat(pose_rotation(pose[None]), n, 0), o["k_tx"][sel])
    g = pattern_field_world(opts.tag_pattern, "V", np.repeat(dipole_rotation(axes[j][None]), n, 0), o["k_rx"][sel])
    a = np.einsum("pr,prt,pt->p", np.conj(g), o["a"][sel], c)
    return a * np.exp(-2j * np.pi * f * o["tau"][sel])


def desc(key):
    d = len(key) // 3
    t, s = key[:d], key[d:2 * d]
    parts = []
    for k in range(d):
        if t[k] == 0:
            break
        parts.append(("R" if t[k] == 1 else "T" if t[k] == 4 else str(t[k])) + ":" + names.get(int(s[k]), "?"))
    return parts


lookups = {A: plane_lookup(rt, large_planes(rt, A)) for A in (1.0, 0.8, 0.5, 0.4, 0.0)}
print({A: len(large_planes(rt, A)) for A in lookups})
D = opts.max_depth
preds = {
    "completion now: R<=3 on >=1 m2": lambda fl: fl["R3_1.0"],
    "+ R<=3 on >=0.8 m2": lambda fl: fl["R3_0.8"],
    "+ R<=3 on >=0.5 m2": lambda fl: fl["R3_0.5"],
    "+ R<=3 on >=0.4 m2": lambda fl: fl["R3_0.4"],
    "+ R<=2 on >=0.4 m2, R3 on >=1 m2": lambda fl: fl["R3_1.0"] or fl["R2_0.4"],
    "+ R<=3 on all planes": lambda fl: fl["R3_0.0"],
    "+ R<=4 on all planes": lambda fl: fl["R4_0.0"],
    "+ R<=5 on all planes": lambda fl: fl["R5_0.0"],
    "R<=3 >=1 m2 + any with T": lambda fl: fl["R3_1.0"] or fl["T"],
    "R<=3 all planes + any with T": lambda fl: fl["R3_0.0"] or fl["T"],
    "R<=3 all + T<=5 whose R-part<=3": lambda fl: fl["R3_0.0"] or (fl["T"] and fl["nR"] <= 3),
    "everything": lambda fl: True,
}
cf_rows = []
stats = Counter()
wstats = Counter()  # (class) -> count of strong one-seed paths
d_all = []
t0 = time.perf_counter()
tr = {}
for u in range(len(uniq)):
    tr[u] = {s: trace(u, s) for s in seeds}
print(f"traced {len(uniq)} positions x 2 seeds at {N} rays in {time.perf_counter() - t0:.0f} s", flush=True)
examples = []
for i in range(len(poses)):
    u = inv[i]
    A, B = tr[u][1], tr[u][2]
    for j in range(len(tags)):
        sa, sb = np.flatnonzero(A["tgt"] == j), np.flatnonzero(B["tgt"] == j)
        aa, ab = amp(A, sa, poses[i], j), amp(B, sb, poses[i], j)
        ga, gb = (10 * np.log10(max(abs(x.sum()) ** 2, 1e-30)) for x in (aa, ab))
        if max(ga, gb) < thr:
            continue
        d_all.append(abs(ga - gb))
        la, lb = A["tau"][sa] * SPEED_OF_LIGHT, B["tau"][sb] * SPEED_OF_LIGHT
        tot = max(abs(aa.sum()) ** 2, abs(ab.sum()) ** 2)
        link_one = []
        for X, sx, lx, ax, Y, sy, ly in ((A, sa, la, aa, B, sb, lb), (B, sb, lb, ab, A, sa, la)):
            for p in range(len(sx)):
                ok = (np.abs(ly - lx[p]) < 1e-4) & np.all(np.abs(Y["k_tx"][sy] - X["k_tx"][sx[p]]) < 1e-4, axis=1)
                if ok.any():
                    continue
                rel = 10 * np.log10(abs(ax[p]) ** 2 / tot)
                key = X["keys"][sx[p]][None]
                ty, sh, pr = key[:, :D], key[:, D:2 * D], key[:, 2 * D:]
                fl = {f"R{o}_{A}": bool(lookups[A].covered(ty, sh, pr, o)[0]) for A in lookups for o in (2, 3, 4, 5)}
                fl["T"] = bool((ty == 4).any())
                fl["nR"] = int((ty == 1).sum())
                link_one.append((X is A, ax[p], fl))
                parts = desc(X["keys"][sx[p]])
                depth = len(parts)
                nref = sum(x.startswith("T") for x in parts)
                shapes = "+".join(sorted(set(x.split(":")[1] for x in parts)))
                band = "strong(>-20dB)" if rel > -20 else "weak"
                stats[(band, depth, nref)] += 1
                if rel > -20:
                    wstats[shapes] += 1
                    examples.append((rel, i, j, " ".join(parts), lx[p] - np.linalg.norm(tags[j] - uniq[u])))
        cf_rows.append((aa.sum(), ab.sum(), link_one))
d_all = np.array(d_all)
for name, pr_ in preds.items():
    dd = []
    for ha, hb, one in cf_rows:
        for in_a, a_, fl in one:
            if pr_(fl):
                if in_a:
                    hb = hb + a_
                else:
                    ha = ha + a_
        dd.append(abs(10 * np.log10(abs(ha) ** 2 / abs(hb) ** 2)))
    print(f"  if one-seed paths of [{name}] were found by both: p95 {np.percentile(dd, 95):.3f} dB, p50 {np.percentile(dd, 50):.3f}")
print(f"readable links {len(d_all)}: p50 {np.percentile(d_all, 50):.3f} p95 {np.percentile(d_all, 95):.3f} dB")
print("one-seed paths by (band, depth, refractions):")
for k in sorted(stats):
    print("  ", k, stats[k])
print("strong one-seed paths by shapes involved:")
for k, v in wstats.most_common(20):
    print("  ", v, k)
print("strongest one-seed paths:")
for e in sorted(examples, reverse=True)[:25]:
    print(f"   {e[0]:6.1f} dB pose {e[1]:3d} tag {e[2]:2d} excess {e[4]:6.2f} m  {e[3]}")
