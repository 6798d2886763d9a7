"""ROS ``map_server`` occupancy-grid maps: the YAML + PGM/PNG pair a SLAM robot saves.

The YAML keys are those of ROS ``map_server`` (ROS 1 ``map_server/src/image_loader.cpp``,
ROS 2 ``nav2_map_server``): ``image`` (path relative to the YAML), ``resolution``
[m/cell], ``origin`` [x_m, y_m, yaw_rad] of the lower-left pixel, ``negate`` (0/1),
``occupied_thresh``, ``free_thresh`` and ``mode`` (``trinary``, ``scale``, ``raw``).
PyYAML reads the YAML, Pillow the image (8-bit grey, grey + alpha, RGB, RGBA, palette
or bilevel; colour is averaged over the channels as map_server does).

Occupancy values follow map_server exactly: with the pixel value x (0..255, after
``negate`` flips it), ``p = (255 - x) / 255``; ``trinary``: 100 where
``p > occupied_thresh``, 0 where ``p < free_thresh``, -1 otherwise; ``scale``: the same
ends, ``1 + 98 (p - free_thresh) / (occupied_thresh - free_thresh)`` in between, -1 where
the alpha channel is not opaque; ``raw``: x itself (values above 100 are unknown, -1).

For geometry the three classes are the same in every mode (:attr:`RosMap.cell_class`):
an obstacle above ``occupied_thresh``, free below ``free_thresh``, unknown between or
where the value is unknown. Unknown cells are then resolved (:func:`resolve_unknown`):
unknown regions connected to the image border are the *outside* of the building (no
geometry, not walkable), enclosed unknown regions that touch free space are free
(unexplored corners of a room), enclosed unknown regions surrounded by obstacles only
are part of the obstacle (the inside of a thick wall or a rack the laser never saw).

Row 0 of :attr:`RosMap.occupancy` is the *lowest* y (the image's last row), so cell
(row, col) covers ``x in origin_x + [col, col + 1) res``, ``y in origin_y + [row, row + 1) res``.
A rotated map (``origin`` yaw other than 0) is refused: the robot's grid is axis-aligned.
"""

from __future__ import annotations

import hashlib
import logging
import math
import stat
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

log = logging.getLogger(__name__)

__all__ = [
    "MAP_KEYS",
    "check_map",
    "OBSTACLE",
    "FREE",
    "UNKNOWN",
    "OUTSIDE",
    "RosMap",
    "RosMapError",
    "boundary_segments",
    "read_map",
    "resolve_unknown",
    "file_state",
    "short_repr",
]

#: YAML keys of a map_server map (every other key is refused by name).
MAP_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode")
_MODES = ("trinary", "scale", "raw")
#: Largest side of a map [m]: a building's map, with room for a campus; a larger one is
#: almost always a resolution in the wrong unit (0.05 typed as 5).
MAX_SIDE_M = 2000.0
#: Share of pixels between 101 and 254 above which an image is no raw occupancy image
#: (raw mode reads 0-100 as occupancy percent and 255 as unknown; a few stray values in
#: an edited map are tolerated).
RAW_STRAY_SHARE = 0.01
#: Most pixels a map image may have, checked before decoding: 40 megapixels is a
#: 300 x 300 m building at 5 cm (a 20000 x 20000 image would take 3.2 GB as float64).
MAX_PIXELS = 40_000_000
#: Finest map resolution [m/cell]: 1 mm; a finer one is a unit error.
MIN_RESOLUTION_M = 1e-3
#: Cell classes of :attr:`RosMap.cell_class` and :func:`resolve_unknown`.
OBSTACLE, FREE, UNKNOWN, OUTSIDE = 1, 0, -1, -2


class RosMapError(ValueError):
    """A map YAML or image that cannot be a map; the message names the file and the key."""


