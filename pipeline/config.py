"""The study configuration: a typed TOML tree, every field documented and defaulted.

``load_config(path)`` reads a study TOML; unknown keys are rejected by name with the
file path, wrong types by key, expected type and value. ``reference_config_toml()``
writes every key with its default and documentation; the shipped
``configs/reference.toml`` is that text (a test keeps them equal).

Angles in TOML carry their unit (``yaw_deg``); the orchestration converts them to
radians before calling the packages, which work in SI.

One schema, one default per key: where a package consumes a section, the section's
dataclass is the package's own and is defined there (``[tour]``:
:class:`pipeline.robot.TourConfig`, ``[localisation]``:
:class:`pipeline.robot.LocalisationConfig`, ``[reader]``:
:class:`pipeline.acquisition.ReaderConfig`), re-exported here; the default antennas
are :func:`pipeline.robot.default_antennas`, the carrier that of
:class:`propagation.LinkBudget` and the ray budget that of :func:`propagation.trace_links`.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import numpy as np

from pipeline.acquisition.config import ReaderConfig
from pipeline.configschema import ConfigError, from_dict, option, reference_toml, section, to_dict
from pipeline.figureconfig import FIGURE_FORMATS, FiguresConfig, check_figure_output
from pipeline.recording.config import RecordingConfig
from pipeline.robot.config import AntennaMountConfig, RobotConfig
from pipeline.robot.simulate import LocalisationConfig
from pipeline.robot.trajectory import TourConfig
from pipeline.sceneconfig import MaterialConfig, material_overrides
from propagation.linkbudget import LinkBudget
from propagation.patterns import PATTERNS, POLARIZATIONS
from propagation.raybudget import memory_shortfall
from propagation.tracing import METHODS, TraceMethod, TraceOptions
from scenes.sources import file_suffixes

#: The library's tracing defaults: the [tracing] section's defaults are these, so the
#: study and ``propagation.trace_links`` trace the same truth.
_TRACE = TraceOptions()

__all__ = [
    "AntennaMountConfig",
    "ConfigError",
    "DownstreamConfig",
    "EvaluationConfig",
    "FIGURE_FORMATS",
    "FiguresConfig",
    "LocalisationConfig",
    "MaterialConfig",
    "ReaderConfig",
    "RecordingConfig",
    "ReplicatesConfig",
    "RobotConfig",
    "StudyConfig",
    "TourConfig",
    "TracingConfig",
    "TrainingConfig",
    "check_figure_output",
    "config_from_mapping",
    "config_to_dict",
    "config_to_toml",
    "base_config",
    "load_config",
    "merge_tables",
    "read_toml",
    "reference_config_toml",
    "is_config_key",
    "replace_path",
]


def _positive(obj, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        if not v > 0:
            raise ConfigError(f"{n} must be > 0, got {v!r}")


def _nonneg(obj, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        if not v >= 0:
            raise ConfigError(f"{n} must be >= 0, got {v!r}")


@section
class TracingConfig:
    """Ray tracing with Sionna RT (propagation package)."""

    reader_pattern: str = option(_TRACE.reader_pattern, "Reader antenna pattern (Sionna name; 8 dBi patch-like).")
    tag_pattern: str = option(_TRACE.tag_pattern, "Tag antenna pattern (Sionna name; half-wave dipole).")
    backend: str = option("auto", "Dr.Jit variant: 'auto' (CUDA if usable, else LLVM), 'cuda' or 'llvm'.")
    deterministic: bool = option(
        False,
        "Trace on one Dr.Jit thread so traces made afresh are bit-reproducible (Sionna's "
        "multi-threaded path solver finds ~1 path in 1000 differently run to run; cached "
        "traces are always reused exactly). About 2x slower tracing on 2 cores. CPU only: "
        "with backend 'auto' it traces on the CPU, with 'cuda' it is an error (GPU traces are "
        "not reproducible).",
    )
    reader_polarization: str = option(
        _TRACE.reader_polarization,
        "Reader antenna polarisation, traced path by path: RHCP or LHCP (a circular panel; the "
        "mismatch with the linear tag dipole is in the gain: 3.01 dB per way on a line-of-sight "
        "path, other values after reflections), V or H (a linear panel). reader.polarization_loss_db "
        "adds to it (default 0).")
    max_depth: int = option(
        _TRACE.max_depth,
        "Maximum number of interactions per path (convergence check in bench/trace.py: depth 5).", max=10)
    samples_per_src: int = option(
        _TRACE.samples_per_src, "Rays shot per antenna position traced alone (method 'direct': every "
        "one; 'shared': one without a neighbour; convergence check: bench/trace.py).", max=5_000_000)
    memory_budget_mb: float = option(
        _TRACE.memory_budget_bytes / 2**20, "Peak memory of one tracing call [MiB] (sources are "
        "chunked to fit; a max_depth and ray count whose one antenna position would not fit "
        "are refused, naming the memory they need).", max=1_048_576)
    method: TraceMethod = option(
        _TRACE.method,
        "Tracer: 'shared' (fast: positions within share_radius_m share the chains their rays "
        "found, plus the image-method completion; uses Sionna internals of the tested versions "
        "only, propagation.sionna_internals) or 'direct' (Sionna's public PathSolver alone, "
        "every position shoots samples_per_src rays: the reference, and the way to run on an "
        "untested Sionna version).",
    )
    share_radius_m: float = option(
        _TRACE.share_radius_m,
        "method 'shared': antenna positions of one tracing call within this distance share "
        "the chains their rays found: each shoots shared_samples_per_src rays and is also "
        "solved, by Sionna's image method at its exact position, for every chain valid at a "
        "neighbour (propagation.shared) [m], in (0, 5]. A position without a neighbour shoots "
        "samples_per_src rays.",
    )
    shared_samples_per_src: int = option(
        _TRACE.shared_samples_per_src,
        "method 'shared': rays shot per antenna position that shares chains with neighbours.",
        max=5_000_000)
    min_samples_per_position: int | None = option(
        _TRACE.min_samples_per_position,
        "method 'shared': the least rays a position's chains come from, whatever its neighbours: "
        "a position whose own and neighbours' shared_samples_per_src rays fall short (sparse "
        "poses, a path's ends) shoots the rest alone (propagation.shared.own_ray_levels); unset "
        "= samples_per_src (no position draws from fewer rays than a lone one); 0 = off, as before "
        "issue 37 (bench/seed_noise.py).", max=5_000_000)
    completion_order: int = option(
        _TRACE.completion_order,
        "method 'shared': also solve every specular reflection path of up to this order (0 = "
        "off, 1-3) over the scene's large planes with the image method: the paths the ray "
        "sampling misses (propagation.completion; at 3 the truth's seed-to-seed p95 on readable "
        "links falls from 1.5 to 1.1 dB for ~10-25 % more tracing time, docs/physics.md).",
    )
    completion_min_area_m2: float = option(
        _TRACE.completion_min_area_m2,
        "method 'shared': the completion's planes are those of at least this area [m^2] "
        "(corridor_lab: 22 planes at 0.5, the metal cabinets' sides among them; 16 at 1, before "
        "issue 37, which left chains over those faces to the rays: most of the truth's "
        "seed-to-seed noise on sparse poses, bench/seed_noise_paths.py).")
    completion_max_planes: int = option(
        0, "method 'shared': at most this many completion planes, the largest (0 = every plane of "
        "completion_min_area_m2 and up). Its cost grows with the square of the planes: a real SLAM "
        "map's jagged walls gave 609 planes where the bundled 30 x 50 m warehouse has 115; the "
        "map-scale profile sets 150.", max=100_000)
    cache_dir: str = option(
        "", "Shared propagation cache directory ('' = $RFIDSTUDY_CACHE or ~/.cache/rfidstudy)."
    )
    scheduler: str = option(
        "", "Dask scheduler address (tcp://host:8786) the study's ray tracing runs on: the "
        "reads and truth_traces stages send their chunks of antenna positions there as Dask "
        "tasks (pipeline.engine.tracetasks; the same paths as traced here). '' = trace in this process. "
        "Not part of any stage's inputs: where a study traces does not change its results.")
    field_cell_m: float = option(0.1, "Cell size of the planar RSSI field [m].")
    field_samples_per_tx: int = option(1_000_000, "Rays per transmitter for the RSSI field.", max=50_000_000)
    field_walls: bool = option(False, "Also map the RSSI field on the wall surfaces (Sionna's "
                               "RadioMapSolver on a 0.1 m triangle mesh of the walls, 10x the rays of "
                               "the plane; saved in fields/field_*.npz as wall_gain): no figure or "
                               "metric of the study uses it, and it costs about 9 s per field on 2 "
                               "cores against 0.5 s for the plane.")

    def __post_init__(self):
        if self.backend not in ("auto", "cuda", "llvm"):
            raise ConfigError(f"backend must be 'auto', 'cuda' or 'llvm', got {self.backend!r}")
        if self.deterministic and self.backend == "cuda":
            raise ConfigError("deterministic = true needs backend = 'llvm' or 'auto': traces on "
                              "CUDA are not bit-reproducible (docs/physics.md, 'On a GPU')")
        _positive(self, "max_depth", "samples_per_src", "memory_budget_mb", "field_cell_m",
                  "field_samples_per_tx")
        if self.completion_order not in (0, 1, 2, 3):
            raise ConfigError(f"completion_order must be 0 (off), 1, 2 or 3, got {self.completion_order!r}")
        if self.method not in METHODS:
            raise ConfigError(f"method must be one of {', '.join(map(repr, METHODS))}, got {self.method!r}")
        if not (np.isfinite(self.share_radius_m) and 0.0 < self.share_radius_m <= 5.0):
            raise ConfigError(f"share_radius_m must be a radius in (0, 5] m, got {self.share_radius_m!r}")
        _positive(self, "shared_samples_per_src")
        _nonneg(self, "completion_min_area_m2", "completion_max_planes")
        if self.min_samples_per_position is not None:
            _nonneg(self, "min_samples_per_position")
        for key, name in (("reader_pattern", self.reader_pattern), ("tag_pattern", self.tag_pattern)):
            if name not in PATTERNS:
                raise ConfigError(f"tracing.{key} = {name!r}: unknown antenna pattern; known: "
                                  f"{', '.join(PATTERNS)}")
        if self.reader_polarization not in POLARIZATIONS:
            raise ConfigError(f"tracing.reader_polarization = {self.reader_polarization!r}: "
                              f"unknown; known: {', '.join(POLARIZATIONS)}")
        # a lone position shoots at least min_samples_per_position rays
        own = max(self.samples_per_src, self.min_samples_per_position or 0)
        short = memory_shortfall(self.method, self.max_depth, own,
                                 self.shared_samples_per_src, int(self.memory_budget_mb * 2**20),
                                 budget_key="memory_budget_mb", prefix="tracing.")
        if short:  # before any work, rather than a tracer taking all the memory
            raise ConfigError(short)


@section
class TrainingConfig:
    """Training sets and the FCM + ANFIS sensor models (RSSI model fs, detection model fT).

    Every study fits both: on the MCL poses (``anfis``, as on a robot) and on the true poses
    (``anfis_truepose``: the localisation split of the error budget).
    """

    d_max_m: float = option(3.0, "Largest antenna-tag distance kept in the training sets [m].")
    rssi_range_dbm: tuple[float, ...] | None = option(
        None, "RSSI range mapped to fs in [0, 1], [lo, hi] [dBm]; unset = (reader sensitivity, max RSSI read)."
    )
    min_attempts: int = option(5, "Detection-model cells with fewer read attempts are dropped.")
    d_bin_m: float = option(0.25, "Distance bin of the detection-model cells [m].")
    alpha_bin_deg: float = option(10.0, "Bearing bin of the detection-model cells [deg].")
    n_clusters: int = option(3, "FCM clusters = Takagi-Sugeno rules per model.", max=100)
    fcm_exponent: float = option(2.0, "FCM fuzziness exponent m (Bezdek 1981).")
    epochs: int = option(100, "ANFIS hybrid-learning epochs (Jang 1993); the best checking epoch is kept.", max=100_000)
    step_size: float = option(0.01, "Initial ANFIS gradient step size (adapted per Jang 1993).")
    check_fraction: float = option(0.2, "Fraction of training samples held out as checking data.")
    max_samples: int = option(0, "Subsample the SSM training set to at most this many (0 = all).")

    def __post_init__(self):
        _positive(self, "d_max_m", "d_bin_m", "alpha_bin_deg", "n_clusters", "fcm_exponent",
                  "epochs", "step_size")
        if not self.fcm_exponent > 1.0:
            raise ConfigError(f"fcm_exponent must be > 1 (FCM's fuzziness exponent m; 1 is hard "
                              f"k-means, memberships undefined; 2 is usual), got {self.fcm_exponent!r}")
        _nonneg(self, "max_samples")
        if not 0.0 <= self.check_fraction < 1.0:
            raise ConfigError("check_fraction must be in [0, 1)")
        _positive(self, "min_attempts")
        if self.rssi_range_dbm is not None and (
            len(self.rssi_range_dbm) != 2 or not self.rssi_range_dbm[0] < self.rssi_range_dbm[1]
        ):
            raise ConfigError(f"rssi_range_dbm must be (lo, hi) with lo < hi, got {self.rssi_range_dbm}")


@section
class EvaluationConfig:
    """Truth grids and comparison of the learned model with the propagation truth."""

    grid_d_max_m: float = option(3.0, "Fig. 6 (d, alpha) grid: largest distance [m].")
    grid_n_d: int = option(13, "Fig. 6 grid: distance samples.", max=10_000)
    grid_n_alpha: int = option(19, "Fig. 6 grid: bearing samples over [-90, 90] deg.", max=10_000)
    n_sample_poses: int = option(4, "Antenna poses around which Fig. 6 truth points are traced.", max=10_000)
    n_field_poses: int = option(1, "Of those, how many also get a ray-traced RSSI field (plane + walls).", max=100)
    fig7_radius_m: float = option(0.1, "Fig. 7: radius of the neighbourhood averaged around a tag [m].")
    field_height_m: float = option(1.0, "Height of the planar RSSI field (tag height) [m].")
    n_eval_tags: int = option(
        16, "Held-out tags drawn on the scene's walls, boxes and cabinets (own seed stream): the "
        "evaluation tour reads only these, the training tour only the scene's own tags (>= 8).",
        max=10_000)
    eval_tag_min_separation_m: float = option(
        0.5, "Smallest distance of a held-out tag from any other tag, training tags included [m].")
    eval_tag_heights_m: tuple[float, ...] = option(
        (0.2, 1.6), "Height range of held-out tags and of the truth's tag sites, [lo, hi] [m].")
    site_spacing_m: float = option(
        0.5, "Spacing of the tag-like truth sites on every vertical surface facing free space [m] "
        "(the solver's cost grows with the sites in reach of each pose).")
    n_site_poses: int = option(
        16, "Evaluation-tour antenna poses at which the truth is traced to every tag site in reach.",
        max=10_000)

    def __post_init__(self):
        _positive(self, "grid_d_max_m", "grid_n_d", "grid_n_alpha", "n_sample_poses",
                  "fig7_radius_m", "field_height_m", "eval_tag_min_separation_m",
                  "site_spacing_m", "n_site_poses")
        _nonneg(self, "n_field_poses")
        if self.n_field_poses > self.n_sample_poses:
            raise ConfigError(f"n_field_poses = {self.n_field_poses} is more than n_sample_poses = "
                              f"{self.n_sample_poses}: the fields are traced at some of the "
                              "sample poses")
        if self.n_eval_tags < 8:
            raise ConfigError(f"n_eval_tags must be >= 8 (a held-out layout worth scoring on), "
                              f"got {self.n_eval_tags}")
        h = self.eval_tag_heights_m
        if len(h) != 2 or not 0.0 <= h[0] < h[1]:
            raise ConfigError(f"eval_tag_heights_m must be (lo, hi) with 0 <= lo < hi, got {h}")


@section
class DownstreamConfig:
    """The downstream benchmark: localise the held-out tags, then the robot, with each
    sensor model and the ray-traced oracle (pipeline.localisation)."""

    enabled: bool = option(True, "Run the downstream benchmark stage.")
    candidate_spacing_m: float = option(
        0.05, "Grid of candidate tag positions on the scene's surfaces, at every height they "
        "have (not the held-out tags' band), for the models, phase estimator and oracle [m].")
    oracle: bool = option(
        False, "Also localise with the ray-traced oracle: the reader's own likelihood of the reads "
        "given the true gains, searched over every candidate coarse to fine without looking at "
        "the truth (a specular image-method model over the large planes finds the modes, the "
        "study's tracer scores windows around them; pipeline.localisation.global_oracle), and "
        "the RFID-only robot filter with the traced local-mean gain field over the free space "
        "(pipeline.localisation.robot_oracle). It costs about 6 minutes more on 2 cores for the "
        "default study from a cache holding only the study's own traces (about 31,000 traced "
        "links), under a minute from the cache.")
    oracle_window_m: float = option(
        0.4, "Radius of the oracle's fine windows: candidates carried from each traced centre [m].")
    oracle_reach_m: float = option(
        16.0, "The oracle's coarse pass scores slots whose antenna is within this distance of a "
        "candidate cell (beyond the longest read of the tour) [m].")
    robot_particles: int = option(2000, "Particles of the RFID-only robot filter.", max=1_000_000)
    robot_runs: int = option(
        3, "Runs of the RFID-only robot filter per model on independent particle streams; "
        "robot_localisation reports the median error over every step of every run and the "
        "spread of the per-run medians (one run is one noisy draw); intervals need at least 5 "
        "runs (with replicates: runs x replicates).", max=1_000)

    def __post_init__(self):
        _positive(self, "candidate_spacing_m", "oracle_window_m", "oracle_reach_m",
                  "robot_particles", "robot_runs")


@section
class ReplicatesConfig:
    """Independent replicates of the study, pooled with 95 % intervals (pipeline.apps.replicates).

    The same scene and config, each replicate with its own seed stream (tour noise, MCL, reader noise,
    held-out tag layout, robot filter), run into ``replicates/<k>/``; the run
    directory's metrics.json and report pool them with intervals."""

    n: int = option(
        1, "Independent replicates (1: one study, intervals over its held-out tags; more: "
        "the study run n times, replicate 0 with `seed`, the others with seeds spawned from it).",
        max=1_000)
    workers: int = option(
        0, "Replicates side by side in local worker processes (0: min(n, 2); 1: one after the "
        "other in the study's own process); ignored with a scheduler.", max=256)
    scheduler: str = option(
        "", "Dask scheduler address (tcp://host:8786) the replicates run on, as sweeps do "
        "('' = local worker processes).")

    def __post_init__(self):
        for name in ("n", "workers"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int):
                raise ConfigError(f"replicates.{name} must be an integer, got {v!r}")
        if self.n < 1:
            raise ConfigError(f"replicates.n must be >= 1 (1 = a single study), got {self.n}")
        if self.workers < 0:
            raise ConfigError(f"replicates.workers must be >= 0 (0 = min(n, 2)), got {self.workers}")


