"""The tag population: what makes one tag of a model read differently from the next.

Real tags of one model are not identical, and where a tag is stuck matters:

- **sensitivity spread**: the chip's turn-on power varies from tag to tag (process
  spread of the chip, antenna-to-chip matching); each tag's threshold is
  ``tag_sensitivity_dbm + N(0, tag_sensitivity_spread_db^2)``;
- **backscatter spread**: the modulation factor M (the difference of the chip's two
  reflection states) varies likewise: ``modulation_loss_db + N(0, tag_modulation_spread_db^2)``;
- **reflection phase**: each tag's chip, inlay and mounting give its backscatter a phase
  offset of its own, uniform on [0, 2 pi) (:mod:`pipeline.acquisition.phase`; the
  reported phase also moves with the power the chip absorbs, see there);
- **detuning on metal**: a dipole inlay a few millimetres from a conductor is detuned
  (its impedance no longer matches the chip) and its radiation efficiency drops. This is
  a loss of the tag antenna's gain, so it counts once on the forward link and twice in
  the backscattered power: ``P_tag -= L``, ``P_rx -= 2 L`` with ``L =
  metal_detuning_loss_db`` for tags whose nearest surface (within 5 cm) is of a material
  listed in ``detuning_materials``, when they are plain dipole inlays
  (``metal_tag_type = "dipole"``). The default, ``"on_metal"``, makes a tag stuck on
  metal an on-metal tag type, with its own ground plane and tuned for the metal (what
  inventory on metal shelving uses): no detuning loss. Either is an explicit choice, and
  the run's metadata records it. Griffin & Durgin ("Complete link budgets for
  backscatter-radio and RFID systems", IEEE Antennas Propag. Mag. 51(2), 2009) call it the
  tag's gain penalty and measured metal as the worst of the mounting materials, around
  10 dB for a dipole tag spaced a few millimetres off a plate; Dobkin ("The RF in RFID",
  2nd ed., 2012, ch. 7) shows a dipole tag flush on metal is effectively unreadable.

What the ray tracer already covers: the tag's half-wave-dipole pattern along the tag's
axis (in the tag plane, along the projection of world z, :func:`propagation.tag_dipole_axes`)
and the reader's polarisation, so the polarisation mismatch of a tag seen off its
broadside or tilted against the reader's field is in the traced gain; and the surfaces'
reflections, so the image of a tag in a nearby wall is in the coherent sum as far as the
ray sampling finds it. What it does not cover is the impedance detuning of the inlay by
its mounting surface: that is this module's loss.

Values are drawn once per read log from the reader's random stream and recorded in its
metadata (``tag_population``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.acquisition.phase import tag_phase_offsets
from scenes.geometry import closest_surface

__all__ = ["TagPopulation", "draw_population", "surface_materials"]

#: A tag is "on" a surface when the surface is within this distance of its centre [m].
MOUNT_DISTANCE_M = 0.05


@dataclass(frozen=True)
class TagPopulation:
    """Per-tag deviations from the nominal tag.

    Attributes
    ----------
    tag_ids : numpy.ndarray
        Tag identifiers, shape (m,), str.
    sensitivity_offset_db : numpy.ndarray
        Added to ``tag_sensitivity_dbm`` (positive: a less sensitive tag), (m,), float64, dB.
    modulation_offset_db : numpy.ndarray
        Added to the modulation factor M (negative: weaker backscatter), (m,), float64, dB.
    surface_material : numpy.ndarray
        Material of the surface the tag is on ("" if none within 5 cm), (m,), str.
    detuning_loss_db : numpy.ndarray
        Tag gain penalty, >= 0, (m,), float64, dB: once on the forward link, twice on the
        backscattered power.
    phase_offset_rad : numpy.ndarray, optional
        The tag's own reflection phase offset, (m,), float64, rad, constant per tag;
        default 0 for every tag (the nominal tag).
    """

    tag_ids: np.ndarray
    sensitivity_offset_db: np.ndarray
    modulation_offset_db: np.ndarray
    surface_material: np.ndarray
    detuning_loss_db: np.ndarray
    phase_offset_rad: np.ndarray | None = None

    def __post_init__(self) -> None:
        m = len(self.tag_ids)
        off = (np.zeros(m) if self.phase_offset_rad is None
               else np.asarray(self.phase_offset_rad, dtype=float).reshape(-1))
        if off.shape != (m,) or not np.isfinite(off).all():
            raise ValueError(f"TagPopulation: phase_offset_rad must be {m} finite values, got "
                             f"shape {off.shape}")
        object.__setattr__(self, "phase_offset_rad", off)

    def to_dict(self) -> dict:
        """JSON-able: one list per attribute."""
        return {"tag_ids": [str(i) for i in self.tag_ids],
                "sensitivity_offset_db": self.sensitivity_offset_db.tolist(),
                "modulation_offset_db": self.modulation_offset_db.tolist(),
                "surface_material": [str(s) for s in self.surface_material],
                "detuning_loss_db": self.detuning_loss_db.tolist(),
                "phase_offset_rad": self.phase_offset_rad.tolist()}


def surface_materials(scene, tags) -> np.ndarray:
    """Material of the surface each tag is stuck on, "" when none is within 5 cm.

    Parameters
    ----------
    scene : scenes.Scene or None
        None: no tag is on a known surface.
    tags : scenes.TagSet

    Returns
    -------
    numpy.ndarray
        shape (m,), str.
    """
    m = len(tags)
    if scene is None or m == 0:
        return np.full(m, "", dtype=object).astype(str)

    q = closest_surface(scene, tags.positions_m)
    return np.where(q.distance_m <= MOUNT_DISTANCE_M, q.material.astype(str), "")


def draw_population(tags, reader, rng: np.random.Generator, materials=None) -> TagPopulation:
    """Draw each tag's sensitivity and backscatter deviations; set its detuning loss.

    Parameters
    ----------
    tags : scenes.TagSet
        m tags.
    reader : ReaderConfig
        ``tag_sensitivity_spread_db``, ``tag_modulation_spread_db``,
        ``metal_detuning_loss_db``, ``detuning_materials``.
    rng : numpy.random.Generator
        Exactly two arrays of m standard normals are drawn (sensitivity, then modulation);
        the tags' phase offsets come from a child stream (``rng.spawn``), so adding them
        left every other draw of ``rng`` as it was.
    materials : array_like of str, optional
        Surface material per tag (:func:`surface_materials`); None: no detuning.

    Returns
    -------
    TagPopulation
    """
    m = len(tags)
    z_s = rng.standard_normal(m)
    z_m = rng.standard_normal(m)
    mat = np.full(m, "", dtype=object).astype(str) if materials is None else np.asarray(materials, str)
    on = np.isin(mat, list(reader.detuning_materials)) if len(mat) else np.zeros(0, bool)
    on &= reader.metal_tag_type == "dipole"  # an on-metal tag type is tuned for the metal
    return TagPopulation(
        tag_ids=np.asarray(tags.ids, dtype=str),
        sensitivity_offset_db=reader.tag_sensitivity_spread_db * z_s,
        modulation_offset_db=reader.tag_modulation_spread_db * z_m,
        surface_material=mat,
        detuning_loss_db=np.where(on, reader.metal_detuning_loss_db, 0.0),
        phase_offset_rad=tag_phase_offsets(m, rng.spawn(1)[0]),
    )
