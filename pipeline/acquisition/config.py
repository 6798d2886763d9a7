"""Typed configuration of the simulated reader and of the acquisition stage.

Both dataclasses reject unknown keys by name (``from_dict``) and validate their
values on construction, naming the offending key, value and source file.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from pipeline.configschema import check_keys

if TYPE_CHECKING:  # pragma: no cover
    from propagation import LinkBudget

__all__ = ["ANTENNA_MODES", "POSE_SOURCES", "ReaderConfig"]

#: How the reader multiplexes its antenna ports, see :class:`ReaderConfig`.
ANTENNA_MODES = ("round_robin", "all")
#: Which antenna poses the training sets use: MCL estimates or ground truth.
POSE_SOURCES = ("est", "true")


def _default_budget() -> LinkBudget:
    from propagation import LinkBudget

    return LinkBudget()


def _budget_from_dict(d: dict, source: str) -> LinkBudget:
    from propagation import LinkBudget

    names = {f.name for f in dataclasses.fields(LinkBudget)}
    check_keys(d, names, f"{source}: [acquisition.reader.budget]")
    return LinkBudget(**d)


@dataclass(frozen=True)
class ReaderConfig:
    """A UHF RFID reader as the acquisition stage simulates it.

    Attributes
    ----------
    read_rate_hz : float
        Read cycles (inventory rounds) per second. Default 10 Hz: an EPC Gen2 inventory
        round over a few tens of tags in a dense-reader mode lasts tens of milliseconds,
        and robot-mounted readers in the literature report a few to ~20 reads per tag per
        second; 10 Hz at 0.2-0.3 m/s gives a read every 2-3 cm of travel, finer than the
        half-wavelength (17 cm) scale of multipath fading. Must be > 0.
    antenna_mode : {"round_robin", "all"}
        ``"round_robin"`` (default, how multi-port readers such as the Alien ALR-8800 or
        Impinj Speedway switch ports): cycle ``k`` uses antenna ``k mod n_antennas`` only,
        so each antenna is read at ``read_rate_hz / n_antennas``. ``"all"``: every cycle
        reads every antenna in turn, antenna ``a`` dwelling in the slot starting at
        ``t_k + a / (read_rate_hz * n_antennas)``.
    rssi_noise_db : float
        Standard deviation of zero-mean Gaussian noise added to the reported RSSI, dB.
        Default 1.0 dB: commercial readers quote RSSI repeatability of about +-1 dB for
        a static tag (Impinj Speedway Revolution application note "Low Level User Data
        Support", rev. 3.0, 2013), below the several-dB small-scale fading the ray
        tracer itself produces. >= 0.
    rssi_resolution_db : float
        Quantisation step of the reported RSSI, dB; values are rounded to the nearest
        multiple. Default 0.5 dB, the step Impinj Speedway readers report RSSI in (same
        note). 0 disables quantisation. >= 0.
    anticollision_miss_probability : float
        Probability that a tag that is powered and heard is still not reported in a
        cycle (slot collisions and lost replies in the Gen2 Q algorithm), independent
        per attempt. Default 0.05. In [0, 1).
    budget : propagation.LinkBudget
        Link budget (transmit power, sensitivities, polarisation and modulation losses)
        turning one-way channel gains into tag power and reader RSSI.
    range_margin_db : float
        Margin added to the free-space link budget (maximum pattern gains) when deciding
        which antenna-tag pairs could possibly be read and so need tracing. Default 10 dB.
        The two-ray bound (direct path plus one in-phase reflection of unit magnitude,
        20 log10(2) = 6 dB) is not enough in a corridor: traced on ``corridor_lab`` (depth
        3, 1e4 rays, a 2-pass tour) gains exceeded that free-space reference by up to
        2.7 dB below 12 m, 6.8 dB at 12-16 m and 9.2 dB at 16-20 m (waveguiding: grazing
        reflections off both walls, floor and ceiling add nearly in phase). 10 dB covers
        that; :func:`simulate_reads` warns when a traced gain exceeds the margin. >= 0.
    """

    read_rate_hz: float = 10.0
    antenna_mode: str = "round_robin"
    rssi_noise_db: float = 1.0
    rssi_resolution_db: float = 0.5
    anticollision_miss_probability: float = 0.05
    budget: LinkBudget = field(default_factory=_default_budget)
    range_margin_db: float = 10.0

    def __post_init__(self) -> None:
        r = self.read_rate_hz
        if not (isinstance(r, (int, float)) and math.isfinite(r) and r > 0):
            raise ValueError(f"ReaderConfig: read_rate_hz must be a finite number > 0, got {r!r}")
        if self.antenna_mode not in ANTENNA_MODES:
            raise ValueError(
                f"ReaderConfig: antenna_mode must be one of {ANTENNA_MODES}, "
                f"got {self.antenna_mode!r}"
            )
        for name in ("rssi_noise_db", "rssi_resolution_db", "range_margin_db"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"ReaderConfig: {name} must be a finite number >= 0, got {v!r}")
        p = self.anticollision_miss_probability
        if not (isinstance(p, (int, float)) and 0.0 <= p < 1.0):
            raise ValueError(
                f"ReaderConfig: anticollision_miss_probability must be in [0, 1), got {p!r}"
            )

    @classmethod
    def from_dict(cls, d: dict, source: str = "<dict>") -> ReaderConfig:
        """Build from a TOML table; ``budget`` is a sub-table of LinkBudget fields.

        Raises
        ------
        KeyError
            Naming an unknown key and the source.
        ValueError
            Naming a key with a bad value and the source.
        """
        names = {f.name for f in dataclasses.fields(cls)}
        check_keys(d, names, f"{source}: [acquisition.reader]")
        kw = dict(d)
        if "budget" in kw:
            kw["budget"] = _budget_from_dict(kw["budget"], source)
        try:
            return cls(**kw)
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from exc

    def to_dict(self) -> dict[str, Any]:
        """JSON/TOML-able dict that :meth:`from_dict` reads back."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out["budget"] = dataclasses.asdict(self.budget)
        return out