@section
class StudyConfig:
    """A whole study: scene, robot, tour, reader, tracing, training and evaluation."""

    scene: str = option("corridor_lab", "Bundled scene name, or a scene.toml / Mitsuba XML path.")
    seed: int = option(2011, "Seed of every random generator in the study (bit-reproducible runs).")
    frequency_hz: float = option(LinkBudget.frequency_hz, "Carrier frequency [Hz] (ETSI UHF RFID band).")
    robot: RobotConfig = option(doc="Robot and antenna mounts.", factory=RobotConfig)
    tour: TourConfig = option(doc="Training tour and evaluation path.", factory=TourConfig)
    localisation: LocalisationConfig = option(doc="Odometry, laser and MCL.", factory=LocalisationConfig)
    reader: ReaderConfig = option(doc="Reader and link budget.", factory=ReaderConfig)
    tracing: TracingConfig = option(doc="Ray tracing.", factory=TracingConfig)
    training: TrainingConfig = option(doc="Training sets and models.", factory=TrainingConfig)
    evaluation: EvaluationConfig = option(doc="Evaluation.", factory=EvaluationConfig)
    downstream: DownstreamConfig = option(doc="Downstream localisation benchmark.",
                                          factory=DownstreamConfig)
    replicates: ReplicatesConfig = option(doc="Independent replicates of the study.",
                                          factory=ReplicatesConfig)
    figures: FiguresConfig = option(doc="The figures' files: formats and resolution.",
                                    factory=FiguresConfig)
    recording: RecordingConfig = option(doc="A real reader's log the study runs on instead of "
                                        "simulating (docs/recordings.md).", factory=RecordingConfig)
    materials: tuple[MaterialConfig, ...] = option(
        doc="Radio properties laid over the building's materials ([[materials]] tables; a "
            "calibration's calibrated.toml writes them).", factory=tuple, max=64)

    def __post_init__(self):
        if not self.scene:
            raise ConfigError("scene must not be empty")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed must be an integer >= 0 (NumPy seeds every random stream "
                              f"from it), got {self.seed!r}")
        if not 1e8 <= self.frequency_hz <= 1e10:
            raise ConfigError(f"frequency_hz must be in [1e8, 1e10] Hz, got {self.frequency_hz!r}")
        material_overrides(self.materials)  # one entry per material, or ConfigError


