"""The placement file: candidate antenna mounts, replicates, objectives and constraints.

A placement study answers "where do I mount the reader antennas?" for one scene. Its
TOML names a base study and the candidates::

    base = "tiny.toml"              # study TOML, relative to this file ("" = defaults)
    replicates = 3                  # studies per candidate (paired seeds, see below)
    primary = "read_rate"           # objective the ranking and recommendation use
    pareto = ["read_rate", "tag_localisation_median_m"]

    [mount]                         # the mount every candidate starts from
    symmetric = true                # a mirrored pair: right = (x, -y, z, -yaw, tilt)
    count = 2                       # 1: the left antenna only; 2: the pair
    x_m = 0.2
    y_m = 0.15
    z_m = 0.7
    yaw_deg = 45.0
    tilt_deg = 0.0

    [grid]                          # values per mount field; the Cartesian product
    z_m = [0.4, 0.9, 1.4]
    tilt_deg = [-20.0, 0.0, 20.0]
    z_right_m = []                  # the right antenna's own height (asymmetric mounts)

    [[preset]]                      # named candidates with explicit antennas
    name = "low-high"
    [[preset.antennas]]
    name = "left"
    z_m = 0.4
    ...

    [[constraint]]                  # candidates that miss a constraint are not recommended
    objective = "completeness"
    min = 0.9

    [envelope]                      # where a mount may be (robot frame) [m]
    x_m = [-0.4, 0.4]
    ...

    [optimise]                      # an optimiser over continuous ranges (Optuna)
    n_trials = 9
    [optimise.ranges]
    z_m = [0.3, 1.5]
    tilt_deg = [-30.0, 30.0]

    [study]                         # overrides of the base study (study TOML keys)
    seed = 7

Every section is a typed dataclass (:mod:`pipeline.configschema`): an unknown key is
refused by name, with the file. :func:`load_placement` checks everything that can be
checked before any tracing (objectives known, ranges non-empty and inside the
envelope, no mount inside the robot's body, contradictory constraints).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from pipeline.apps.placement.candidates import (
    MOUNT_FIELDS,
    candidates_of,
    check_candidate,
    check_ranges,
)
from pipeline.apps.placement.objectives import OBJECTIVES
from pipeline.config import AntennaMountConfig, ConfigError, StudyConfig, base_config, read_toml
from pipeline.configschema import check_bounds, from_dict, option, section

__all__ = [
    "MOUNT_FIELDS",
    "OBJECTIVE_KEYS",
    "ConstraintConfig",
    "EnvelopeConfig",
    "GridConfig",
    "MountConfig",
    "OptimiseConfig",
    "PlacementSpec",
    "PresetConfig",
    "RangesConfig",
    "load_placement",
    "placement_from_mapping",
]

#: Most candidates (grid points + presets + optimiser trials) a placement file may ask
#: for: each is ``replicates`` studies of minutes, so more is a typo, not a study.
MAX_CANDIDATES = 500

#: Objectives a placement can rank by or constrain (pipeline.apps.placement.objectives).
OBJECTIVE_KEYS = tuple(OBJECTIVES)

#: Objectives only the downstream stage computes (refused with [downstream] off).
DOWNSTREAM_OBJECTIVES = tuple(k for k, o in OBJECTIVES.items()
                              if o.table in ("tag_errors", "robot_steps"))


@section
class MountConfig:
    """The mount every candidate starts from (robot frame: x forward, y left, z up)."""

    symmetric: bool = option(True, "A mirrored pair: the right antenna at (x, -y, z) with yaw -yaw_deg.")
    count: int = option(2, "Antennas: 1 (the left one) or 2 (the pair); more with [[preset]].",
                        max=2)
    x_m: float = option(0.2, "Mount position along the robot's forward axis [m].")
    y_m: float = option(0.15, "Lateral offset of the left antenna (the right one at -y_m) [m].")
    z_m: float = option(0.7, "Mount height above the floor [m].")
    yaw_deg: float = option(45.0, "Boresight yaw of the left antenna (right: -yaw_deg) [deg].")
    tilt_deg: float = option(0.0, "Boresight tilt, positive up [deg].")
    z_right_m: float | None = option(None, "The right antenna's own height (None: z_m) [m].")
    tilt_right_deg: float | None = option(None, "The right antenna's own tilt (None: tilt_deg) [deg].")
    yaw_right_deg: float | None = option(None, "The right antenna's own yaw (None: -yaw_deg) [deg].")
    y_right_m: float | None = option(None, "The right antenna's own lateral offset (None: -y_m) [m].")


@section
class GridConfig:
    """Values per mount field; the candidates are their Cartesian product."""

    x_m: tuple[float, ...] = option((), "Forward positions [m].")
    y_m: tuple[float, ...] = option((), "Lateral offsets [m].")
    z_m: tuple[float, ...] = option((), "Heights [m].")
    yaw_deg: tuple[float, ...] = option((), "Yaws of the left antenna [deg].")
    tilt_deg: tuple[float, ...] = option((), "Tilts [deg].")
    z_right_m: tuple[float, ...] = option((), "Heights of the right antenna [m].")
    tilt_right_deg: tuple[float, ...] = option((), "Tilts of the right antenna [deg].")
    yaw_right_deg: tuple[float, ...] = option((), "Yaws of the right antenna [deg].")
    y_right_m: tuple[float, ...] = option((), "Lateral offsets of the right antenna [m].")
    count: tuple[int, ...] = option((), "Antenna counts (1 or 2).")


@section
class RangesConfig:
    """Continuous ranges [low, high] the optimiser searches (an empty field is fixed)."""

    x_m: tuple[float, ...] = option((), "Forward position range [m].")
    y_m: tuple[float, ...] = option((), "Lateral offset range [m].")
    z_m: tuple[float, ...] = option((), "Height range [m].")
    yaw_deg: tuple[float, ...] = option((), "Yaw range [deg].")
    tilt_deg: tuple[float, ...] = option((), "Tilt range [deg].")
    z_right_m: tuple[float, ...] = option((), "Right antenna height range [m].")
    tilt_right_deg: tuple[float, ...] = option((), "Right antenna tilt range [deg].")
    yaw_right_deg: tuple[float, ...] = option((), "Right antenna yaw range [deg].")
    y_right_m: tuple[float, ...] = option((), "Right antenna lateral offset range [m].")


@section
class PresetConfig:
    """A named candidate with explicit antennas."""

    name: str = option("preset", "Candidate name (unique).")
    antennas: tuple[AntennaMountConfig, ...] = option(
        doc="Its antennas ([[preset.antennas]] tables, as [[robot.antennas]]).", factory=tuple)


@section
class ConstraintConfig:
    """A requirement on an objective's estimate (e.g. completeness >= 0.9)."""

    objective: str = option("completeness", "Objective key.")
    min: float | None = option(None, "Smallest acceptable value (None: no lower bound).")
    max: float | None = option(None, "Largest acceptable value (None: no upper bound).")


