"""The registry of sensor models (issue 55, item 3): one line per model, and every consumer
(fitting, the evaluation, recorded and downstream stages, the figures, the README's
tables) reads it instead of naming models."""

from __future__ import annotations

import ast
import dataclasses
import runpy
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.sensormodels import ablations, competitors, registry
from pipeline.sensormodels._common import CompetitorModel
from pipeline.stages import downstream, evaluation, recorded_eval
from pipeline.stages import models as models_stage  # imported before a test patches the registry

ROOT = Path(__file__).resolve().parents[3]

# --------------------------------------------------------------- the registry itself


def test_keys_are_unique_and_the_modules_agree_with_the_registry():
    keys = [m.key for m in registry.SENSOR_MODELS]
    assert len(keys) == len(set(keys)) and list(registry.MODELS) == keys
    assert registry.model_names(role="ablation") == ablations.ABLATIONS
    assert competitors.COMPETITORS == registry.model_names(role="competitor")
    for key in registry.model_names(role="competitor"):
        m = registry.model_info(key)
        cls = m.model_class
        assert cls.KIND == key and competitors.MODEL_CLASSES[key] is cls
        assert cls.predicts_rssi == m.predicts_rssi, key  # kind says what the class does
        assert m.file == f"models/{key}.json" and callable(m.fit)
    for m in registry.SENSOR_MODELS:
        assert m.label and (m.role != "localiser" or not m.scored_in)


#: The models before the registry: their order is pinned, a model added may go anywhere.
BEFORE = ("anfis", "anfis_truepose", "log_distance", "grid_count", "joho2009", "liu2006",
          "vorst2008", "fcm_only", "anfis_gridinit", "phase", "phase_anfis", "oracle")


def test_the_orders_the_stages_and_tables_had_before_the_registry():
    """Pinned: metrics.json, the unit tables and the figures keep their rows and order."""
    def names(**kw):
        return tuple(n for n in registry.model_names(**kw) if n in BEFORE)

    core = ("grid_count", "joho2009", "liu2006", "vorst2008", "fcm_only", "anfis_gridinit")
    assert names(scored_in="heldout") == ("anfis", "anfis_truepose", "log_distance", *core)
    assert names(scored_in="heldout", predicts="rssi") == (
        "anfis", "anfis_truepose", "log_distance", "joho2009", "fcm_only", "anfis_gridinit")
    assert names(scored_in="heldout", predicts="detection") == ("anfis", "anfis_truepose", *core)
    assert names(scored_in="recorded") == names(scored_in="downstream") == (
        "anfis", "log_distance", *core)
    assert names(role="competitor") == ("joho2009", "liu2006", "vorst2008")
    assert [n for n in registry.table_order(["oracle", "x", *names()]) if n in (*BEFORE, "x")] == [
        "anfis", "anfis_truepose", "fcm_only", "anfis_gridinit", "joho2009", "log_distance",
        "grid_count", "liu2006", "vorst2008", "phase", "phase_anfis", "oracle", "x"]
    assert registry.model_label("vorst2008") == "after Vorst & Zell 2008 (reconstructed)"
    assert registry.model_label("unknown") == "unknown"


def test_entries_are_checked():
    with pytest.raises(ValueError, match="kind"):
        registry.ModelInfo("x", "X", "phase", role="localiser", scored_in=())
    with pytest.raises(ValueError, match="role"):
        registry.ModelInfo("x", "X", role="rival", scored_in=())
    with pytest.raises(ValueError, match="model_class"):
        registry.ModelInfo("x", "X", role="baseline")
    with pytest.raises(ValueError, match="fit"):
        registry.ModelInfo("x", "X", model_class=_FakeModel)
    with pytest.raises(KeyError, match="no sensor model 'x'"):
        registry.model_info("x")
    with pytest.raises(ValueError, match="unknown competitors"):
        competitors.fit_competitors(pd.DataFrame(), (-80, -30), d_max_m=3.0,
                                    rng=np.random.default_rng(0), options={"x": {}})


# ------------------------------------------------ no consumer names a model itself

#: The modules that fit, load, score, draw or tabulate the models.
CONSUMERS = (*sorted((ROOT / "pipeline" / "stages").glob("*.py")),
             *sorted((ROOT / "pipeline" / "figures").glob("*.py")),
             *sorted((ROOT / "pipeline" / "report").glob("*.py")),
             ROOT / "scripts" / "readme_tables.py")
#: (file, key) -> why it may spell the key.
ALLOWED = {("scripts/readme_tables.py", "grid_count"):
           "the single-run prose quotes the grid count's in-sample and held-out MAE"}


def _literals(path: Path) -> set[str]:
    return {n.value for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
            if isinstance(n, ast.Constant) and isinstance(n.value, str)}


def test_no_consumer_spells_a_baseline_competitor_or_ablation():
    """The chapter's model (the reference of every comparison) and the localisers the
    downstream stage builds itself may be named; the models a study can add or drop not."""
    keys = {m.key for m in registry.SENSOR_MODELS
            if m.role in ("baseline", "competitor", "ablation")}
    assert {"grid_count", "joho2009", "fcm_only"} <= keys
    found = []
    for path in CONSUMERS:
        rel = path.relative_to(ROOT).as_posix()
        found += [(rel, k) for k in sorted(_literals(path) & keys) if (rel, k) not in ALLOWED]
    assert not found, f"models named outside the registry: {found}"


def test_the_check_sees_a_named_model(tmp_path):
    p = tmp_path / "stage.py"
    p.write_text('"""doc naming joho2009"""\nNAMES = ("anfis", "joho2009")\n')
    assert _literals(p) & {"joho2009"} == {"joho2009"}


