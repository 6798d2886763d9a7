"""The NumPy pre-test of the image-method completion: which (link, chain) pairs can be
specular paths at all.

:func:`propagation.completion.complete_specular` enumerates every chain of reflections
over the scene's large planes (:func:`chains`); before Sionna's image method solves them
exactly, :func:`candidate_chains` drops the (link, chain) pairs that cannot be paths even
on the unbounded planes, clipped to their bounding boxes and to the cells their
triangles cover (:func:`_pretest`, in float32). Blocks of pairs run side by side in threads (NumPy releases the GIL in its
array loops) and are joined in block order.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from propagation.plane_cover import covered
from propagation.planes import Planes

__all__ = ["BOX_SLACK_M", "candidate_chains", "chains", "iter_candidate_chains"]

#: Slack on the planes' bounding boxes in the pre-test, m: far above float32 rounding of
#: the reflection point (~1e-5 m at 100 m from the sources' mean), so a box test never
#: drops a chain Sionna would accept (the side tests may, within ~1e-5 m of a corner:
#: see :func:`_pretest`).
BOX_SLACK_M = 1e-3
#: (link, chain) pairs tested at once in the NumPy pre-test (~10 MB of float32 temporaries).
_BLOCK = 1 << 18
#: Most threads running pre-test blocks side by side: a block's temporaries are ~10 MB
#: in float32 plus its images in float64 (up to ~25 MB at order 3 with one link per
#: source), so 8 threads hold at most ~300 MB.
_PRETEST_MAX_THREADS = 8
#: The environment variable capping a study's side-by-side work (pipeline.parallel's).
_WORKERS_ENV = "RFIDSTUDY_WORKERS"


def chains(n_planes: int, order: int) -> np.ndarray:
    """All plane sequences of ``order`` reflections with no plane twice in a row, (c, order)."""
    ch = np.arange(n_planes, dtype=np.int64)[:, None]
    for _ in range(order - 1):
        nxt = np.tile(np.arange(n_planes, dtype=np.int64), len(ch))
        ch = np.repeat(ch, n_planes, axis=0)
        keep = nxt != ch[:, -1]
        ch = np.column_stack([ch[keep], nxt[keep]])
    return ch


def candidate_chains(planes: Planes, src, tgt, link_src, link_tgt, min_order: int,
                max_order: int) -> tuple[np.ndarray, np.ndarray]:
    """Every (link, chain) of ``min_order..max_order`` reflections that passes
    :func:`_pretest`: link rows (c,) int64 and chains (c, max_order) int64, -1 padded.

    All of :func:`iter_candidate_chains` joined; a caller that can work block by block
    should iterate instead: on a large scene the candidates run to hundreds of millions.
    """
    found = list(iter_candidate_chains(planes, src, tgt, link_src, link_tgt, min_order, max_order))
    if not found:
        return np.zeros(0, np.int64), np.zeros((0, max_order), np.int64)
    return np.concatenate([f[0] for f in found]), np.concatenate([f[1] for f in found])


def iter_candidate_chains(planes: Planes, src, tgt, link_src, link_tgt, min_order: int,
                          max_order: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The candidates of :func:`candidate_chains`, one block at a time, in block order.

    Chains go through the pre-test in blocks of about ``_BLOCK`` pairs; NumPy releases
    the GIL in the pre-test's array loops, so blocks run side by side in threads
    (:func:`_pretest_threads`) and are yielded in block order: the same candidates in the
    same order as one block after the other. At most two blocks per thread are pending
    at a time, so memory stays bounded however many candidates pass (a 30 m x 50 m
    warehouse of shelving racks: ~3,500 per link, 16 GB when joined before solving).

    Yields
    ------
    (numpy.ndarray, numpy.ndarray)
        Link rows (b,) int64 and chains (b, max_order) int64, -1 padded, of one block.
    """
    step = max(1, _BLOCK // max(1, len(link_src)))
    blocks = []
    for k in range(min_order, max_order + 1):
        ch = chains(len(planes), k) if len(planes) else np.zeros((0, k), np.int64)
        blocks += [ch[c0:c0 + step] for c0 in range(0, len(ch), step)]

    def passed(block):
        li, ci = _pretest(planes, src, tgt, link_src, link_tgt, block)
        return li, np.pad(block[ci], ((0, 0), (0, max_order - block.shape[1])), constant_values=-1)

    n_threads = _pretest_threads(len(blocks))
    pool = ThreadPoolExecutor(n_threads)
    pending: deque = deque()
    try:
        for block in blocks:
            pending.append(pool.submit(passed, block))
            if len(pending) >= 2 * n_threads:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:  # an error, Ctrl-C or a consumer that stops early: drop the blocks not started
        pool.shutdown(wait=True, cancel_futures=True)


def _pretest_threads(n_blocks: int) -> int:
    """Threads for ``n_blocks`` pre-test blocks: the CPUs this process may use, within a
    positive ``RFIDSTUDY_WORKERS`` (a sweep's share of the CPUs for each of its studies),
    at most ``_PRETEST_MAX_THREADS``, at least one."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    cap = os.environ.get(_WORKERS_ENV, "").strip()
    if cap.isdecimal() and int(cap) >= 1:
        cpus = min(cpus, int(cap))
    return max(1, min(int(n_blocks), cpus, _PRETEST_MAX_THREADS))


def _pretest(planes: Planes, src, tgt, link_src, link_tgt, chains) -> tuple[np.ndarray, np.ndarray]:
    """(link, chain) pairs that are paths over the unbounded planes, clipped to their boxes.

    Backtracks from the target toward the source images like Sionna's image method, on
    infinite planes: each segment must cross its plane (ends strictly on opposite sides)
    at a point inside the plane's bounding box (with ``BOX_SLACK_M``) and, where the
    planes carry a :class:`~propagation.plane_cover.PlaneCover`, in a cell its triangles
    cover. A necessary condition only: Sionna then checks the triangles and occlusion.

    In float32 (the images in float64): the last reflection dense over (link, chain),
    the earlier ones on the pairs it kept (at order 2 on warehouse_large about a tenth,
    the planes' rasters dropping the reflection points off their triangles; without the
    rasters, with most pairs kept, compacting costs more than testing them all again).
    Coordinates are taken relative to the sources' mean, so float32 rounding scales with
    the scene's extent (~1e-5 m at 100 m), far below the 1 mm slack: a pair Sionna could
    accept is dropped only where a reflection point lies within ~1e-5 m of another
    plane of its chain (a corner, where Sionna's own float32 test is undecided too).
    """
    k = chains.shape[1]
    origin = src.mean(axis=0) if len(src) else np.zeros(3)
    src, tgt = src - origin, tgt - origin  # float32 errors then scale with the scene, not its offset
    off_all = planes.offset_m - planes.normal @ origin
    lo_all = planes.lo_m - origin - BOX_SLACK_M
    hi_all = planes.hi_m - origin + BOX_SLACK_M
    nrm, off = planes.normal[chains], off_all[chains]
    img = np.empty((len(src), len(chains), k + 1, 3))
    img[:, :, 0] = src[:, None, :]
    for j in range(k):
        prev = img[:, :, j]
        dist = np.einsum("scx,cx->sc", prev, nrm[:, j]) - off[:, j]
        img[:, :, j + 1] = prev - 2.0 * dist[..., None] * nrm[None, :, j]
    f32 = np.float32
    # the last reflection (the one the target sees), dense over (link, chain)
    j = k - 1
    p = chains[:, j]
    n, o = planes.normal[p], off_all[p]
    lo, hi = lo_all[p].astype(f32), hi_all[p].astype(f32)
    im = img[:, :, j + 1]
    b = (np.einsum("scx,cx->sc", im, n) - o).astype(f32)[link_src]
    a = (tgt @ n.T - o).astype(f32)[link_tgt]
    ok = (a * b) < 0.0
    r = np.divide(a, a - b, where=ok, out=np.zeros_like(a))
    tgt32 = tgt.astype(f32)
    pt = []
    for ax in range(3):
        x = np.ascontiguousarray(im[:, :, ax], dtype=f32)[link_src]
        t_ax = tgt32[link_tgt, ax][:, None]
        x -= t_ax
        x *= r
        x += t_ax
        ok &= (x >= lo[:, ax]) & (x <= hi[:, ax])
        pt.append(x)
    if planes.cover is not None:  # on the plane's triangles, not only in its box
        ok &= covered(planes.cover, p, pt, origin)
    li, ci = (v.astype(np.int64) for v in np.nonzero(ok))
    # the earlier reflections on the pairs still in, one plane after the other (same
    # float32 operations per pair as densely, so the same answers)
    if k > 1:
        pt = [x[li, ci] for x in pt]
    for j in range(k - 2, -1, -1):
        p = chains[:, j]
        n, o = planes.normal[p], off_all[p]
        im = img[:, :, j + 1]
        s_of = link_src[li]
        b = (np.einsum("scx,cx->sc", im, n) - o).astype(f32)[s_of, ci]
        n32 = n.astype(f32)[ci]
        a = pt[0] * n32[:, 0] + pt[1] * n32[:, 1] + pt[2] * n32[:, 2]
        a -= o.astype(f32)[ci]
        keep = (a * b) < 0.0
        li, ci, s_of, a, b = li[keep], ci[keep], s_of[keep], a[keep], b[keep]
        pt = [x[keep] for x in pt]
        r = a / (a - b)
        lo, hi = lo_all[p[ci]].astype(f32), hi_all[p[ci]].astype(f32)
        keep = np.ones(len(li), bool)
        new = []
        for ax in range(3):
            x = np.ascontiguousarray(im[:, :, ax], dtype=f32)[s_of, ci]
            x -= pt[ax]
            x *= r
            x += pt[ax]
            keep &= (x >= lo[:, ax]) & (x <= hi[:, ax])
            new.append(x)
        if planes.cover is not None:
            keep &= covered(planes.cover, p[ci], new, origin)
        li, ci = li[keep], ci[keep]
        pt = [x[keep] for x in new]
    return li, ci
