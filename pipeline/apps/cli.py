"""The ``rfidstudy`` command line (typer).

::

    rfidstudy run [CONFIG.toml | SCENE] --out runs/x   # the whole study, cached and resumable
    rfidstudy figures RUN_DIR                          # redraw figures + report from saved files
    rfidstudy figures RUN_DIR --format pdf --dpi 300 --only baselines   # figures for a paper
    rfidstudy compare RUN_A RUN_B ... --out DIR        # headline numbers of several runs side by side
    rfidstudy report RUN_DIR                           # rewrite report.html only
    rfidstudy sweep SWEEP.toml --out sweeps/x [--scheduler tcp://host:8786] [--workers N]
    rfidstudy placement PLACEMENT.toml --out runs/placement [--workers N | --scheduler ADDR]
    rfidstudy export RUN --format csv --out DIR                # the tour as a recording
    rfidstudy calibrate STUDY.toml --recording REC --out DIR   # the reader fitted to a recording
    rfidstudy scenes list | show NAME [--png top.png]
    rfidstudy config [CONFIG.toml]                     # print the resolved (or reference) config

Errors are one line on stderr (``error: ...``, naming the file, key or value) with exit
status 2 for a bad config, scene or run directory and 1 for a failed stage; Ctrl-C
during ``run`` exits 130 after naming the stage it interrupted.
"""

from __future__ import annotations

import contextlib
import json
import logging
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from pipeline import runfiles
from pipeline.apps.clicommon import WRITE_ERRNOS, fail, fail_os
from pipeline.apps.cliscenes import scenes_app
from pipeline.apps.export import export_recording
from pipeline.apps.targets import resolve_target
from pipeline.config import (
    ConfigError,
    config_to_toml,
    reference_config_toml,
)
from pipeline.engine.preflight import check_before_run
from pipeline.engine.runstore import RunDirError, RunStore, is_run_dir
from pipeline.engine.study import StageError, StudyInterrupted
from pipeline.engine.tracetasks import check_scheduler
from pipeline.outdirs import check_output_dir, mark_output_dir
from pipeline.recording.config import recording_overrides

__all__ = ["app", "resolve_target"]  # resolve_target: pipeline.apps.targets, re-exported

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Ray-traced UHF RFID sensor-model study (Cicirelli, Milella & Di Paola 2011).")
app.add_typer(scenes_app, name="scenes")

log = logging.getLogger("pipeline.apps.cli")


def _setup_logging(verbose: bool) -> None:
    from rich.logging import RichHandler

    root = logging.getLogger()
    if not any(isinstance(h, RichHandler) for h in root.handlers):
        handler = RichHandler(show_path=False, rich_tracebacks=False)
        handler.setFormatter(logging.Formatter("%(message)s"))
        root.addHandler(handler)
    for h in root.handlers:
        if isinstance(h, RichHandler):
            h.setLevel(logging.DEBUG if verbose else logging.WARNING)
    root.setLevel(logging.WARNING)
    # the console shows progress bars and warnings, INFO and DEBUG lines only with -v; the
    # project's loggers pass INFO so that run.log (pipeline.engine.runlog) holds every INFO line
    for name in ("pipeline", "scenes", "propagation", "fuzzymodel"):
        logging.getLogger(name).setLevel(logging.DEBUG if verbose else logging.INFO)


