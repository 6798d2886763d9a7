"""UHF material library against hand-computed ITU-R P.2040-3 values at 865 MHz."""

import warnings

import pytest

import scenes
from scenes import materials

# Hand computation, P.2040-3 Table 3, f = 0.865 GHz: sigma = c * 0.865**d, eps_r = a (b = 0).
# ln(0.865) = -0.145026; e.g. concrete: 0.0462 * exp(0.7822 * -0.145026) = 0.0462 * 0.89275.
HAND_865MHZ = {
    "concrete": (5.24, 0.041245),
    "brick": (3.91, 0.023254),  # 0.0238 * exp(0.16 * -0.145026) = 0.0238 * 0.97706
    "plasterboard": (2.73, 0.0074173),  # 0.0085 * exp(0.9395 * -0.145026)
    "wood": (1.99, 0.0040234),  # 0.0047 * exp(1.0718 * -0.145026)
    "glass": (6.31, 0.0029644),  # 0.0036 * exp(1.3394 * -0.145026)
    "metal": (1.0, 1e7),  # d = 0: frequency independent
}


@pytest.mark.filterwarnings("ignore::scenes.FrequencyRangeWarning")
@pytest.mark.parametrize("name", sorted(HAND_865MHZ))
def test_material_values_at_865_mhz(name):
    eps, sigma = scenes.material(name, 865e6)
    eps_hand, sigma_hand = HAND_865MHZ[name]
    assert eps == pytest.approx(eps_hand, rel=1e-12)  # b = 0: eps_r is exactly a
    # 5 significant digits in the hand values: 1e-4 relative covers their rounding only
    assert sigma == pytest.approx(sigma_hand, rel=1e-4)


@pytest.mark.filterwarnings("ignore::scenes.FrequencyRangeWarning")
def test_concrete_conductivity_named_in_notes():
    # the bare-Sionna two-ray check (docs/physics.md) used sigma = 0.0412 S/m for concrete at 865 MHz
    assert scenes.material("concrete", 865e6)[1] == pytest.approx(0.0412, abs=5e-5)


def test_warning_emitted_once_outside_validity(monkeypatch):
    monkeypatch.setattr(materials, "_warned", set())
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        scenes.material("concrete", 400e6)
        scenes.material("concrete", 400e6)
        scenes.material("itu_concrete", 450e6)
    hits = [w for w in rec if issubclass(w.category, scenes.FrequencyRangeWarning)]
    assert len(hits) == 1
    assert "concrete" in str(hits[0].message) and "1-100 GHz" in str(hits[0].message)


def test_uhf_extrapolation_is_an_info_line_not_a_warning(monkeypatch, caplog):
    """865 MHz lies 13 % below concrete's range: stated once in the log, no warning."""
    import logging

    monkeypatch.setattr(materials, "_warned", set())
    with warnings.catch_warnings(), caplog.at_level(logging.INFO, logger="scenes.materials"):
        warnings.simplefilter("error", scenes.FrequencyRangeWarning)
        eps, sigma = scenes.material("concrete", 865e6)
        scenes.material("concrete", 865e6)
    lines = [r.getMessage() for r in caplog.records if "concrete" in r.getMessage()]
    assert len(lines) == 1 and "extrapolated to 0.865 GHz" in lines[0]
    (row,) = materials.extrapolated_materials(["itu_concrete", "wood"], 865e6)
    assert row["material"] == "concrete" and row["conductivity_s_per_m"] == sigma


def test_no_warning_inside_validity(monkeypatch):
    monkeypatch.setattr(materials, "_warned", set())
    with warnings.catch_warnings():
        warnings.simplefilter("error", scenes.FrequencyRangeWarning)
        scenes.material("wood", 865e6)  # wood's fit is valid from 1 MHz
        scenes.material("concrete", 2.4e9)


@pytest.mark.parametrize(
    ("given", "expected"),
    [
        ("itu_concrete", "concrete"),
        ("mat-itu_brick", "brick"),
        ("uhf-glass", "glass"),
        ("ITU_Metal", "metal"),
        ("itu_floorboard", "wood"),
        ("ceiling-board", "ceiling_board"),
    ],
)
def test_itu_name_mapping(given, expected):
    assert scenes.resolve_material_name(given) == expected


def test_unknown_material_named():
    with pytest.raises(scenes.UnknownMaterialError, match="unobtainium"):
        scenes.material("unobtainium")
