"""Truth at tag sites: obstruction by geometry and the comparison numbers."""

from __future__ import annotations

import numpy as np
import pytest

import scenes
from pipeline.evaluation.sites import SiteTruth, obstructed_pairs, site_comparison
from propagation import LinkBudget
from tests.helpers.constant_sensor import ConstantSensor


def test_wall_behind_a_cabinet_is_obstructed():
    lab = scenes.load("corridor_lab")
    ant = np.array([[14.0, 1.2, 0.7]])
    sites = np.array([[14.0, 0.005, 1.0],    # on the wall behind cabinet C2 (x 13.55-14.45)
                      [10.0, 0.005, 1.0]])   # on the open brick wall
    obs = obstructed_pairs(lab, ant, sites)
    assert obs.tolist() == [[True, False]]


def test_site_comparison_numbers(tmp_path):
    budget = LinkBudget()
    poses = np.array([[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]])
    pos = np.array([[1.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 2.0, 1.0]])
    gain = np.array([[-10.0, -200.0, -np.inf]])  # closes / does not close / not traced
    truth = SiteTruth(poses, pos, np.tile([-1.0, 0, 0], (3, 1)), np.array(["brick"] * 3), gain,
                      np.array([[True, True, False]]), np.array([[False, True, False]]))
    truth.save(tmp_path / "s.npz")
    truth = SiteTruth.load(tmp_path / "s.npz")
    s = ConstantSensor(-50.0, 0.5)
    out = site_comparison(truth, s, budget, miss_probability=0.05)
    assert out.summary["all"]["n_pairs"] == 2 and out.summary["obstructed"]["n_pairs"] == 1
    # fT 0.5 against p_true 0.95 (closed) and 0 (not closed)
    assert out.summary["all"]["fT_mae"] == pytest.approx((0.45 + 0.5) / 2)
    assert out.summary["clear"]["true_read_fraction"] == pytest.approx(0.95)
    assert len(out.per_site) == 2 and out.per_site["obstructed_fraction"].tolist() == [0.0, 1.0]
    with pytest.raises(ValueError, match="missing key"):
        np.savez(tmp_path / "bad.npz", gain_db=gain)
        SiteTruth.load(tmp_path / "bad.npz")
