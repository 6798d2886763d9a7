"""The (d, alpha) cell grid shared by the detection truth and the grid-count baseline.

Cells are ``d_bin_m`` wide in distance from 0 to ``d_max_m`` and
``alpha_bin_deg`` wide in bearing over (-180, 180] deg. A sample with d outside
[0, d_max_m) lies in no cell. Bearings are wrapped to (-pi, pi] first; the
bearing ``+pi`` falls in the last bearing bin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fuzzymodel import wrap_angle
from pipeline.configschema import check_keys

__all__ = ["CellGrid", "CellIndex"]


@dataclass(frozen=True)
class CellIndex:
    """Cell membership of samples.

    Attributes
    ----------
    i_d : numpy.ndarray, shape (n,), int64
        Distance-bin index (clipped into range; meaningless where ``valid`` is False).
    i_alpha : numpy.ndarray, shape (n,), int64
        Bearing-bin index.
    valid : numpy.ndarray, shape (n,), bool
        True where the sample lies inside the grid (finite, 0 <= d < d_max_m).
    flat : numpy.ndarray, shape (n,), int64
        ``i_d * n_alpha + i_alpha``; -1 where not valid.
    """

    i_d: np.ndarray
    i_alpha: np.ndarray
    valid: np.ndarray
    flat: np.ndarray


@dataclass(frozen=True)
class CellGrid:
    """Regular polar grid over (d [m], alpha [rad]).

    Attributes
    ----------
    d_max_m : float
        Outer distance edge [m].
    d_bin_m : float
        Distance bin width [m]; ``d_max_m / d_bin_m`` is rounded to the nearest
        integer number of bins.
    alpha_bin_deg : float
        Bearing bin width [deg]; 360 / alpha_bin_deg is rounded likewise.
    """

    d_max_m: float = 3.0
    d_bin_m: float = 0.25
    alpha_bin_deg: float = 15.0

    def __post_init__(self) -> None:
        for key in ("d_max_m", "d_bin_m", "alpha_bin_deg"):
            v = float(getattr(self, key))
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"CellGrid: {key} must be finite and > 0, got {v!r}")
            object.__setattr__(self, key, v)
        if self.d_bin_m > self.d_max_m:
            raise ValueError(
                f"CellGrid: d_bin_m ({self.d_bin_m}) exceeds d_max_m ({self.d_max_m})"
            )
        if self.alpha_bin_deg > 360.0:
            raise ValueError(f"CellGrid: alpha_bin_deg must be <= 360, got {self.alpha_bin_deg}")

    @property
    def n_d(self) -> int:
        """Number of distance bins."""
        return max(1, int(round(self.d_max_m / self.d_bin_m)))

    @property
    def n_alpha(self) -> int:
        """Number of bearing bins."""
        return max(1, int(round(360.0 / self.alpha_bin_deg)))

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_d, n_alpha)``."""
        return (self.n_d, self.n_alpha)

    @property
    def d_edges_m(self) -> np.ndarray:
        """Distance bin edges, shape (n_d + 1,), metres."""
        return np.linspace(0.0, self.d_max_m, self.n_d + 1)

    @property
    def alpha_edges_rad(self) -> np.ndarray:
        """Bearing bin edges, shape (n_alpha + 1,), radians, from -pi to pi."""
        return np.linspace(-np.pi, np.pi, self.n_alpha + 1)

    @property
    def d_centres_m(self) -> np.ndarray:
        """Distance bin centres, shape (n_d,), metres."""
        e = self.d_edges_m
        return 0.5 * (e[:-1] + e[1:])

    @property
    def alpha_centres_rad(self) -> np.ndarray:
        """Bearing bin centres, shape (n_alpha,), radians."""
        e = self.alpha_edges_rad
        return 0.5 * (e[:-1] + e[1:])

    def centre_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre coordinates ``(D, A)``, each shape (n_d, n_alpha) (ij indexing)."""
        return np.meshgrid(self.d_centres_m, self.alpha_centres_rad, indexing="ij")

    def index(self, d_m, alpha_rad) -> CellIndex:
        """Cells of samples at distances `d_m` [m] and bearings `alpha_rad` [rad].

        Parameters
        ----------
        d_m, alpha_rad : array_like, shape (n,), float

        Returns
        -------
        CellIndex
        """
        d = np.asarray(d_m, dtype=np.float64).ravel()
        a = wrap_angle(np.asarray(alpha_rad, dtype=np.float64).ravel())
        if d.shape != a.shape:
            raise ValueError(f"d_m {d.shape} and alpha_rad {a.shape} differ in shape")
        valid = np.isfinite(d) & np.isfinite(a) & (d >= 0.0) & (d < self.d_max_m)
        with np.errstate(invalid="ignore"):
            fd = np.where(valid, d, 0.0) / (self.d_max_m / self.n_d)
            fa = (np.where(valid, a, 0.0) + np.pi) / (2.0 * np.pi / self.n_alpha)
        i_d = np.clip(np.floor(fd).astype(np.int64), 0, self.n_d - 1)
        i_a = np.clip(np.floor(fa).astype(np.int64), 0, self.n_alpha - 1)
        flat = np.where(valid, i_d * self.n_alpha + i_a, -1)
        return CellIndex(i_d=i_d, i_alpha=i_a, valid=valid, flat=flat)

    def count(self, d_m, alpha_rad, weights=None) -> np.ndarray:
        """Per-cell sum of `weights` (default 1), shape (n_d, n_alpha), float64."""
        idx = self.index(d_m, alpha_rad)
        w = np.ones(idx.flat.shape) if weights is None else np.asarray(weights, float).ravel()
        if w.shape != idx.flat.shape:
            raise ValueError(f"weights {w.shape} differ in shape from d_m {idx.flat.shape}")
        out = np.bincount(idx.flat[idx.valid], weights=w[idx.valid],
                          minlength=self.n_d * self.n_alpha)
        return out.reshape(self.shape)

    def to_dict(self) -> dict:
        """JSON-able dict of the three parameters."""
        return {"d_max_m": self.d_max_m, "d_bin_m": self.d_bin_m,
                "alpha_bin_deg": self.alpha_bin_deg}

    @classmethod
    def from_dict(cls, d: dict, where: str = "CellGrid") -> CellGrid:
        """Inverse of :meth:`to_dict`; unknown or missing keys raise naming the key."""
        allowed = {"d_max_m", "d_bin_m", "alpha_bin_deg"}
        check_keys(d, allowed, where, required=allowed)
        return cls(**{k: float(d[k]) for k in allowed})