# --------------------------------- a registry of fakes: every consumer takes them


@dataclass(frozen=True, eq=False)
class _FakeModel(CompetitorModel):
    """A constant detection rate and RSSI (tests only)."""

    p: float = 0.5
    rssi_dbm: float = -60.0
    rssi_range_dbm: tuple = (-80.0, -30.0)

    KIND = "fake_both"

    def _detection(self, d, a):
        return np.full(d.shape, self.p)

    def _rssi_dbm(self, d, a):
        return np.full(d.shape, self.rssi_dbm)

    def params_dict(self) -> dict:
        return {"p": self.p, "rssi_dbm": self.rssi_dbm}

    @classmethod
    def from_params(cls, params, rssi_range_dbm, where):
        return cls(float(params["p"]), float(params["rssi_dbm"]), tuple(rssi_range_dbm))


@dataclass(frozen=True, eq=False)
class _FakeDetection(_FakeModel):
    KIND = "fake_det"  # scored on detection only, though it predicts RSSI


def _fit(cls):
    def fit(attempts, rssi_range_dbm, *, d_max_m, grid, rng, scale=1.0):
        return cls(float(attempts.read.mean()) * scale, float(np.nanmean(attempts.rssi)),
                   tuple(rssi_range_dbm))
    return fit


FAKES = (registry.ModelInfo("fake_det", "a fake detection model", "detection",
                            model_class=_FakeDetection, fit=_fit(_FakeDetection),
                            fit_options={"scale": 0.5}),
         registry.ModelInfo("fake_both", "a fake model", model_class=_FakeModel,
                            fit=_fit(_FakeModel)))


@pytest.fixture
def fake_registry(monkeypatch):
    """The registry holds the two fakes only (table order: fake_det, fake_both)."""
    monkeypatch.setattr(registry, "SENSOR_MODELS", FAKES)
    monkeypatch.setattr(registry, "MODELS", {m.key: m for m in FAKES})
    return FAKES


@pytest.fixture
def fake_run(fake_registry, synth, tmp_path):
    """A run directory holding the fakes' files, fitted by fit_competitors, and a stage
    context reading it."""
    reads = synth.as_reads(*synth.sample(5_000, seed=3))
    fitted = competitors.fit_competitors(reads, synth.RSSI_RANGE, d_max_m=3.0,
                                         rng=np.random.default_rng(0), dz_m=0.0)
    assert tuple(fitted) == ("fake_det", "fake_both")
    assert fitted["fake_det"].p == pytest.approx(0.5 * fitted["fake_both"].p)  # fit_options
    for key, m in fitted.items():
        m.save(tmp_path / registry.model_info(key).file)

    class Ctx:
        def input(self, rel):
            p = tmp_path / rel
            if not p.is_file():
                raise FileNotFoundError(rel)
            return p

    return Ctx()


def test_the_stages_load_and_score_exactly_the_registry(fake_run):
    from pipeline.localisation.benchmark import DetectionOnly

    for where in ("heldout", "recorded"):
        sensors, rssi, det, comps = evaluation.study_models(fake_run, where)
        assert tuple(sensors) == ("fake_det", "fake_both") == det == comps
        assert rssi == ("fake_both",)
        assert isinstance(sensors["fake_det"], _FakeDetection)
    models = downstream._models(fake_run)
    assert tuple(models) == ("fake_det", "fake_both")
    assert isinstance(models["fake_det"], DetectionOnly) and isinstance(models["fake_both"], _FakeModel)
    loaded = competitors.load_competitor(fake_run.input("models/fake_both.json"))
    assert isinstance(loaded, _FakeModel)


def test_the_tables_and_figures_label_and_order_by_the_registry(fake_registry):
    from pipeline.figures.headline import draw_headline

    metrics = {"intervals": {"heldout.rssi_mae_db": {"models": {
        "fake_both": {"estimate": 1.0}, "zzz": {"estimate": 3.0}, "fake_det": {"estimate": 2.0}}}}}
    table = runpy.run_path(str(ROOT / "scripts" / "readme_tables.py"))["table"]
    rows = table(metrics, (("heldout.rssi_mae_db", "RSSI MAE [dB]", 2),)).splitlines()[2:]
    assert [r.split(" | ")[0] for r in rows] == [
        "| a fake detection model (`fake_det`)", "| a fake model (`fake_both`)", "| zzz"]
    df = pd.DataFrame({"metric": "heldout.rssi_mae_db", "label": "RSSI", "model": ["fake_both", "fake_det"],
                       "estimate": [1.0, 2.0], "low": np.nan, "high": np.nan, "unit": "tag",
                       "n_units": 3, "verdict": "", "lower_is_better": True})
    fig = draw_headline({"run": df})
    ticks = [t.get_text() for t in fig.axes[0].get_yticklabels()]
    assert ticks == ["a fake detection model", "a fake model"]


def test_the_stages_that_fit_and_score_rerun_when_the_registry_changes(monkeypatch):
    digest = registry.stage_version(1).split("+")[1]
    for st in (models_stage.STAGE, evaluation.STAGE, downstream.STAGE, recorded_eval.STAGE):
        assert st.version.endswith(f"+{digest}"), st.name
    relabelled = tuple(dataclasses.replace(m, label=m.label + "!") for m in registry.SENSOR_MODELS)
    monkeypatch.setattr(registry, "SENSOR_MODELS", relabelled)
    assert registry.stage_version(1) == f"1+{digest}"  # labels: the figures' business
    monkeypatch.setattr(registry, "SENSOR_MODELS", (*relabelled, FAKES[1]))
    assert registry.stage_version(1) != f"1+{digest}"