@dataclass(frozen=True)
class RosMap:
    """An occupancy-grid map as map_server publishes it.

    Attributes
    ----------
    path : str
        The YAML file.
    image_path : str
        The image file.
    resolution_m : float
        Cell size [m], > 0.
    origin_m : numpy.ndarray
        World (x, y) of the lower-left corner of the lower-left cell, shape (2,) [m].
    negate : bool
        Whether white means occupied.
    occupied_thresh, free_thresh : float
        Probability thresholds, ``0 <= free_thresh < occupied_thresh <= 1``.
    mode : str
        ``"trinary"``, ``"scale"`` or ``"raw"``.
    occupancy : numpy.ndarray
        Occupancy values as map_server publishes them, shape (ny, nx), int8: 0..100, -1
        unknown; row 0 at the lowest y.
    cell_class : numpy.ndarray
        Shape (ny, nx), int8: :data:`OBSTACLE` (1), :data:`FREE` (0), :data:`UNKNOWN` (-1).
    """

    path: str
    image_path: str
    resolution_m: float
    origin_m: np.ndarray
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: str
    occupancy: np.ndarray
    cell_class: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """Grid shape (ny, nx)."""
        return self.occupancy.shape

    @property
    def extent_m(self) -> np.ndarray:
        """[[x_min, y_min], [x_max, y_max]] of the whole grid, shape (2, 2) [m]."""
        ny, nx = self.shape
        return np.stack([self.origin_m, self.origin_m + self.resolution_m * np.array([nx, ny])])

    def cell_centres(self, rows, cols) -> np.ndarray:
        """World (x, y) of cell centres, shape (..., 2) [m], for integer rows and cols."""
        r = np.asarray(rows, dtype=float)
        c = np.asarray(cols, dtype=float)
        return self.origin_m + self.resolution_m * np.stack([c + 0.5, r + 0.5], axis=-1)

    def digest(self) -> str:
        """SHA-256 of the grid, resolution and origin (enters the scene's content hash)."""
        h = hashlib.sha256(b"rosmap-v1")
        h.update(np.ascontiguousarray(self.cell_class).tobytes())
        h.update(np.asarray([self.resolution_m, *self.origin_m], dtype=np.float64).tobytes())
        h.update(str(self.shape).encode())
        return h.hexdigest()


#: Largest map_server YAML read [bytes]: its seven keys take a few hundred.
MAX_YAML_BYTES = 64 * 1024


def _no_alias_loader():
    import yaml

    class NoAliasLoader(yaml.SafeLoader):
        """PyYAML's safe loader that refuses aliases: a map_server YAML has none, and a
        nest of aliases (a "billion laughs") expands to gigabytes."""

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                event = self.peek_event()
                raise yaml.composer.ComposerError(
                    None, None, "a YAML alias (*name): map_server YAML has none",
                    event.start_mark)
            return super().compose_node(parent, index)

    return NoAliasLoader


def short_repr(value, limit: int = 60) -> str:
    """``repr(value)``, at most ``limit`` characters: an error never echoes a whole file.

    Parameters
    ----------
    value : object
        A value read from a file (a string, a list, a number).
    limit : int
        Most characters returned, the closing ``...`` included.

    Returns
    -------
    str
        ``repr(value)``, or its first ``limit - 3`` characters and ``...``.
    """
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def file_state(path: Path) -> str:
    """What ``path`` is, without opening it (a FIFO would wait) and without raising.

    Parameters
    ----------
    path : Path
        A file named by a scene or a map YAML.

    Returns
    -------
    str
        ``"regular"``; ``"missing"``; ``"is not a regular file"`` (a folder, a FIFO, a
        device); or ``"cannot be looked up (<reason>)"`` (a name too long, no permission).
    """
    try:
        mode = path.stat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        return "missing"
    except OSError as exc:
        return f"cannot be looked up ({exc.strerror or type(exc).__name__})"
    return "regular" if stat.S_ISREG(mode) else "is not a regular file"


def _short_line(text: str, limit: int = 100) -> str:
    """The first line of a library's message, at most ``limit`` characters (PyYAML quotes
    the text it stumbled on: a tag, a key)."""
    first = text.splitlines()[0] if text else ""
    return first if len(first) <= limit else first[:limit - 3] + "..."


