"""UHF material library: ITU-R P.2040-3 building materials, defined down to 865 MHz.

Each material follows ITU-R P.2040-3 (08/2023), Table 3, equations (28)-(29)::

    eps_r' = a * f_GHz ** b
    sigma  = c * f_GHz ** d          [S/m]

Sionna RT's own ``itu_*`` materials raise below 1 GHz for concrete, brick,
plasterboard, metal and the grounds, so this library carries the coefficients
itself, with their validity range. UHF RFID (860-960 MHz) sits just below most
ranges, which start at 1 GHz; the P.2040 fits are smooth power laws, so extrapolating
them down to :data:`UHF_EXTRAPOLATION_MIN_HZ` (800 MHz, a 20 % step in frequency) is the
usual practice (Sionna's own P.2040 implementation does it for wood and glass). That
extrapolation is stated once per material in the log at INFO level, with the values
used (and in a study report's methods section); a frequency farther outside a
material's range warns once with :class:`FrequencyRangeWarning`.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

__all__ = [
    "Material",
    "MATERIALS",
    "ITU_NAME_MAP",
    "UnknownMaterialError",
    "FrequencyRangeWarning",
    "UHF_EXTRAPOLATION_MIN_HZ",
    "extrapolated_materials",
    "material",
    "get_material",
    "resolve_material_name",
]


_P2040 = "ITU-R P.2040-3 (08/2023), Table 3"


class UnknownMaterialError(KeyError, ValueError):
    """A material name that is not in the UHF library (nor an ITU alias of one)."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0])


class FrequencyRangeWarning(UserWarning):
    """A material was evaluated outside its coefficients' validity range."""


@dataclass(frozen=True)
class Material:
    """One material of the library.

    Attributes
    ----------
    name : str
        Library key, e.g. ``"concrete"``.
    a, b : float
        Relative permittivity ``eps_r = a * f_GHz ** b`` (dimensionless).
    c, d : float
        Conductivity ``sigma = c * f_GHz ** d`` in S/m.
    f_min_hz, f_max_hz : float
        Frequency range over which the source validates the fit, Hz.
    thickness_m : float
        Default slab thickness used by Sionna's layered-slab reflection model, m.
    source : str
        Where the coefficients come from.
    """

    name: str
    a: float
    b: float
    c: float
    d: float
    f_min_hz: float
    f_max_hz: float
    thickness_m: float
    source: str = _P2040

    def relative_permittivity(self, frequency_hz: float) -> float:
        """Real relative permittivity at ``frequency_hz`` (P.2040-3 eq. 28)."""
        return self.a * (frequency_hz / 1e9) ** self.b

    def conductivity(self, frequency_hz: float) -> float:
        """Conductivity in S/m at ``frequency_hz`` (P.2040-3 eq. 29)."""
        return self.c * (frequency_hz / 1e9) ** self.d


def _m(name, a, b, c, d, fmin_ghz, fmax_ghz, thickness_m):
    return Material(name, a, b, c, d, fmin_ghz * 1e9, fmax_ghz * 1e9, thickness_m)


#: The library, keyed by name. Coefficients: ITU-R P.2040-3 Table 3; thickness:
#: typical indoor construction (not part of P.2040; used for Sionna's slab model).
MATERIALS: dict[str, Material] = {
    m.name: m
    for m in [
        _m("vacuum", 1.0, 0.0, 0.0, 0.0, 0.001, 100, 0.1),
        _m("concrete", 5.24, 0.0, 0.0462, 0.7822, 1, 100, 0.2),
        _m("brick", 3.91, 0.0, 0.0238, 0.16, 1, 40, 0.12),
        _m("plasterboard", 2.73, 0.0, 0.0085, 0.9395, 1, 100, 0.0125),
        _m("wood", 1.99, 0.0, 0.0047, 1.0718, 0.001, 100, 0.04),
        _m("glass", 6.31, 0.0, 0.0036, 1.3394, 0.1, 100, 0.008),
        _m("ceiling_board", 1.48, 0.0, 0.0011, 1.0750, 1, 100, 0.015),
        _m("chipboard", 2.58, 0.0, 0.0217, 0.7800, 1, 100, 0.018),
        _m("plywood", 2.71, 0.0, 0.33, 0.0, 1, 40, 0.018),
        _m("marble", 7.074, 0.0, 0.0055, 0.9262, 1, 60, 0.03),
        _m("metal", 1.0, 0.0, 1e7, 0.0, 1, 100, 0.002),
        _m("very_dry_ground", 3.0, 0.0, 0.00015, 2.52, 1, 10, 1.0),
        _m("medium_dry_ground", 15.0, -0.1, 0.035, 1.63, 1, 10, 1.0),
        _m("wet_ground", 30.0, -0.4, 0.15, 1.30, 1, 10, 1.0),
    ]
}

