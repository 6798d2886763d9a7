"""Held-out scores: the oracle bound bounds every cell model on its links, its excess
splits exactly, and the error budget is built from bounds that bound."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.bound import bound_by_cell_size, cell_mean_bound, excess_over_bound
from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.comparison import rssi_cell_mean_floor
from pipeline.evaluation.heldout import error_budget, heldout_scores
from pipeline.evaluation.truth import detection_truth, true_rssi_dbm
from propagation import LinkBudget
from tests.helpers.constant_sensor import ConstantSensor

GRID = CellGrid(d_max_m=3.0, d_bin_m=0.5, alpha_bin_deg=30.0)
SIGMA_GAIN_DB = 2.0  # position-dependent fading about each cell's value, one way


class CellSensor(ConstantSensor):
    """Predicts a given per-cell gain table (+ an offset) as RSSI: a (d, alpha) cell model."""

    def __init__(self, table_db, budget, offset_db=0.0, slope_db_per_m=0.0):
        super().__init__(-50.0, 0.5)
        self.table, self.budget, self.offset, self.slope = table_db, budget, offset_db, slope_db_per_m

    def fs_dbm(self, d, a):
        idx = GRID.index(np.ravel(d), np.ravel(a))
        g = self.table.ravel()[np.maximum(idx.flat, 0)] + self.offset
        # a slope makes it vary inside a cell (not a cell model any more)
        g = g + self.slope * (np.ravel(d) - GRID.d_centres_m[idx.i_d])
        return np.reshape(self.budget.reader_rssi_dbm(g), np.shape(d))


def _reads(rng, n, table_db, offset_db=0.0):
    """Links whose gain is their cell's table value (+ offset) with Gaussian fading."""
    d = rng.uniform(0.3, 2.9, n)
    a = rng.uniform(-1.4, 1.4, n)
    idx = GRID.index(d, a)
    gain = table_db.ravel()[idx.flat] + offset_db + rng.normal(0, SIGMA_GAIN_DB, n)
    return pd.DataFrame({"tag_id": rng.choice(["A", "B"], n), "read": rng.random(n) < 0.8,
                         "rssi_dbm": np.nan, "d_true_m": d, "alpha_true_rad": a, "gain_db": gain})


def _table(rng):
    # cell values well above the closing threshold, so every link closes
    return -25.0 - 10 * np.log10(GRID.d_centres_m)[:, None] + rng.normal(0, 3, GRID.shape)


def test_bound_is_below_every_models_error_on_its_links():
    """Known answer: within a cell the truth is the cell's value plus fading of 2 dB one
    way, i.e. 4 dB in the RSSI (the link crosses the channel twice), so the bound is
    4 sqrt(1 - cells / links) dB; the model that knows each cell's value exactly scores
    ~4 dB, and every model, cell models or not, scores at least the bound on its links.
    The former floor (the TRAINING truth's cell means) is not a bound: in a held-out
    building 3 dB stronger it scores worse than the exact cell model."""
    rng = np.random.default_rng(0)
    budget = LinkBudget()
    table = _table(rng)
    train = _reads(rng, 6000, table)
    held = _reads(rng, 6000, table, offset_db=3.0)
    b = cell_mean_bound(held, GRID, budget, d_max_m=3.0, min_count=5)
    assert b.n_links == len(held)  # dense: every cell holds >= 5 links
    expected = 2 * SIGMA_GAIN_DB * np.sqrt(1 - b.n_cells / b.n_links)
    # standard error of an RMSE of 6000 Gaussian residuals: 4 / sqrt(2 * 6000) = 0.04 dB
    assert b.rmse_db == pytest.approx(expected, abs=0.15)
    models = {"exact": CellSensor(table, budget, offset_db=3.0),
              "stale": CellSensor(table, budget),  # the training building's cells
              "sloped": CellSensor(table, budget, offset_db=3.0, slope_db_per_m=4.0),
              "constant": ConstantSensor(-50.0, 0.5)}
    truth = true_rssi_dbm(held["gain_db"].to_numpy(), budget)
    for name, m in models.items():
        pred = m.fs_dbm(held["d_true_m"].to_numpy(), held["alpha_true_rad"].to_numpy())[b.rows]
        ex = excess_over_bound(b, pred)
        assert ex.rmse_db == pytest.approx(np.sqrt(np.mean((pred - truth[b.rows]) ** 2)))
        assert ex.rmse_db >= b.rmse_db, name
        # the split is exact; the between-cell term is >= 0 by construction
        assert ex.rmse_db ** 2 == pytest.approx(b.rmse_db ** 2 + ex.between_cells_db ** 2
                                                + ex.within_cells_db2, rel=1e-12)
        assert ex.between_cells_db >= 0
        if name != "sloped":  # a cell model has no within-cell term
            assert ex.within_cells_db2 == pytest.approx(0.0, abs=1e-9)
    exact = excess_over_bound(b, models["exact"].fs_dbm(held["d_true_m"].to_numpy(),
                                                        held["alpha_true_rad"].to_numpy()))
    assert exact.rmse_db == pytest.approx(2 * SIGMA_GAIN_DB, abs=0.15)  # as above
    old_floor = rssi_cell_mean_floor(held, detection_truth(train, budget, grid=GRID), budget,
                                     d_max_m=3.0)
    assert old_floor.rmse > exact.rmse_db + 1.0  # 6 dB off (3 dB x 2) on top of the fading