def config_from_mapping(data: dict, source: str = "<config>", base_dir: Path | None = None) -> StudyConfig:
    """Build a :class:`StudyConfig` from a nested dict (parsed TOML).

    A relative ``scene`` path (one that is not a bundled name) and a relative
    ``tracing.cache_dir`` are resolved against ``base_dir``.
    """
    _removed_keys(data, source)
    cfg = from_dict(StudyConfig, data, source=source)
    if base_dir is not None:
        cfg = _resolve_paths(cfg, Path(base_dir))
    return cfg


#: Keys of older configs that no longer exist -> what to write instead (an old run
#: directory's config.toml holds them).
REMOVED_KEYS = {
    "tracing.lattice_spacing_m": "pooled tracing was removed; delete the key (0 meant off, "
                                 "the default)",
    "tracing.pooled": "pooled tracing was removed; delete the key",
}


def _removed_keys(data: dict, source: str) -> None:
    """A removed key gets a migration hint instead of 'unknown key'; share_radius_m = 0
    (the old way to trace every position alone) points to tracing.method = "direct"."""
    tracing = data.get("tracing") if isinstance(data, dict) else None
    if not isinstance(tracing, dict):
        return
    for dotted, hint in REMOVED_KEYS.items():
        if dotted.split(".", 1)[1] in tracing:
            raise ConfigError(f"{source}: {dotted}: {hint}")
    r = tracing.get("share_radius_m")
    if isinstance(r, (int, float)) and not isinstance(r, bool) and r == 0:
        raise ConfigError(f"{source}: tracing.share_radius_m = 0 no longer switches sharing "
                          "off: set tracing.method = \"direct\" (every position traced alone) "
                          "and delete share_radius_m")