def _as_float(value):
    """A YAML scalar as ROS's map_server reads it (yaml-cpp ``as<double>``): a number, or
    a string that spells one (YAML 1.1, which PyYAML follows, reads ``1e-9`` without a
    dot as a string); anything else unchanged."""
    if isinstance(value, str) and len(value) <= 40:
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _number(data: dict, key: str, where: str, default=None) -> float:
    value = _as_float(data.get(key, default))
    if value is None:
        raise RosMapError(f"{where}: missing required key {key!r}")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RosMapError(f"{where}: key {key!r} must be a finite number, got {short_repr(value)}")
    return float(value)


def _pixels(image_path: Path, where: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Channel-averaged pixel values (ny, nx) float64 in 0..255 and alpha (or None)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():  # Pillow's own bomb warning: our bound is below it
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im_ctx = Image.open(image_path)
        with im_ctx as im:
            n_px = im.size[0] * im.size[1]  # read from the header, before decoding
            if n_px > MAX_PIXELS:
                raise RosMapError(f"{where}: key 'image': {image_path} has {im.size[0]} x "
                                  f"{im.size[1]} pixels, more than {MAX_PIXELS:,} (MAX_PIXELS); "
                                  "crop the map to the building or save it coarser")
            im.load()
            mode = im.mode
            if mode == "P":
                im = im.convert("RGBA")
                mode = "RGBA"
            elif mode == "1":
                im = im.convert("L")
                mode = "L"
            if mode not in ("L", "LA", "RGB", "RGBA"):
                raise RosMapError(f"{where}: key 'image': {image_path} has pixel mode {im.mode!r}; "
                                  "a map image is 8-bit grey, grey + alpha, RGB or RGBA")
            arr = np.asarray(im, dtype=np.float64)
    except Image.DecompressionBombError as exc:  # beyond Pillow's own limit, still no pixels read
        raise RosMapError(f"{where}: key 'image': {image_path} has more than {MAX_PIXELS:,} pixels "
                          f"(MAX_PIXELS; {str(exc)[:80]})") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise RosMapError(f"{where}: key 'image': cannot read {image_path} as an image "
                          f"({type(exc).__name__}: {exc})") from None
    if arr.ndim == 2:
        return arr, None
    alpha = arr[..., -1] if mode in ("LA", "RGBA") else None
    colour = arr[..., :-1] if alpha is not None else arr
    return colour.mean(axis=-1), alpha


def _check_agrees(x: np.ndarray, res: float, mode: str, where: str, image_path: Path) -> None:
    """Refuse an image the YAML describes wrongly: a map larger than :data:`MAX_SIDE_M`
    (resolution in the wrong unit), ``mode: raw`` over a grey-level image, or a raw
    occupancy image (only the values 0, 100 and 255) read as grey levels."""
    ny, nx = x.shape
    side = max(nx, ny) * res
    if side > MAX_SIDE_M:
        raise RosMapError(f"{where}: key 'resolution': {res} m/cell makes the {nx} x {ny} image "
                          f"{nx * res:.0f} m x {ny * res:.0f} m (largest side allowed "
                          f"{MAX_SIDE_M:.0f} m); is it in metres per cell?")
    values = np.round(x)
    if mode == "raw":
        stray = float(np.mean((values > 100) & (values < 255)))
        if stray > RAW_STRAY_SHARE:
            raise RosMapError(f"{where}: key 'mode': 'raw' reads pixels as occupancy 0-100 or "
                              f"255 (unknown), but {stray:.0%} of {image_path.name} are 101-254: "
                              "a grey-level map; use mode 'trinary' or 'scale'")
    else:
        levels = set(np.unique(values).tolist())
        if 100.0 in levels and levels <= {0.0, 100.0, 255.0}:
            raise RosMapError(f"{where}: key 'mode': {image_path.name} holds only the values "
                              f"0, 100 and 255, a raw occupancy image; read as grey levels "
                              f"({mode!r}) its walls would be unknown: use mode 'raw'")


#: The pixel value map_saver writes for an unknown cell in trinary mode.
_SAVED_UNKNOWN = 205


def _saved_trinary_unknown_read_free(x: np.ndarray, free_t: float) -> bool:
    """Whether ``x`` (after negate) is a map_saver trinary image whose unknown pixel the
    thresholds would read as free: its values are 0, 205 and 254 (255 allowed: edited
    images), 205 makes up over 1 % of it, and ``free_thresh`` lets p = 50/255 through."""
    if not (255.0 - _SAVED_UNKNOWN) / 255.0 < free_t:
        return False
    values, counts = np.unique(np.round(x).astype(int), return_counts=True)
    if not set(values.tolist()) <= {0, _SAVED_UNKNOWN, 254, 255}:
        return False
    return counts[values == _SAVED_UNKNOWN].sum() > 0.01 * x.size


def check_map(path: str | Path) -> RosMap:
    """:func:`read_map` without its warnings: the pre-check of a map scene before a run
    (:attr:`scenes.sources.SceneSource.precheck`; the build that follows reads the map
    again and warns once)."""
    return read_map(path, warn=False)


def read_map(path: str | Path, *, warn: bool = True) -> RosMap:
    """Read a map_server YAML and its image.

    Parameters
    ----------
    path : str or Path
        The YAML file; ``image`` is relative to its folder (or absolute).
    warn : bool
        Log at WARNING where the map is read otherwise than its YAML says (a map_saver
        trinary image's unknown pixels). False for the pre-check before a run
        (:func:`check_map`), whose build reads the map again and says it then.

    Returns
    -------
    RosMap

    Raises
    ------
    RosMapError
        One line naming the file and the key: a missing or unknown key, a value of the
        wrong type, ``resolution <= 0``, thresholds outside ``0 <= free < occupied <= 1``,
        an unknown ``mode``, a rotated ``origin``, a missing or unreadable image, an
        empty image, an image the YAML describes wrongly (:func:`_check_agrees`), a map
        without a single free or obstacle cell.
    FileNotFoundError
        The YAML does not exist.
    """
    import yaml

    path = Path(path)
    state = file_state(path)
    if state == "missing":
        raise FileNotFoundError(f"map file {short_repr(str(path), 200)} does not exist")
    if state != "regular":  # a folder, a FIFO (a read would wait), a device (/dev/zero)
        raise RosMapError(f"map file {short_repr(str(path), 200)} {state}")
    where = str(path)
    if path.stat().st_size > MAX_YAML_BYTES:
        raise RosMapError(f"{where}: {path.stat().st_size:,} bytes, more than a map_server YAML "
                          f"has ({MAX_YAML_BYTES:,}, MAX_YAML_BYTES)")
    try:
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=_no_alias_loader())  # noqa: S506 - a SafeLoader
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        first = _short_line(str(exc)) or type(exc).__name__
        raise RosMapError(f"{where}: invalid YAML: {first}") from None
    if not isinstance(data, dict):
        raise RosMapError(f"{where}: expected a mapping of map_server keys, got a "
                          f"{type(data).__name__} (is this a map_server YAML?)")
    unknown = sorted(str(k) for k in set(data) - set(MAP_KEYS))
    if unknown:
        raise RosMapError(f"{where}: unknown key {short_repr(unknown[0])}; known keys: {', '.join(MAP_KEYS)}")
    image = data.get("image")
    if not isinstance(image, str) or not image:
        raise RosMapError(f"{where}: key 'image' must be the image file name, got {short_repr(image)}")
    res = _number(data, "resolution", where)
    if not res > 0:
        raise RosMapError(f"{where}: key 'resolution' must be positive [m/cell], got {res!r}")
    if res < MIN_RESOLUTION_M:
        raise RosMapError(f"{where}: key 'resolution' {res!r} m/cell is finer than "
                          f"{MIN_RESOLUTION_M} m (MIN_RESOLUTION_M): a unit error?")
    origin = data.get("origin")
    if isinstance(origin, list):
        origin = [_as_float(v) for v in origin]
    if (not isinstance(origin, list) or len(origin) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                       and abs(v) <= 1e6 for v in origin)):
        raise RosMapError(f"{where}: key 'origin' must be [x_m, y_m, yaw_rad], finite and within "
                          f"1e6 m, got {short_repr(origin)}")
    if abs(origin[2]) > 1e-9:
        raise RosMapError(f"{where}: key 'origin': yaw {origin[2]!r} rad is not supported (the "
                          "robot's grid is axis-aligned); rotate the image instead")
    negate = data.get("negate", 0)
    if negate not in (0, 1) or isinstance(negate, float):
        raise RosMapError(f"{where}: key 'negate' must be 0 or 1, got {short_repr(negate)}")
    occ_t = _number(data, "occupied_thresh", where, 0.65)
    free_t = _number(data, "free_thresh", where, 0.196)
    if not 0.0 <= free_t < occ_t <= 1.0:
        raise RosMapError(f"{where}: keys 'free_thresh' ({free_t}) and 'occupied_thresh' ({occ_t}) "
                          "must satisfy 0 <= free_thresh < occupied_thresh <= 1")
    mode = data.get("mode", "trinary")
    if mode not in _MODES:
        raise RosMapError(f"{where}: key 'mode' must be one of {', '.join(_MODES)}, got {short_repr(mode)}")
    image_path = Path(image) if Path(image).is_absolute() else path.parent / image
    state = file_state(image_path)
    if state == "missing":
        folder = "" if Path(image).is_absolute() else f" in {str(path.parent)!r}"
        raise RosMapError(f"{where}: key 'image': image file {short_repr(image)} does not exist{folder}")
    if state != "regular":  # a folder, a FIFO (a read would wait), a device
        raise RosMapError(f"{where}: key 'image': image file {short_repr(image)} {state}")
    x, alpha = _pixels(image_path, where)
    if x.size == 0:
        raise RosMapError(f"{where}: key 'image': {image_path} has no pixels")
    # map_server negates first, then reads the values: so does the check
    _check_agrees(255.0 - x if negate else x, res, mode, where, image_path)
    if negate:
        x = 255.0 - x
    x = np.flipud(x)  # image row 0 is the top (largest y); grid row 0 the lowest y
    alpha = None if alpha is None else np.flipud(alpha)
    p = (255.0 - x) / 255.0
    occ_cell, free_cell = p > occ_t, p < free_t
    if mode == "trinary" and _saved_trinary_unknown_read_free(x, free_t):
        # map_saver's trinary image: 254 free, 0 occupied, 205 unknown; a YAML saved with
        # ROS 2's free_thresh default 0.25 reads 205 (p = 0.196) as free, so the unmapped
        # outside becomes floor (slam_toolbox #587; navigation2 #5278 fixes the thresholds
        # map_saver writes). The saved pixels mean unknown: they are read as such.
        say = log.warning if warn else log.debug
        say("%s: a map_saver trinary image (pixels 0/205/254) with free_thresh %s: pixel 205 "
            "is map_saver's unknown and is read as unknown, not free (navigation2 PR 5278; "
            "slam_toolbox issue 587)", where, free_t)
        free_cell &= np.round(x) != _SAVED_UNKNOWN
    if mode == "raw":
        raw = np.round(x).astype(int)
        occupancy = np.where(raw <= 100, raw, -1)
        known = occupancy >= 0
        occ_cell = known & (occupancy >= 100.0 * occ_t)
        free_cell = known & (occupancy <= 100.0 * free_t)
    else:
        occupancy = np.where(occ_cell, 100, np.where(free_cell, 0, -1))
        if mode == "scale":
            between = ~occ_cell & ~free_cell
            scaled = np.round(1 + 98 * (p - free_t) / (occ_t - free_t)).astype(int)
            occupancy = np.where(between, scaled, occupancy)
            if alpha is not None:  # map_server: a transparent pixel is unknown in scale mode
                see_through = alpha < 255
                occupancy = np.where(see_through, -1, occupancy)
                occ_cell &= ~see_through
                free_cell &= ~see_through
    cls = np.full(x.shape, UNKNOWN, dtype=np.int8)
    cls[occ_cell] = OBSTACLE
    cls[free_cell] = FREE
    if not np.any(cls == FREE):
        raise RosMapError(f"{where}: key 'image': {image_path} has no free cell (p < free_thresh "
                          f"= {free_t}); is 'negate' ({negate}) right?")
    return RosMap(str(path), str(image_path), res, np.asarray(origin[:2], dtype=float),
                  bool(negate), occ_t, free_t, str(mode), occupancy.astype(np.int8), cls)