#: Names used by Sionna's ITU materials (and common spellings) mapped onto the library.
ITU_NAME_MAP: dict[str, str] = {
    **{f"itu_{k}": k for k in MATERIALS},
    "itu_ceiling_board": "ceiling_board",
    "itu_floorboard": "wood",
    "itu_plywood": "plywood",
}

_warned: set[str] = set()
_log = logging.getLogger(__name__)

#: Below a material's P.2040 range but at or above this, the power-law fit is extrapolated
#: with an INFO line (the UHF RFID bands); farther out a FrequencyRangeWarning is raised.
UHF_EXTRAPOLATION_MIN_HZ = 0.8e9


def extrapolated_materials(names, frequency_hz: float) -> list[dict]:
    """The materials of ``names`` whose P.2040 fit is extrapolated at ``frequency_hz``.

    Returns
    -------
    list of dict
        ``{"material", "range_ghz", "relative_permittivity", "conductivity_s_per_m"}``
        per extrapolated material (for a report's methods section).
    """
    out = []
    for name in sorted({resolve_material_name(n) for n in names}):
        mat = MATERIALS[name]
        if not mat.f_min_hz <= frequency_hz <= mat.f_max_hz:
            out.append({"material": name,
                        "range_ghz": [mat.f_min_hz / 1e9, mat.f_max_hz / 1e9],
                        "relative_permittivity": mat.relative_permittivity(frequency_hz),
                        "conductivity_s_per_m": mat.conductivity(frequency_hz)})
    return out


def resolve_material_name(name: str) -> str:
    """Map a library name, an ITU name (``itu_concrete``) or a Mitsuba id
    (``mat-itu_concrete``, ``uhf-concrete``) onto a library key.

    Raises
    ------
    UnknownMaterialError
        If the name maps onto nothing; the message lists the known names.
    """
    key = name.strip().lower()
    for prefix in ("mat-", "uhf-"):
        if key.startswith(prefix):
            key = key[len(prefix):]
    key = key.replace("-", "_").replace(" ", "_")
    if key in MATERIALS:
        return key
    if key in ITU_NAME_MAP:
        return ITU_NAME_MAP[key]
    raise UnknownMaterialError(
        f"unknown material {name!r}; known materials: {', '.join(sorted(MATERIALS))} "
        "(ITU names such as 'itu_concrete' are accepted too)"
    )


def get_material(name: str) -> Material:
    """The :class:`Material` for a library or ITU name."""
    return MATERIALS[resolve_material_name(name)]


def material(name: str, frequency_hz: float = 865e6) -> tuple[float, float]:
    """Relative permittivity and conductivity of a material at a frequency.

    Parameters
    ----------
    name : str
        Library name (``"concrete"``) or ITU name (``"itu_concrete"``).
    frequency_hz : float
        Frequency in Hz (default 865 MHz, the ETSI UHF RFID band).

    Returns
    -------
    (relative_permittivity, conductivity_s_per_m) : tuple of float
        P.2040-3 eqs. (28)-(29). Below the coefficients' validity range but at or above
        :data:`UHF_EXTRAPOLATION_MIN_HZ` the fit is extrapolated with one INFO log line
        per material; farther outside the range it warns once per material.
    """
    mat = get_material(name)
    if not frequency_hz > 0:
        raise ValueError(f"frequency_hz must be positive, got {frequency_hz!r}")
    uhf = UHF_EXTRAPOLATION_MIN_HZ <= frequency_hz < mat.f_min_hz
    if not (mat.f_min_hz <= frequency_hz <= mat.f_max_hz) and mat.name not in _warned:
        _warned.add(mat.name)
        if uhf:
            _log.info("material %r: P.2040-3 fit (valid %.4g-%.4g GHz) extrapolated to %.4g GHz: "
                      "eps_r = %.4g, sigma = %.4g S/m", mat.name, mat.f_min_hz / 1e9,
                      mat.f_max_hz / 1e9, frequency_hz / 1e9, mat.relative_permittivity(frequency_hz),
                      mat.conductivity(frequency_hz))
            return mat.relative_permittivity(frequency_hz), mat.conductivity(frequency_hz)
        warnings.warn(
            f"material {mat.name!r}: {frequency_hz / 1e9:.4g} GHz lies outside the P.2040-3 "
            f"validity range {mat.f_min_hz / 1e9:.4g}-{mat.f_max_hz / 1e9:.4g} GHz; "
            "extrapolating the power-law fit",
            FrequencyRangeWarning,
            stacklevel=2,
        )
    return mat.relative_permittivity(frequency_hz), mat.conductivity(frequency_hz)
