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
