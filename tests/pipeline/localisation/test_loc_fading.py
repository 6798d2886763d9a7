"""The fading-aware oracle likelihood on local-mean gains (pipeline.localisation.fading):
its constants against the closed forms and sampled fading, and its calibration on links
faded and read as the reader simulation reads them."""

import numpy as np
import pytest
from scipy import stats

from pipeline.acquisition.config import ReaderConfig
from pipeline.acquisition.reader import reader_response
from pipeline.localisation import OracleLikelihood
from pipeline.localisation.fading import (
    RAYLEIGH,
    RAYLEIGH_POWER_SIGMA_DB,
    RAYLEIGH_RSSI_MEAN_DB,
    RAYLEIGH_RSSI_SIGMA_DB,
    FadedLikelihood,
    FadingModel,
)
from pipeline.localisation.global_oracle import widened

N_LINKS = 40_000  # per local-mean level: KS's 1 % critical value 1.63 / sqrt(n_reads) < 0.013


def test_rayleigh_rssi_offset_is_twice_the_one_way_fading_with_its_log_bias():
    """The RSSI carries the one-way fading twice (monostatic, reciprocal): 20 log10 E of
    E ~ Exp(1) has mean -gamma 20/ln 10 and std pi/sqrt(6) 20/ln 10 (Gumbel), checked on draws."""
    assert RAYLEIGH_RSSI_MEAN_DB == pytest.approx(-5.0136, abs=1e-4)
    assert RAYLEIGH_RSSI_SIGMA_DB == pytest.approx(11.1401, abs=1e-4)
    assert RAYLEIGH_RSSI_SIGMA_DB == pytest.approx(2 * RAYLEIGH_POWER_SIGMA_DB)
    x = 20 * np.log10(RAYLEIGH.sample_power_ratio(400_000, np.random.default_rng(1)))
    # standard errors: 11.1 / sqrt(4e5) = 0.018 dB on the mean, ~0.03 dB on the std
    assert x.mean() == pytest.approx(RAYLEIGH_RSSI_MEAN_DB, abs=0.08)
    assert x.std() == pytest.approx(RAYLEIGH_RSSI_SIGMA_DB, abs=0.12)


@pytest.mark.parametrize("k", [0.0, 4.0])
def test_fading_law_matches_its_draws(k):
    """Unit-mean power; survival function and moments of the dB offset against draws
    (a Rician K of 4 included: its moments come from quadrature)."""
    f = FadingModel(k)
    e = f.sample_power_ratio(400_000, np.random.default_rng(2))
    assert e.mean() == pytest.approx(1.0, abs=0.01)  # std of the mean <= 1 / sqrt(4e5)
    for q in (0.1, 1.0, 2.0):  # binomial standard error <= 0.0008
        assert (e >= q).mean() == pytest.approx(np.exp(f.power_logsf(q)), abs=0.004)
    m, s = f.rssi_offset_moments_db()
    x = 20 * np.log10(e)
    assert x.mean() == pytest.approx(m, abs=0.08) and x.std() == pytest.approx(s, abs=0.12)


def _faded_reads(level_db, k, rng):
    """Links whose local-mean gain lies ``level_db`` above the closing threshold, faded by
    the Rician law and read by the study's reader (noise 1 dB, 0.5 dB steps, fixed misses)."""
    reader = ReaderConfig(inventory="fixed", anticollision_miss_probability=0.05)
    g_bar = reader.link_budget().min_gain_db() + level_db
    g = g_bar + 10 * np.log10(FadingModel(k).sample_power_ratio(N_LINKS, rng))
    resp = reader_response(g, reader, rng)
    return reader, g_bar, resp.read, resp.rssi_dbm


def _pit(lik, g_bar, rssi, rng, step_db):
    """Probability integral transform of reads' RSSI under the likelihood's own density
    (integrated on a grid, so the density itself is what is tested); a rounded reading is
    spread over its rounding step (randomised PIT)."""
    terms = lik.terms(np.array([g_bar]))
    mu = float(lik.budget.reader_rssi_dbm(g_bar))
    grid = np.linspace(mu - 120.0, mu + 45.0, 33_001)
    dens = np.exp(terms.read_loglik(grid, np.zeros(grid.size, int)) - terms.log_read[0])
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(grid))])
    cdf /= cdf[-1]
    r = rssi + rng.uniform(-step_db / 2, step_db / 2, rssi.size)
    return np.interp(r, grid, cdf)


@pytest.mark.parametrize("k", [0.0, 4.0])
@pytest.mark.parametrize("level_db", [15.0, 4.0, 0.0])
def test_faded_likelihood_is_calibrated(level_db, k):
    """On links faded and read as the simulator reads them, the read fraction is P(read)
    and the PIT of the RSSI is uniform (KS), far above the threshold and at it (where the
    density is truncated); the Gaussian at the local mean with a 5.57 dB spread (the
    former oracle) is far from calibrated on the same links."""
    rng = np.random.default_rng(int(level_db * 10 + k))
    reader, g_bar, read, rssi = _faded_reads(level_db, k, rng)
    oracle = OracleLikelihood.from_reader(reader)
    lik = FadedLikelihood(oracle, FadingModel(k))
    p = float(lik.read_probability(g_bar))
    assert read.mean() == pytest.approx(p, abs=4 * np.sqrt(p * (1 - p) / N_LINKS))
    pit = _pit(lik, g_bar, rssi[read], rng, reader.rssi_resolution_db)
    d = stats.kstest(pit, "uniform").statistic
    # 1 % critical value (< 0.013 with >= 15,000 reads) plus 0.005 for the Gaussian that
    # stands in for the uniform rounding error inside the likelihood
    assert d < 1.63 / np.sqrt(read.sum()) + 0.005, d
    if k == 0.0:
        old = widened(oracle, RAYLEIGH_POWER_SIGMA_DB)  # mean at the local mean, 5.6 dB
        z = (rssi[read] - float(old.budget.reader_rssi_dbm(g_bar))) / old.sigma_db
        assert stats.kstest(stats.norm.cdf(z), "uniform").statistic > 0.05  # >3x the bound


def test_faded_terms_match_the_likelihood_and_floor_outliers():
    """FadedTerms: a miss scores log(1 - P(read)), a read log P(read) + log p(rssi | read);
    an RSSI far beyond the fading's reach is floored, not -inf; untraced pairs (-inf) are
    certain misses up to eps."""
    oracle = OracleLikelihood.from_reader(ReaderConfig(inventory="fixed"))
    lik = FadedLikelihood(oracle)
    g = np.array([[-40.0, -45.0, -np.inf]])
    terms = lik.terms(g)
    p = np.clip(lik.read_probability(g), lik.eps, 1 - lik.eps)
    mu = lik.budget.reader_rssi_dbm(g)
    r = np.array([[mu[0, 0] - 3.0, mu[0, 1] + 200.0, -60.0]])
    ll = terms.loglik(np.array([[True, True, False]]), r)
    assert ll[0, 0] == pytest.approx(np.log(p[0, 0]) + lik.rssi_logpdf_given_read(r[0, 0], mu[0, 0]))
    assert np.isfinite(ll[0, 1]) and ll[0, 1] == pytest.approx(np.log(p[0, 1]) + lik._log_floor)
    assert ll[0, 2] == pytest.approx(np.log1p(-lik.eps))
    with pytest.raises(ValueError, match="k_factor"):
        FadingModel(-1.0)
