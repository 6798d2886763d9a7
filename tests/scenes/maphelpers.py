"""Writing small ROS map_server maps (YAML + PGM) for tests, with Pillow, cell by cell."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

RES = 0.05
FREE, OCC, UNKNOWN = 254, 0, 205  # map_saver's pixel values


def blank(width_m: float, height_m: float, value: int = UNKNOWN) -> np.ndarray:
    """A grid (ny, nx) uint8 in world orientation (row 0 at the lowest y), one pixel per cell."""
    return np.full((int(round(height_m / RES)), int(round(width_m / RES))), value, dtype=np.uint8)


def paint(grid: np.ndarray, x0: float, y0: float, x1: float, y1: float, value: int) -> None:
    """Set every cell whose centre lies in [x0, x1] x [y0, y1] (metres, origin 0, 0)."""
    xc = (np.arange(grid.shape[1]) + 0.5) * RES
    yc = (np.arange(grid.shape[0]) + 0.5) * RES
    cols = (xc >= x0) & (xc <= x1)
    rows = (yc >= y0) & (yc <= y1)
    grid[np.ix_(rows, cols)] = value


def building(width_m: float = 8.0, length_m: float = 6.0, wall_m: float = 0.2,
             pad_m: float = 0.5) -> np.ndarray:
    """Unknown margin ``pad_m``, an outer wall ``wall_m`` thick, free inside.

    The inside spans x in [pad + wall, pad + wall + width], likewise y.
    """
    g = blank(width_m + 2 * (wall_m + pad_m), length_m + 2 * (wall_m + pad_m))
    paint(g, pad_m, pad_m, pad_m + 2 * wall_m + width_m, pad_m + 2 * wall_m + length_m, OCC)
    paint(g, pad_m + wall_m, pad_m + wall_m, pad_m + wall_m + width_m, pad_m + wall_m + length_m, FREE)
    return g


def write_map(folder: Path, grid: np.ndarray, name: str = "map", image_name: str | None = None,
              suffix: str = ".pgm", **keys) -> Path:
    """Write ``grid`` as an image (top row first, as map_server reads it) and its YAML."""
    folder.mkdir(parents=True, exist_ok=True)
    image_name = image_name or f"{name}{suffix}"
    Image.fromarray(np.flipud(grid)).save(folder / image_name)
    yaml = {"image": image_name, "resolution": RES, "origin": "[0.0, 0.0, 0.0]", "negate": 0,
            "occupied_thresh": 0.65, "free_thresh": 0.196, **keys}
    text = "".join(f"{k}: {v}\n" for k, v in yaml.items() if v is not None)
    path = folder / f"{name}.yaml"
    path.write_text(text)
    return path