def test_the_mae_bound_is_the_cell_medians_not_the_means():
    """With skewed fading (an exponential tail, as deep fades are) the cell means' MAE is
    beaten by the cell medians', so the means cannot be the MAE bound: the bound's MAE is
    the medians', and no cell model (here: any per-cell quantile) scores an MAE below it."""
    rng = np.random.default_rng(3)
    budget = LinkBudget()
    table = _table(rng)
    held = _reads(rng, 4000, table)
    held["gain_db"] = table.ravel()[GRID.index(held["d_true_m"], held["alpha_true_rad"]).flat] \
        - rng.exponential(4.0, len(held))
    b = cell_mean_bound(held, GRID, budget, d_max_m=3.0, min_count=5)
    y, cell = b.truth_dbm, b.cell
    means_mae = float(np.mean(np.abs(y - b.cell_mean_dbm)))
    assert b.mae_db < means_mae - 0.1  # the mean is not the least-MAE constant here
    for q in (0.3, 0.5, 0.7):
        qs = pd.Series(y).groupby(cell).transform(lambda v, q=q: np.quantile(v, q)).to_numpy()
        assert np.mean(np.abs(y - qs)) >= b.mae_db - 1e-9, q
    scores = heldout_scores({"c": ConstantSensor(-50.0, 0.5)}, held,
                            detection_truth(held, budget, grid=GRID),
                            detection_truth(held, budget, grid=GRID), budget, d_max_m=3.0,
                            min_attempts=5, rssi_models=("c",), detection_models=())
    assert scores["bound"]["rssi_dbm"]["mae"] == pytest.approx(b.mae_db)
    assert scores["bound"]["rssi_dbm"]["rmse"] == pytest.approx(b.rmse_db)


def test_bound_falls_with_the_cell_size():
    """Nested cells on the same links: a finer partition's cell means fit at least as
    well, so the bound does not rise as the cells shrink; the models are scored on each
    bound's links."""
    rng = np.random.default_rng(1)
    budget = LinkBudget()
    table = _table(rng)
    held = _reads(rng, 20_000, table)
    rows = bound_by_cell_size(held, GRID, budget, d_max_m=3.0, min_count=5,
                              scales=(0.5, 1.0, 2.0), models={"c": ConstantSensor(-50.0, 0.5)})
    assert [r["n_links"] for r in rows] == [len(held)] * 3  # every cell full: same links
    b = [r["rmse_db"] for r in rows]
    assert b[0] <= b[1] <= b[2]
    assert all(r["c_rmse_db"] >= r["rmse_db"] for r in rows)
    with pytest.raises(ValueError, match="min_count"):
        cell_mean_bound(held, GRID, budget, d_max_m=3.0, min_count=1)


def test_heldout_scores_and_budget_use_the_bound():
    rng = np.random.default_rng(2)
    budget = LinkBudget()
    table = _table(rng)
    train, held = _reads(rng, 4000, table), _reads(rng, 4000, table, offset_db=3.0)
    tt = detection_truth(train, budget, grid=GRID)
    et = detection_truth(held, budget, grid=GRID)
    sensors = {"anfis": CellSensor(table, budget, offset_db=2.0),
               "anfis_truepose": CellSensor(table, budget, offset_db=3.0)}
    out = heldout_scores(sensors, held, tt, et, budget, d_max_m=3.0, min_attempts=5)
    bound = out["bound"]
    assert bound["rssi_dbm"]["n"] == bound["cells"]["n_links"] == len(held)
    for name in sensors:  # matched: every model on exactly the bound's links
        m = out["models"][name]
        assert m["rssi_dbm_bound_links"]["n"] == bound["rssi_dbm"]["n"]
        assert m["rssi_dbm_bound_links"]["rmse"] >= bound["rssi_dbm"]["rmse"]
        assert m["bound_excess"]["rmse_db"] == pytest.approx(m["rssi_dbm_bound_links"]["rmse"])
    assert set(bound["by_cell_size"]) == {"x0.5", "x1", "x2", "x4"}
    # detection: the held-out cells' own read frequencies; their Brier is what a cell
    # model's cannot undercut on those attempts
    assert 0 < bound["detection"]["brier"] <= 0.25
    b = error_budget(out)
    assert b["representation_bound"]["rmse_db"] == bound["cells"]["rmse_db"]
    assert b["model_form"]["between_cells_db"] >= 0
    assert b["localisation"]["step_db"] == pytest.approx(
        out["models"]["anfis"]["rssi_dbm_bound_links"]["rmse"]
        - out["models"]["anfis_truepose"]["rssi_dbm_bound_links"]["rmse"])
    assert b["total"]["rmse_db"] == out["models"]["anfis"]["rssi_dbm"]["rmse"]
    assert b["n_links"]["value"] == len(held)
    assert b["reader_noise"]["rmse_db"] is None  # no reads with an RSSI here


def test_a_cell_size_without_full_cells_scores_no_model():
    """Few links in fine cells: no cell reaches min_count, and the models are not asked
    to predict on no links (a fuzzy model refuses an empty input: the default study's
    replicate 2 stopped there)."""

    class Refuses(ConstantSensor):
        def fs_dbm(self, d, a):
            if len(np.atleast_1d(d)) == 0:
                raise ValueError("X is empty")
            return super().fs_dbm(d, a)

    rng = np.random.default_rng(2)
    held = _reads(rng, 40, _table(rng))
    rows = bound_by_cell_size(held, GRID, LinkBudget(), d_max_m=3.0, min_count=5,
                              scales=(0.25,), models={"c": Refuses(-50.0, 0.5)})
    assert rows[0]["n_links"] == 0 and np.isnan(rows[0]["c_rmse_db"])
