"""Run a placement study: every candidate's replicates, the optimiser's trials, the answer.

Directory layout of ``rfidstudy placement FILE --out DIR``::

    DIR/placement.json                 the file as read, the candidates (marks DIR as a
                                       placement directory: nothing else is written into
                                       a non-empty directory without it)
    DIR/candidates/<name>/<k>/         replicate k of candidate <name>: a study run directory
                                       (k >= replicates: the confirmation's fresh seeds)
    DIR/placement/summary.parquet      one row per candidate (see pipeline.apps.placement.summary)
    DIR/placement/ranking.csv          the ranked table
    DIR/placement/answer.json          recommendation, margin, comparisons, Pareto front
    DIR/placement/figures/*.png        heatmap, Pareto front, bands, marginals, read maps
    DIR/placement/report.html

Replicate k of every candidate has the seed :func:`pipeline.apps.replicates.replicate_seed`
gives it (the same for all candidates: paired comparisons) and all studies share the
propagation cache, so what one candidate traced another reads: orientation-only
candidates trace nothing new, candidates at one height share every antenna position
of the tours. A study that finished is skipped stage by stage on a rerun (its run
directory is a cache), so a rerun computes nothing and an interrupted placement study
resumes where it stopped; the optimiser's sampler is seeded, so it proposes the same
trials again and finds them done.

Each study runs only as far as the objectives need (:func:`.objectives.needed_stage`):
a placement ranked and constrained by inventory objectives stops its studies after
the ``reads`` stage and fits no model. A failure stops the placement at its second
candidate (:class:`PlacementStopped`): two candidates failing at one stage with one
exception type is the study's problem, not a mount's, and the rest would fail alike.
Where that stage serves only a ``pareto`` objective, the placement goes on without it
(the remaining studies stop before it; ``answer.json``'s ``dropped`` says why).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pipeline.apps.placement.candidates import Candidate, candidates_of
from pipeline.apps.placement.objectives import OBJECTIVES, needed_stage, traced_counts
from pipeline.apps.placement.optimise import optimise
from pipeline.apps.placement.results import PlacementResult, candidate_dir
from pipeline.apps.placement.spec import PlacementSpec
from pipeline.apps.placement.summary import summarise, top_candidates, write_outputs
from pipeline.apps.replicates import replicate_seed
from pipeline.apps.studypool import run_studies
from pipeline.config import ConfigError, config_to_dict, replace_path
from pipeline.engine.runstore import (
    HOUSEKEEPING,
    RunStore,
    UnsafePathError,
    atomic_write_json,
    check_no_writer,
)
from pipeline.outdirs import check_marker_file, own_marker
from pipeline.stages import resolve_cache_dir, stage_names

__all__ = ["PlacementResult", "PlacementStopped", "ProgressEvent", "candidate_dir",
           "position_waves", "run_placement"]

log = logging.getLogger(__name__)

MARKER = "placement.json"


class PlacementStopped(ConfigError):
    """Two candidates' studies failed alike at a stage the ranking needs: the placement
    stopped instead of running the remaining candidates into the same failure."""


@dataclass
class ProgressEvent:
    """One candidate finished (all its replicates).

    Attributes
    ----------
    candidate : str
    done, total : int
        Candidates finished / planned so far (the optimiser adds trials as it goes).
    elapsed_s : float
        Wall time of this candidate's replicates (0 when they were all cached).
    n_sources_traced : int
        Antenna positions its studies traced afresh (0: everything from the cache).
    failed : int
        Its replicates that failed.
    n_stages_run : int
        Study stages its replicates computed (0: everything was in their run directories).
    remaining_s : float or None
        Estimate of the time still to run (mean candidate time x candidates left).
    """

    candidate: str
    done: int
    total: int
    elapsed_s: float
    n_sources_traced: int
    failed: int
    remaining_s: float | None
    n_stages_run: int = 0


def _prepare_dir(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a directory")
    marker = out / MARKER
    # the lock files alone (a first run stopped before its marker) are not someone's files
    theirs = out.is_dir() and any(p.name not in HOUSEKEEPING for p in out.iterdir())
    check_marker_file(out, MARKER)  # a link is refused by name, never followed
    if theirs and not own_marker(marker, "placement", ("source", "file", "replicates", "candidates")):
        raise ConfigError(f"--out {out}: a non-empty directory that is not a placement study "
                          f"(no {MARKER}); choose a new or empty directory")
    for sub in ("candidates", "placement"):
        p = out / sub
        if os.path.islink(p):
            raise UnsafePathError(f"{p} is a symbolic link: a placement directory's folders "
                                  "must be its own")
    out.mkdir(parents=True, exist_ok=True)


def _replicate_config(spec: PlacementSpec, cand: Candidate, k: int, cache_dir: str):
    cfg = cand.config(spec.base)
    cfg = replace_path(cfg, "replicates.n", 1)
    cfg = replace_path(cfg, "tracing.cache_dir", cache_dir)
    return replace_path(cfg, "seed", replicate_seed(spec.base.seed, k))


def position_key(cand: Candidate) -> tuple:
    """The antenna positions of a candidate (robot frame, 1 um), orientation left out: the
    propagation cache is keyed by position, so candidates with one key share traces."""
    return tuple(sorted((round(a.x_m, 6), round(a.y_m, 6), round(a.z_m, 6))
                        for a in cand.antennas))


def position_waves(cands: list[Candidate]) -> list[list[Candidate]]:
    """``cands`` in two waves: the first candidate of each set of antenna positions, then
    the rest. Studies run side by side (``workers`` > 1) would otherwise trace the same
    positions twice at once, each before the other's traces reach the cache; in waves the
    siblings find every position traced."""
    seen: set = set()
    first, rest = [], []
    for c in cands:
        key = position_key(c)
        (rest if key in seen else first).append(c)
        seen.add(key)
    return [w for w in (first, rest) if w]


def _cause(error: str, limit: int = 300) -> str:
    """A failed study's error without the engine's frame ("stage 'x' failed: ... (earlier
    stages' outputs ... intact ...)"): the cause, at most ``limit`` characters."""
    text = error.split(" (earlier stages' outputs", 1)[0]
    if text.startswith("stage '") and "' failed: " in text:
        text = text.split("' failed: ", 1)[1]
    return text if len(text) <= limit else text[:limit - 3] + "..."


class _Runner:
    """Runs candidates' replicates in batches and keeps the progress books."""

    def __init__(self, spec, out, workers, scheduler, client, progress):
        self.spec, self.out = spec, out
        self.workers, self.scheduler, self.client = workers, scheduler, client
        self.progress = progress
        self.cache = str(resolve_cache_dir(spec.base))
        self.done: dict[str, dict] = {}
        self.confirmed: dict[str, dict] = {}  # candidates run on the fresh replicates
        self.expected = 0  # candidates this study will run (grid + presets + trials)
        self.wall_s = 0.0  # wall time spent running batches
        self.n_run = 0  # candidates finished in those batches
        s = spec.settings
        #: the last stage the ranking needs (primary and constraints) and the last one any
        #: objective asked for needs (with the pareto pair): what the studies run up to
        self.required = needed_stage([s.primary, *(c.objective for c in s.constraint)])
        self.upto = needed_stage([s.primary, *(c.objective for c in s.constraint), *s.pareto])
        self.failures: dict[tuple, dict[str, str]] = {}  # (stage, kind) -> {candidate: error}
        self.dropped: list[str] = []  # why the studies stopped earlier than asked
        self.stop: str | None = None

    def _failed(self, name: str, row: dict) -> bool:
        """Book a failed replicate; True when its kind repeats in a second candidate (the
        pending studies are then cancelled)."""
        stage, kind = row.get("stage"), row.get("kind")
        seen = self.failures.setdefault((stage, kind), {})
        seen.setdefault(name, str(row.get("error") or ""))
        if len(seen) < 2:
            return False
        first = _cause(next(iter(seen.values())))
        cands = " and ".join(list(seen)[:2])
        order = stage_names()
        if stage in order and order.index(stage) > order.index(self.required):
            if self.upto != self.required:
                keys = [k for k in self.spec.settings.pareto
                        if order.index(OBJECTIVES[k].stage) > order.index(self.required)]
                self.dropped.append(
                    f"stage {stage} failed ({kind}) in candidates {cands}: {first}; "
                    f"{', '.join(keys)} not computed, the remaining studies stop after "
                    f"{self.required}")
                log.warning("placement: %s", self.dropped[-1])
                self.upto = self.required
                return True
            return False
        self.stop = (f"placement stopped: {'stage ' + stage if stage else 'a study'} failed "
                     f"with {kind} in candidates {cands} (the ranking by "
                     f"{self.spec.settings.primary} needs it): {first}")
        return True

    def run(self, cands: list[Candidate]) -> None:
        """Run ``cands``' replicates not done yet: one candidate per set of antenna
        positions first, then their orientation-only siblings (:func:`position_waves`)."""
        todo = [c for c in cands if c.name not in self.done]
        if not todo:
            return
        self.expected = max(self.expected, len(self.done) + len(todo))
        for wave in self._waves(todo):
            self._run_batch(wave)

    def confirm(self, cands: list[Candidate]) -> None:
        """Run ``cands`` on fresh replicates ``R .. 2R - 1`` (R = ``replicates``): seeds
        that took no part in selecting them (:attr:`confirmed` books them)."""
        n = self.spec.settings.replicates
        todo = [c for c in cands if c.name not in self.confirmed]
        for wave in self._waves(todo):
            self._run_batch(wave, range(n, 2 * n), self.confirmed)

    def _waves(self, todo: list[Candidate]) -> list[list[Candidate]]:
        """The batches ``todo`` runs in: :func:`position_waves`, or with one local worker
        (studies one after the other, in the order given, in this process) the waves in
        order as one batch: the siblings still find their positions traced."""
        waves = position_waves(todo)
        if self.workers == 1 and not (self.scheduler or self.client):
            return [[c for w in waves for c in w]]
        return waves

    def _run_batch(self, todo: list[Candidate], ks=None, book: dict | None = None) -> None:
        if self.stop:
            raise PlacementStopped(self.stop)

        ks = list(range(self.spec.settings.replicates) if ks is None else ks)
        book = self.done if book is None else book
        n = len(ks)
        args, owner = [], []
        for c in todo:
            for k in ks:
                run_dir = candidate_dir(self.out, c.name, k)
                args.append((config_to_dict(_replicate_config(self.spec, c, k, self.cache)),
                             str(run_dir)))
                owner.append(c.name)
        books: dict[str, dict] = {c.name: {} for c in todo}
        t0 = time.monotonic()
        batch_done = [0]

        def on_done(i: int, row: dict) -> bool:
            name = owner[i]
            b = books[name]
            b[i] = row
            stop = row.get("status") != "complete" and self._failed(name, row)
            if len(b) < n:
                return stop
            rows = list(b.values())
            elapsed = float(sum(r.get("elapsed_s") or 0.0 for r in rows
                                if r.get("status") == "complete"))
            traced = sum(traced_counts(candidate_dir(self.out, name, k))["n_sources_traced"]
                         for k in ks)
            failed = sum(r.get("status") != "complete" for r in rows)
            book[name] = {"elapsed_s": elapsed, "failed": failed,
                          "errors": [r.get("error") for r in rows if r.get("error")]}
            batch_done[0] += 1
            # wall time per finished candidate so far (batches run their studies side by
            # side, so this is the pace, not one candidate's time) x candidates left
            per = (self.wall_s + time.monotonic() - t0) / (self.n_run + batch_done[0])
            eta = per * max(0, self.expected - len(self.done) - len(self.confirmed))
            if self.progress:
                ran = int(sum(r.get("stages_ran") or 0 for r in rows))
                label = name if book is self.done else f"{name} (confirmation)"
                self.progress(ProgressEvent(label, len(self.done) + len(self.confirmed),
                                            self.expected, elapsed, traced, failed, eta, ran))
            return stop

        rows = run_studies(args, scheduler=self.scheduler, workers=self.workers or None,
                           client=self.client, on_done=on_done, command="placement", upto=self.upto,
                           summarise=False)  # the objectives read the run directories
        # a worker of an earlier, killed run still writing a replicate: nothing is ranked
        check_no_writer([a[1] for a in args], "ranking the candidates", rows)
        self.wall_s += time.monotonic() - t0
        self.n_run += batch_done[0]
        if self.stop:
            raise PlacementStopped(self.stop)
        cancelled = [c for c in todo if c.name not in book]
        if cancelled:  # cancelled when a pareto-only stage was dropped: run them without it
            self._run_batch(cancelled, ks, book)


def run_placement(spec: PlacementSpec, out_dir: str | Path, *, workers: int | None = None,
                  scheduler: str | None = None, client=None,
                  progress: Callable[[ProgressEvent], None] | None = None) -> PlacementResult:
    """Run (or resume) a placement study and write its answer.

    Parameters
    ----------
    spec : PlacementSpec
        From :func:`~.spec.load_placement`.
    out_dir : path
        New, empty, or an earlier placement directory of this study.
    workers : int, optional
        Local worker processes (default: the file's ``workers``, else 2 at most).
    scheduler : str, optional
        Dask scheduler address: the studies run on that cluster.
    client : distributed.Client, optional
    progress : callable, optional
        Called with a :class:`ProgressEvent` as each candidate finishes.

    Raises
    ------
    ConfigError
        The directory is not a placement directory; no candidate finished.
    pipeline.engine.runstore.RunDirLocked
        Another process runs a placement study in it, or still writes a candidate's
        study (a worker of an earlier, killed run): nothing is ranked.
    """
    try:
        out = Path(out_dir).resolve()
    except (OSError, RuntimeError) as exc:  # a symbolic link loop (ELOOP), no permission
        raise ConfigError(f"--out {out_dir}: cannot be used as a placement directory: {exc}") from None
    _prepare_dir(out)
    # the run directories' own lock: one writer, the holder named to a second one
    with RunStore(out).lock(command="rfidstudy placement"):
        cands = candidates_of(spec)
        runner = _Runner(spec, out, workers or spec.settings.workers or None, scheduler, client,
                         progress)
        _write_marker(out, spec, cands)
        runner.expected = len(cands) + spec.settings.optimise.n_trials
        runner.run(cands)
        if spec.settings.optimise.n_trials:
            trials = optimise(spec, runner, out)
            for t in trials:  # a trial rounded onto an earlier one is that candidate
                if t.name not in {c.name for c in cands}:
                    cands.append(t)
            _write_marker(out, spec, cands)
        # the candidates on disk (earlier runs' too): none may still be written while ranked
        check_no_writer([d for d in sorted(out.glob("candidates/*/*"))  # never through a link
                         if not d.is_symlink() and not d.parent.is_symlink()], "ranking the candidates")
        top, summary = [], None
        if spec.settings.confirm_top:
            summary = summarise(spec, out, cands)  # the selection's: reused for the answer
            top = top_candidates(spec, cands, spec.settings.confirm_top, summary)
            if len(top) >= 2:
                runner.expected += len(top)
                try:
                    runner.confirm(top)
                except PlacementStopped as exc:  # the selection's answer still stands
                    runner.dropped.append(f"the confirmation on fresh replicates: {exc}")
                    top = []
        return write_outputs(spec, out, cands, runner.done, upto=runner.upto,
                             dropped=runner.dropped, confirmed=[c.name for c in top],
                             summary=summary)


def _write_marker(out: Path, spec: PlacementSpec, cands: list[Candidate]) -> None:
    atomic_write_json(out / MARKER, {
        "tool": "rfidstudy", "kind": "placement",
        "source": spec.source,
        "file": spec.raw,
        "replicates": spec.settings.replicates,
        "candidates": [{"name": c.name, "origin": c.origin, "values": c.values,
                        "antennas": [a.__dict__ for a in c.antennas]} for c in cands],
    })
