"""Small scenes for the propagation tests (boxes wrapped in scenes.Scene).

A normal module (not conftest.py) so test files import it by a unique name.
"""

import numpy as np
import trimesh

from scenes import Scene, TagSet

__all__ = ["box", "make_corridor", "make_far_floor_scene", "make_floor_scene"]


def box(lo, hi):
    """An axis-aligned box mesh between corners lo and hi [m]."""
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def _tags(pos):
    pos = np.asarray(pos, float)
    return TagSet([f"t{i}" for i in range(len(pos))], pos, np.tile([0.0, -1.0, 0.0], (len(pos), 1)))


def make_floor_scene(material="concrete", size=60.0):
    """A single 0.2 m slab whose top face is z = 0, extending to +-size/2 around x in [-5, 55]."""
    floor = box([-10.0, -size / 2, -0.2], [size, size / 2, 0.0])
    return Scene("floor", {material: floor}, _tags([[5.0, 0.0, 1.0]]), metadata={"test": "floor"})


def make_far_floor_scene():
    """A floor 500 m below the antennas: the ground reflection is ~-60 dB below the direct path."""
    floor = box([-1000.0, -1000.0, -500.2], [1000.0, 1000.0, -500.0])
    return Scene("far_floor", {"concrete": floor}, _tags([[5.0, 0.0, 1.0]]), metadata={"test": "far"})


def make_corridor(length=25.0, width=2.4, height=3.0, t=0.1):
    """Corridor along +x: concrete floor, ceiling board, plasterboard wall slabs outside the free space."""
    floor = box([-t, -t, -0.2], [length + t, width + t, 0.0])
    ceil = box([-t, -t, height], [length + t, width + t, height + 0.05])
    walls = trimesh.util.concatenate([
        box([-t, -t, 0], [length + t, 0, height]), box([-t, width, 0], [length + t, width + t, height]),
        box([-t, 0, 0], [0, width, height]), box([length, 0, 0], [length + t, width, height])])
    xs = np.linspace(1.0, length - 1.0, 8)
    pos = np.array([[x, 0.01, 1.0] for x in xs] + [[x, width - 0.01, 1.0] for x in xs])
    normals = np.where(pos[:, 1:2] < 1, [[0.0, 1.0, 0.0]], [[0.0, -1.0, 0.0]])
    tags = TagSet([f"t{i}" for i in range(len(pos))], pos, normals)
    return Scene("test_corridor", {"concrete": floor, "ceiling_board": ceil, "plasterboard": walls},
                 tags, metadata={"test": "corridor"})
