"""Detection coverage of a hand-built field plane against the link-budget closed form."""

import numpy as np
import pytest

from pipeline.evaluation import detection_coverage
from propagation import LinkBudget


def test_coverage_of_hand_built_plane_matches_forward_link_threshold():
    budget = LinkBudget()
    # forward link (docs/physics.md): P_tx + g + G_tag - L_pol >= S_tag  <=>  g >= threshold;
    # with the defaults the reverse link (-80 dBm) closes ~3 dB further out, so the
    # tag threshold alone decides
    thr = (budget.tag_sensitivity_dbm - budget.tx_power_dbm + budget.polarization_loss_db
           - budget.tag_antenna_gain_dbi)
    gain = np.array([[thr + 0.01, thr - 0.01, -np.inf],
                     [-10.0, thr + 5.0, thr - 20.0]])
    res = detection_coverage(gain, budget)
    assert (res.n_cells, res.n_covered) == (6, 3)
    assert res.fraction == pytest.approx(0.5)
    # cells outside free space are not counted
    free = np.array([[True, True, False], [False, True, True]])
    res = detection_coverage(gain, budget, free)
    assert (res.n_cells, res.n_covered) == (4, 2)
    # a reader missing more than half of its replies covers nothing
    assert detection_coverage(gain, budget, miss_probability=0.6).n_covered == 0
    assert detection_coverage(gain, budget, miss_probability=0.4).n_covered == 3
    # the reverse link decides once the reader is deaf enough
    deaf = LinkBudget(reader_sensitivity_dbm=-40.0)
    assert detection_coverage(gain, deaf).n_covered == 1  # only the -10 dB cell


def test_coverage_rejects_bad_input():
    with pytest.raises(ValueError, match="free has 2 cells"):
        detection_coverage(np.zeros(3), LinkBudget(), free=[True, False])
    with pytest.raises(ValueError, match="miss_probability"):
        detection_coverage(np.zeros(3), LinkBudget(), miss_probability=1.0)
    assert detection_coverage(np.zeros((0,)), LinkBudget()).fraction == 0.0
