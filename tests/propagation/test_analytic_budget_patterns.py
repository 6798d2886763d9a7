"""Closed forms, link budget, NumPy patterns and the backend finder (no ray tracing)."""

import numpy as np
import pytest

from propagation import (
    LinkBudget,
    antenna_frame_angles,
    db_to_linear,
    free_space_gain_db,
    fresnel_reflection,
    linear_to_db,
    pattern_gain_db,
)
from propagation import backend as backend_mod
from propagation.constants import SPEED_OF_LIGHT


def test_friis_closed_form():
    # lambda/(4 pi d) at 865 MHz, 1 m: 0.346572 m / 12.566 m = -31.19 dB (exact arithmetic)
    lam = SPEED_OF_LIGHT / 865e6
    expected = 20 * np.log10(lam / (4 * np.pi * 10.0)) + 8.0 + 2.15
    assert free_space_gain_db(10.0, 865e6, 8.0, 2.15) == pytest.approx(expected, abs=1e-12)
    # doubling distance costs 6.02 dB (inverse square law)
    assert free_space_gain_db(2.0, 865e6) - free_space_gain_db(4.0, 865e6) == pytest.approx(6.0206, abs=1e-4)
    with pytest.raises(ValueError, match="distance_m"):
        free_space_gain_db(0.0, 865e6)


def test_db_conversions_roundtrip():
    x = np.array([1e-9, 0.5, 1.0, 1e3])
    np.testing.assert_allclose(db_to_linear(linear_to_db(x)), x, rtol=1e-12)
    assert linear_to_db(0.0) == -np.inf


def test_fresnel_limits():
    # grazing incidence: both polarisations reflect with -1 (classic two-ray limit)
    for pol in ("V", "H"):
        assert fresnel_reflection(1e-9, 5.24, 0.04, 865e6, pol) == pytest.approx(-1.0, abs=1e-6)
    # normal incidence, lossless: |R| = (sqrt(eps)-1)/(sqrt(eps)+1) for both (Hecht)
    r = (np.sqrt(4.0) - 1) / (np.sqrt(4.0) + 1)
    assert abs(fresnel_reflection(np.pi / 2, 4.0, 0.0, 865e6, "V")) == pytest.approx(r, abs=1e-12)
    assert abs(fresnel_reflection(np.pi / 2, 4.0, 0.0, 865e6, "H")) == pytest.approx(r, abs=1e-12)
    # Brewster angle (TM, lossless): tan(psi_B) = 1/sqrt(eps) in grazing terms -> R_V = 0
    psi_b = np.arctan(1 / np.sqrt(4.0))
    assert abs(fresnel_reflection(psi_b, 4.0, 0.0, 865e6, "V")) < 1e-12
    with pytest.raises(ValueError, match="polarization"):
        fresnel_reflection(0.1, 4.0, 0.0, 865e6, "X")


def test_link_budget_defaults_and_thresholds_exact():
    b = LinkBudget()
    # 2 W ERP = 33 dBm ERP; EIRP = ERP + 2.15 dB = P_tx + 8 dBi
    assert b.tx_power_dbm + b.reader_antenna_gain_dbi - 2.15 == pytest.approx(33.0)
    # no polarisation loss by default: the traced gain holds the reader's polarisation
    assert b.polarization_loss_db == 0.0
    g = np.array([-50.0, -45.15, -45.150001, -30.0])
    np.testing.assert_allclose(b.tag_power_dbm(g), 27.15 + g)
    np.testing.assert_allclose(b.reader_rssi_dbm(g), 27.15 + 2 * g - 6.0)
    # tag threshold: -18 = 27.15 + G  ->  G = -45.15 dB exactly (forward-link limited)
    assert b.min_gain_db() == pytest.approx(-45.15)
    np.testing.assert_array_equal(b.detected(g), [False, True, False, True])
    # a loss set explicitly counts once forward, twice in the RSSI
    b3 = LinkBudget(polarization_loss_db=3.0)
    np.testing.assert_allclose(b3.tag_power_dbm(g), 27.15 + g - 3.0)
    np.testing.assert_allclose(b3.reader_rssi_dbm(g), 27.15 + 2 * g - 6.0 - 6.0)
    assert b3.min_gain_db() == pytest.approx(-42.15)
    # reader-limited budget: a very sensitive tag makes the reader threshold bind
    b2 = LinkBudget(tag_sensitivity_dbm=-40.0)
    g_r = (-80.0 - 27.15 + 6.0) / 2
    assert b2.min_gain_db() == pytest.approx(g_r)
    assert b2.detected(g_r + 1e-9) and not b2.detected(g_r - 1e-6)


def test_link_budget_max_range_consistent_with_friis():
    b = LinkBudget()
    r = b.max_range_m(margin_db=6.0)
    g = free_space_gain_db(r, b.frequency_hz, b.reader_antenna_gain_dbi, b.tag_antenna_gain_dbi)
    assert g == pytest.approx(b.min_gain_db() - 6.0, abs=1e-9)
    assert b.max_range_m(margin_db=0.0) < r


