import numpy as np
import pytest

from pipeline.sensormodels import Attempts, Liu2006Model, Vorst2008Model, fit_liu2006


def _h(p):
    """Bernoulli log-likelihood per trial at its own rate: p log p + (1 - p) log(1 - p)."""
    return p * np.log(p) + (1 - p) * np.log1p(-p)


def test_recovers_a_sector_model_sampled_from_itself(synth):
    R, hw, b, p_in, p_out = 2.0, np.deg2rad(40), np.deg2rad(10), 0.8, 0.05

    def p(d, a):
        inside = (d < R) & (np.abs(np.angle(np.exp(1j * (a - b)))) < hw)
        return np.where(inside, p_in, p_out)

    m = fit_liu2006(Attempts(*synth.sample(200_000, seed=2, p=p)), synth.RSSI_RANGE, d_max_m=3.0)
    # the true sector lies on the candidate grid (0.05 m, 2.5 deg); ~750 attempts fall in
    # each 0.05 m / 2.5 deg boundary strip, so the edge is off by at most one step
    assert m.range_m == pytest.approx(R, abs=0.05 + 1e-9)
    assert np.rad2deg(m.half_width_rad) == pytest.approx(40, abs=2.5 + 1e-9)
    assert np.rad2deg(m.boresight_rad) == pytest.approx(10, abs=2.5 + 1e-9)
    # rates: binomial SE with ~29 000 attempts inside (0.0023) and ~170 000 outside
    # (0.0005), plus at most one misassigned strip: 0.01 and 0.003
    assert m.p_inside == pytest.approx(p_in, abs=0.01)
    assert m.p_outside == pytest.approx(p_out, abs=0.003)
    np.testing.assert_array_equal(m.fT([1.0, 1.0, 2.5], [b, b + 1.0, b]), [m.p_inside,
                                                                           m.p_outside, m.p_outside])


def test_cone_truth_gives_the_cone_and_the_likelihood_optimal_range(big_attempts, synth):
    m = fit_liu2006(big_attempts, synth.RSSI_RANGE, d_max_m=3.0)
    # the cone's edge is sharp (0.95 - 0.25 d vs 0.05): recovered to one angle step
    assert np.rad2deg(m.half_width_rad) == pytest.approx(45, abs=2.5 + 1e-9)
    assert np.rad2deg(m.boresight_rad) == pytest.approx(0, abs=2.5 + 1e-9)
    # along d the truth falls smoothly; the best range is where including the next
    # strip stops paying: maximise the expected log-likelihood per attempt over R
    # for the 90-deg cone (quadrature over d, exact for the truth's linear p)
    Rs = np.arange(1, 59) * 0.05
    w_cone, span = 0.25, synth.D_HI - synth.D_LO
    ll, pins, pouts = [], [], []
    for R in Rs:
        lo_len = max(R - synth.D_LO, 1e-12)
        p_in = 0.95 - 0.25 * (synth.D_LO + R) / 2  # mean of the linear p over [D_LO, R)
        w_in = w_cone * lo_len / span
        mass_out = 0.05 * (1 - w_cone) + w_cone * (span - lo_len) / span * (
            0.95 - 0.25 * (R + synth.D_HI) / 2)
        p_out = mass_out / (1 - w_in)
        ll.append(w_in * _h(p_in) + (1 - w_in) * _h(p_out))
        pins.append(p_in)
        pouts.append(p_out)
    k = int(np.argmax(ll))
    # the expected log-likelihood is flat near its optimum (2.75 m): one step (0.05 m)
    # away it is < 7e-5 nats/attempt lower, two steps < 2.5e-4, while the sampling noise
    # of such a difference (~860 attempts in a 0.05 m strip of the cone) is ~1e-4
    assert m.range_m == pytest.approx(Rs[k], abs=0.1 + 1e-9)
    j = int(np.argmin(np.abs(Rs - m.range_m)))
    # rates at the fitted range: binomial SE < 0.003 inside and < 0.001 outside
    assert m.p_inside == pytest.approx(pins[j], abs=0.01)
    assert m.p_outside == pytest.approx(pouts[j], abs=0.003)
    assert m.at_search_bound == ()  # an interior optimum
    assert m.train_log_likelihood < 0 and m.n_attempts == 200_000


