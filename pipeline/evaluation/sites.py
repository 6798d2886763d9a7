"""The truth where tags are: the learned model against the ray-traced link at tag sites.

The chapter's Fig. 6 compares rho over a (d, alpha) plane at antenna height in free
space, but tags sit on walls, boxes and cabinets, facing into the corridor, and a model
of (d, alpha) alone cannot know that a tag 1.5 m away behind a metal cabinet is never
read. Here the truth is traced from antenna poses of the held-out evaluation tour to
every tag site in reach (:func:`scenes.tagsites.tag_sites`: a grid on every vertical
surface facing free space, with the tag dipole in the surface plane), and compared with
the model at each (pose, site) pair:

- ``p_true = closed * (1 - miss_probability)`` (the ``"fixed"`` reader's constant, or the
  Gen2 reader's per pose: a tag at the site joins the pose's antenna slot,
  :func:`pipeline.acquisition.singulation.miss_probability_at_poses`), ``fs_true`` the noise-free RSSI
  normalised by the model's range (0 where the link does not close), ``rho_true =
  fs_true * p_true`` (as :func:`~.comparison.rho_points_truth`);
- the model's ``fT``, ``fs``, ``rho`` at the site's (d, alpha) in the TRUE antenna frame.

Pairs are split by geometry: ``obstructed`` where the straight segment from the antenna
to the site crosses the scene's solid geometry (behind a cabinet, box or wall), else
``clear``. Per site, the mean error over the poses that reach it makes the per-location
error map of the report.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from fuzzymodel import normalise_rssi
from pipeline.evaluation.geometry import antenna_frame_geometry
from pipeline.evaluation.interface import check_sensor
from pipeline.evaluation.metrics import error_stats, nan_to_none
from pipeline.evaluation.truth import check_miss_probability, true_detected, true_rssi_dbm
from scenes.fileio import atomic_save_npz, read_npz
from scenes.geometry import raycast

__all__ = ["SiteComparison", "SiteTruth", "obstructed_pairs", "site_comparison"]


@dataclass(frozen=True)
class SiteTruth:
    """Ray-traced one-way gains from antenna poses to tag sites.

    Attributes
    ----------
    antenna_poses : numpy.ndarray, shape (p, 6), float64
        True antenna poses [x, y, z, yaw, pitch, roll] (m, rad).
    positions_m : numpy.ndarray, shape (s, 3), float64
        Tag sites [m].
    normals : numpy.ndarray, shape (s, 3), float64
        Unit surface normals of the sites (into free space).
    material : numpy.ndarray, shape (s,), str
        Surface material of each site.
    gain_db : numpy.ndarray, shape (p, s), float64
        One-way gain [dB]; -inf where not traced (out of reach) or no path.
    traced : numpy.ndarray, shape (p, s), bool
        Pairs traced (in reach of the pose).
    obstructed : numpy.ndarray, shape (p, s), bool
        The antenna-site segment crosses solid geometry.
    """

    antenna_poses: np.ndarray
    positions_m: np.ndarray
    normals: np.ndarray
    material: np.ndarray
    gain_db: np.ndarray
    traced: np.ndarray
    obstructed: np.ndarray

    def save(self, path) -> Path:
        """Write every attribute to an NPZ file atomically (``truth/site_truth.npz``)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_save_npz(path, antenna_poses=self.antenna_poses, positions_m=self.positions_m,
                        normals=self.normals, material=np.asarray(self.material, dtype=str),
                        gain_db=self.gain_db, traced=self.traced, obstructed=self.obstructed)
        return path

    @classmethod
    def load(cls, path) -> SiteTruth:
        """Read a file written by :meth:`save`; errors name the file and missing keys."""
        path = Path(path)
        need = ("antenna_poses", "positions_m", "normals", "material", "gain_db", "traced",
                "obstructed")
        with read_npz(path) as z:
            missing = [k for k in need if k not in z.files]
            if missing:
                raise ValueError(f"{path}: missing key(s) {missing}")
            out = cls(**{k: z[k] for k in need})
        p, s = len(out.antenna_poses), len(out.positions_m)
        for k in ("gain_db", "traced", "obstructed"):
            if getattr(out, k).shape != (p, s):
                raise ValueError(f"{path}: {k} has shape {getattr(out, k).shape}, expected {(p, s)}")
        if np.any(np.isnan(out.gain_db)):
            raise ValueError(f"{path}: gain_db contains NaN")
        return out


def obstructed_pairs(scene, antenna_xyz: np.ndarray, sites_m: np.ndarray) -> np.ndarray:
    """Whether the segment from each antenna position to each site crosses a solid.

    Parameters
    ----------
    scene : scenes.Scene
    antenna_xyz : numpy.ndarray, shape (p, 3)
    sites_m : numpy.ndarray, shape (s, 3)
        Sites a few millimetres in front of their surface (so their own surface is not hit
        from the front).

    Returns
    -------
    numpy.ndarray, shape (p, s), bool
    """
    a = np.asarray(antenna_xyz, float).reshape(-1, 3)
    s = np.asarray(sites_m, float).reshape(-1, 3)
    o = np.repeat(a, len(s), axis=0)
    v = np.tile(s, (len(a), 1)) - o
    dist = np.linalg.norm(v, axis=1)
    # each ray only as far as its site: the chunks' boxes (one antenna, neighbouring sites)
    # then prune the triangles, with the same decisions (a hit beyond the site is no
    # obstruction either way)
    hit = raycast(scene, o, v, max_range_m=dist)
    # 1 mm short of the site: the site itself is in free space, 5 mm off its surface
    return (hit < dist - 1e-3).reshape(len(a), len(s))


