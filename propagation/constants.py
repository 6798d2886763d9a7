"""Physical constants, defined once for every package (SI units).

The speed of light is exact by the SI definition; the vacuum permittivity is the
CODATA 2018 value.
"""

from __future__ import annotations

__all__ = ["EPSILON_0", "SPEED_OF_LIGHT"]

#: Speed of light in vacuum, m/s (exact).
SPEED_OF_LIGHT = 299_792_458.0
#: Vacuum permittivity, F/m (CODATA 2018).
EPSILON_0 = 8.8541878128e-12
