"""The Gen2 reader's true miss probability: p_singulated(n) and the truth built on it."""

import numpy as np
import pandas as pd
import pytest

from pipeline.acquisition import ReaderConfig
from pipeline.acquisition.gen2 import Gen2Config, inventory_counts, link_timing
from pipeline.acquisition.singulation import (
    closing_tags_per_slot,
    miss_probability_at_poses,
    miss_probability_of_attempts,
    p_singulated,
    reader_dwell_s,
    singulation_curve,
)
from pipeline.evaluation import CellGrid, detection_truth
from pipeline.evaluation.sites import SiteTruth, site_comparison
from pipeline.localisation import OracleLikelihood

# 40 read cycles/s: a 20 ms dwell (25 ms slot less 5 ms switching) holds about five
# singulations (3.75 ms each), so a dozen tags already crowd it
FAST = ReaderConfig(read_rate_hz=40.0, inventory="gen2")


def test_lone_tag_is_read_and_more_tags_are_read_less():
    dwell = reader_dwell_s(ReaderConfig())
    assert dwell == pytest.approx(0.25 - 0.005)
    assert ReaderConfig().inventory == "gen2"  # the default reader
    assert p_singulated(1, Gen2Config(), dwell) == pytest.approx(1.0, abs=0.01)
    c = singulation_curve(Gen2Config(), reader_dwell_s(FAST), 10, np.random.default_rng(5))
    assert np.all(c.standard_error < 0.01)
    assert c.p_singulated[0] == pytest.approx(1.0, abs=0.01)
    # monotone within the Monte Carlo error, and clearly falling over the range
    slack = 3 * np.hypot(c.standard_error[1:], c.standard_error[:-1]) + 1e-9
    assert np.all(np.diff(c.p_singulated) <= slack)
    assert c.p_singulated[-1] < 0.7
    # the table the truth uses is the same model (another seed: within the errors)
    p = p_singulated(np.arange(1, 11), Gen2Config(), reader_dwell_s(FAST))
    assert np.all(np.abs(p - c.p_singulated) < 5 * np.hypot(c.standard_error, 0.005) + 1e-9)


def test_closed_forms_of_q0_rounds():
    cfg = Gen2Config(q_initial=0)
    tm = link_timing(cfg)
    rng = np.random.default_rng(11)
    # one tag, Q = 0: it replies in the only slot of the first round and is read if the
    # Query and that slot fit in the dwell, never otherwise
    fits = tm.query_extra_s + tm.single_s
    assert singulation_curve(cfg, fits * (1 + 1e-9), 1, rng).p_singulated[0] == 1.0
    assert singulation_curve(cfg, fits * (1 - 1e-6), 1, rng).p_singulated[0] == 0.0
    # two tags, Q = 0: two collided rounds (Qfp 0.3, 0.6), QueryAdjust to Q = 1; a dwell
    # that then holds one single slot reads a given tag only when the tags split (1/2) and
    # it took slot 0 (1/2): p = 1/4 (an empty or collided slot 0 leaves no time for a read)
    dwell = 2 * (tm.query_extra_s + tm.collided_s) + tm.adjust_extra_s + tm.single_s + 1e-6
    c = singulation_curve(cfg, dwell, 2, rng)
    assert c.standard_error[1] < 0.01
    assert abs(c.p_singulated[1] - 0.25) < 4 * c.standard_error[1]


def test_reader_misses_match_the_table():
    # the simulated Gen2 reader with 6 closing tags in every slot reads each with p(6)
    dwell = reader_dwell_s(FAST)
    on = np.ones((500, 6), bool)
    counts = inventory_counts(on, on, dwell, FAST.gen2, np.random.default_rng(3))
    frac = (counts > 0).mean(axis=1)
    se = frac.std(ddof=1) / np.sqrt(len(frac))
    assert abs(frac.mean() - p_singulated(6, FAST.gen2, dwell)) < 4 * np.hypot(se, 0.005)


def _log(n_closed: int, n_slots: int = 30, n_tags: int = 16):
    """A read log with ``n_closed`` of ``n_tags`` tags closing in every slot, all in one
    (d, alpha) cell; the other tags' links are not traced (-inf)."""
    budget = FAST.link_budget()
    g = np.where(np.arange(n_tags) < n_closed, budget.min_gain_db() + 3.0, -np.inf)
    slot = np.repeat(np.arange(n_slots), n_tags)
    return pd.DataFrame({
        "cycle": slot, "antenna": slot % 2, "tag_id": np.tile(np.arange(n_tags), n_slots),
        "gain_db": np.tile(g, n_slots), "read": np.tile(np.isfinite(g), n_slots),
        "d_true_m": 1.1, "alpha_true_rad": 0.1,
        "true_ant_x_m": slot * 0.1, "true_ant_y_m": 0.0, "true_ant_z_m": 0.7,
        "true_ant_yaw_rad": np.where(slot % 2 == 0, 0.5, -0.5),
    }), budget


def test_fixed_inventory_is_the_constant_everywhere():
    reads, budget = _log(12)
    fixed = ReaderConfig(inventory="fixed", anticollision_miss_probability=0.07)
    np.testing.assert_array_equal(miss_probability_of_attempts(reads, fixed, budget),
                                  np.full(len(reads), 0.07))
    poses = reads[["true_ant_x_m", "true_ant_y_m", "true_ant_z_m", "true_ant_yaw_rad"]].to_numpy()[:5]
    np.testing.assert_array_equal(miss_probability_at_poses(reads, poses, fixed, budget),
                                  np.full(5, 0.07))
    # a constant array gives the scalar truth (up to rounding)
    grid = CellGrid(d_max_m=3.0, d_bin_m=0.5, alpha_bin_deg=30.0)
    a = detection_truth(reads, budget, grid, miss_probability=0.07)
    b = detection_truth(reads, budget, grid, miss_probability=np.full(len(reads), 0.07))
    np.testing.assert_allclose(b.p_detect, a.p_detect)
    assert b.miss_probability == pytest.approx(0.07)


