"""Reported phase and Doppler against closed forms on a hand-built line-of-sight path."""

import numpy as np
import pytest

from pipeline.acquisition.channels import REGIONS
from pipeline.acquisition.phase import (
    antenna_velocity,
    doppler_hz,
    phase_offsets,
    reported_phase_rad,
)
from propagation.channels import link_channels
from propagation.constants import SPEED_OF_LIGHT
from propagation.pathcache import SourcePaths
from propagation.tracing import tag_dipole_axes

C = SPEED_OF_LIGHT


def _los_channels(d_m, channel_hz, gradient=False):
    """One LOS path per tag from an antenna at the origin (boresight +x) to tags on +x.

    The transfer matrix is the free-space amplitude times the identity (V to V, H to H),
    as Sionna's ``a`` of a LOS path between isotropic VH antennas.
    """
    d = np.asarray(d_m, float)
    tags = np.column_stack([d, np.zeros_like(d), np.zeros_like(d)])
    lam = C / 865e6
    sp = SourcePaths(
        source_m=np.zeros(3), tag_positions_m=tags, offsets=np.arange(len(d) + 1, dtype=np.int64),
        transfer=(lam / (4 * np.pi * d))[:, None, None] * np.eye(2)[None].astype(complex),
        tau_s=d / C, k_tx=np.tile([1.0, 0.0, 0.0], (len(d), 1)),
        k_rx=np.tile([-1.0, 0.0, 0.0], (len(d), 1)))
    n = len(d)
    return link_channels([sp], np.zeros(n, np.int64), np.arange(n), np.zeros((n, 6)), tags,
                         np.broadcast_to(channel_hz, (n,)), "tr38901", "V", "hw_dipole",
                         tag_dipole_axes(None, n), gradient=gradient)


@pytest.mark.parametrize("channel_hz", REGIONS["ETSI"].channels_hz + (902.75e6, 927.25e6))
def test_free_space_phase_is_4_pi_d_over_lambda_mod_pi(channel_hz):
    d = np.linspace(0.5, 6.0, 200)
    ch = _los_channels(d, channel_hz)
    rng = np.random.default_rng(0)
    # zero noise, zero offsets, no quantisation: only the reader's pi ambiguity remains
    phase = reported_phase_rad(ch.h, 0.0, 0.0, rng)
    assert np.all((phase >= 0) & (phase < 2 * np.pi))
    expected = 4 * np.pi * d * channel_hz / C
    err = np.angle(np.exp(2j * (phase - expected))) / 2  # difference modulo pi
    np.testing.assert_allclose(err, 0.0, atol=1e-9)
    # both branches of the ambiguity occur
    branch = np.round(np.mod(phase - expected, 2 * np.pi) / np.pi) % 2
    assert 0.3 < branch.mean() < 0.7


def test_phase_noise_offset_and_quantisation():
    h = np.full(20_000, np.exp(-0.3j))
    rng = np.random.default_rng(1)
    step = 2 * np.pi / 4096
    ph = reported_phase_rad(h, 1.0, 0.1, rng, resolution_rad=step)
    np.testing.assert_allclose(ph / step, np.round(ph / step), atol=1e-6)
    # folded modulo pi the reported phase is 0.6 + 1.0 rad with 0.1 rad noise
    folded = np.angle(np.exp(2j * (ph - 1.6))) / 2
    assert abs(folded.mean()) < 5 * 0.1 / np.sqrt(len(h))
    assert abs(folded.std() - 0.1) < 0.005
    # a link without a channel reports nothing
    assert np.isnan(reported_phase_rad(np.array([0j]), 0.0, 0.0, rng)[0])
    off = phase_offsets(2, 4, np.random.default_rng(2))
    assert off.shape == (2, 4) and np.all((off >= 0) & (off < 2 * np.pi))


