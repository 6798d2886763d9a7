"""Reader response: both link thresholds exactly, RSSI noise and quantisation, misses."""

import numpy as np
import pytest

from pipeline.acquisition import ReaderConfig, reader_response
from pipeline.config import config_from_mapping
from propagation import LinkBudget

# Numbers chosen so every dB sum below is exact in binary floating point:
# P_tag = 30 + g - 3, P_rx = 30 + 2 g - 6 - 2 * 3.
BUDGET = dict(
    tx_power_dbm=30.0,
    tag_sensitivity_dbm=-18.0,
    reader_sensitivity_dbm=-80.0,
    polarization_loss_db=3.0,
    modulation_loss_db=-6.0,
)


def _reader(**kw):
    base = dict(rssi_noise_db=0.0, rssi_resolution_db=0.0, anticollision_miss_probability=0.0)
    return ReaderConfig(**{**BUDGET, **base, **kw.pop("budget", {}), **kw})


def test_budget_equations_as_in_design():
    r = _reader()
    g = np.array([-45.0, -30.0])
    np.testing.assert_array_equal(r.link_budget().tag_power_dbm(g), [-18.0, -3.0])
    np.testing.assert_array_equal(r.link_budget().reader_rssi_dbm(g), [-72.0, -42.0])


def test_forward_link_threshold_exact():
    # The tag threshold binds here: g = -45 dB gives P_tag = -18 dBm exactly and
    # P_rx = -72 dBm, above the -80 dBm reader sensitivity.
    r = _reader()
    g = np.array([-45.0 - 1e-9, -45.0, -45.0 + 1e-9])
    resp = reader_response(g, r, np.random.default_rng(0))
    np.testing.assert_array_equal(resp.powered, [False, True, True])
    np.testing.assert_array_equal(resp.read, [False, True, True])
    assert np.all(resp.heard)
    # Zero noise, no quantisation: the reported RSSI is the budget's P_rx.
    np.testing.assert_allclose(resp.rssi_dbm[1:], [-72.0, -72.0], atol=1e-8)
    assert np.isnan(resp.rssi_dbm[0])


def test_reverse_link_threshold_exact():
    # Reader sensitivity raised to -60 dBm: g = -39 dB gives P_rx = -60 dBm exactly while
    # the tag is well powered (P_tag = -12 dBm), so the reverse link binds.
    r = _reader(budget={"reader_sensitivity_dbm": -60.0})
    g = np.array([-39.0 - 1e-9, -39.0, -39.0 + 1e-9])
    resp = reader_response(g, r, np.random.default_rng(0))
    assert np.all(resp.powered)
    np.testing.assert_array_equal(resp.heard, [False, True, True])
    np.testing.assert_array_equal(resp.read, [False, True, True])


def test_untraced_links_never_read():
    resp = reader_response(np.array([-np.inf]), _reader(), np.random.default_rng(0))
    assert not resp.read[0] and not resp.powered[0] and resp.tag_power_dbm[0] == -np.inf


def test_rssi_noise_statistics():
    n = 20_000
    r = _reader(rssi_noise_db=1.5)
    resp = reader_response(np.full(n, -30.0), r, np.random.default_rng(1))
    err = resp.rssi_dbm - (-42.0)
    # Mean: 5 standard errors (1.5 / sqrt(n) = 0.011 dB); std: 5 standard errors of a
    # Gaussian sample std (sigma / sqrt(2 n) = 0.0075 dB).
    assert abs(err.mean()) < 5 * 1.5 / np.sqrt(n)
    assert abs(err.std(ddof=1) - 1.5) < 5 * 1.5 / np.sqrt(2 * n)


def test_rssi_quantisation_step():
    r = _reader(rssi_resolution_db=0.5)
    # Noise-free -42.3 dBm rounds to the nearest 0.5 dB step: -42.5 dBm.
    resp = reader_response(np.array([-30.15]), r, np.random.default_rng(0))
    assert resp.rssi_dbm[0] == -42.5
    n = 20_000
    rq = _reader(rssi_resolution_db=0.5, rssi_noise_db=1.0)
    resp = reader_response(np.full(n, -30.0), rq, np.random.default_rng(2))
    steps = resp.rssi_dbm / 0.5
    np.testing.assert_array_equal(steps, np.round(steps))
    assert len(np.unique(resp.rssi_dbm)) > 10  # noise spreads over many steps
    # Sheppard: quantising adds step^2 / 12 to the variance; 5 standard errors.
    expected = np.sqrt(1.0 + 0.5**2 / 12)
    assert abs(resp.rssi_dbm.std(ddof=1) - expected) < 5 * expected / np.sqrt(2 * n)


def test_anticollision_miss_rate_binomial():
    n, p = 20_000, 0.07
    r = _reader(anticollision_miss_probability=p)
    resp = reader_response(np.full(n, -30.0), r, np.random.default_rng(4))
    misses = int((~resp.read).sum())
    sigma = np.sqrt(n * p * (1 - p))  # binomial standard deviation, 36 misses
    assert abs(misses - n * p) < 4 * sigma
    assert np.array_equal(~resp.read, resp.collided)


def test_same_seed_same_response():
    r = _reader(rssi_noise_db=1.0, rssi_resolution_db=0.5, anticollision_miss_probability=0.1)
    g = np.linspace(-60, -20, 500)
    a = reader_response(g, r, np.random.default_rng(9))
    b = reader_response(g, r, np.random.default_rng(9))
    np.testing.assert_array_equal(a.rssi_dbm, b.rssi_dbm)
    np.testing.assert_array_equal(a.read, b.read)


@pytest.mark.parametrize("rate", [0.0, -1.0, float("nan")])
def test_read_rate_must_be_positive(rate):
    with pytest.raises(ValueError, match="read_rate_hz"):
        ReaderConfig(read_rate_hz=rate)


def test_config_errors_name_key_and_file():
    # the study's [reader] section is the reader's config: read by the study's schema
    with pytest.raises(KeyError, match=r"study.toml.*reader.read_rate"):
        config_from_mapping({"reader": {"read_rate": 5.0}}, source="study.toml")
    with pytest.raises(ValueError, match=r"study.toml.*read_rate_hz"):
        config_from_mapping({"reader": {"read_rate_hz": 0}}, source="study.toml")
    with pytest.raises(KeyError, match=r"reader.tx_power.*tx_power_dbm"):
        config_from_mapping({"reader": {"tx_power": 1.0}}, source="study.toml")
    with pytest.raises(ValueError, match="anticollision_miss_probability"):
        ReaderConfig(anticollision_miss_probability=1.0)


def test_reader_config_is_the_study_section_and_builds_the_budget():
    cfg = config_from_mapping({"frequency_hz": 866e6,
                               "reader": {"read_rate_hz": 8.0, "tx_power_dbm": 25.0}}, source="study.toml")
    r = cfg.reader
    assert isinstance(r, ReaderConfig) and r.read_rate_hz == 8.0
    b = r.link_budget(cfg.frequency_hz)
    assert b.tx_power_dbm == 25.0 and b.frequency_hz == 866e6
    # one default per key: the budget keys default to LinkBudget's
    assert ReaderConfig().link_budget() == LinkBudget()
