"""Phase-based tag localisation (synthetic aperture) on free-space phases along a straight
track: exact phases pin the tag down, reader noise costs little, MCL-like pose error
costs more; a tag never read keeps a finite uniform posterior; a read table without
phases is refused by name."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.localisation import (
    PhaseColumnsMissing,
    PhaseReads,
    combine_posteriors,
    localise_tags_phase,
    phase_reads_from_table,
    simulate_phase_rad,
    tag_position_errors,
)
from pipeline.localisation.observations import pair_geometry
from pipeline.robot.kinematics import antenna_poses, default_antennas
from tests.helpers.localisation import straight_path, wall_candidates

L, W = 8.0, 2.4
CHANNELS_HZ = np.array([865.7e6, 866.3e6, 866.9e6, 867.5e6])  # ETSI, hopping
# candidates on both walls at 5 cm, heights 0.75-1.55 m: a straight track at the
# antennas' height (0.70 m) leaves every tag's mirror image about that height equally
# likely (the range to the track is all the phase sees), so the half-space keeps one
CAND = wall_candidates(L, W, 0.05, (0.75, 1.55))
_WANT = np.array([[2.0, 0.0, 0.9], [3.1, W, 1.2], [4.4, 0.0, 1.4], [5.3, W, 1.0],
                  [6.2, 0.0, 1.1], [6.5, W, 1.5]])
TAGS = CAND[np.argmin(((CAND[None] - _WANT[:, None]) ** 2).sum(-1), axis=1)]
IDS = tuple(f"P{i}" for i in range(len(TAGS)))


def _track(n_cycles: int = 800):
    """One pass at 0.3 m/s along y = 0.9 m, round-robin antennas, a random channel per
    slot; reads where the tag is within 3 m and in front of the antenna."""
    t = np.arange(n_cycles) / n_cycles * (L - 1.0) / 0.3
    robot = straight_path(0.5, L - 0.5, 0.9, 0.3, t)
    ant = np.arange(n_cycles) % 2
    poses = antenna_poses(robot, default_antennas())[np.arange(n_cycles), ant]
    d, a = pair_geometry(poses, TAGS)
    return t, ant, poses, (d < 3.0) & (np.abs(a) < np.pi / 2)  # (S, T) reads


def _phase_reads(seed: int, noise_std_rad: float, pose_error=None) -> PhaseReads:
    """Free-space phases of the reads, random (antenna, channel) offsets, the pi
    ambiguity; antenna positions as the localiser believes them (true + `pose_error`)."""
    rng = np.random.default_rng(seed)
    t, ant, poses, read = _track()
    freq = CHANNELS_HZ[rng.integers(0, len(CHANNELS_HZ), len(t))]
    offset = rng.uniform(0.0, 2 * np.pi, (2, len(CHANNELS_HZ)))
    believed = poses[:, :3] + (0.0 if pose_error is None else pose_error(rng, len(t)))
    tag, slot = np.nonzero(read.T)  # grouped by tag
    phase = np.concatenate([
        simulate_phase_rad(poses[s, :3], TAGS[i], freq[s],
                           offset[ant[s], np.searchsorted(CHANNELS_HZ, freq[s])], rng,
                           noise_std_rad=noise_std_rad)
        for i in range(len(TAGS)) for s in [slot[tag == i]]])
    return PhaseReads(IDS, tag, t[slot], ant[slot], freq[slot], phase, believed[slot],
                      np.full(len(TAGS), len(t)))


def _errors(rd: PhaseReads, **kw):
    post = localise_tags_phase(rd, CAND, reach_m=4.0, **kw)
    return (tag_position_errors(post, (IDS, TAGS)),
            tag_position_errors(post, (IDS, TAGS), horizontal=True), post)


def _drift(std_m: float, corr_m: float, step_m: float):
    """Pose error as MCL makes it: AR(1) per axis along the track, correlation length
    `corr_m` of travel (the default study's MCL error decorrelates over about 1 m)."""
    def err(rng, n):
        a = np.exp(-step_m / corr_m)
        e = np.empty((n, 3))
        e[0] = std_m * rng.standard_normal(3)
        for i in range(1, n):
            e[i] = a * e[i - 1] + std_m * np.sqrt(1 - a * a) * rng.standard_normal(3)
        e[:, 2] = 0.0  # the robot drives on the floor: height is known
        return e
    return err


def test_exact_phases_find_the_true_tag():
    # offsets and the pi ambiguity are unknown to the estimator; with exact phases the
    # truth's every group sums coherently (R_g = n_g), the maximum possible
    for seed in range(3):
        e3, _, post = _errors(_phase_reads(seed, 0.0))
        assert e3.max() <= 0.05, (seed, e3)
        assert np.all(np.isfinite(post.log_posterior[:, post.map_index[0]]))


def test_reader_noise_costs_centimetres():
    # 0.1 rad of noise on ~50 reads over a 4-6 m aperture moves the holographic peak by
    # millimetres (lambda / 8 pi * 0.2 rad / sqrt(n)); what noise can do is swap the main
    # lobe for a neighbouring sidelobe or grating lobe, which are a few cm apart across the
    # track (lambda / 4 * d / L) and, in height, wider: a straight track at 0.7 m measures a
    # tag's height only through the curvature of its range, flat near the antenna height.
    # Seen over seeds 0-4: horizontal 0.00 m (every tag on its candidate), 3-D median 0.00,
    # p90 0.055, worst 0.10 m (one or two 5 cm steps in height); bounds about twice that.
    e3, e2 = [], []
    for seed in range(3):
        a, b, post = _errors(_phase_reads(seed, 0.1))
        e3.append(a)
        e2.append(b)
        assert 5.0 <= post.kappa <= 40.0, post.kappa  # exp(-2 sigma^2) -> kappa ~ 25
    assert np.concatenate(e2).max() <= 0.075, e2
    assert np.concatenate(e3).max() <= 0.2, e3
    assert np.median(np.concatenate(e3)) <= 0.05


def test_pose_error_degrades_the_estimate():
    # lambda / 8 = 4.3 cm of range error turns the doubled phase by pi. A constant pose
    # offset shifts the hologram by as much (3 cm along the track: one 5 cm grid step);
    # a drifting MCL-like error (AR(1), 1 m correlation) blurs it: seen over seeds 0-4,
    # 3-D median / p90 0.00 / 0.06 m without pose error, 0.05 / 0.20 m at 1 cm,
    # 0.15 / 0.36 m at 2 cm and 0.25 / 2.4 m at 3 cm (tags then flip to the opposite
    # wall, which the range to a straight track cannot rule out: see combine_posteriors)
    def med(pose_error, seeds=range(3), horizontal=False):
        return np.median(np.concatenate([_errors(_phase_reads(s, 0.1, pose_error))[
            1 if horizontal else 0] for s in seeds]))

    base = med(None, horizontal=True)
    assert base <= 0.025
    assert med(lambda rng, n: np.array([0.03, 0.0, 0.0]), horizontal=True) <= 0.075
    small, large = med(_drift(0.01, 1.0, 0.0087)), med(_drift(0.03, 1.0, 0.0087))
    assert small <= 0.1
    assert 0.1 <= large <= 0.6 and large > small


def test_tag_without_reads_is_uniform_and_finite():
    rd = _phase_reads(0, 0.1)
    keep = rd.tag_index != 2
    rd2 = PhaseReads(rd.tag_ids, rd.tag_index[keep], rd.time_s[keep], rd.antenna[keep],
                     rd.frequency_hz[keep], rd.phase_rad[keep], rd.antenna_xyz_m[keep],
                     rd.n_attempts)
    post = localise_tags_phase(rd2, CAND, reach_m=4.0)
    assert post.n_reads[2] == 0 and np.all(np.isfinite(post.log_posterior[2]))
    np.testing.assert_allclose(post.posterior[2], 1.0 / len(CAND))
    assert tag_position_errors(post, (IDS, TAGS))[[0, 1, 3]].max() <= 0.2
    # no reads at all: every tag uniform
    none = PhaseReads(IDS, [], [], [], [], [], np.zeros((0, 3)), np.zeros(len(IDS)))
    np.testing.assert_allclose(localise_tags_phase(none, CAND).posterior, 1.0 / len(CAND))


def _table(rd: PhaseReads) -> pd.DataFrame:
    return pd.DataFrame({
        "time_s": rd.time_s, "cycle": np.arange(len(rd.time_s)), "antenna": rd.antenna,
        "tag_id": np.array(rd.tag_ids)[rd.tag_index], "read": True, "rssi_dbm": -60.0,
        "frequency_hz": rd.frequency_hz, "phase_rad": rd.phase_rad,
        "est_ant_x_m": rd.antenna_xyz_m[:, 0], "est_ant_y_m": rd.antenna_xyz_m[:, 1],
        "est_ant_z_m": rd.antenna_xyz_m[:, 2], "est_ant_yaw_rad": 0.0})


def test_read_table_round_trip_and_missing_phase_is_named():
    rd = _phase_reads(0, 0.1)
    tab = _table(rd)
    tab.loc[0, "read"] = False  # a miss: an attempt, not a read
    tab.loc[1, "phase_rad"] = np.nan  # read without a phase: not used
    back = phase_reads_from_table(tab, tag_ids=(*IDS, "never"))
    assert back.n_reads.sum() == len(tab) - 2 and back.n_reads[-1] == 0
    assert back.n_attempts[:-1].sum() == len(tab)
    with pytest.raises(PhaseColumnsMissing, match="phase_rad"):
        phase_reads_from_table(tab.drop(columns=["phase_rad"]))
    with pytest.raises(PhaseColumnsMissing, match="frequency_hz"):
        phase_reads_from_table(tab.drop(columns=["frequency_hz"]))
    with pytest.raises(ValueError, match="PhaseReads"):
        localise_tags_phase(tab, CAND)


def test_refined_cells_carry_the_cell_mean_likelihood():
    # a candidate stands for its cell: refined, its likelihood is the mean of the point
    # likelihood over the cell's 27 sub-points (log-mean-exp), so the posterior over the
    # cells is exactly what the posterior over every sub-point sums to per cell. A
    # maximum over the sub-points (not a likelihood) gives a different, unnormalised
    # answer and fails this.
    from pipeline.localisation.phase import cell_points

    rd = _phase_reads(1, 0.1)
    cell = 0.05
    near = np.all(np.abs(CAND - TAGS[0]) <= [0.16, 0.01, 0.16], axis=1)  # 7 x 7 cells on its wall
    coarse = CAND[near]
    assert len(coarse) == 49
    cells = localise_tags_phase(rd, coarse, phase_sigma_rad=0.1, refine_top=len(coarse),
                                cell_m=cell)
    fine_pts = cell_points(coarse, cell)  # (49, 27, 3)
    fine = localise_tags_phase(rd, fine_pts.reshape(-1, 3), phase_sigma_rad=0.1, refine_top=0)
    from scipy.special import logsumexp

    summed = logsumexp(fine.log_posterior.reshape(len(IDS), len(coarse), 27), axis=2)
    np.testing.assert_allclose(cells.log_posterior, summed, rtol=1e-5, atol=2e-3)
    np.testing.assert_allclose(np.exp(cells.log_posterior).sum(axis=1), 1.0, atol=1e-9)
    # the likelihood is peaked within the cells (else the test would not tell mean from max)
    lp = fine.log_posterior[0].reshape(len(coarse), 27)
    assert np.median(lp.max(axis=1) - lp.min(axis=1)) > 1.0


def test_combined_posterior_is_the_normalised_product():
    _, _, post = _errors(_phase_reads(0, 0.1))
    both = combine_posteriors(post, post, name="twice")
    expect = 2 * post.log_posterior
    expect -= np.log(np.exp(expect).sum(axis=1, keepdims=True))
    np.testing.assert_allclose(both.log_posterior, expect, atol=1e-9)
    assert both.source == "twice"


def test_benchmark_records_why_the_phase_model_did_not_run():
    from pipeline.localisation.benchmark import phase_posteriors

    rd = _phase_reads(0, 0.1)
    tab = _table(rd)
    posts, info = phase_posteriors(tab.drop(columns=["phase_rad"]), IDS, CAND, reach_m=4.0)
    assert posts == {} and info["run"] is False and "phase_rad" in info["reason"]
    posts, info = phase_posteriors(tab, IDS, CAND, reach_m=4.0)
    assert info["run"] is True and set(posts) == {"phase"}
    assert info["n_reads_with_phase"] == len(tab) and info["tags_without_phase"] == 0


class _Sites:
    """Candidates with their surface normals, as scenes.tagsites.TagSites carries them."""

    def __init__(self, positions_m):
        self.positions_m = np.asarray(positions_m, float)
        # the corridor's walls y = 0 and y = W face its middle
        self.normals = np.zeros_like(self.positions_m)
        self.normals[:, 1] = np.sign(W / 2 - self.positions_m[:, 1])


def test_cells_of_candidates_on_a_face_are_patches_in_its_plane():
    from pipeline.localisation.phase import cell_points

    sites = _Sites(CAND[:5])
    pts = cell_points(sites.positions_m, 0.06, sites.normals)
    assert pts.shape == (5, 9, 3)
    off = pts - sites.positions_m[:, None]
    # no sub-point leaves the face's plane (the cube put 9 of 27 inside the wall)
    np.testing.assert_allclose(np.einsum("cki,ci->ck", off, sites.normals), 0.0, atol=1e-12)
    # a 3 x 3 midpoint grid of the 6 cm square: along the wall (x) and up (z)
    np.testing.assert_allclose(np.unique(np.round(off[0, :, 0], 12)), [-0.02, 0.0, 0.02])
    np.testing.assert_allclose(np.unique(np.round(off[0, :, 2], 12)), [-0.02, 0.0, 0.02])
    assert cell_points(sites.positions_m, 0.06).shape == (5, 27, 3)  # bare positions: the cube


def test_partial_refinement_mixes_cell_means_and_centre_values():
    # refine_top of 49: those candidates carry the cell mean (as with every cell refined),
    # the others their centre's point likelihood (as with none refined): the documented
    # approximation, and `refined` says which is which
    rd = _phase_reads(1, 0.1)
    near = np.all(np.abs(CAND - TAGS[0]) <= [0.16, 0.01, 0.16], axis=1)
    sites = _Sites(CAND[near])
    kw = {"phase_sigma_rad": 0.1, "cell_m": 0.05}
    part = localise_tags_phase(rd, sites, refine_top=10, **kw)
    full = localise_tags_phase(rd, sites, refine_top=49, **kw)
    none = localise_tags_phase(rd, sites, refine_top=0, **kw)
    assert part.refined.shape == (len(IDS), 49) and full.refined.all() and not none.refined.any()
    ref = part.refined[0]
    assert ref.sum() == 10
    # likelihoods up to each posterior's normalising constant
    d_full = part.log_posterior[0, ref] - full.log_posterior[0, ref]
    d_none = part.log_posterior[0, ~ref] - none.log_posterior[0, ~ref]
    # the resultants are float32 sums by BLAS, whose blocking (hence rounding) depends on
    # the batch's shape: 10 refined cells here, 49 there. With numpy 2.4.6 / its OpenBLAS
    # the two differ by up to 2.4e-4 in log-likelihood (1e-9 held with earlier builds);
    # 1e-3 is 4x that and 100x below the gap between the two approximations checked below
    np.testing.assert_allclose(d_full, d_full[0], atol=1e-3)
    np.testing.assert_allclose(d_none, d_none[0], atol=1e-3)
    # and the two quantities differ (else the test could not tell them apart)
    gap = full.log_posterior[0] - none.log_posterior[0]
    assert np.ptp(gap) > 0.1
