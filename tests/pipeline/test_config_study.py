"""Study config: typed TOML, errors naming file and key, reference.toml in sync."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from pipeline.config import (
    ConfigError,
    StudyConfig,
    config_from_mapping,
    config_to_toml,
    load_config,
    reference_config_toml,
    replace_path,
)

ROOT = Path(__file__).resolve().parents[2]


def test_reference_toml_in_sync():
    shipped = (ROOT / "configs" / "reference.toml").read_text(encoding="utf-8")
    assert shipped == reference_config_toml(), (
        "configs/reference.toml is stale: regenerate with "
        "`python -c 'from pipeline.config import reference_config_toml as r; print(r(), end=\"\")'"
        " > configs/reference.toml`"
    )


def test_reference_toml_reads_back_to_defaults():
    cfg = config_from_mapping(tomllib.loads(reference_config_toml()))
    assert cfg == StudyConfig()


def test_every_field_documented():
    text = reference_config_toml()
    # each value line is preceded by a non-empty comment line
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if "=" in line and not line.startswith("#"):
            assert lines[i - 1].startswith("# ") and len(lines[i - 1]) > 4, line


def test_unknown_key_named_with_file(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text("[training]\nepochz = 3\n")
    with pytest.raises(ConfigError) as exc:
        load_config(p)
    msg = str(exc.value)
    assert str(p) in msg and "training.epochz" in msg and "epochs" in msg


def test_unknown_top_level_section(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text("[trainig]\nepochs = 3\n")
    with pytest.raises(ConfigError, match=r"study\.toml: trainig: unknown key"):
        load_config(p)


def test_wrong_type_named(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text('[tracing]\nmax_depth = "five"\n')
    with pytest.raises(ConfigError, match=r"study\.toml: tracing\.max_depth: must be an integer, got 'five'"):
        load_config(p)


def test_tracing_method_is_a_name_checked_in_one_line(tmp_path):
    # the tracer is chosen by name; anything else is refused with the key and the choices
    from pipeline.config import TracingConfig

    p = tmp_path / "study.toml"
    p.write_text('[tracing]\nmethod = "pooled"\n')
    with pytest.raises(ConfigError, match=r"tracing\.method: must be one of 'shared', 'direct', got 'pooled'") as err:
        load_config(p)
    assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match="method must be one of 'shared', 'direct'"):
        TracingConfig(method="naive")
    assert TracingConfig().method == "shared"  # the fast tracer, as propagation.TraceOptions()


def test_bool_is_not_int(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text("seed = true\n")
    with pytest.raises(ConfigError, match="seed: must be an integer, got True"):
        load_config(p)


def test_bad_value_in_array_of_tables(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text('[[robot.antennas]]\nname = "a"\nz_m = -0.5\n')
    with pytest.raises(ConfigError, match=r"robot\.antennas\[0\].*z_m must be > 0"):
        load_config(p)


def test_unknown_key_in_antenna(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text('[[robot.antennas]]\nname = "a"\nheight_m = 0.5\n')
    with pytest.raises(ConfigError, match=r"robot\.antennas\[0\]\.height_m: unknown key"):
        load_config(p)


def test_invalid_toml_names_file(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text("seed = = 3\n")
    with pytest.raises(ConfigError, match="broken.toml: invalid TOML"):
        load_config(p)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="nope.toml: cannot read"):
        load_config(tmp_path / "nope.toml")


def test_resolved_toml_roundtrip(tmp_path):
    cfg = replace_path(StudyConfig(), "training.epochs", 7)
    cfg = replace_path(cfg, "robot.antennas[*].z_m", 0.9)
    p = tmp_path / "c.toml"
    p.write_text(config_to_toml(cfg))
    back = load_config(p)
    assert back == cfg
    assert back.training.epochs == 7
    assert all(a.z_m == 0.9 for a in back.robot.antennas)


def test_relative_scene_path_resolved(tmp_path):
    p = tmp_path / "sub" / "c.toml"
    p.parent.mkdir()
    p.write_text('scene = "../myscene.toml"\n')
    assert load_config(p).scene == str((tmp_path / "myscene.toml").resolve())
    p.write_text('scene = "corridor_lab"\n')
    assert load_config(p).scene == "corridor_lab"


def test_replace_path_unknown_key():
    with pytest.raises(ConfigError, match="unknown config key 'trainig'"):
        replace_path(StudyConfig(), "trainig.epochs", 3)


@pytest.mark.parametrize("name", ["reference.toml", "paper_scale.toml", "tiny.toml", "warehouse.toml",
                                  "warehouse_large.toml"])
def test_shipped_configs_load(name):
    p = ROOT / "configs" / name
    if not p.exists():
        pytest.skip(f"{name} not shipped yet")
    load_config(p)


def test_package_sections_are_the_packages_own_configs_with_one_default_per_key():
    """[tour], [localisation] and [reader] are the dataclasses the packages consume, and
    what they build from their defaults is the packages' defaults (no second default)."""
    from pipeline.acquisition import ReaderConfig
    from pipeline.robot import (
        LaserScanner,
        LocalisationConfig,
        MCLConfig,
        OdometryNoise,
        TourConfig,
        default_antennas,
    )
    from propagation import DEFAULT_MAX_DEPTH, DEFAULT_SAMPLES_PER_SRC, LinkBudget

    cfg = StudyConfig()
    assert type(cfg.tour) is TourConfig
    assert type(cfg.localisation) is LocalisationConfig
    assert type(cfg.reader) is ReaderConfig
    loc = cfg.localisation
    assert loc.mcl == MCLConfig() and loc.scanner == LaserScanner() and loc.odometry == OdometryNoise()
    assert cfg.reader.link_budget(cfg.frequency_hz) == LinkBudget()
    assert (cfg.tracing.max_depth, cfg.tracing.samples_per_src) == (DEFAULT_MAX_DEPTH,
                                                                     DEFAULT_SAMPLES_PER_SRC)
    robot = [(a.name, a.x_m, a.y_m, a.z_m) for a in cfg.robot.antennas]
    assert robot == [(m.name, m.x_m, m.y_m, m.z_m) for m in default_antennas()]


