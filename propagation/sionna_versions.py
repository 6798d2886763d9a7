"""The Sionna RT, Mitsuba and Dr.Jit versions the study's fast tracer was tested with, and
the guard that refuses others (:mod:`propagation.sionna_internals` calls it before every
use of Sionna's non-public API)."""

from __future__ import annotations

__all__ = ["TESTED_VERSIONS", "SionnaVersionError", "check_versions", "installed_versions"]

#: The versions every use of Sionna's internals (:mod:`propagation.sionna_internals`) was
#: written against and tested with (the pins of ``constraints.txt``). Another version is
#: refused by :func:`check_versions`.
TESTED_VERSIONS = {"sionna-rt": "2.2.0", "mitsuba": "3.9.1", "drjit": "1.5.0"}


class SionnaVersionError(RuntimeError):
    """The installed sionna-rt, mitsuba or drjit is not the tested one."""


def installed_versions() -> dict[str, str]:
    """The versions of the imported ``sionna.rt``, ``mitsuba`` and ``drjit`` modules.

    Read from the modules themselves (``__version__``), i.e. the code that runs, not
    the package metadata. Needs a Mitsuba variant (:func:`propagation.backend.ensure_variant`).

    Returns
    -------
    dict
        Keys of :data:`TESTED_VERSIONS`, version strings as values.
    """
    import drjit as dr
    import mitsuba as mi
    import sionna.rt as rt

    return {"sionna-rt": str(rt.__version__), "mitsuba": str(mi.__version__),
            "drjit": str(dr.__version__)}


def check_versions() -> None:
    """Refuse to run Sionna's internals on versions other than :data:`TESTED_VERSIONS`.

    Raises
    ------
    SionnaVersionError
        One line naming the installed and the tested versions and the two ways out.
    """
    got = installed_versions()
    if got != TESTED_VERSIONS:
        have = ", ".join(f"{k} {v}" for k, v in got.items())
        want = ", ".join(f"{k} {v}" for k, v in TESTED_VERSIONS.items())
        raise SionnaVersionError(
            f"the fast tracer uses Sionna internals tested only with {want}, but {have} is "
            f"installed: set tracing.method = \"direct\" (TraceOptions(method=\"direct\"), "
            f"Sionna's public API only) or install the tested versions (constraints.txt)")