@app.command()
def run(
    target: Annotated[str | None, typer.Argument(
        help="Study TOML, or a scene (bundled name, scene.toml, Mitsuba XML, or a ROS map "
             "YAML: run with the map-scale profile). Default: the default study on the "
             "bundled 'corridor_lab' scene.")] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Run directory.")] = Path("runs/default"),
    set_: Annotated[list[str] | None, typer.Option(
        "--set", "-s", help="Override a config key, e.g. --set training.epochs=10 (repeatable).")] = None,
    backend: Annotated[str | None, typer.Option(
        help="Dr.Jit variant: auto (CUDA if a GPU is usable, else LLVM), cuda or llvm. "
             "Default: tracing.backend of the config ('auto').")] = None,
    force: Annotated[list[str] | None, typer.Option(
        help="Re-run this stage even if cached (repeatable).")] = None,
    progress: Annotated[bool, typer.Option(help="Show progress bars.")] = True,
    force_dir: Annotated[bool, typer.Option(
        "--force-dir", help="Run into a non-empty --out directory that is not a run directory "
                            "(its other files are left alone).")] = False,
    replicates: Annotated[int | None, typer.Option(
        "--replicates", "-r", help="Independent replicates of the study (sets replicates.n): "
        "each its own seed stream, run into OUT/replicates/<k>/, pooled with 95 % intervals "
        "in OUT/metrics.json and OUT/report.html.")] = None,
    scheduler: Annotated[str | None, typer.Option(
        help="Dask scheduler address (tcp://host:8786): the study's ray tracing runs there as "
             "Dask tasks, chunks of antenna positions (sets tracing.scheduler).")] = None,
    recording: Annotated[Path | None, typer.Option(help="Run on a recording: a folder, reads file "
        "or ROS 2 bag (docs/recordings.md).")] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Debug logging.")] = False,
):
    """Run (or resume) the whole study into a run directory.

    Stages: scene -> tour (robot, MCL) -> reads (ray-traced, train tour and the held-out
    evaluation path) -> training sets -> models (FCM + ANFIS; MCL-pose and true-pose;
    baselines) -> truth -> downstream -> evaluation -> figures -> report; truth_traces
    (the truth's ray traces) runs beside tour and reads. A recording: docs/recordings.md.
    Stages are cached in the run directory, ray traces in tracing.cache_dir.

    Every config key and its default: configs/reference.toml (or `rfidstudy config`).
    """
    _setup_logging(verbose)
    from pipeline.apps.studyrun import run_full_study  # lazy: start-up time

    scheduler = _scheduler(scheduler)
    try:
        rec_sets = recording_overrides(recording) if recording is not None else []
        cfg = resolve_target(target, [*(set_ or []), *rec_sets, *(
            [f"replicates.n={replicates}"] if replicates is not None else []), *(
            [f"tracing.scheduler={json.dumps(scheduler)}"] if scheduler else [])], backend)
    except ConfigError as exc:
        fail(str(exc))
    except KeyboardInterrupt:
        fail("interrupted before the run started", code=130)
    try:  # a bad map or a budget over ulimit -v stops here, before the run directory is made

        check_before_run(cfg)
    except (FileNotFoundError, ValueError) as exc:
        fail(str(exc))
    t0 = time.perf_counter()
    try:
        res = run_full_study(cfg, out, progress=progress, force=force or [], command_line=sys.argv,
                             force_dir=force_dir)
    except StudyInterrupted as exc:
        typer.echo(str(exc), err=True)
        raise typer.Exit(130) from None
    except KeyboardInterrupt:
        typer.echo("interrupted; rerun the same command to resume", err=True)
        raise typer.Exit(130) from None
    except RunDirError as exc:
        fail(str(exc))
    except StageError as exc:
        fail(str(exc), code=1)
    except ValueError as exc:
        fail(str(exc))
    except OSError as exc:
        if exc.errno not in WRITE_ERRNOS:
            raise
        fail_os(exc, str(out))
    import textwrap

    typer.echo(f"run directory: {res.run_dir}")
    if res.previous:
        typer.echo(f"resumed: {res.previous}")
    typer.echo(textwrap.fill(f"stages run: {', '.join(res.ran) or 'none'}; cached: "
                             f"{', '.join(res.cached) or 'none'}", width=80,
                             subsequent_indent="  "))
    typer.echo(f"elapsed {time.perf_counter() - t0:.1f} s, peak memory {res.peak_rss_mib:.0f} MiB")
    typer.echo(f"report: {res.run_dir / runfiles.REPORT}")
    typer.echo(f"log:    {res.run_dir / 'run.log'}")


def _existing_run_dir(run_dir: Path, command: str):
    """The :class:`~pipeline.engine.runstore.RunStore` of an existing run directory, or a one-line
    error: ``figures`` and ``report`` rewrite files, so they refuse any other directory."""
    if not run_dir.is_dir():
        fail(f"{run_dir}: not a directory")
    if not is_run_dir(run_dir):
        fail(f"{run_dir}: not a run directory of rfidstudy (no manifest.json of rfidstudy's): "
              f"`rfidstudy {command}` rewrites files only in a run directory")
    return RunStore(run_dir)


