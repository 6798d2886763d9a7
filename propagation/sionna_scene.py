"""Loading a :class:`scenes.Scene` into Sionna RT, and checks on where antennas may go.

Two geometries, two uses: Sionna traces the scene's radio surfaces (each physical layer
crossed once, :mod:`scenes.radio`; the solid meshes as they are when a scene has none),
while geometric checks (an antenna inside a wall, a cabinet) use the closed solids.

All Sionna imports are lazy and happen after :func:`propagation.backend.ensure_variant`.
"""

from __future__ import annotations

import logging
import tempfile

import numpy as np

from propagation.backend import ensure_variant
from propagation.jitarrays import jit_points
from propagation.sionna_internals import use_endpoints_at_once
from scenes.geometry import solid_material_at

__all__ = [
    "check_antenna_positions",
    "clear_devices",
    "device_point",
    "load_sionna_scene",
]

logger = logging.getLogger(__name__)

# Loaded Sionna scenes, keyed by (content hash, frequency); the temporary export
# directory lives as long as the scene. Filled on first use, never at import.
_SCENES: dict[tuple[str, float, bool], tuple[object, tempfile.TemporaryDirectory]] = {}
_MAX_CACHED_SCENES = 2


def load_sionna_scene(scene, frequency_hz: float, *, public_api: bool = False):
    """A Sionna RT scene for ``scene`` at ``frequency_hz`` (exported once, then reused).

    The scene's traced surfaces (``scene.radio_surfaces``, or its solid meshes when
    ``None``) are exported by :func:`scenes.export.export_mitsuba` with materials
    evaluated at ``frequency_hz``: one shape per (material, thickness), not merged, so
    object names are ``<material>-t<thickness>`` (``brick-t0p120``). Cached by
    :meth:`scenes.Scene.content_hash`, which covers the radio surfaces. Transmitters and
    receivers left from an earlier call are removed.

    Parameters
    ----------
    scene : scenes.Scene
    frequency_hz : float
        Carrier frequency [Hz]; materials are evaluated there.
    public_api : bool
        False (the fast tracer's scenes): the scene builds its endpoint arrays with
        :func:`propagation.sionna_internals.use_endpoints_at_once` (fewer kernels; guarded
        by the tested versions). True: Sionna's scene as it is loaded, for the public-API
        tracer (``method="direct"``).

    Raises
    ------
    scenes.UnknownMaterialError
        If a mesh carries a material the library does not know.
    """
    ensure_variant()
    import sionna.rt as rt

    key = (scene.content_hash(), float(frequency_hz), bool(public_api))
    if key not in _SCENES:
        while len(_SCENES) >= _MAX_CACHED_SCENES:
            _, (_, tmp) = _SCENES.popitem()
            tmp.cleanup()
        tmp = tempfile.TemporaryDirectory(prefix="rfidstudy-scene-")
        xml = scene.export_mitsuba(tmp.name, frequency_hz)
        rt_scene = rt.load_scene(str(xml), merge_shapes=False)
        if not public_api:
            # Sionna's own method compiles a kernel per device (a literal index)

            use_endpoints_at_once(rt_scene)
        rt_scene.frequency = float(frequency_hz)
        _SCENES[key] = (rt_scene, tmp)
        logger.debug("loaded Sionna scene %s at %.6g Hz", scene.name, frequency_hz)
    rt_scene = _SCENES[key][0]
    clear_devices(rt_scene)
    return rt_scene


def clear_devices(rt_scene) -> None:
    """Remove every transmitter and receiver from a Sionna scene."""
    for name in list(rt_scene.transmitters) + list(rt_scene.receivers):
        rt_scene.remove(name)


def place_devices(rt_scene, sources_m=(), targets_m=(), polarization: str = "VH") -> None:
    """Clear the scene's devices, set single isotropic antennas of ``polarization`` at
    both ends (patterns are applied later, in NumPy), and add a transmitter per source
    and a receiver per target, (k, 3) metres, named ``tx<i>`` / ``rx<j>``."""
    import sionna.rt as rt

    clear_devices(rt_scene)
    rt_scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization=polarization)
    rt_scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization=polarization)
    for k, p in enumerate(np.asarray(sources_m, float).reshape(-1, 3)):
        rt_scene.add(rt.Transmitter(f"tx{k}", position=device_point(p)))
    for k, p in enumerate(np.asarray(targets_m, float).reshape(-1, 3)):
        rt_scene.add(rt.Receiver(f"rx{k}", position=device_point(p)))


def device_point(xyz):
    """A radio device's position [m] or orientation [rad] as a Dr.Jit array held in
    memory, not a literal.

    A position given as numbers becomes a Dr.Jit literal, compiled into every kernel it
    enters: each device placed anew cost kernel compilations (~10 ms each, far more
    inside Sionna's kernels) on an empty kernel cache. An array uploaded from NumPy is a
    kernel argument instead.

    Parameters
    ----------
    xyz : array_like
        (3,) position [m] or Sionna orientation angles [rad].

    Returns
    -------
    mitsuba.Point3f
        One point (float32, like any Sionna position).
    """
    import mitsuba as mi

    return jit_points(mi.Point3f, np.reshape(xyz, (1, 3)))


def check_antenna_positions(scene, positions_m, what: str = "antenna pose") -> None:
    """Raise if a position is outside the scene's bounds or inside solid geometry.

    Parameters
    ----------
    scene : scenes.Scene
        The scene; solids are its closed mesh bodies (wall slabs, cabinets, boxes), tested
        with :func:`scenes.solid_material_at` (generalised winding number, pure NumPy).
        The solids, not the radio surfaces: an antenna inside a wall's thickness is
        refused although the tracer sees only the wall's inner face.
    positions_m : array_like
        Shape (n, 3), metres. x and y must lie strictly inside ``scene.bounds_m``, z above
        its lowest point (a point above the top of an open scene is accepted).
    what : str
        Name used in the error message ("antenna pose 3 at (x, y, z) ...").

    Raises
    ------
    ValueError
        Naming the first offending index and its coordinates.
    """
    pos = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    lo, hi = scene.bounds_m
    # x and y strictly inside the bounds, z above the lowest geometry; above the top is
    # allowed so that open scenes (a bare floor) can be traced.
    outside = np.any((pos[:, :2] <= lo[:2]) | (pos[:, :2] >= hi[:2]), axis=1) | (pos[:, 2] <= lo[2])
    if np.any(outside):
        i = int(np.flatnonzero(outside)[0])
        raise ValueError(
            f"{what} {i} at ({pos[i, 0]:.4g}, {pos[i, 1]:.4g}, {pos[i, 2]:.4g}) m lies outside "
            f"the scene {scene.name!r} bounds {lo.round(3).tolist()} .. {hi.round(3).tolist()}"
        )
    material = solid_material_at(scene, pos)
    inside = material != ""
    if np.any(inside):
        i = int(np.flatnonzero(inside)[0])
        raise ValueError(
            f"{what} {i} at ({pos[i, 0]:.4g}, {pos[i, 1]:.4g}, {pos[i, 2]:.4g}) m lies "
            f"inside solid geometry of scene {scene.name!r} (a closed {material} body)"
        )
