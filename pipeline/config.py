"""The study configuration: a typed TOML tree, every field documented and defaulted.

``load_config(path)`` reads a study TOML; unknown keys are rejected by name with the
file path, wrong types by key, expected type and value. ``reference_config_toml()``
writes every key with its default and documentation; the shipped
``configs/reference.toml`` is that text (a test keeps them equal).

Angles in TOML carry their unit (``yaw_deg``); the orchestration converts them to
radians before calling the packages, which work in SI.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

from pipeline.configschema import ConfigError, from_dict, option, reference_toml, section, to_dict

__all__ = [
    "AntennaMountConfig",
    "ConfigError",
    "EvaluationConfig",
    "LocalisationConfig",
    "ReaderConfigSection",
    "RobotConfig",
    "StudyConfig",
    "TourConfig",
    "TracingConfig",
    "TrainingConfig",
    "config_from_mapping",
    "config_to_dict",
    "config_to_toml",
    "load_config",
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
class AntennaMountConfig:
    """One reader antenna mounted on the robot (robot frame: x forward, y left, z up)."""

    name: str = option("antenna", "Antenna name (unique), used in tables and figures.")
    x_m: float = option(0.0, "Mount position along the robot's forward axis [m].")
    y_m: float = option(0.0, "Mount position along the robot's left axis [m].")
    z_m: float = option(0.6, "Mount height above the floor [m].")
    yaw_deg: float = option(0.0, "Boresight yaw relative to the robot heading, counter-clockwise [deg].")
    tilt_deg: float = option(0.0, "Boresight tilt (pitch), positive up [deg].")

    def __post_init__(self):
        if not self.name:
            raise ConfigError("name must not be empty")
        _positive(self, "z_m")


def _default_antennas() -> tuple[AntennaMountConfig, ...]:
    # pipeline.robot.default_antennas(): the chapter's two panels at the front corners of
    # a mast 0.70 m above the floor, yawed +-45 deg (see that function for why).
    return (
        AntennaMountConfig(name="left", x_m=0.20, y_m=0.15, z_m=0.70, yaw_deg=45.0),
        AntennaMountConfig(name="right", x_m=0.20, y_m=-0.15, z_m=0.70, yaw_deg=-45.0),
    )


@section
class RobotConfig:
    """The mobile robot (a Pioneer P3-AT, pipeline.robot.Robot) and its reader antennas."""

    antennas: tuple[AntennaMountConfig, ...] = option(
        doc="Reader antennas mounted on the robot ([[robot.antennas]] tables).",
        factory=_default_antennas,
    )

    def __post_init__(self):
        if not self.antennas:
            raise ConfigError("robot.antennas must list at least one antenna")
        names = [a.name for a in self.antennas]
        if len(set(names)) != len(names):
            raise ConfigError(f"antenna names must be unique, got {names}")


@section
class TourConfig:
    """The guided training tour and the held-out evaluation path (pipeline.robot)."""

    n_passes: int = option(
        2, "Passes along the corridor route, alternating direction (2 = up and back; paper_scale: 9)."
    )
    lane_fractions: tuple[float, ...] = option(
        (-0.6, 0.0, 0.6), "Lateral lanes as fractions of the free band, in [-1, 1] (0 = middle)."
    )
    lane_changes_per_pass: int = option(1, "Lane changes inside each pass.")
    stops_per_pass: int = option(1, "Stops inside each pass.")
    speed_m_per_s: float = option(0.3, "Cruise speed [m/s] (the chapter's robot: about 0.3 m/s).")
    dt_s: float = option(0.1, "Pose sampling period (one laser scan / MCL update per pose) [s].")
    max_length_m: float = option(
        0.0, "Drive only the first max_length_m metres of the scene's route (0 = whole route) [m]."
    )
    n_eval_poses: int = option(200, "Robot poses on the held-out evaluation path (chapter Fig. 7: 200).")

    def __post_init__(self):
        _positive(self, "n_passes", "speed_m_per_s", "dt_s", "n_eval_poses")
        _nonneg(self, "max_length_m", "lane_changes_per_pass", "stops_per_pass")
        if not self.lane_fractions or any(abs(f) > 1 for f in self.lane_fractions):
            raise ConfigError(f"lane_fractions must be non-empty and in [-1, 1], got {self.lane_fractions}")
        if self.n_eval_poses < 2:
            raise ConfigError(f"n_eval_poses must be >= 2, got {self.n_eval_poses}")


@section
class LocalisationConfig:
    """Odometry noise, the laser scanner and Monte Carlo Localization (pipeline.robot)."""

    enabled: bool = option(True, "Run MCL; if false the estimated poses equal the true poses.")
    n_particles: int = option(500, "MCL particles.")
    n_beams_used: int = option(30, "Laser beams per scan used by the likelihood field.")
    laser_beams: int = option(181, "Laser beams over the field of view (SICK LMS-200: 181).")
    laser_fov_deg: float = option(180.0, "Laser field of view [deg].")
    laser_max_range_m: float = option(8.0, "Laser maximum range [m].")
    laser_noise_m: float = option(0.01, "Laser range noise standard deviation [m].")
    odometry_noise: tuple[float, ...] = option(
        (0.02, 0.02, 0.02, 0.002),
        "Robot odometry noise alpha1..alpha4 (Thrun et al. 2005, Table 5.6).",
    )
    map_resolution_m: float = option(0.05, "Likelihood-field grid resolution [m].")
    map_error_m: float = option(
        0.05,
        "Std of the signed offset of each wall of the robot's map along its normal (one draw "
        "per wall line, once per building, shared by both tours; survey/SLAM error, as-built "
        "tolerances) [m]; 0 = every wall where it is.",
    )
    map_scale_error: float = option(
        0.0, "Std of the fractional scale error of the robot's map (scaled about the building's "
        "centre by 1 + s; 0.001 = 1 mm per metre) [1]; 0 = none.",
    )
    map_noise_m: float = option(
        0.0, "Std of a smooth, unsigned random displacement of the map's likelihood field on top "
        "of the wall offsets [m]; 0 = none.",
    )
    map_noise_correlation_m: float = option(
        1.0, "Correlation length of that smooth displacement along surfaces [m]."
    )
    sigma_hit_m: float = option(
        0.10,
        "Likelihood-field std of the MCL laser model [m]; keep it >= map_error_m (corridor_lab, "
        "per-wall offsets of 0.05 m std: MCL tracks at 0.05 and 0.10, position error median "
        "3-8 cm; at 0.2 m std the p90 reached 2-6 m on 2 of 3 maps).",
    )
    max_position_error_median_m: float = option(
        0.5, "The tour stage fails when the MCL position error median of either tour exceeds "
        "this (MCL lost track: lower the map error or widen sigma_hit_m) [m].",
    )
    max_position_error_p90_m: float = option(
        1.0, "The tour stage fails when the 90th percentile of the MCL position error of either "
        "tour exceeds this [m].",
    )

    def __post_init__(self):
        _positive(self, "n_particles", "n_beams_used", "laser_beams", "laser_fov_deg",
                  "laser_max_range_m", "map_resolution_m", "map_noise_correlation_m", "sigma_hit_m",
                  "max_position_error_median_m", "max_position_error_p90_m")
        _nonneg(self, "laser_noise_m", "map_error_m", "map_scale_error", "map_noise_m")
        if len(self.odometry_noise) != 4 or min(self.odometry_noise) < 0:
            raise ConfigError(f"odometry_noise must be 4 values >= 0, got {self.odometry_noise}")


@section
class ReaderConfigSection:
    """The UHF reader and the backscatter link budget (docs/physics.md, 'The backscatter link')."""

    read_rate_hz: float = option(
        4.0, "Read cycles per second; each is a new antenna position to trace (paper_scale: 10)."
    )
    antenna_mode: str = option(
        "round_robin", "Antenna multiplexing: 'round_robin' (one port per cycle) or 'all'."
    )
    rssi_noise_db: float = option(1.0, "Reader RSSI noise standard deviation [dB].")
    rssi_resolution_db: float = option(0.5, "Reader RSSI quantisation step [dB].")
    anticollision_miss_probability: float = option(
        0.05, "Probability that a powered, audible tag is still missed in a cycle."
    )
    tx_power_dbm: float = option(
        27.15, "Conducted reader power [dBm] (2 W ERP = 35.15 dBm EIRP with the 8 dBi antenna)."
    )
    tag_sensitivity_dbm: float = option(-18.0, "Tag chip sensitivity [dBm] (Monza-4 class).")
    reader_sensitivity_dbm: float = option(-80.0, "Reader receiver sensitivity [dBm].")
    polarization_loss_db: float = option(3.0, "Polarisation mismatch loss per way [dB] (circular to linear).")
    modulation_loss_db: float = option(-6.0, "Backscatter modulation factor M [dB].")
    range_margin_db: float = option(
        10.0, "Margin over the free-space budget when choosing which links can be read and are traced [dB]."
    )

    def __post_init__(self):
        _positive(self, "read_rate_hz")
        _nonneg(self, "rssi_noise_db", "rssi_resolution_db", "polarization_loss_db", "range_margin_db")
        if self.antenna_mode not in ("round_robin", "all"):
            raise ConfigError(f"antenna_mode must be 'round_robin' or 'all', got {self.antenna_mode!r}")
        if not 0.0 <= self.anticollision_miss_probability < 1.0:
            raise ConfigError("anticollision_miss_probability must be in [0, 1)")


@section
class TracingConfig:
    """Ray tracing with Sionna RT (propagation package)."""

    reader_pattern: str = option("tr38901", "Reader antenna pattern (Sionna name; 8 dBi patch-like).")
    tag_pattern: str = option("hw_dipole", "Tag antenna pattern (Sionna name; half-wave dipole).")
    backend: str = option("auto", "Dr.Jit variant: 'auto' (CUDA if usable, else LLVM), 'cuda' or 'llvm'.")
    deterministic: bool = option(
        False,
        "Trace on one Dr.Jit thread so traces made afresh are bit-reproducible (Sionna's "
        "multi-threaded path solver finds ~1 path in 1000 differently run to run; cached "
        "traces are always reused exactly). About 2x slower tracing on 2 cores.",
    )
    reader_polarization: str = option(
        "V", "Reader antenna polarisation: V, H, RHCP or LHCP (circular: set reader.polarization_loss_db = 0)."
    )
    max_depth: int = option(
        5, "Maximum number of interactions per path (convergence check in bench/trace.py: depth 5)."
    )
    samples_per_src: int = option(30_000, "Rays shot per antenna position (convergence check: bench/trace.py).")
    memory_budget_mb: float = option(2048.0, "Peak memory of one tracing call [MiB] (sources are chunked to fit).")
    cache_dir: str = option(
        "", "Shared propagation cache directory ('' = $RFIDSTUDY_CACHE or ~/.cache/rfidstudy)."
    )
    field_cell_m: float = option(0.1, "Cell size of the planar RSSI field [m].")
    field_samples_per_tx: int = option(1_000_000, "Rays per transmitter for the RSSI field.")

    def __post_init__(self):
        if self.backend not in ("auto", "cuda", "llvm"):
            raise ConfigError(f"backend must be 'auto', 'cuda' or 'llvm', got {self.backend!r}")
        _positive(self, "max_depth", "samples_per_src", "memory_budget_mb", "field_cell_m",
                  "field_samples_per_tx")


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
    n_clusters: int = option(3, "FCM clusters = Takagi-Sugeno rules per model.")
    fcm_exponent: float = option(2.0, "FCM fuzziness exponent m (Bezdek 1981).")
    epochs: int = option(100, "ANFIS hybrid-learning epochs (Jang 1993); the best checking epoch is kept.")
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
    grid_n_d: int = option(13, "Fig. 6 grid: distance samples.")
    grid_n_alpha: int = option(19, "Fig. 6 grid: bearing samples over [-90, 90] deg.")
    n_sample_poses: int = option(4, "Antenna poses around which Fig. 6 truth points are traced.")
    n_field_poses: int = option(1, "Of those, how many also get a ray-traced RSSI field (plane + walls).")
    fig7_radius_m: float = option(0.1, "Fig. 7: radius of the neighbourhood averaged around a tag [m].")
    field_height_m: float = option(1.0, "Height of the planar RSSI field (tag height) [m].")
    n_eval_tags: int = option(
        16, "Held-out tags drawn on the scene's walls, boxes and cabinets (own seed stream): the "
        "evaluation tour reads only these, the training tour only the scene's own tags (>= 8).")
    eval_tag_min_separation_m: float = option(
        0.5, "Smallest distance of a held-out tag from any other tag, training tags included [m].")
    eval_tag_heights_m: tuple[float, ...] = option(
        (0.2, 1.6), "Height range of held-out tags and of the truth's tag sites, [lo, hi] [m].")
    site_spacing_m: float = option(
        0.5, "Spacing of the tag-like truth sites on every vertical surface facing free space [m] "
        "(the solver's cost grows with the sites in reach of each pose).")
    n_site_poses: int = option(
        16, "Evaluation-tour antenna poses at which the truth is traced to every tag site in reach.")

    def __post_init__(self):
        _positive(self, "grid_d_max_m", "grid_n_d", "grid_n_alpha", "n_sample_poses",
                  "fig7_radius_m", "field_height_m", "eval_tag_min_separation_m",
                  "site_spacing_m", "n_site_poses")
        _nonneg(self, "n_field_poses")
        if self.n_eval_tags < 8:
            raise ConfigError(f"n_eval_tags must be >= 8 (a held-out layout worth scoring on), "
                              f"got {self.n_eval_tags}")
        h = self.eval_tag_heights_m
        if len(h) != 2 or not 0.0 <= h[0] < h[1]:
            raise ConfigError(f"eval_tag_heights_m must be (lo, hi) with 0 <= lo < hi, got {h}")


@section
class StudyConfig:
    """A whole study: scene, robot, tour, reader, tracing, training and evaluation."""

    scene: str = option("corridor_lab", "Bundled scene name, or a scene.toml / Mitsuba XML path.")
    seed: int = option(2011, "Seed of every random generator in the study (bit-reproducible runs).")
    frequency_hz: float = option(865e6, "Carrier frequency [Hz] (ETSI UHF RFID band).")
    robot: RobotConfig = option(doc="Robot and antenna mounts.", factory=RobotConfig)
    tour: TourConfig = option(doc="Training tour and evaluation path.", factory=TourConfig)
    localisation: LocalisationConfig = option(doc="Odometry, laser and MCL.", factory=LocalisationConfig)
    reader: ReaderConfigSection = option(doc="Reader and link budget.", factory=ReaderConfigSection)
    tracing: TracingConfig = option(doc="Ray tracing.", factory=TracingConfig)
    training: TrainingConfig = option(doc="Training sets and models.", factory=TrainingConfig)
    evaluation: EvaluationConfig = option(doc="Evaluation.", factory=EvaluationConfig)

    def __post_init__(self):
        if not self.scene:
            raise ConfigError("scene must not be empty")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed must be an integer >= 0 (NumPy seeds every random stream "
                              f"from it), got {self.seed!r}")
        if not 1e8 <= self.frequency_hz <= 1e10:
            raise ConfigError(f"frequency_hz must be in [1e8, 1e10] Hz, got {self.frequency_hz!r}")


def config_from_mapping(data: dict, source: str = "<config>", base_dir: Path | None = None) -> StudyConfig:
    """Build a :class:`StudyConfig` from a nested dict (parsed TOML).

    A relative ``scene`` path (one that is not a bundled name) and a relative
    ``tracing.cache_dir`` are resolved against ``base_dir``.
    """
    cfg = from_dict(StudyConfig, data, source=source)
    if base_dir is not None:
        cfg = _resolve_paths(cfg, Path(base_dir))
    return cfg


def _resolve_paths(cfg: StudyConfig, base_dir: Path) -> StudyConfig:
    scene = cfg.scene
    if ("/" in scene or scene.endswith((".toml", ".xml"))) and not Path(scene).is_absolute():
        scene = str((base_dir / scene).resolve())
    tracing = cfg.tracing
    if tracing.cache_dir and not Path(tracing.cache_dir).expanduser().is_absolute():
        tracing = dataclasses.replace(tracing, cache_dir=str((base_dir / tracing.cache_dir).resolve()))
    return dataclasses.replace(cfg, scene=scene, tracing=tracing)


def load_config(path: str | Path) -> StudyConfig:
    """Read a study TOML file.

    Raises
    ------
    ConfigError
        If the file is missing, is not valid TOML, holds an unknown key or a value of
        the wrong type or range; the message names the file and the key.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config file: {exc.strerror}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None
    return config_from_mapping(data, source=str(path), base_dir=path.parent)


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