def _claim(out: Path, kind: str, files: list[str]) -> None:
    """Stop unless ``out`` may take ``files`` (:func:`pipeline.outdirs.check_output_dir`)."""
    try:
        check_output_dir(out, kind, files)
    except ConfigError as exc:
        fail(str(exc))


def _scheduler(address: str | None) -> str | None:
    """``--scheduler`` checked before any work (:func:`pipeline.engine.tracetasks.check_scheduler`)."""
    if address is None:
        return None

    try:
        return check_scheduler(address)
    except ConfigError as exc:
        fail(str(exc))


def _csv_option(value: str | None) -> list[str] | None:
    return None if value is None else [v.strip() for v in value.split(",") if v.strip()]


def _figure_output(format_: str | None, dpi: int | None):
    """The :class:`~pipeline.figures.FigureOutput` of ``--format`` and ``--dpi`` (each
    default where not given); ValueError naming a bad value."""
    from pipeline.figures import FigureOutput  # lazy: start-up time

    return FigureOutput(**({"formats": tuple(_csv_option(format_))} if format_ else {}),
                        **({"dpi": dpi} if dpi is not None else {}))


@contextlib.contextmanager
def _output_errors(where: str, data_errors=(FileNotFoundError, ValueError)):
    """One line for what a command reading a run directory and writing files can meet: a
    refused run directory (exit 2), unreadable inputs (``data_errors``, exit 1), a place
    that cannot be written (exit 2, naming `where` or the file)."""

    try:
        yield
    except RunDirError as exc:
        fail(str(exc))
    except data_errors as exc:
        fail(str(exc), code=1)
    except OSError as exc:
        if exc.errno not in WRITE_ERRNOS:
            raise
        fail_os(exc, where)


@app.command()
def figures(
    run_dir: Annotated[Path, typer.Argument(help="A run directory.")],
    format_: Annotated[str | None, typer.Option(
        "--format", help="Comma-separated formats: png, pdf, svg (default png,pdf).")] = None,
    dpi: Annotated[int | None, typer.Option(
        help="Resolution of PNG and rasterised parts [dpi] (default 120).")] = None,
    only: Annotated[str | None, typer.Option(
        help="Comma-separated figure names (default all; `--list` names them).")] = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Where to write. Default: RUN/figures (and report.html is "
        "rewritten) without --format/--dpi/--only, RUN/paper_figures with them.")] = None,
    list_: Annotated[bool, typer.Option("--list", help="List the figure names and exit.")] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Also print INFO and DEBUG log lines (stages, traces, materials).")] = False,
):
    """Redraw figures from a run directory's files alone (no ray tracer needed).

    Without options every figure is redrawn into RUN/figures and report.html is rewritten.
    For a paper: `rfidstudy figures RUN --format pdf,png --dpi 300 --only baselines,downstream`
    writes into RUN/paper_figures (or --out DIR); PDFs embed TrueType (Type 42) fonts.
    """
    _setup_logging(verbose)
    from pipeline.figures import FIGURES, draw_all, run_figure_output  # lazy: start-up time
    from pipeline.report.html import write_report  # lazy: start-up time

    if list_:
        for name, fn in FIGURES.items():
            doc = (fn.__doc__ or "").strip().splitlines()[0] if fn.__doc__ else ""
            typer.echo(f"{name:28s} {doc}")
        return
    custom = format_ is not None or dpi is not None or only is not None
    try:
        # without options: as the study's figures stage drew them (its [figures])
        output = _figure_output(format_, dpi) if custom else run_figure_output(run_dir)
    except ValueError as exc:
        fail(str(exc))
    names = _csv_option(only)
    if names is not None:
        unknown = [n for n in names if n not in FIGURES]
        if unknown or not names:
            fail(f"--only: unknown figure(s) {unknown}; known: {', '.join(FIGURES)}")
    store = _existing_run_dir(run_dir, "figures")
    try:
        # a link planted at RUN/paper_figures is refused, not followed (runstore.inside)
        target = out if out is not None else store.path("paper_figures" if custom else "figures")
    except RunDirError as exc:
        fail(str(exc))
    study_figures = target.resolve() == (run_dir / "figures").resolve()
    if study_figures and custom:
        fail("--format, --dpi and --only do not write into the study's own figures/ (its "
              "stage record hashes them): leave out --out, or give another directory")
    own_out = out is not None and not study_figures  # a folder of the user's choosing
    if own_out:
        _claim(out, "figures", [f"{n}.{e}" for n in (names or FIGURES) for e in output.formats])
    t0 = time.perf_counter()
    with _output_errors(str(target), (FileNotFoundError, ValueError, KeyError)), \
            store.lock("rfidstudy figures"):
        paths = draw_all(run_dir, out_dir=target, names=names, output=output)
        report = write_report(run_dir) if study_figures else None
        if own_out:
            mark_output_dir(out, "figures", paths)
    tail = f"; report {report}" if report is not None else ""
    typer.echo(f"{len(paths)} figure files in {target}{tail} "
               f"({time.perf_counter() - t0:.1f} s)")


