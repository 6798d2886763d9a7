"""Vorst & Zell's ground-plane table at a known tag height: the localisers and the
held-out scores give it each candidate's / tag's / link's height above the antenna
rather than the training height mix (``fT``)."""

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.comparison import cell_centre_fT, detection_vs_truth
from pipeline.evaluation.interface import detection_probability, uses_tag_height
from pipeline.evaluation.truth import TruthGrid
from pipeline.evaluation.units import detection_cells
from pipeline.localisation import ModelLikelihood, Observations, localise_tags
from pipeline.localisation.benchmark import DetectionOnly
from pipeline.sensormodels import Attempts, fit_vorst2008

D = 1.65  # a 3-D range where the two heights disagree: r = 1.65 (not read) or 1.38 (read)
UP = 0.9


@pytest.fixture(scope="module")
def two_heights(synth):
    """Tags read iff within the 45-deg half-cone and 1.5 m HORIZONTALLY of the antenna,
    half of them in its plane and half 0.9 m above it."""
    rng = np.random.default_rng(7)
    n = 150_000
    r = rng.uniform(0.05, 2.6, n)
    a = rng.uniform(-np.pi, np.pi, n)
    dz = rng.choice([0.0, UP], n)
    att = Attempts(np.hypot(r, dz), a, (r < 1.5) & (np.abs(a) < np.pi / 4), dz_m=dz)
    return fit_vorst2008(att, synth.RSSI_RANGE, np.random.default_rng(0), d_max_m=3.0,
                         cell_m=0.1, bandwidths_m=[0.0])


def test_fT_at_height_is_the_ground_plane_table(two_heights):
    m = two_heights
    assert uses_tag_height(m)
    # the averaged fT mixes the two heights at this range; each height alone does not
    assert 0.3 < m.fT(D, 0.0) < 0.7
    np.testing.assert_allclose(m.fT_at_height([D, D], 0.0, [0.0, UP]), [0.0, 1.0], atol=0.05)
    r = np.sqrt(D ** 2 - UP ** 2)
    assert m.fT_at_height(D, 0.3, UP) == m.ground_plane_fT(r, 0.3)
    # beyond d_max (3-D range, no training data) 0 like fT, even where the horizontal
    # range is inside the table (3.2 m at 1.2 m up: r = 2.97 m); NaN in, NaN out;
    # |dz| >= d: the antenna's own cell
    assert m.ground_plane_fT(np.sqrt(3.2 ** 2 - 1.2 ** 2), 0.0) > 0
    np.testing.assert_array_equal(m.fT_at_height([3.0, 3.2], 0.0, [0.0, 1.2]), [0.0, 0.0])
    assert np.isnan(m.fT_at_height(np.nan, 0.0, 0.0))
    assert np.isnan(m.fT_at_height(1.0, 0.0, np.nan))
    assert m.fT_at_height(0.5, 0.0, 0.7) == m.ground_plane_fT(0.0, 0.0)
    # the helper: the height where the model uses it, fT otherwise
    assert detection_probability(m, D, 0.0, UP) == m.fT_at_height(D, 0.0, UP)
    assert detection_probability(m, D, 0.0) == m.fT(D, 0.0)


class _Constant:
    """A detection model that ignores the height (every model but Vorst & Zell's)."""

    rssi_range_dbm = (-80.0, -30.0)

    def fT(self, d, alpha):  # noqa: N802
        return np.full(np.broadcast(np.asarray(d), np.asarray(alpha)).shape, 0.4)


def test_other_models_ignore_the_height():
    m = DetectionOnly(_Constant())  # the project's detection-only wrapper
    assert not uses_tag_height(m)
    np.testing.assert_array_equal(detection_probability(m, [1.0, 2.0], 0.0, [0.0, 5.0]), 0.4)
    lik = ModelLikelihood(m, use_rssi=False)
    assert not lik.uses_height
    np.testing.assert_array_equal(lik.terms([1.0], [0.0], [9.0]).log_read, np.log(0.4))


