"""What a reader reports besides RSSI: the backscatter phase and the Doppler shift.

The one-way channel ``h`` (complex, both patterns, at the attempt's channel; from
:func:`propagation.trace_links`) makes the monostatic, reciprocal backscatter channel
``h^2``. An Impinj-class reader reports per read

- ``phase = mod(-arg(h^2) + offset(antenna, channel) + offset(tag) + chip(P_tag)
  + N(0, phase_noise_rad^2) + pi B, 2 pi)`` with ``B ~ Bernoulli(1/2)`` per read (the
  reader's pi ambiguity: its demodulator cannot tell the two backscatter states apart,
  so Impinj documents the reported angle as defined modulo pi), quantised to
  ``phase_resolution_rad`` (Impinj reports 12 bits, 2 pi / 4096). In free space
  ``-arg(h^2) = 4 pi d / lambda`` (mod 2 pi): the phase grows with distance, as in the
  phase-ranging literature. The other terms:

  * ``offset(antenna, channel)``: cables and reader front end, constant per (antenna
    port, channel), drawn once per reader (:func:`phase_offsets`);
  * ``offset(tag)``: the tag's own reflection phase (chip impedance, inlay, mounting),
    uniform on [0, 2 pi) and constant per tag, drawn once per read log
    (:attr:`~pipeline.acquisition.population.TagPopulation.phase_offset_rad`): tag
    chips of one model differ, so one offset shared by every tag would be optimistic
    for any estimator that pools tags;
  * ``chip(P_tag)``: the chip's reflection phase moves with the power it absorbs (its
    rectifier's input impedance is non-linear). Megalou, Bletsas, Yioultsis & Dimitriou
    ("Power and phase variation of backscattered RFID signal with respect to the
    incident power at the tag", IEEE RFID-TA 2021, pp. 36-39,
    doi:10.1109/RFID-TA53372.2021.9617367) measured a backscatter phase shift of 100
    degrees (and 14 dB of backscattered power) across the incident powers of a
    commercial tag. :func:`power_phase_rad` takes that magnitude
    (``reader.phase_power_shift_rad``) as a ramp linear in dB from the tag's own
    threshold to ``reader.phase_power_span_db`` (20 dB) above it, constant beyond: the
    shape and the span are this project's assumption (the paper's curve is not
    reproduced here); the default study's reads lie 0-23 dB above threshold, so they
    see nearly the whole 100 degrees. Its sign is a convention (it adds to the phase).
- ``doppler = (1 / pi) Im(hdot / h)`` with ``hdot = dh/dpos . v_antenna``: the rate of
  change of the two-way phase over 2 pi, positive when antenna and tag approach
  (``2 v_radial / lambda`` in free space), plus ``N(0, doppler_noise_hz^2)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["antenna_velocity", "doppler_hz", "phase_offsets", "power_phase_rad", "reported_phase_rad",
           "tag_phase_offsets"]

_TWO_PI = 2.0 * np.pi


def phase_offsets(n_antennas: int, n_channels: int, rng: np.random.Generator) -> np.ndarray:
    """Constant phase offset of each (antenna port, channel), uniform in [0, 2 pi).

    Returns
    -------
    numpy.ndarray
        shape (n_antennas, n_channels), float64, rad.
    """
    return rng.uniform(0.0, _TWO_PI, size=(int(n_antennas), int(n_channels)))


def tag_phase_offsets(n_tags: int, rng: np.random.Generator) -> np.ndarray:
    """Each tag's own reflection phase offset, uniform in [0, 2 pi).

    Returns
    -------
    numpy.ndarray
        shape (n_tags,), float64, rad.
    """
    return rng.uniform(0.0, _TWO_PI, size=int(n_tags))


def power_phase_rad(excess_db, shift_rad: float, span_db: float) -> np.ndarray:
    """The chip's power-dependent reflection phase: ``shift_rad * clip(excess_db / span_db, 0, 1)``.

    Parameters
    ----------
    excess_db : array_like
        Power absorbed by the chip above the tag's own threshold [dB] (negative or NaN
        for a tag that is not powered: 0 there).
    shift_rad : float
        Phase shift over the span [rad] (Megalou et al. 2021: 100 degrees; module docstring).
    span_db : float
        Power range above threshold over which the shift builds up [dB] (> 0).

    Returns
    -------
    numpy.ndarray
        float64, shape of ``excess_db``, rad, in [0, shift_rad] (for shift_rad >= 0).
    """
    if not float(span_db) > 0:
        raise ValueError(f"power_phase_rad: span_db must be > 0, got {span_db!r}")
    x = np.nan_to_num(np.asarray(excess_db, dtype=float), nan=0.0, posinf=float(span_db),
                      neginf=0.0)
    return float(shift_rad) * np.clip(x / float(span_db), 0.0, 1.0)


def reported_phase_rad(h, offset_rad, phase_noise_rad: float, rng: np.random.Generator,
                       resolution_rad: float = 0.0) -> np.ndarray:
    """Reported backscatter phase of each read, in [0, 2 pi).

    Parameters
    ----------
    h : array_like of complex
        One-way channel coefficients, any shape.
    offset_rad : array_like
        Offset per entry (broadcast to ``h``), rad: the (antenna, channel) offset plus the
        tag's own and its power-dependent chip phase.
    phase_noise_rad : float
        Standard deviation of the reader's phase noise [rad].
    rng : numpy.random.Generator
        Exactly two arrays of ``h.size`` draws: standard normals, then Bernoulli(1/2).
    resolution_rad : float
        Quantisation step [rad]; 0: none.

    Returns
    -------
    numpy.ndarray
        float64, shape of ``h``, rad; NaN where ``h`` is 0 (no channel).
    """
    h = np.asarray(h, dtype=complex)
    z = rng.standard_normal(h.shape)
    flip = rng.random(h.shape) < 0.5
    ph = -np.angle(h * h) + offset_rad + phase_noise_rad * z + np.pi * flip
    ph = np.mod(ph, _TWO_PI)
    if resolution_rad > 0:
        ph = np.mod(np.round(ph / resolution_rad) * resolution_rad, _TWO_PI)
    return np.where(h != 0, ph, np.nan)


def doppler_hz(h, dh_dpos, velocity_mps) -> np.ndarray:
    """Doppler shift of the backscatter of a moving antenna, ``(1/pi) Im(hdot / h)``.

    Parameters
    ----------
    h : array_like of complex, shape (...)
        One-way channel coefficients.
    dh_dpos : array_like of complex, shape (..., 3)
        d h / d (antenna position), 1/m.
    velocity_mps : array_like, shape (..., 3)
        Antenna velocity (broadcast against ``dh_dpos``), m/s.

    Returns
    -------
    numpy.ndarray
        float64, Hz, shape of ``h``; positive when approaching; NaN where ``h`` is 0.
    """
    h = np.asarray(h, dtype=complex)
    hdot = np.sum(np.asarray(dh_dpos, dtype=complex) * np.asarray(velocity_mps, dtype=float), axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.imag(hdot / np.where(h != 0, h, 1.0)) / np.pi
    return np.where(h != 0, f, np.nan)


def antenna_velocity(time_s, pose_at, dt_s: float = 0.01, t_range_s=None) -> np.ndarray:
    """Antenna velocity by central finite differences of its true track.

    Parameters
    ----------
    time_s : array_like, shape (n,)
        Times [s].
    pose_at : callable
        ``pose_at(t)`` -> antenna positions (n, 3) [m] at times ``t`` (n,), e.g. the
        interpolated true robot track composed with the antenna's mount.
    dt_s : float
        Half-width of the difference [s] (the track is piecewise linear: any width
        within one track step gives its exact velocity there).
    t_range_s : tuple of float, optional
        (start, end) of the track [s]: the differences are one-sided at its ends.

    Returns
    -------
    numpy.ndarray
        shape (n, 3), float64, m/s.
    """
    t = np.asarray(time_s, dtype=float)
    lo, hi = (-np.inf, np.inf) if t_range_s is None else t_range_s
    ta = np.clip(t - dt_s, lo, hi)
    tb = np.clip(t + dt_s, lo, hi)
    a = np.asarray(pose_at(ta), dtype=float)[:, :3]
    b = np.asarray(pose_at(tb), dtype=float)[:, :3]
    span = tb - ta
    return np.where(span[:, None] > 0, (b - a) / np.where(span > 0, span, 1.0)[:, None], 0.0)