@app.command()
def compare(
    run_dirs: Annotated[list[Path], typer.Argument(help="Run directories (single or replicated studies).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Where compare.csv and the figure go.")] = Path("runs/compare"),
    format_: Annotated[str | None, typer.Option(
        "--format", help="Comma-separated formats: png, pdf, svg (default png,pdf).")] = None,
    dpi: Annotated[int | None, typer.Option(help="Resolution of PNG [dpi] (default 120).")] = None,
):
    """Draw the headline numbers of several runs side by side, each with its 95 % interval."""
    from pipeline.figures import figure_output  # lazy: start-up time
    from pipeline.figures.headline import compare_runs  # lazy: start-up time

    for d in run_dirs:
        if not d.is_dir() or not is_run_dir(d):
            fail(f"{d}: not a run directory of rfidstudy")
    try:
        output = _figure_output(format_, dpi)
    except ValueError as exc:
        fail(str(exc))
    _claim(out, "compare", ["compare.csv", *(f"compare.{e}" for e in output.formats)])
    with _output_errors(str(out)):
        with figure_output(output):
            paths = compare_runs(run_dirs, out)
            mark_output_dir(out, "compare", paths)
    typer.echo(f"{len(run_dirs)} runs compared: {', '.join(str(p) for p in paths)}")


@app.command()
def report(run_dir: Annotated[Path, typer.Argument(help="A run directory.")]):
    """Rewrite report.html from a run directory's files."""
    from pipeline.report.html import write_report  # lazy: start-up time

    store = _existing_run_dir(run_dir, "report")
    with _output_errors(str(run_dir)), store.lock("rfidstudy report"):
        typer.echo(str(write_report(run_dir)))


