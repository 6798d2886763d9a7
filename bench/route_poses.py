"""Antenna poses along a scene's route, shared by the tracing benchmarks (not a library module)."""

from __future__ import annotations

import numpy as np


def route_poses(scene, n: int) -> np.ndarray:
    """``n`` antenna poses (n, 4) [x, y, z, yaw] along the scene's route (its x extent at
    y = 1.2 m without one), from 5 % to 95 % of its length, yaw alternating +-45 deg,
    every third pose 0.5 m high, the others 1.0 m."""
    lo, hi = scene.bounds_m
    route = scene.route_m if scene.route_m is not None else np.array([[lo[0] + 1, 1.2], [hi[0] - 1, 1.2]])
    seg = np.linalg.norm(np.diff(route, axis=0), axis=1)
    s = np.linspace(0.05, 0.95, n) * seg.sum()
    cum = np.concatenate([[0], np.cumsum(seg)])
    xy = np.stack([np.interp(s, cum, route[:, 0]), np.interp(s, cum, route[:, 1])], axis=1)
    yaw = np.where(np.arange(n) % 2 == 0, np.pi / 4, -np.pi / 4)
    z = np.where(np.arange(n) % 3 == 0, 0.5, 1.0)
    return np.column_stack([xy, z, yaw])
