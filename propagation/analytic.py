"""Closed-form propagation references: Friis free space, the two-ray ground model, a slab.

Used to validate the ray tracer and as cheap baselines. All gains are one-way channel
power gains (linear or dB) including the antenna gains given.
"""

from __future__ import annotations

import numpy as np

from propagation.constants import EPSILON_0, SPEED_OF_LIGHT

__all__ = [
    "EPSILON_0",
    "SPEED_OF_LIGHT",
    "complex_permittivity",
    "db_to_linear",
    "free_space_gain_db",
    "fresnel_reflection",
    "linear_to_db",
    "slab_coefficients",
    "slab_transmission_db",
    "two_ray_gain_db",
    "wavelength_m",
]


def db_to_linear(value_db):
    """10 ** (value_db / 10) (power ratio), element-wise."""
    return 10.0 ** (np.asarray(value_db, dtype=float) / 10.0)


def linear_to_db(value):
    """10 log10(value) (power ratio), element-wise; 0 gives -inf."""
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(np.asarray(value, dtype=float))


def wavelength_m(frequency_hz):
    """Free-space wavelength c / f [m]."""
    return SPEED_OF_LIGHT / np.asarray(frequency_hz, dtype=float)


def free_space_gain_db(distance_m, frequency_hz, gain_tx_dbi=0.0, gain_rx_dbi=0.0):
    """Friis one-way gain ``G_t + G_r + 20 log10(lambda / (4 pi d))`` [dB].

    Parameters
    ----------
    distance_m : array_like
        Antenna separation [m], > 0.
    frequency_hz : float or array_like
        Frequency [Hz].
    gain_tx_dbi, gain_rx_dbi : float or array_like
        Antenna gains toward each other [dBi].

    Returns
    -------
    numpy.ndarray
        Gain in dB (Friis 1946), broadcast shape.
    """
    d = np.asarray(distance_m, dtype=float)
    if np.any(d <= 0):
        raise ValueError("distance_m must be > 0")
    return (np.asarray(gain_tx_dbi, float) + np.asarray(gain_rx_dbi, float)
            + 20.0 * np.log10(wavelength_m(frequency_hz) / (4.0 * np.pi * d)))


def complex_permittivity(relative_permittivity, conductivity, frequency_hz):
    """eta = eps_r - j sigma / (omega eps_0) (ITU-R P.2040-3 eq. 9b)."""
    omega = 2.0 * np.pi * np.asarray(frequency_hz, dtype=float)
    return np.asarray(relative_permittivity, float) - 1j * np.asarray(conductivity, float) / (omega * EPSILON_0)


def fresnel_reflection(grazing_angle_rad, relative_permittivity, conductivity, frequency_hz,
                       polarization="V"):
    """Fresnel reflection coefficient of a half-space (ITU-R P.2040-3 eq. 31/32).

    Parameters
    ----------
    grazing_angle_rad : array_like
        Angle between the ray and the surface [rad] (pi/2 - angle of incidence).
    relative_permittivity, conductivity : float
        Real eps_r and sigma [S/m] of the material.
    frequency_hz : float
        Frequency [Hz].
    polarization : {"V", "H"}
        ``"V"``: E in the plane of incidence (TM, parallel); ``"H"``: E perpendicular (TE).

    Returns
    -------
    numpy.ndarray
        Complex reflection coefficient, sign convention of the classic two-ray model
        (both -> -1 at grazing incidence), i.e. R_V = (eta sin psi - sqrt(eta - cos^2 psi))
        / (eta sin psi + sqrt(eta - cos^2 psi)), R_H = (sin psi - sqrt(eta - cos^2 psi)) /
        (sin psi + sqrt(eta - cos^2 psi)).
    """
    psi = np.asarray(grazing_angle_rad, dtype=float)
    eta = complex_permittivity(relative_permittivity, conductivity, frequency_hz)
    root = np.sqrt(eta - np.cos(psi) ** 2)
    s = np.sin(psi)
    if polarization == "V":
        return (eta * s - root) / (eta * s + root)
    if polarization == "H":
        return (s - root) / (s + root)
    raise ValueError(f"polarization must be 'V' or 'H', got {polarization!r}")