def resolve_unknown(cell_class: np.ndarray) -> np.ndarray:
    """Cell classes with every unknown cell decided (see the module docstring).

    Parameters
    ----------
    cell_class : numpy.ndarray
        Shape (ny, nx), int8, :data:`OBSTACLE` / :data:`FREE` / :data:`UNKNOWN`.

    Returns
    -------
    numpy.ndarray
        Shape (ny, nx), int8: :data:`OBSTACLE`, :data:`FREE` or :data:`OUTSIDE`. Unknown
        regions (8-connected) touching the image border become :data:`OUTSIDE`, enclosed
        ones touching a free cell :data:`FREE`, the rest :data:`OBSTACLE`.
    """
    cls = np.asarray(cell_class, dtype=np.int8).copy()
    unknown = cls == UNKNOWN
    if not unknown.any():
        return cls
    labels, n = ndimage.label(unknown, structure=np.ones((3, 3)))
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    near_free = np.unique(labels[ndimage.binary_dilation(cls == FREE) & unknown])
    kind = np.full(n + 1, OBSTACLE, dtype=np.int8)
    kind[near_free] = FREE
    kind[border] = OUTSIDE  # the border wins: a free room open to the image edge is not outside
    out = np.where(unknown, kind[labels], cls)
    return out.astype(np.int8)