@section
class EnvelopeConfig:
    """Where a mount may be, robot frame [low, high] per axis; at most max_antennas."""

    x_m: tuple[float, ...] = option((-0.45, 0.45), "Forward extent [m].")
    y_m: tuple[float, ...] = option((-0.45, 0.45), "Lateral extent [m].")
    z_m: tuple[float, ...] = option((0.1, 2.0), "Height extent [m].")
    max_antennas: int = option(4, "Most antennas a candidate may have (reader ports).", max=16)


@section
class OptimiseConfig:
    """An optimiser (Optuna) over [optimise.ranges]; off when n_trials is 0."""

    n_trials: int = option(0, "Candidates the optimiser runs (each with every replicate).",
                           max=10_000)
    sampler: str = option("tpe", "'tpe' (Optuna TPESampler) or 'cmaes' (CmaEsSampler).")
    seed: int = option(0, "Seed of the sampler (a rerun proposes the same trials).")
    ranges: RangesConfig = option(doc="The ranges searched.", factory=RangesConfig)


@section
class PlacementSettings:
    """The placement file's top-level keys (besides base and [study])."""

    replicates: int = option(3, "Studies per candidate, on paired seeds.", max=1_000)
    primary: str = option("read_rate", "Objective the ranking and recommendation use.")
    pareto: tuple[str, ...] = option(("read_rate", "tag_localisation_median_m"),
                                     "Two objectives whose Pareto front is drawn.")
    min_reads: int = option(3, "Reads a tag needs in one pass to count as inventoried.",
                            max=1_000_000)
    height_bands_m: tuple[float, ...] = option(
        (0.0, 0.5, 1.0, 1.5, 3.0), "Edges of the tag-height bands of completeness [m].")
    confirm_top: int = option(
        2, "Top candidates run again on `replicates` fresh replicate seeds after the selection "
           "(0: no confirmation): estimates free of the selection's winner's curse.", max=20)
    workers: int = option(0, "Local worker processes (0: as many as the CPUs allow, <= 2).",
                          max=256)
    mount: MountConfig = option(doc="The base mount.", factory=MountConfig)
    grid: GridConfig = option(doc="Grid of mount values.", factory=GridConfig)
    preset: tuple[PresetConfig, ...] = option(doc="Named candidates.", factory=tuple)
    constraint: tuple[ConstraintConfig, ...] = option(doc="Requirements.", factory=tuple)
    envelope: EnvelopeConfig = option(doc="Mounting envelope.", factory=EnvelopeConfig)
    optimise: OptimiseConfig = option(doc="Optimiser.", factory=OptimiseConfig)