def two_ray_gain_db(distance_m, h_tx_m, h_rx_m, frequency_hz, relative_permittivity,
                    conductivity, polarization="V", gain_direct_tx=1.0, gain_direct_rx=1.0,
                    gain_reflected_tx=1.0, gain_reflected_rx=1.0):
    """Direct plus ground-reflected ray over a flat half-space [dB] (Rappaport eq. 4.47 with
    the Fresnel coefficient of the ground, ITU-R P.2040-3).

    h = (lambda / 4 pi) [ sqrt(G_d) e^{-jk r1} / r1 + R(psi) sqrt(G_r) e^{-jk r2} / r2 ]

    with r1 = sqrt(d^2 + (h_t - h_r)^2), r2 = sqrt(d^2 + (h_t + h_r)^2), tan psi = (h_t + h_r)/d.
    For ``"V"`` the field direction of the reflected ray differs from the direct one by the
    angle between them; this model, like the classic one, neglects it (fine at d >> h).

    Parameters
    ----------
    distance_m : array_like
        Horizontal distance [m].
    h_tx_m, h_rx_m : float or array_like
        Antenna heights above the ground plane [m].
    frequency_hz : float
        Frequency [Hz].
    relative_permittivity, conductivity : float
        Ground material (real eps_r, sigma in S/m).
    polarization : {"V", "H"}
        See :func:`fresnel_reflection`.
    gain_direct_tx, gain_direct_rx, gain_reflected_tx, gain_reflected_rx : array_like
        Linear power pattern gains of each antenna toward each ray (default isotropic).

    Returns
    -------
    numpy.ndarray
        One-way coherent gain |h|^2 in dB.
    """
    d = np.asarray(distance_m, dtype=float)
    lam = wavelength_m(frequency_hz)
    k = 2.0 * np.pi / lam
    r1 = np.hypot(d, np.asarray(h_tx_m, float) - h_rx_m)
    r2 = np.hypot(d, np.asarray(h_tx_m, float) + h_rx_m)
    psi = np.arctan2(np.asarray(h_tx_m, float) + h_rx_m, d)
    refl = fresnel_reflection(psi, relative_permittivity, conductivity, frequency_hz, polarization)
    h = lam / (4.0 * np.pi) * (
        np.sqrt(np.asarray(gain_direct_tx, float) * gain_direct_rx) * np.exp(-1j * k * r1) / r1
        + refl * np.sqrt(np.asarray(gain_reflected_tx, float) * gain_reflected_rx) * np.exp(-1j * k * r2) / r2
    )
    return linear_to_db(np.abs(h) ** 2)


def slab_coefficients(incidence_angle_rad, relative_permittivity, conductivity, thickness_m,
                      frequency_hz, polarization="TE"):
    """Reflection and transmission coefficients of a single lossy slab in vacuum.

    ITU-R P.2040-3, section 3.4 "Single layer slab" (the multiple internal reflections
    summed in closed form; Sionna RT 2.2 implements the same equations, citing them as
    P.2040-4 eqs. (43)-(44))::

        R = R' (1 - exp(-j 2q)) / (1 - R'^2 exp(-j 2q))
        T = (1 - R'^2) exp(-j q) / (1 - R'^2 exp(-j 2q))
        q = (2 pi d / lambda) sqrt(eta - sin^2 theta)

    with eta = eps_r - j sigma / (omega eps_0) (:func:`complex_permittivity`) and R' the
    Fresnel coefficient of the air-material interface: TE
    ``(cos t - sqrt(eta - sin^2 t)) / (cos t + sqrt(eta - sin^2 t))``, TM
    ``(eta cos t - sqrt(eta - sin^2 t)) / (eta cos t + sqrt(eta - sin^2 t))``.

    Parameters
    ----------
    incidence_angle_rad : array_like
        Angle between the ray and the slab normal, rad (0: normal incidence).
    relative_permittivity, conductivity : float
        Real eps_r and sigma [S/m] of the material.
    thickness_m : array_like
        Slab thickness d, metres.
    frequency_hz : float
        Frequency, Hz.
    polarization : {"TE", "TM"}
        E perpendicular to (TE) or in (TM) the plane of incidence; equal at normal incidence.

    Returns
    -------
    (R, T) : tuple of numpy.ndarray
        Complex field coefficients, broadcast shape. T's phase is referred to the slab's
        two faces (a zero-thickness surface in a ray tracer).
    """
    theta = np.asarray(incidence_angle_rad, dtype=float)
    eta = complex_permittivity(relative_permittivity, conductivity, frequency_hz)
    cos_t, sin2 = np.cos(theta), np.sin(theta) ** 2
    root = np.sqrt(eta - sin2)  # principal branch: Im < 0, the wave decays in the slab
    if polarization == "TE":
        r1 = (cos_t - root) / (cos_t + root)
    elif polarization == "TM":
        r1 = (eta * cos_t - root) / (eta * cos_t + root)
    else:
        raise ValueError(f"polarization must be 'TE' or 'TM', got {polarization!r}")
    q = 2.0 * np.pi * np.asarray(thickness_m, dtype=float) / wavelength_m(frequency_hz) * root
    e1, e2 = np.exp(-1j * q), np.exp(-2j * q)
    den = 1.0 - r1**2 * e2
    return r1 * (1.0 - e2) / den, (1.0 - r1**2) * e1 / den


def slab_transmission_db(relative_permittivity, conductivity, thickness_m, frequency_hz,
                         incidence_angle_rad=0.0, polarization="TE"):
    """Power transmission ``20 log10 |T|`` of a single lossy slab [dB] (ITU-R P.2040-3, 3.4).

    Parameters
    ----------
    relative_permittivity, conductivity : float
        Real eps_r and sigma [S/m] of the material.
    thickness_m : array_like
        Slab thickness, metres.
    frequency_hz : float
        Frequency, Hz.
    incidence_angle_rad : array_like
        Angle from the slab normal, rad (default 0: normal incidence).
    polarization : {"TE", "TM"}
        See :func:`slab_coefficients`.

    Returns
    -------
    numpy.ndarray
        Transmission in dB (<= 0), broadcast shape; e.g. 0.12 m of P.2040 brick at
        865 MHz and normal incidence: -3.74 dB.
    """
    _, t = slab_coefficients(incidence_angle_rad, relative_permittivity, conductivity,
                             thickness_m, frequency_hz, polarization)
    return linear_to_db(np.abs(t) ** 2)