@pytest.mark.parametrize("channel_hz", [865.7e6, 915.25e6])
def test_radial_doppler_is_2v_over_lambda(channel_hz):
    d = np.array([1.0, 2.5, 4.0])
    ch = _los_channels(d, channel_hz, gradient=True)
    v = 0.6  # m/s along +x, toward the tags: approaching
    f = doppler_hz(ch.h, ch.dh_dpos, np.array([v, 0.0, 0.0]))
    np.testing.assert_allclose(f, 2 * v * channel_hz / C, rtol=1e-9)
    # receding flips the sign; moving across the line of sight gives none
    np.testing.assert_allclose(doppler_hz(ch.h, ch.dh_dpos, np.array([-v, 0, 0])),
                               -2 * v * channel_hz / C, rtol=1e-9)
    np.testing.assert_allclose(doppler_hz(ch.h, ch.dh_dpos, np.array([0, v, 0])), 0.0, atol=1e-9)


def test_antenna_velocity_finite_difference():
    # straight track at 0.3 m/s along y; one-sided at the ends
    def pose_at(t):
        return np.column_stack([np.zeros_like(t), 0.3 * np.clip(t, 0, 10), np.ones_like(t)])

    v = antenna_velocity(np.array([0.0, 5.0, 10.0]), pose_at, t_range_s=(0.0, 10.0))
    np.testing.assert_allclose(v, [[0, 0.3, 0]] * 3, atol=1e-12)


def _reads_with_phase(shift_rad, seed=5, n_tags=5, sensitivity_spread_db=0.0):
    """reads_from_gains on hand-made channels: every attempt of every tag readable, no
    phase noise or quantisation; returns the reads, the channels, offsets and population."""
    from pipeline.acquisition import PoseTrack, ReaderConfig, draw_population, read_attempts
    from pipeline.acquisition.reader import reads_from_gains
    from pipeline.robot.kinematics import Robot
    from scenes.scene import TagSet

    t = np.linspace(0.0, 4.0, 41)
    true = np.column_stack([np.linspace(0.0, 1.2, 41), np.zeros(41), np.zeros(41)])
    track = PoseTrack(t, true, true, np.full_like(true, np.nan))
    reader = ReaderConfig(read_rate_hz=10.0, inventory="fixed", anticollision_miss_probability=0.0,
                          phase_noise_rad=0.0, phase_resolution_rad=0.0,
                          phase_power_shift_rad=shift_rad, phase_power_span_db=20.0,
                          tag_sensitivity_spread_db=sensitivity_spread_db,
                          # hand-made gains: the 3 dB per way a traced circular reader
                          # carries in its gains is set here, so the gains below sit where
                          # the comment says whatever the default loss
                          polarization_loss_db=3.0)
    att = read_attempts(track, Robot().antennas, reader)
    tags = TagSet([f"t{i}" for i in range(n_tags)], np.column_stack(
        [np.arange(n_tags, dtype=float), np.full(n_tags, 1.5), np.ones(n_tags)]),
        np.tile([0.0, -1.0, 0.0], (n_tags, 1)))
    rng = np.random.default_rng(seed)
    n = len(att.time_s)
    # gains from 3 to 23 dB above the tag threshold's gain: every tag powered and heard
    gain_db = rng.uniform(-33.0, -13.0, (n, n_tags))
    h = 10 ** (gain_db / 20) * np.exp(1j * rng.uniform(-np.pi, np.pi, (n, n_tags)))
    pop = draw_population(tags, reader, np.random.default_rng(seed + 1))
    offsets = rng.uniform(0, 2 * np.pi, (2, len(att.plan.channels_hz)))
    reads = reads_from_gains(att, tags, gain_db, np.ones((n, n_tags), bool), reader, rng, h=h,
                             population=pop, offsets_rad=offsets, aux_rng=np.random.default_rng(9))
    return reads, att, h, offsets, pop, reader