def test_one_value_converter_for_scenes_and_config(tmp_path):
    """The study config and the scene specs check values with scenes.schema.convert_value."""
    import pipeline.configschema
    import scenes.spec
    from scenes.schema import ValueTypeError, convert_value

    assert pipeline.configschema.convert_value is convert_value
    assert scenes.spec._convert is convert_value
    with pytest.raises(ValueTypeError, match=r"key 'lanes\[1\]' must be a number, got 'x'"):
        convert_value([0.5, "x"], tuple[float, ...], "lanes")
    p = tmp_path / "study.toml"
    p.write_text("[tour]\nlane_fractions = [0.0, nan]\n")
    with pytest.raises(ConfigError, match=r"study\.toml: tour\.lane_fractions: must hold finite"):
        load_config(p)


@pytest.mark.parametrize(("backend", "deterministic", "want"), [
    ("auto", False, "auto"), ("cuda", False, "cuda"), ("llvm", False, "llvm"),
    ("auto", True, "llvm"), ("llvm", True, "llvm"), ("cuda", True, None)])
def test_deterministic_tracing_asks_for_the_cpu(backend, deterministic, want):
    # On CUDA the path solver is not bit-reproducible whatever the thread count (measured
    # on an H200: 93 of 144 gains of two identical cold traces differed): a deterministic
    # study traces on the CPU, and one that names CUDA is refused, naming both keys.
    from pipeline.studyscene import preferred_backend

    if want is None:  # refused by the config itself, before any stage runs
        with pytest.raises(ConfigError, match=r"deterministic = true needs backend"):
            replace_path(replace_path(StudyConfig(), "tracing.backend", backend),
                         "tracing.deterministic", deterministic)
        return
    cfg = replace_path(replace_path(StudyConfig(), "tracing.backend", backend),
                       "tracing.deterministic", deterministic)
    assert preferred_backend(cfg.tracing) == want


def test_unknown_detuning_material_is_named():
    from pipeline.config import ConfigError, config_from_mapping

    with pytest.raises(ConfigError, match="unobtainium"):
        config_from_mapping({"reader": {"detuning_materials": ["unobtainium"]}})
    cfg = config_from_mapping({"reader": {"detuning_materials": ["metal", "glass"]}})
    assert cfg.reader.detuning_materials == ("metal", "glass")


def test_keys_of_older_configs_get_a_migration_hint():
    from pipeline.config import ConfigError, config_from_mapping

    with pytest.raises(ConfigError, match="lattice_spacing_m: pooled tracing was removed"):
        config_from_mapping({"tracing": {"lattice_spacing_m": 0.0}})
    with pytest.raises(ConfigError, match='tracing.method = "direct"'):
        config_from_mapping({"tracing": {"share_radius_m": 0.0}})


@pytest.mark.parametrize("formats, why", [(["pdf"], "png first"), (["png", "png"], "distinct"),
                                          (["png", "jpg"], "distinct names from"),
                                          ([], "png first")])
def test_figure_formats_are_named_formats_png_first(formats, why):
    from pipeline.config import config_from_mapping

    assert config_from_mapping({"figures": {"formats": ["png", "svg"]}}).figures.formats == (
        "png", "svg")
    with pytest.raises(ConfigError, match=why):
        config_from_mapping({"figures": {"formats": formats}})
    with pytest.raises(ConfigError, match=r"figures.dpi must be an integer in \[50, 1200\]"):
        config_from_mapping({"figures": {"dpi": 20}})


def test_figure_formats_of_the_config_are_the_figures_formats():
    # the config names them without importing the plotting library: kept alike here
    from pipeline.config import FIGURE_FORMATS
    from pipeline.figures import FigureOutput
    from pipeline.figures.common import FORMATS

    assert FIGURE_FORMATS == FORMATS
    assert FigureOutput().formats == StudyConfig().figures.formats
    assert FigureOutput().dpi == StudyConfig().figures.dpi