def test_detection_only_and_degenerate_data_raise(synth):
    """The sector predicts no RSSI (so no RSSI row is scored for it)."""
    d = np.array([0.5, 0.6, 0.7, 2.5, 2.6])
    a = np.zeros(5)
    read = np.array([True, True, True, False, True])
    rssi = np.array([-40.0, -42.0, -44.0, np.nan, -60.0])
    m = fit_liu2006(Attempts(d, a, read, rssi), synth.RSSI_RANGE, d_max_m=3.0)
    assert m.predicts_rssi is False
    assert np.all(np.isnan(m.fs_dbm([0.5, 2.0], [0.0, 1.0])))
    np.testing.assert_array_equal(m.rho([0.5, 2.0], [0.0, 1.0]), m.fT([0.5, 2.0], [0.0, 1.0]))
    assert "project's own" in m.DISPLAY_NAME and "not checked" in m.REFERENCE
    with pytest.raises(ValueError, match="both reads and misses"):
        fit_liu2006(Attempts(d, a, np.ones(5, bool), rssi), synth.RSSI_RANGE, d_max_m=3.0)


def test_a_fit_on_the_search_edge_says_so(synth):
    """A sector read at a constant rate up to the data's end: the best range is the
    largest searched (d_max), a bound and not an optimum, and the fit says so; likewise a
    boresight beyond the searched +-45 deg."""
    def p(d, a):  # 0.8 inside |alpha - 60 deg| < 20 deg at every distance, 0.05 elsewhere
        return np.where(np.abs(np.angle(np.exp(1j * (a - np.deg2rad(60))))) < np.deg2rad(20),
                        0.8, 0.05)

    m = fit_liu2006(Attempts(*synth.sample(100_000, seed=9, p=p)), synth.RSSI_RANGE, d_max_m=3.0)
    assert m.range_m == pytest.approx(3.0)
    assert np.rad2deg(abs(m.boresight_rad)) == pytest.approx(45.0)
    assert m.at_search_bound == ("range_m", "boresight_rad")
    free = fit_liu2006(Attempts(*synth.sample(100_000, seed=9, p=p)), synth.RSSI_RANGE,
                       d_max_m=3.0, boresight_max_deg=90.0)
    assert free.at_search_bound == ("range_m",)
    # and the study's metrics say so (metrics.json model_fits)
    from pipeline.stages.evaluation import model_fits

    fits = model_fits({"liu2006": m})["liu2006"]
    assert fits["at_search_bound"] == "range_m, boresight_rad" and "bound" in fits["note"]
    assert fits["predicts_rssi"] is False
    assert np.rad2deg(free.boresight_rad) == pytest.approx(60.0, abs=2.5 + 1e-9)


def test_json_round_trip_and_wrong_kind(big_attempts, synth, tmp_path):
    m = fit_liu2006(big_attempts, synth.RSSI_RANGE, d_max_m=3.0)
    path = m.save(tmp_path / "liu.json")
    back = Liu2006Model.load(path)
    rng = np.random.default_rng(4)
    d, a = rng.uniform(0, 4, 3000), rng.uniform(-4, 4, 3000)
    for name in ("fT", "fs", "fs_dbm", "rho", "inside"):
        np.testing.assert_array_equal(getattr(back, name)(d, a), getattr(m, name)(d, a))
    assert back.at_search_bound == m.at_search_bound
    assert back.params_dict() == m.params_dict()
    with pytest.raises(ValueError, match=r"liu\.json.*'liu2006'.*'vorst2008'"):
        Vorst2008Model.load(path)