@app.command()
def export(
    run_dir: Annotated[Path, typer.Argument(help="A finished run directory.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="New, empty, or an earlier export.")],
    format_: Annotated[str, typer.Option("--format", help="csv, or mcap (a ROS 2 bag).")] = "csv",
):
    """Write a study's training tour as a recording: reads in sllurp's CSV layout (or a ROS 2
    bag), the robot's estimated poses, the tag layout, the antenna mounts (docs/recordings.md)."""
    _existing_run_dir(run_dir, "export")
    try:
        files = export_recording(run_dir, out, format_)
    except (ConfigError, ValueError) as exc:
        fail(str(exc))
    typer.echo(f"{len(files)} files in {out}: {', '.join(p.name for p in files)}")


@app.command()
def config(
    target: Annotated[str | None, typer.Argument(help="Study TOML or scene (as for `run`).")] = None,
    set_: Annotated[list[str] | None, typer.Option("--set", "-s", help="KEY=VALUE override.")] = None,
    reference: Annotated[bool, typer.Option(help="Print the commented reference config.")] = False,
):
    """Print the fully resolved study config (or the commented reference with every default)."""
    if reference:
        typer.echo(reference_config_toml(), nl=False)
        return
    try:
        typer.echo(config_to_toml(resolve_target(target, set_)), nl=False)
    except ConfigError as exc:
        fail(str(exc))


@app.command()
def sweep(
    sweep_file: Annotated[Path, typer.Argument(help="Sweep TOML (see configs/sweep_example.toml).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Sweep directory.")] = Path("runs/sweep"),
    scheduler: Annotated[str | None, typer.Option(
        help="Dask scheduler address (tcp://host:8786); default: local worker processes.")] = None,
    workers: Annotated[int | None, typer.Option(
        help="Local worker processes (default: min(points, 2); 1: the points one after the "
             "other in this process).")] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Also print INFO and DEBUG log lines (stages, traces, materials).")] = False,
):
    """Run a what-if grid (antenna height/yaw/tilt/count, power, tag sensitivity, scene).

    \b
    The sweep file (configs/sweep_example.toml):
      base = "tiny.toml"    # study TOML beside it ("": default)
      mode = "grid"         # every combination; "zip": side by side
      \\[parameters]          # each a list of values
      antenna_height_m = [0.5, 0.9]
      tx_power_dbm = [24.0, 27.15]
      \\[study]               # overrides of base for every point
      seed = 11
    \b
    Optional: upto = "evaluation" stops every point after that stage
    (no figures or report per point; the summary reads its metrics).
    \b
    Parameters: antenna_height_m, antenna_yaw_deg, antenna_tilt_deg,
    antenna_count, tx_power_dbm, tag_sensitivity_dbm, scene, seed,
    replicates, or any dotted study key. Each point prints its time and
    the time left; the end prints the points, best read rate first. A
    ranked answer with intervals: `rfidstudy placement`.
    """
    _setup_logging(verbose)
    from pipeline.apps.sweep import check_sweep_dir, load_sweep, run_sweep  # lazy: start-up time

    if workers is not None and workers < 1:
        fail(f"--workers {workers}: at least 1")
    try:
        plan = load_sweep(sweep_file)
        check_sweep_dir(out)
    except ConfigError as exc:
        fail(str(exc))
    scheduler = _scheduler(scheduler)
    typer.echo(f"{len(plan.configs)} runs: {', '.join(plan.names)}")
    t0 = time.perf_counter()
    n_done = 0

    def done(i, row):
        nonlocal n_done
        n_done += 1
        left = len(plan.configs) - n_done
        # the points run side by side: the wall time per finished point so far, times the
        # points left, is the estimate (it ignores that the last points may overlap)
        eta = (time.perf_counter() - t0) / n_done * left
        took = row.get("elapsed_s")
        took = _duration(took) if isinstance(took, float) and took == took else "?"
        typer.echo(f"  [{n_done}/{len(plan.configs)}] {plan.names[i]}: {row.get('status')}"
                   f" in {took}" + (f" ({row.get('error')})" if row.get("error") else "")
                   + (f"; about {_duration(eta)} left" if left else ""))

    try:
        res = run_sweep(plan, out, scheduler=scheduler, workers=workers, on_done=done)
    except KeyboardInterrupt:
        typer.echo(f"interrupted after {n_done} of {len(plan.configs)} points; rerun the same "
                   "command to resume (finished points are not run again)", err=True)
        raise typer.Exit(130) from None
    except ConfigError as exc:
        fail(str(exc))
    typer.echo(_sweep_table(res.summary, list(plan.parameters)))
    typer.echo(f"summary: {res.out_dir / 'summary.csv'}")
    if (res.summary["status"] != "complete").any():
        raise typer.Exit(1)


def _sweep_table(summary, params: list[str], width: int = 80) -> str:
    """The sweep's points as a short table, best read rate first (the full table is in
    summary.csv): parameters, status and the inventory numbers, cut to `width` columns."""
    cols = [c for c in [*params, "status", "read_rate", "completeness", "surface_coverage",
                        "ssm_rmse_db"] if c in summary.columns]
    t = summary[cols].copy()
    if "read_rate" in t.columns:
        t = t.sort_values("read_rate", ascending=False, na_position="last")
    while True:  # whole columns dropped from the right until it fits: never a cut number
        text = t.to_string(index=False, max_colwidth=20, float_format=lambda v: f"{v:.4g}")
        if max(map(len, text.splitlines())) <= width or t.shape[1] <= 1:
            return text
        t = t.iloc[:, :-1]


def _duration(s: float | None) -> str:
    if s is None:
        return "?"
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min"


@app.command()
def placement(
    placement_file: Annotated[Path, typer.Argument(
        help="Placement TOML: candidate mounts, replicates, objectives, constraints "
             "(see configs/placement_example.toml and docs/placement.md).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Placement directory (new, empty, "
                                      "or an earlier one of this study: it resumes).")] = Path(
        "runs/placement"),
    scheduler: Annotated[str | None, typer.Option(
        help="Dask scheduler address (tcp://host:8786); default: local worker processes.")] = None,
    workers: Annotated[int | None, typer.Option(
        help="Local worker processes (default: the file's workers, else up to 2).")] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Also print INFO and DEBUG log lines (stages, traces, materials).")] = False,
):
    """Choose an antenna mount: run every candidate with replicates, rank them with 95 %
    intervals, recommend one and say whether its lead is real."""
    _setup_logging(verbose)
    from pipeline.apps.placement import (  # lazy: start-up time
        candidates_of,
        load_placement,
        run_placement,
    )
    from pipeline.apps.placement.summary import ranking_table  # lazy: start-up time

    if workers is not None and workers < 1:
        fail(f"--workers {workers}: at least 1")
    scheduler = _scheduler(scheduler)
    try:
        spec = load_placement(placement_file)
    except ConfigError as exc:
        fail(str(exc))
    from pipeline.apps.placement.objectives import needed_stage  # lazy: start-up time

    n = len(candidates_of(spec))
    s = spec.settings
    upto = needed_stage([s.primary, *(c.objective for c in s.constraint), *s.pareto])
    typer.echo(f"{n} candidates x {s.replicates} replicates"
               + (f" + {s.optimise.n_trials} optimiser trials" if s.optimise.n_trials else "")
               + f"; ranked by {s.primary}; each study runs up to its {upto} stage")

    def progress(ev):
        what = ("done before, nothing computed" if ev.n_stages_run == 0 and not ev.failed else
                f"{_duration(ev.elapsed_s)}, {ev.n_sources_traced} antenna positions traced")
        typer.echo(f"  [{ev.done}/{ev.total}] {ev.candidate}: {what}"
                   + (f", {ev.failed} replicate(s) failed" if ev.failed else "")
                   + (f"; about {_duration(ev.remaining_s)} left" if ev.done < ev.total else ""))

    try:
        res = run_placement(spec, out, workers=workers, scheduler=scheduler, progress=progress)
    except (ConfigError, RunDirError) as exc:
        fail(str(exc))
    from pipeline.apps.placement.report import answer_lines  # lazy: start-up time

    table = ranking_table(res.summary, s)
    cols = ["rank", "candidate", "feasible", s.primary, f"{s.primary} minus best", "verdict"]
    typer.echo(table[cols].head(10).to_string(index=False, max_colwidth=34))
    for line in answer_lines(res.summary, res.answer):
        typer.echo(line)
    typer.echo(f"report: {res.out_dir / 'placement' / 'report.html'}")  # runfiles: placement's own


@app.command()
def calibrate(
    target: Annotated[str, typer.Argument(help="Study TOML: the building, the robot and the reader.")],
    recording: Annotated[Path | None, typer.Option(help="A recording folder (reads.csv, tags.csv, "
        "poses.csv) or reads file; default: the study's [recording].")] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Run directory.")] = Path("runs/calibration"),
    set_: Annotated[list[str] | None, typer.Option(
        "--set", "-s", help="Override a config key (repeatable).")] = None,
    progress: Annotated[bool, typer.Option(help="Show progress bars.")] = True,
):
    """Fit the simulated reader to a recording: OUT/calibration.json (each value with its
    95 % interval, held-out residuals before and after) and OUT/calibrated.toml (the study
    with the calibrated reader, for `rfidstudy run` or a placement study)."""
    if recording is None:  # the study's own [recording], or nothing to calibrate to
        try:
            enabled = resolve_target(target, list(set_ or []), None).recording.enabled
        except ConfigError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        if not enabled:
            typer.echo(f"error: {target}: no recording to calibrate to: give --recording or a "
                       "[recording] section (docs/recordings.md)", err=True)
            raise typer.Exit(2)
    run(target=target, out=out, set_=set_, recording=recording, progress=progress)
    typer.echo(f"calibration: {out / runfiles.CALIBRATION}\ncalibrated study: {out / runfiles.CALIBRATED_CONFIG}")