def _residual_mod_pi(reads, att, h, offsets, n_tags):
    """Reported phase less the channel's and the (antenna, channel) offset, modulo pi (n, m)."""
    ph = reads["phase_rad"].to_numpy().reshape(-1, n_tags)
    base = -np.angle(h * h) + offsets[att.antenna, att.channel_index][:, None]
    return np.mod(ph - base, np.pi)


def test_each_tag_has_its_own_constant_phase_offset():
    # without the power term the residual is the tag's own offset: constant over every
    # read of a tag (all antennas, channels, ranges), different from tag to tag
    reads, att, h, offsets, pop, _ = _reads_with_phase(0.0)
    assert reads["read"].all()
    res = _residual_mod_pi(reads, att, h, offsets, 5)
    circ = np.exp(2j * res)  # modulo pi, as a point on the circle
    spread = np.abs(np.angle(circ / circ[:1]))
    assert spread.max() < 1e-5  # constant per tag (the table stores float32)
    np.testing.assert_allclose(np.angle(circ[0]) / 2 % np.pi, np.mod(pop.phase_offset_rad, np.pi),
                               atol=1e-5)
    gaps = np.abs(np.angle(circ[0][:, None] / circ[0][None, :]))[np.triu_indices(5, 1)]
    assert gaps.min() > 1e-3  # every pair of tags differs (uniform offsets)
    # drawn once per population, recorded with it; a new draw gives new offsets
    assert np.all((pop.phase_offset_rad >= 0) & (pop.phase_offset_rad < 2 * np.pi))
    assert len(pop.to_dict()["phase_offset_rad"]) == 5
    other = _reads_with_phase(0.0, seed=6)[4]
    assert not np.allclose(other.phase_offset_rad, pop.phase_offset_rad)


def test_phase_offsets_do_not_change_the_other_population_draws():
    from pipeline.acquisition import ReaderConfig, draw_population
    from scenes.scene import TagSet

    tags = TagSet(["a", "b", "c"], np.zeros((3, 3)) + np.arange(3)[:, None], np.tile([1.0, 0, 0], (3, 1)))
    rng = np.random.default_rng(3)
    pop = draw_population(tags, ReaderConfig(tag_sensitivity_spread_db=1.0), rng)
    ref = np.random.default_rng(3)
    np.testing.assert_array_equal(pop.sensitivity_offset_db, ref.standard_normal(3))
    ref.standard_normal(3)
    # the offsets come from a child stream: the parent's next draw is untouched
    assert rng.random() == ref.random()


def test_power_dependent_chip_phase_follows_the_ramp():
    # with 100 degrees over 20 dB: the residual less the tag's offset is the ramp of the
    # chip's absorbed power above its own threshold (per-tag thresholds included)
    shift = np.radians(100.0)
    reads, att, h, offsets, pop, reader = _reads_with_phase(shift, sensitivity_spread_db=2.0)
    res = _residual_mod_pi(reads, att, h, offsets, 5) - pop.phase_offset_rad[None, :]
    excess = (reads["tag_power_dbm"].to_numpy().reshape(-1, 5)
              - reader.tag_sensitivity_dbm - pop.sensitivity_offset_db[None, :])
    expected = shift * np.clip(excess / 20.0, 0.0, 1.0)
    err = np.angle(np.exp(2j * (res - expected))) / 2
    np.testing.assert_allclose(err, 0.0, atol=1e-5)
    assert expected.max() - expected.min() > np.radians(60)  # the term is exercised
    assert excess.max() > 20.0  # and saturates


def test_power_phase_ramp_closed_form():
    from pipeline.acquisition.phase import power_phase_rad

    x = np.array([-5.0, 0.0, 5.0, 10.0, 20.0, 30.0, np.nan])
    np.testing.assert_allclose(power_phase_rad(x, 2.0, 20.0), [0, 0, 0.5, 1.0, 2.0, 2.0, 0.0])
    with pytest.raises(ValueError, match="span_db"):
        power_phase_rad(x, 1.0, 0.0)