@dataclass
class PlacementSpec:
    """A loaded placement file.

    Attributes
    ----------
    base : StudyConfig
        The base study (with ``[study]`` overrides applied).
    settings : PlacementSettings
        Everything else, typed.
    source : str
        The file (for messages).
    """

    base: StudyConfig
    settings: PlacementSettings
    source: str = "<placement>"
    raw: dict = field(default_factory=dict)
    """The file's parsed TOML (saved with the study)."""


_TOP = ("base", "study")


def _fail(source: str, msg: str) -> ConfigError:
    return ConfigError(f"{source}: {msg}")


def placement_from_mapping(data: dict, source: str = "<placement>",
                           base_dir: Path | None = None) -> PlacementSpec:
    """Build and check a :class:`PlacementSpec` from parsed TOML.

    Raises
    ------
    ConfigError
        Naming the file and the key: unknown keys, unknown objectives, empty or inverted
        ranges, ranges or mounts outside the envelope or inside the robot's body,
        contradictory constraints, a primary objective that is also impossible.
    """
    base_dir = Path(".") if base_dir is None else base_dir
    base = base_config(data, source, base_dir)
    rest = {k: v for k, v in data.items() if k not in _TOP}
    settings = from_dict(PlacementSettings, rest, source=source)
    check_bounds(settings)
    spec = PlacementSpec(base=base, settings=settings, source=source, raw=data)
    check_placement(spec)
    return spec


def load_placement(path: str | Path) -> PlacementSpec:
    """Read, type-check and validate a placement TOML (see the module docstring)."""
    path = Path(path)
    data = read_toml(path, "placement")
    return placement_from_mapping(data, source=str(path), base_dir=path.parent)


def _pair(source: str, key: str, v: tuple) -> tuple[float, float]:
    if len(v) != 2:
        raise _fail(source, f"{key}: expected [low, high], got {list(v)}")
    lo, hi = float(v[0]), float(v[1])
    if not lo < hi:
        raise _fail(source, f"{key}: empty range [{lo}, {hi}] (low must be below high)")
    return lo, hi