def test_tag_localiser_uses_each_candidates_height(two_heights):
    # one antenna at the origin (boresight +x) reads the tag; two candidates at the same
    # 3-D range and bearing: in the antenna's plane (not readable there) and 0.9 m up
    # (readable). The height mix would give both the same likelihood.
    cand = np.array([[D, 0.0, 0.0], [np.sqrt(D ** 2 - UP ** 2), 0.0, UP]])
    obs = Observations(("t",), [0.0], [0], np.zeros((1, 6)), [[True]], [[np.nan]], [[True]])
    for d_max in (None, 3.0):
        kw = {} if d_max is None else {"d_max_m": d_max, "p_far": 0.0}
        post = localise_tags(obs, cand, {"v": ModelLikelihood(two_heights, **kw)})["v"]
        assert post.posterior[0, 1] > 0.95


def test_robot_filter_uses_each_tags_height(two_heights):
    # the same two tags read from one antenna pose: the robot filter's pose likelihood
    tags = np.array([[D, 0.0, 0.0], [np.sqrt(D ** 2 - UP ** 2), 0.0, UP]])
    pose = np.zeros((1, 6))
    for kw in ({}, {"d_max_m": 3.0, "p_far": 0.0}):
        lik = ModelLikelihood(two_heights, **kw)
        low = lik.pose_loglik(pose, tags[:1], [True], [np.nan])[0]
        high = lik.pose_loglik(pose, tags[1:], [True], [np.nan])[0]
        assert high > np.log(0.9) and low < np.log(0.1)
        # pair_loglik with the heights agrees with pose_loglik
        d = np.full((1, 2), D)
        pl = lik.pair_loglik(d, np.zeros((1, 2)), [True, True], [np.nan, np.nan],
                             dz_m=tags[None, :, 2])
        np.testing.assert_allclose(pl[0], [low, high], rtol=1e-12)


def test_heldout_scores_use_each_links_height(two_heights):
    # held-out links at the same (d, alpha): 3 of 4 tags 0.9 m up (read), 1 of 4 in the
    # antennas' plane (missed). With each link's height the model is right on every
    # link; the training height mix (~1:1 at this range) would predict ~0.5 throughout
    n = 400
    dz = np.where(np.arange(n) % 4 == 0, 0.0, UP)
    reads = pd.DataFrame({"d_true_m": np.full(n, D), "alpha_true_rad": np.zeros(n),
                          "read": dz > 0})
    grid = CellGrid(d_max_m=3.0, d_bin_m=0.1, alpha_bin_deg=10.0)
    idx = grid.index(reads["d_true_m"], reads["alpha_true_rad"])
    n_att = np.zeros(grid.shape, np.int64)
    n_att.ravel()[idx.flat[0]] = n
    p = np.where(n_att > 0, 0.75, np.nan)
    truth = TruthGrid(grid, n_att, (n_att * 0.75).astype(np.int64), (n_att * 0.75).astype(np.int64),
                      p, np.full(grid.shape, np.nan), 0.0)
    with_h = detection_vs_truth(reads, two_heights, truth, min_attempts=5, dz_m=dz)
    mixed = detection_vs_truth(reads, two_heights, truth, min_attempts=5)
    assert with_h.brier < 0.01 and mixed.brier > 0.15
    assert with_h.cells.mae < 0.05 and mixed.cells.mae > 0.1
    # the per-unit table of the cell MAE holds the same cell prediction
    cells = detection_cells({"v": two_heights}, grid, names=["v"], eval_reads=reads, dz_m=dz)
    ft = cells.set_index("cell")["ft_centre"]
    assert ft[idx.flat[0]] == pytest.approx(
        float(cell_centre_fT(two_heights, grid, n_att > 0, reads["d_true_m"],
                             reads["alpha_true_rad"], dz)[0]), abs=1e-15)
    assert abs(ft[idx.flat[0]] - 0.75) < 0.05