def test_gen2_truth_is_lower_with_more_tags_in_the_field():
    grid = CellGrid(d_max_m=3.0, d_bin_m=0.5, alpha_bin_deg=30.0)
    dwell = reader_dwell_s(FAST)
    truths = {}
    for n in (2, 12):
        reads, budget = _log(n)
        n_slot = closing_tags_per_slot(reads, budget)
        assert np.all(n_slot == n)
        q = miss_probability_of_attempts(reads, FAST, budget)
        np.testing.assert_allclose(q, 1.0 - p_singulated(n, FAST.gen2, dwell))
        t = detection_truth(reads, budget, grid, miss_probability=q)
        cell = np.unravel_index(np.argmax(t.n_attempts), t.n_attempts.shape)
        # n closing of 16 tags, each read with p_singulated(n)
        assert t.p_detect[cell] == pytest.approx(n / 16 * p_singulated(n, FAST.gen2, dwell))
        truths[n] = t.p_detect[cell] / (n / 16)  # P(read | closed)
    assert truths[2] == pytest.approx(1.0, abs=0.01)
    assert truths[12] < truths[2] - 0.2


def test_sites_and_oracle_take_the_slot_population():
    reads, budget = _log(5)
    cols = ["true_ant_x_m", "true_ant_y_m", "true_ant_z_m", "true_ant_yaw_rad"]
    first = reads.drop_duplicates("cycle")
    poses = np.column_stack([first[cols].to_numpy(), np.zeros((len(first), 2))])[[3, 8]]
    dwell = reader_dwell_s(FAST)
    # a site not in the log joins the slot's five closing tags; a logged tag does not
    q_site = miss_probability_at_poses(reads, poses, FAST, budget, extra_tags=1)
    np.testing.assert_allclose(q_site, 1.0 - p_singulated([6, 6], FAST.gen2, dwell))
    q_tag = miss_probability_at_poses(reads, poses, FAST, budget, extra_tags=0)
    np.testing.assert_allclose(q_tag, 1.0 - p_singulated([5, 5], FAST.gen2, dwell))
    # per pose into the tag-site comparison: the true read fraction follows it
    g = np.full((2, 1), budget.min_gain_db() + 3.0)
    st = SiteTruth(antenna_poses=poses, positions_m=np.array([[0.5, 1.0, 0.7]]),
                   normals=np.array([[0.0, -1.0, 0.0]]), material=np.array(["wall"]), gain_db=g,
                   traced=np.ones((2, 1), bool), obstructed=np.zeros((2, 1), bool))

    class Flat:
        rssi_range_dbm = (-90.0, -30.0)

        def fs_dbm(self, d, a):
            return np.full(np.shape(d), -60.0)

        def fT(self, d, a):
            return np.full(np.shape(d), 0.5)

        def fs(self, d, a):
            return np.full(np.shape(d), 0.5)

        def rho(self, d, a):
            return np.full(np.shape(d), 0.25)

    out = site_comparison(st, Flat(), budget, miss_probability=q_site)
    assert out.summary["all"]["true_read_fraction"] == pytest.approx(1.0 - q_site.mean())
    # the oracle: per-slot miss probabilities scale P(read) of each slot
    orc = OracleLikelihood.from_reader(FAST)
    gains = np.full((2, 3), budget.min_gain_db() + 20.0)
    src = orc.with_gains(gains, np.array([0.0, 0.5]))
    p = np.exp(src.terms_for(np.arange(3)).log_read)
    np.testing.assert_allclose(p[0], 1.0 - orc.eps)  # a sure read, clipped
    np.testing.assert_allclose(p[1], 0.5, rtol=1e-6)
    with pytest.raises(ValueError, match="miss_probability"):
        orc.with_gains(gains, np.array([0.0, 1.0]))


def test_stopping_once_all_are_read_keeps_who_was_read():
    from pipeline.acquisition.gen2 import inventory

    on = np.ones(7, bool)
    heard = on.copy()
    heard[2] = False  # powered, not heard: never read, does not hold the stop back
    for seed in range(5):
        full = inventory(on, heard, 0.02, Gen2Config(), np.random.default_rng(seed))
        stop = inventory(on, heard, 0.02, Gen2Config(), np.random.default_rng(seed),
                         until_all_read=True)
        np.testing.assert_array_equal(stop > 0, full > 0)
        assert stop.max() <= 1 and stop[2] == 0


def test_fixed_study_keeps_the_constant_float():
    from pipeline.config import StudyConfig, replace_path
    from pipeline.stages.truth import pose_miss_probability

    reads, budget = _log(3)
    cfg = replace_path(StudyConfig(), "reader.inventory", "fixed")
    q = pose_miss_probability(cfg, reads, np.zeros((2, 6)), budget)
    assert isinstance(q, float) and q == cfg.reader.anticollision_miss_probability
    gen2 = pose_miss_probability(StudyConfig(), reads, np.zeros((2, 6)), budget)
    assert gen2.shape == (2,)