def test_link_budget_rejects_bad_values():
    with pytest.raises(ValueError, match="tx_power_dbm"):
        LinkBudget(tx_power_dbm=float("nan"))
    with pytest.raises(ValueError, match="modulation_loss_db"):
        LinkBudget(modulation_loss_db=6.0)


def test_patterns_match_tr38901_and_dipole_definitions():
    # TR 38.901 Table 7.3-1: 8 dBi boresight, -3 dB at +-32.5 deg, 30 dB front-back
    assert pattern_gain_db("tr38901", np.pi / 2, 0.0) == pytest.approx(8.0, abs=1e-12)
    assert pattern_gain_db("tr38901", np.pi / 2, np.deg2rad(32.5)) == pytest.approx(5.0, abs=1e-12)
    assert pattern_gain_db("tr38901", np.pi / 2 + np.deg2rad(32.5), 0.0) == pytest.approx(5.0, abs=1e-12)
    assert pattern_gain_db("tr38901", np.pi / 2, np.pi) == pytest.approx(8.0 - 30.0, abs=1e-12)
    # half-wave dipole: 1.643 = 2.156 dBi broadside (Balanis 4-84), null along the axis
    assert pattern_gain_db("hw_dipole", np.pi / 2, 0.3) == pytest.approx(10 * np.log10(1.643), abs=1e-12)
    assert pattern_gain_db("hw_dipole", 1e-7, 0.0) < -100
    assert pattern_gain_db("iso", 0.3, 2.0) == 0.0
    with pytest.raises(ValueError, match="patch"):
        pattern_gain_db("patch", 0.0, 0.0)


def test_tr38901_numpy_matches_sionna_function():
    # Sionna's own pattern function evaluated through Dr.Jit (same formula, float32)
    from propagation import select_variant

    select_variant()
    import mitsuba as mi
    from sionna.rt.antenna_pattern import v_hw_dipole_pattern, v_tr38901_pattern

    rng = np.random.default_rng(0)
    th = rng.uniform(0, np.pi, 500)
    ph = rng.uniform(-4, 4, 500)
    for name, fn in (("tr38901", v_tr38901_pattern), ("hw_dipole", v_hw_dipole_pattern)):
        c = fn(mi.Float(th), mi.Float(ph))
        ref = np.abs(np.array(c.real))
        ours = 10 ** (pattern_gain_db(name, th, ph) / 20)
        # field amplitudes (peak 2.5), compared in amplitude, not dB: Sionna evaluates in
        # float32, and within ~2 deg of the dipole axis cos(pi/2 cos(theta)) loses most of
        # its digits there (errors up to 2e-4 on amplitudes of 1e-3, i.e. -68 dB below the
        # peak); 5e-4 absolute bounds that, 1e-4 relative (float32 inputs) checks everything above -34 dB
        np.testing.assert_allclose(ours, ref, atol=5e-4, rtol=1e-5)
        big = ref > 0.05
        np.testing.assert_allclose(ours[big], ref[big], rtol=1e-4)


def test_antenna_frame_angles_conventions():
    poses = np.array([[0.0, 0.0, 1.0, np.pi / 2, 0.0, 0.0],     # facing +y
                      [0.0, 0.0, 1.0, 0.0, np.pi / 4, 0.0]])    # tilted up 45 deg
    pts = np.array([[0.0, 2.0, 1.0], [-1.0, 0.0, 1.0], [1.0, 0.0, 2.0]])
    a = antenna_frame_angles(poses, pts)
    assert a.d_m[0, 0] == pytest.approx(2.0)
    assert a.alpha_rad[0, 0] == pytest.approx(0.0, abs=1e-12)       # straight ahead
    assert a.alpha_rad[0, 1] == pytest.approx(np.pi / 2)            # -x is to the left of +y
    assert a.elevation_rad[1, 2] == pytest.approx(0.0, abs=1e-12)   # on the tilted boresight
    assert np.all(a.alpha_rad > -np.pi) and np.all(a.alpha_rad <= np.pi)
    with pytest.raises(ValueError, match="antenna_poses"):
        antenna_frame_angles(np.zeros((2, 5)), pts)


def test_find_libllvm_rejects_old_and_explains(monkeypatch, tmp_path):
    path = backend_mod.find_libllvm()
    assert backend_mod._llvm_major(path) >= 16
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "libLLVM-15.so"))
    monkeypatch.setattr(backend_mod, "_LIB_DIRS", (str(tmp_path),))
    monkeypatch.setattr(backend_mod.glob, "glob", lambda pattern: [])
    with pytest.raises(backend_mod.BackendError, match="apt-get install libllvm19"):
        backend_mod.find_libllvm()


def test_select_variant_rejects_unknown():
    with pytest.raises(ValueError, match="prefer"):
        backend_mod.select_variant("metal")
