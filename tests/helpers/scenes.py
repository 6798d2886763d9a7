"""Small scenes of the tests, boxes wrapped in scenes.Scene: one synthetic corridor
builder (:func:`box_corridor`), a room, a floor slab."""

import numpy as np
import trimesh

from scenes import Scene, TagSet

__all__ = ["box", "box_corridor", "box_room", "corridor_links", "make_corridor", "make_far_floor_scene",
           "make_floor_scene"]


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


def corridor_links(scene, rng, n_sources=5, tag_step=2, p_need=0.8):
    """Random antenna positions in a 20 m corridor, every ``tag_step``-th tag of ``scene``
    and a random ``p_need`` share of their links: (src (n, 3), tgt (m, 3), link_src,
    link_tgt), the sources drawn from ``rng`` before the links."""
    src = np.column_stack([rng.uniform(1, 19, n_sources), rng.uniform(0.3, 2.1, n_sources),
                           rng.uniform(0.3, 2.2, n_sources)])
    tgt = scene.tags.positions_m[::tag_step]
    link_src, link_tgt = np.nonzero(rng.random((len(src), len(tgt))) < p_need)
    return src, tgt, link_src, link_tgt


def make_floor_scene(material="concrete", size=60.0):
    """A single 0.2 m slab whose top face is z = 0, extending to +-size/2 around x in [-5, 55]."""
    floor = box([-10.0, -size / 2, -0.2], [size, size / 2, 0.0])
    return Scene("floor", {material: floor}, _tags([[5.0, 0.0, 1.0]]), metadata={"test": "floor"})


def make_far_floor_scene():
    """A floor 500 m below the antennas: the ground reflection is ~-60 dB below the direct path."""
    floor = box([-1000.0, -1000.0, -500.2], [1000.0, 1000.0, -500.0])
    return Scene("far_floor", {"concrete": floor}, _tags([[5.0, 0.0, 1.0]]), metadata={"test": "far"})


def box_corridor(length_m=20.0, width_m=2.4, height_m=3.0, *, wall_m=0.2, floor_m=0.1,
                 ceiling_m=0.0, cabinets=True, wall_tags=0, name="test_corridor"):
    """The tests' one synthetic corridor: along +x from 0 to ``length_m``, free space y in
    [0, ``width_m``], plasterboard wall slabs (``wall_m`` thick) outside it, end walls, a
    concrete floor slab ``floor_m`` thick whose top is z = 0.

    ``ceiling_m`` > 0 adds a ceiling board of that thickness at ``height_m``; ``cabinets``
    adds wooden cabinets (0.45 m deep, 1.2 m high) against alternating walls every 3.3 m,
    so a laser sees features along the corridor; ``wall_tags`` puts that many tags on each
    long wall at 1.0 m height, 1 cm off the wall, facing the corridor. The route runs
    along the centre line.
    """
    t = wall_m
    walls = trimesh.util.concatenate([
        box([-t, -t, 0], [length_m + t, 0, height_m]),
        box([-t, width_m, 0], [length_m + t, width_m + t, height_m]),
        box([-t, 0, 0], [0, width_m, height_m]),
        box([length_m, 0, 0], [length_m + t, width_m, height_m])])
    meshes = {"concrete": box([-t, -t, -floor_m], [length_m + t, width_m + t, 0.0])}
    if ceiling_m > 0:
        meshes["ceiling_board"] = box([-t, -t, height_m], [length_m + t, width_m + t, height_m + ceiling_m])
    meshes["plasterboard"] = walls
    if cabinets:
        xs = np.arange(2.5, length_m - 2.0, 3.3)
        meshes["wood"] = trimesh.util.concatenate([
            box([x, 0, 0], [x + 0.9, 0.45, 1.2]) if i % 2 == 0
            else box([x, width_m - 0.45, 0], [x + 0.9, width_m, 1.2]) for i, x in enumerate(xs)])
    xs = np.linspace(1.0, length_m - 1.0, wall_tags)
    pos = np.array([[x, 0.01, 1.0] for x in xs] + [[x, width_m - 0.01, 1.0] for x in xs]).reshape(-1, 3)
    normals = np.where(pos[:, 1:2] < width_m / 2, [[0.0, 1.0, 0.0]], [[0.0, -1.0, 0.0]])
    tags = TagSet(np.array([f"t{i}" for i in range(len(pos))], dtype=str), pos, normals.reshape(-1, 3))
    route = np.array([[0.0, width_m / 2], [length_m, width_m / 2]])
    return Scene(name=name, meshes=meshes, tags=tags, route_m=route)


def make_corridor(length=25.0, width=2.4, height=3.0, t=0.1):
    """The propagation tests' corridor: :func:`box_corridor` with 0.1 m walls, a 0.2 m floor,
    a 5 cm ceiling board, no cabinets and 8 tags on each long wall."""
    return box_corridor(length, width, height, wall_m=t, floor_m=0.2, ceiling_m=0.05,
                        cabinets=False, wall_tags=8)


def box_room(size_x=4.0, size_y=3.0, height=2.5):
    """A closed concrete room (0.2 m walls, no floor) with a route along its middle."""
    t = 0.2
    walls = [
        box([-t, -t, 0], [size_x + t, 0, height]),
        box([-t, size_y, 0], [size_x + t, size_y + t, height]),
        box([-t, 0, 0], [0, size_y, height]),
        box([size_x, 0, 0], [size_x + t, size_y, height]),
    ]
    tags = TagSet(np.array([], dtype=str), np.zeros((0, 3)), np.zeros((0, 3)))
    return Scene(
        name="box_room",
        meshes={"concrete": trimesh.util.concatenate(walls)},
        tags=tags,
        route_m=np.array([[0.5, size_y / 2], [size_x - 0.5, size_y / 2]]),
    )
