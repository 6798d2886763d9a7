"""Propagation: Sionna RT ray tracing, the RFID link budget and analytic references.

The only package that imports sionna, mitsuba or drjit -- always lazily, after
:func:`select_variant` (never at import).
"""

from propagation.analytic import (
    db_to_linear,
    free_space_gain_db,
    fresnel_reflection,
    linear_to_db,
    slab_coefficients,
    slab_transmission_db,
    two_ray_gain_db,
)
from propagation.backend import (
    BackendError,
    backend_info,
    find_libllvm,
    select_variant,
    set_deterministic,
)
from propagation.fields import RssiField, rssi_field
from propagation.linkbudget import LinkBudget
from propagation.pathcache import CacheWarning
from propagation.patterns import (
    AntennaFrameAngles,
    antenna_frame_angles,
    pattern_gain_db,
)
from propagation.sionna_internals import TESTED_VERSIONS, SionnaVersionError
from propagation.tracing import (
    DEFAULT_MAX_DEPTH,
    DEFAULT_SAMPLES_PER_SRC,
    METHODS,
    LinkSet,
    TraceOptions,
    trace_links,
)

__all__ = [
    "DEFAULT_MAX_DEPTH",
    "DEFAULT_SAMPLES_PER_SRC",
    "METHODS",
    "TESTED_VERSIONS",
    "AntennaFrameAngles",
    "BackendError",
    "CacheWarning",
    "LinkBudget",
    "LinkSet",
    "RssiField",
    "SionnaVersionError",
    "TraceOptions",
    "antenna_frame_angles",
    "backend_info",
    "db_to_linear",
    "find_libllvm",
    "free_space_gain_db",
    "fresnel_reflection",
    "linear_to_db",
    "pattern_gain_db",
    "rssi_field",
    "select_variant",
    "set_deterministic",
    "slab_coefficients",
    "slab_transmission_db",
    "trace_links",
    "two_ray_gain_db",
]
