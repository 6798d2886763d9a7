"""Candidate antenna mounts: the grid, the presets, the optimiser's trials, and their checks.

A candidate is a named set of antenna mounts (:class:`Candidate`). Mount values come
from the placement file's ``[mount]`` with the varied fields set
(:func:`mount_antennas`): symmetric mounts are mirrored pairs, the right antenna at
``(x, -y, z)`` with yaw ``-yaw``, unless a ``*_right_*`` field gives it its own value.
:func:`check_candidate` refuses, naming the candidate and the field, a mount outside
the envelope, inside the robot's body (:class:`pipeline.robot.Robot`'s own check), or
more antennas than the envelope allows.
"""

from __future__ import annotations

import dataclasses
import itertools
import re
from collections import Counter
from dataclasses import dataclass

from pipeline.config import AntennaMountConfig, ConfigError, StudyConfig
from pipeline.robot import AntennaMount, Robot

__all__ = [
    "MOUNT_FIELDS",
    "Candidate",
    "candidate_from_trial",
    "candidate_from_values",
    "candidates_of",
    "check_candidate",
    "check_ranges",
    "mount_antennas",
]

#: Mount fields a grid or a range may vary (``*_right_*``: the right antenna's own value).
MOUNT_FIELDS = ("x_m", "y_m", "z_m", "yaw_deg", "tilt_deg", "z_right_m", "tilt_right_deg",
                "yaw_right_deg", "y_right_m", "count")

# short labels of the mount fields in candidate names
_LABEL = {"x_m": "x", "y_m": "y", "z_m": "z", "yaw_deg": "yaw", "tilt_deg": "tilt",
          "z_right_m": "zR", "tilt_right_deg": "tiltR", "yaw_right_deg": "yawR", "y_right_m": "yR",
          "count": "n"}


@dataclass(frozen=True)
class Candidate:
    """One candidate mount.

    Attributes
    ----------
    name : str
        Unique, file-name safe (its run directories are ``candidates/<name>/``).
    values : dict
        The mount fields this candidate sets (grid or optimiser values; empty for a preset).
    antennas : tuple of AntennaMountConfig
        The antennas, robot frame.
    origin : str
        "grid", "preset" or "optimiser".
    """

    name: str
    values: dict
    antennas: tuple[AntennaMountConfig, ...]
    origin: str = "grid"

    def config(self, base: StudyConfig) -> StudyConfig:
        """``base`` with this candidate's antennas."""
        return dataclasses.replace(base, robot=dataclasses.replace(base.robot, antennas=self.antennas))


def _num(v: float) -> str:
    return f"{float(v):g}"


def candidate_name(values: dict, prefix: str = "") -> str:
    """A readable, file-name safe name: ``z0.4_tilt-20`` (``prefix`` first)."""
    body = "_".join(f"{_LABEL.get(k, k)}{_num(v)}" for k, v in values.items()) or "base"
    return re.sub(r"[^A-Za-z0-9_.+-]", "-", prefix + body)


def mount_antennas(mount, values: dict | None = None) -> tuple[AntennaMountConfig, ...]:
    """The antennas of ``mount`` (a :class:`~.spec.MountConfig`) with ``values`` set.

    Parameters
    ----------
    mount : MountConfig
    values : dict, optional
        Mount field -> value (:data:`MOUNT_FIELDS`).

    Returns
    -------
    tuple of AntennaMountConfig
        ``left`` (and ``right`` for count 2).
    """
    m = dataclasses.replace(mount, **(values or {}))
    left = AntennaMountConfig(name="left", x_m=m.x_m, y_m=m.y_m, z_m=m.z_m, yaw_deg=m.yaw_deg,
                              tilt_deg=m.tilt_deg)
    if int(m.count) == 1:
        return (left,)
    mirror = m.symmetric
    right = AntennaMountConfig(
        name="right", x_m=m.x_m,
        y_m=(-m.y_m if mirror else m.y_m) if m.y_right_m is None else m.y_right_m,
        z_m=m.z_m if m.z_right_m is None else m.z_right_m,
        yaw_deg=(-m.yaw_deg if mirror else m.yaw_deg) if m.yaw_right_deg is None else m.yaw_right_deg,
        tilt_deg=m.tilt_deg if m.tilt_right_deg is None else m.tilt_right_deg)
    return (left, right)


def candidate_from_values(spec, values: dict, origin: str = "grid", prefix: str = "") -> Candidate:
    """The candidate of ``spec``'s base mount with ``values`` set."""
    values = {k: (int(v) if k == "count" else float(v)) for k, v in values.items()}
    return Candidate(candidate_name(values, prefix), values,
                     mount_antennas(spec.settings.mount, values), origin)