def _resolve_paths(cfg: StudyConfig, base_dir: Path) -> StudyConfig:
    scene = cfg.scene
    if ("/" in scene or scene.endswith((".toml", *file_suffixes()))) and not Path(scene).is_absolute():
        scene = str((base_dir / scene).resolve())
    tracing = cfg.tracing
    if tracing.cache_dir and not Path(tracing.cache_dir).expanduser().is_absolute():
        tracing = dataclasses.replace(tracing, cache_dir=str((base_dir / tracing.cache_dir).resolve()))
    return dataclasses.replace(cfg, scene=scene, tracing=tracing,
                               recording=cfg.recording.resolved(base_dir))


def read_toml(path: str | Path, what: str = "config") -> dict:
    """Parse a TOML file; :class:`ConfigError` naming the file (``cannot read <what>
    file`` or ``invalid TOML``) when it cannot be read or parsed."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what} file: {exc.strerror}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None


def merge_tables(a: dict, b: dict) -> dict:
    """``a`` with ``b``'s keys laid over it, nested tables merged key by key."""
    out = dict(a)
    for k, v in b.items():
        out[k] = merge_tables(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def base_config(data: dict, source: str, base_dir: Path) -> StudyConfig:
    """The study a sweep or placement file starts from: its ``base`` study TOML (relative
    to ``base_dir``; ``""`` or absent: the defaults) with its ``[study]`` table laid over.

    Raises
    ------
    ConfigError
        ``base`` not a string, ``study`` not a table, or either invalid (file and key named).
    """
    base_ref = data.get("base", "")
    if not isinstance(base_ref, str):
        raise ConfigError(f"{source}: base: expected a path string, got {base_ref!r}")
    base = load_config(Path(base_dir) / base_ref) if base_ref else StudyConfig()
    overrides = data.get("study", {})
    if not isinstance(overrides, dict):
        raise ConfigError(f"{source}: study must be a table of study keys")
    if not overrides:
        return base
    return config_from_mapping(merge_tables(config_to_dict(base), overrides),
                               source=f"{source} [study]", base_dir=base_dir)


def load_config(path: str | Path) -> StudyConfig:
    """Read a study TOML file.

    Raises
    ------
    ConfigError
        If the file is missing, is not valid TOML, holds an unknown key or a value of
        the wrong type or range; the message names the file and the key.
    """
    path = Path(path)
    return config_from_mapping(read_toml(path, "config"), source=str(path), base_dir=path.parent)


def config_to_dict(cfg: StudyConfig) -> dict:
    """Nested dict of the resolved config (TOML-able)."""
    return to_dict(cfg)


def config_to_toml(cfg: StudyConfig) -> str:
    """The fully resolved config as TOML text (reads back to an equal config)."""
    import tomli_w

    return tomli_w.dumps(to_dict(cfg))


REFERENCE_HEADER = """\
rfidstudy reference configuration: every key with its default value.
Generated by pipeline.config.reference_config_toml(); do not edit by hand
(tests/pipeline/test_config_study.py checks that this file equals the generated text).
A study TOML may set any subset of these keys; the rest keep these defaults.
Units are in the key names (_m, _hz, _dbm, _deg, _s)."""


def reference_config_toml() -> str:
    """The reference TOML (``configs/reference.toml``): every key, default and doc."""
    return reference_toml(StudyConfig(), header=REFERENCE_HEADER)


def is_config_key(dotted: str) -> bool:
    """Whether ``dotted`` names a section or key of :class:`StudyConfig` (``"training"``,
    ``"training.epochs"``); list items (``robot.antennas[0]``) are not keys of their own."""
    cls = StudyConfig
    for part in dotted.split("."):
        if not (dataclasses.is_dataclass(cls) and isinstance(cls, type)):
            return False
        fields = {f.name: f for f in dataclasses.fields(cls)}
        if part not in fields:
            return False
        default = StudyConfig() if cls is StudyConfig else cls()
        cls = type(getattr(default, part))
    return True


def replace_path(cfg, dotted: str, value):
    """Return a copy of ``cfg`` with the field at the dotted path replaced.

    ``robot.antennas[*].z_m`` sets the field in every antenna; ``robot.antennas[1].z_m``
    in one. Used by sweeps.
    """
    head, _, rest = dotted.partition(".")
    idx = None
    if head.endswith("]"):
        head, _, sel = head[:-1].partition("[")
        idx = sel
    if not any(f.name == head for f in dataclasses.fields(cfg)):
        raise ConfigError(f"unknown config key {head!r} in {dotted!r}")
    current = getattr(cfg, head)
    if idx is not None:
        items = list(current)
        targets = range(len(items)) if idx == "*" else [int(idx)]
        for i in targets:
            items[i] = replace_path(items[i], rest, value) if rest else value
        return dataclasses.replace(cfg, **{head: tuple(items)})
    if rest:
        return dataclasses.replace(cfg, **{head: replace_path(current, rest, value)})
    return dataclasses.replace(cfg, **{head: value})