def boundary_segments(mask: np.ndarray, origin_m, resolution_m: float) -> np.ndarray:
    """Cell edges between ``mask`` cells and the others, merged into straight runs.

    The exact outline of a raster region (what a map draws), for the robot's likelihood
    field; edges on the grid border count when the mask cell is on it.

    Parameters
    ----------
    mask : numpy.ndarray
        Shape (ny, nx), bool.
    origin_m : array_like
        World (x, y) of the grid's lower-left corner, shape (2,) [m].
    resolution_m : float
        Cell size [m].

    Returns
    -------
    numpy.ndarray
        Segments (k, 2, 2) [m], each a maximal run of collinear edges.
    """
    m = np.pad(np.asarray(mask, dtype=bool), 1)
    o = np.asarray(origin_m, dtype=float)
    res = float(resolution_m)
    out = []
    # horizontal edges: between rows r-1 and r (padded indices), y = origin + (r - 1) res
    diff = m[1:, 1:-1] != m[:-1, 1:-1]  # (ny + 1, nx): edge below padded row r = index + 1
    for r in np.flatnonzero(diff.any(axis=1)):
        runs = _runs(diff[r])
        y = o[1] + r * res
        out += [[[o[0] + a * res, y], [o[0] + b * res, y]] for a, b in runs]
    diff = m[1:-1, 1:] != m[1:-1, :-1]  # (ny, nx + 1)
    for c in np.flatnonzero(diff.any(axis=0)):
        runs = _runs(diff[:, c])
        x = o[0] + c * res
        out += [[[x, o[1] + a * res], [x, o[1] + b * res]] for a, b in runs]
    return np.asarray(out, dtype=float).reshape(-1, 2, 2)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the True runs of a 1-D bool array."""
    d = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))