def check_placement(spec: PlacementSpec) -> None:
    """Every check that needs no tracing; raises :class:`ConfigError` naming the key."""
    s, src = spec.settings, spec.source
    if s.replicates < 1:
        raise _fail(src, f"replicates = {s.replicates}: at least 1")
    if s.replicates == 2:
        raise _fail(src, "replicates = 2: the intervals resample replicates first, and two give "
                         "none (pipeline.evaluation.intervals.MIN_REPLICATES); use 1 (intervals "
                         "over one replicate's tags) or 3 and more")
    if s.confirm_top < 0 or s.confirm_top == 1:
        raise _fail(src, f"confirm_top = {s.confirm_top}: 0 (off) or at least 2 (the best and "
                         "whom it is confirmed against)")
    for key, name in [("primary", s.primary), *((f"pareto[{i}]", p) for i, p in enumerate(s.pareto))]:
        if name not in OBJECTIVE_KEYS:
            raise _fail(src, f"{key} = {name!r}: unknown objective; known: {', '.join(OBJECTIVE_KEYS)}")
    if not spec.base.downstream.enabled:  # these objectives would be NaN for every candidate
        used = [("primary", s.primary), *((f"pareto[{i}]", p) for i, p in enumerate(s.pareto)),
                *((f"constraint[{i}].objective", c.objective) for i, c in enumerate(s.constraint))]
        for key, name in used:
            if name in DOWNSTREAM_OBJECTIVES:
                raise _fail(src, f"{key} = {name!r} needs the downstream stage, which the study "
                                 "switches off (downstream.enabled = false)")
    if len(s.pareto) != 2 or s.pareto[0] == s.pareto[1]:
        raise _fail(src, f"pareto = {list(s.pareto)}: name two different objectives")
    if s.min_reads < 1:
        raise _fail(src, f"min_reads = {s.min_reads}: at least 1")
    bands = list(s.height_bands_m)
    if len(bands) < 2 or any(b <= a for a, b in zip(bands, bands[1:], strict=False)):
        raise _fail(src, f"height_bands_m = {bands}: at least two increasing edges")
    for i, c in enumerate(s.constraint):
        key = f"constraint[{i}]"
        if c.objective not in OBJECTIVE_KEYS:
            raise _fail(src, f"{key}.objective = {c.objective!r}: unknown objective; known: "
                             f"{', '.join(OBJECTIVE_KEYS)}")
        if c.min is None and c.max is None:
            raise _fail(src, f"{key}: give min or max")
        if c.min is not None and c.max is not None and c.min > c.max:
            raise _fail(src, f"{key}: min = {c.min} > max = {c.max} (no value can meet it)")
    by_obj: dict[str, list[float]] = {}
    for c in s.constraint:  # two constraints on one objective that exclude each other
        lo = -float("inf") if c.min is None else c.min
        hi = float("inf") if c.max is None else c.max
        cur = by_obj.setdefault(c.objective, [-float("inf"), float("inf")])
        cur[0], cur[1] = max(cur[0], lo), min(cur[1], hi)
        if cur[0] > cur[1]:
            raise _fail(src, f"constraint: the constraints on {c.objective} contradict each other "
                             f"(min {cur[0]} > max {cur[1]})")
    env = s.envelope
    for ax in ("x_m", "y_m", "z_m"):
        _pair(src, f"envelope.{ax}", getattr(env, ax))
    if not 1 <= env.max_antennas:
        raise _fail(src, f"envelope.max_antennas = {env.max_antennas}: at least 1")
    if s.mount.count not in (1, 2):
        raise _fail(src, f"mount.count = {s.mount.count}: 1 or 2 (more antennas: [[preset]])")
    if any(c not in (1, 2) for c in s.grid.count):
        raise _fail(src, f"grid.count = {list(s.grid.count)}: each 1 or 2")
    names = [p.name for p in s.preset]
    if len(set(names)) != len(names):
        raise _fail(src, f"preset names must be unique, got {names}")
    for i, p in enumerate(s.preset):
        if not p.antennas:
            raise _fail(src, f"preset[{i}] ({p.name!r}).antennas: at least one antenna")
    opt = s.optimise
    if opt.n_trials < 0:
        raise _fail(src, f"optimise.n_trials = {opt.n_trials}: 0 (off) or more")
    if opt.sampler not in ("tpe", "cmaes"):
        raise _fail(src, f"optimise.sampler = {opt.sampler!r}: 'tpe' or 'cmaes'")
    ranges = {k: _pair(src, f"optimise.ranges.{k}", v)
              for k, v in ((k, getattr(opt.ranges, k)) for k in MOUNT_FIELDS if k != "count")
              if v}
    if opt.n_trials and not ranges:
        raise _fail(src, "optimise.n_trials > 0 but optimise.ranges is empty: give at least one range")
    if opt.n_trials and opt.sampler == "cmaes" and len(ranges) < 2:
        raise _fail(src, "optimise.sampler = 'cmaes' needs at least two ranges (Optuna's CMA-ES "
                         "is multivariate); use 'tpe' for one")
    if opt.n_trials and opt.sampler == "cmaes" and s.constraint:
        raise _fail(src, "optimise.sampler = 'cmaes' with [[constraint]]: Optuna's CMA-ES "
                         "cannot honour constraints; use 'tpe' (constrained TPE)")
    n_grid = 1
    for k in MOUNT_FIELDS:  # the grid's size before building it: a 1000 x 1000 grid is refused
        n_grid *= max(1, len(getattr(s.grid, k, ()) or ()))
    total = n_grid + len(s.preset) + opt.n_trials
    if total > MAX_CANDIDATES:
        raise _fail(src, f"{total} candidates ({n_grid} grid points, {len(s.preset)} presets, "
                         f"{opt.n_trials} trials) x {s.replicates} replicates: more than "
                         f"{MAX_CANDIDATES} candidates; narrow the grid or use [optimise]")
    cands = candidates_of(spec)
    if not cands and not opt.n_trials:
        raise _fail(src, "no candidates: give [grid] values, [[preset]] tables or [optimise]")
    for c in cands:
        check_candidate(c, spec)
    if opt.n_trials:  # the corners of the search box must be valid mounts too
        check_ranges(spec, ranges)