@dataclass(frozen=True)
class SiteComparison:
    """A sensor model against the truth at tag sites.

    Attributes
    ----------
    summary : dict
        ``{"all" | "clear" | "obstructed": {"rho": ErrorStats dict, "fT_mse": float,
        "fT_mae": float, "rssi_dbm": ErrorStats dict (closing links), "n_pairs": int,
        "true_read_fraction": float, "predicted_read_fraction": float}}``.
    per_site : pandas.DataFrame
        One row per site reached by at least one pose: site, x_m, y_m, z_m, nx, ny,
        material, n_poses, rho_true_mean, rho_model_mean, rho_error_mean (signed,
        model - truth), rho_abs_error_mean, obstructed_fraction.
    """

    summary: dict
    per_site: pd.DataFrame

    def to_dict(self) -> dict:
        """JSON-able summary (the per-site table is saved separately)."""
        return nan_to_none(self.summary)


def _subset_stats(sel, rho_m, rho_t, ft_m, p_t, fs_dbm_m, rssi_t, closed) -> dict:
    c = sel & closed
    return {
        "n_pairs": int(sel.sum()),
        "rho": error_stats(rho_m[sel], rho_t[sel]).to_dict(),
        "fT_mae": float(np.mean(np.abs(ft_m[sel] - p_t[sel]))) if sel.any() else float("nan"),
        "fT_mse": float(np.mean((ft_m[sel] - p_t[sel]) ** 2)) if sel.any() else float("nan"),
        "rssi_dbm": error_stats(fs_dbm_m[c], rssi_t[c]).to_dict(),
        "true_read_fraction": float(np.mean(p_t[sel])) if sel.any() else float("nan"),
        "predicted_read_fraction": float(np.mean(ft_m[sel])) if sel.any() else float("nan"),
    }


def site_comparison(truth: SiteTruth, sensor, budget, miss_probability=0.0,
                    d_max_m: float | None = None) -> SiteComparison:
    """Compare ``sensor`` with the ray-traced truth at every traced (pose, site) pair.

    Parameters
    ----------
    truth : SiteTruth
    sensor : SensorLike
        Its ``rssi_range_dbm`` normalises the true RSSI.
    budget : propagation.LinkBudget
    miss_probability : float or array_like, shape (p,) or (p, s)
        Reader anti-collision miss probability of a closing link in [0, 1): one for all
        pairs, one per antenna pose (p,), or one per pair (p, s).
    d_max_m : float, optional
        Only pairs with d <= d_max_m (the model's training domain) are compared.

    Returns
    -------
    SiteComparison
    """
    sensor = check_sensor(sensor)
    shape = (len(truth.antenna_poses), len(truth.positions_m))
    q = np.asarray(miss_probability, dtype=np.float64)
    if q.ndim == 1 and q.shape[0] == shape[0]:
        q = q[:, None]  # one per pose
    q = check_miss_probability(q, shape, "one per pose (p,) or pair (p, s)")
    geo = antenna_frame_geometry(truth.antenna_poses, truth.positions_m)
    d, a = geo.d_m, geo.alpha_rad
    sel = np.asarray(truth.traced, bool).copy()
    if d_max_m is not None:
        sel &= d <= float(d_max_m)
    g = np.where(sel, truth.gain_db, -np.inf)
    closed = true_detected(g, budget)
    rssi_t = np.where(closed, true_rssi_dbm(np.where(closed, g, 0.0), budget), np.nan)
    fs_t = np.where(closed, normalise_rssi(np.nan_to_num(rssi_t), sensor.rssi_range_dbm), 0.0)
    p_t = closed * (1.0 - q)
    rho_t = fs_t * p_t
    rho_m = np.asarray(sensor.rho(d, a), float)
    ft_m = np.asarray(sensor.fT(d, a), float)
    fs_dbm_m = np.asarray(sensor.fs_dbm(d, a), float)
    obs = np.asarray(truth.obstructed, bool)
    args = (rho_m, rho_t, ft_m, p_t, fs_dbm_m, rssi_t, closed)
    summary = {"all": _subset_stats(sel, *args), "clear": _subset_stats(sel & ~obs, *args),
               "obstructed": _subset_stats(sel & obs, *args), "d_max_m": d_max_m,
               "n_poses": int(len(truth.antenna_poses)), "n_sites": int(len(truth.positions_m))}
    n = sel.sum(axis=0)
    reached = n > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        def mean(x):
            return np.where(reached, np.where(sel, x, 0.0).sum(axis=0) / np.maximum(n, 1), np.nan)

        per = pd.DataFrame({
            "site": np.arange(len(truth.positions_m)),
            "x_m": truth.positions_m[:, 0], "y_m": truth.positions_m[:, 1],
            "z_m": truth.positions_m[:, 2], "nx": truth.normals[:, 0], "ny": truth.normals[:, 1],
            "material": np.asarray(truth.material, str), "n_poses": n,
            "rho_true_mean": mean(rho_t), "rho_model_mean": mean(rho_m),
            "rho_error_mean": mean(rho_m - rho_t), "rho_abs_error_mean": mean(np.abs(rho_m - rho_t)),
            "obstructed_fraction": mean(obs.astype(float)),
        })
    return SiteComparison(summary=summary, per_site=per.loc[reached].reset_index(drop=True))