def candidates_of(spec) -> list[Candidate]:
    """The grid's candidates (Cartesian product of the non-empty ``[grid]`` fields) and
    the presets, in file order; names are unique (a clash is an error)."""
    s = spec.settings
    grid = {k: list(getattr(s.grid, k)) for k in MOUNT_FIELDS if getattr(s.grid, k)}
    out = []
    if grid:
        keys = list(grid)
        for combo in itertools.product(*(grid[k] for k in keys)):
            out.append(candidate_from_values(spec, dict(zip(keys, combo, strict=True))))
    for i, p in enumerate(s.preset):
        name = p.name
        # a preset's name is a folder name, used as given (never silently renamed);
        # "opt_" names are the optimiser's trials
        if re.fullmatch(r"[A-Za-z0-9_.+-]{1,64}", name) is None:
            raise ConfigError(f"{spec.source}: preset[{i}].name = {p.name[:40]!r}: letters, digits "
                              "and _ . + - only, at most 64 (it names a folder)")
        if name in (".", "..") or name.startswith(("opt_", ".")):
            raise ConfigError(f"{spec.source}: preset[{i}].name = {p.name!r}: give a name that "
                              "does not start with '.' or 'opt_' (the optimiser's trials)")
        out.append(Candidate(name, {}, tuple(p.antennas), "preset"))
    names = [c.name for c in out]
    dup = sorted(n for n, k in Counter(names).items() if k > 1)  # linear in the candidates
    if dup:
        raise ConfigError(f"{spec.source}: candidate names repeat: {dup} (a grid value listed "
                          "twice, or a preset named like a grid point)")
    return out


def _envelope_violation(a: AntennaMountConfig, env) -> str | None:
    for ax in ("x_m", "y_m", "z_m"):
        lo, hi = getattr(env, ax)
        v = getattr(a, ax)
        if not lo <= v <= hi:
            return f"{ax} = {v} outside envelope.{ax} = [{lo}, {hi}]"
    return None


def check_candidate(c: Candidate, spec, what: str = "") -> None:
    """Refuse a candidate the robot cannot carry.

    Raises
    ------
    ConfigError
        Naming the candidate (and ``what`` produced it): more antennas than
        ``envelope.max_antennas``, an antenna outside the envelope, or inside the body.
    """
    src, env = spec.source, spec.settings.envelope
    where = f"{src}: {what + ': ' if what else ''}candidate {c.name!r}"
    if len(c.antennas) > env.max_antennas:
        raise ConfigError(f"{where} has {len(c.antennas)} antennas, envelope.max_antennas = "
                          f"{env.max_antennas}")
    names = [a.name for a in c.antennas]
    if len(set(names)) != len(names):
        raise ConfigError(f"{where}: antenna names repeat: {names}")
    for a in c.antennas:
        bad = _envelope_violation(a, env)
        if bad:
            raise ConfigError(f"{where}: antenna {a.name!r} {bad}")
    try:  # the robot's own body check (a mount inside the chassis is shielded)
        Robot(antennas=[AntennaMount(a.name, x_m=a.x_m, y_m=a.y_m, z_m=a.z_m, yaw_rad=0.0)
                             for a in c.antennas])
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def check_ranges(spec, ranges: dict) -> None:
    """Refuse optimiser ranges whose box leaves the envelope or reaches into the body.

    Every corner of the search box is checked as a candidate (envelope: the box is
    inside iff its corners are), and the box of each antenna's positions is intersected
    with the robot's body box.
    """
    keys = list(ranges)
    for combo in itertools.product(*(ranges[k] for k in keys)):
        check_candidate(candidate_from_values(spec, dict(zip(keys, combo, strict=True))), spec,
                        what=f"optimise.ranges corner {dict(zip(keys, combo, strict=True))}")
    body = Robot(antennas=[])
    half = {"x_m": body.length_m / 2, "y_m": body.width_m / 2}
    corners = [mount_antennas(spec.settings.mount, dict(zip(keys, combo, strict=True)))
               for combo in itertools.product(*(ranges[k] for k in keys))]
    for i in range(len(corners[0])):
        box = {ax: (min(getattr(c[i], ax) for c in corners), max(getattr(c[i], ax) for c in corners))
               for ax in ("x_m", "y_m", "z_m")}
        inside = (box["x_m"][0] < half["x_m"] and box["x_m"][1] > -half["x_m"]
                  and box["y_m"][0] < half["y_m"] and box["y_m"][1] > -half["y_m"]
                  and box["z_m"][0] < body.body_height_m)
        if inside:
            name = corners[0][i].name
            raise ConfigError(
                f"{spec.source}: optimise.ranges let antenna {name!r} into the robot's body "
                f"(x {box['x_m']}, y {box['y_m']}, z from {box['z_m'][0]} m; body "
                f"{body.length_m} x {body.width_m} m, top at {body.body_height_m} m): raise the "
                "lowest height above the body top or move the mount outside the footprint")


def candidate_from_trial(spec, values: dict) -> Candidate:
    """The optimiser's candidate for ``values`` (rounded to 1 mm / 0.1 deg: a mount is
    built to that precision, and equal rounded values share one run directory)."""
    vals = {k: round(float(v), 3 if k.endswith("_m") else 1) for k, v in values.items()
            if k in MOUNT_FIELDS}
    c = candidate_from_values(spec, vals, origin="optimiser", prefix="opt_")
    check_candidate(c, spec, what="optimiser trial")
    return c
