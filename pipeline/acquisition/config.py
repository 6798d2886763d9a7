"""The simulated reader's configuration: the study's ``[reader]`` section.

:class:`ReaderConfig` is both what ``[reader]`` of a study TOML is read into and what
:func:`pipeline.acquisition.simulate_reads` consumes; its link-budget keys build a
:class:`propagation.LinkBudget` at the carrier frequency (:meth:`ReaderConfig.link_budget`),
and their defaults are that class's.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from pipeline.configschema import ConfigError, option, section
from propagation.linkbudget import LinkBudget

__all__ = ["ANTENNA_MODES", "POSE_SOURCES", "ReaderConfig", "reader_metadata"]

#: How the reader multiplexes its antenna ports, see :class:`ReaderConfig`.
ANTENNA_MODES = ("round_robin", "all")
#: Which antenna poses the training sets use: MCL estimates or ground truth.
POSE_SOURCES = ("est", "true")


@section
class ReaderConfig:
    """The UHF reader and the backscatter link budget (docs/physics.md, 'The backscatter link').

    ``read_rate_hz``: an EPC Gen2 inventory round over a few tens of tags in a
    dense-reader mode lasts tens of milliseconds, and robot-mounted readers in the
    literature report a few to ~20 reads per tag per second; at 4 Hz and 0.3 m/s a read
    cycle comes every 7.5 cm of travel (paper_scale: 10 Hz, 3 cm).
    ``antenna_mode``: ``"round_robin"`` (how multi-port readers such as the Alien
    ALR-8800 or Impinj Speedway switch ports): cycle ``k`` uses antenna
    ``k mod n_antennas`` only, so each antenna is read at ``read_rate_hz / n_antennas``;
    ``"all"``: every cycle reads every antenna in turn, antenna ``a`` dwelling in the slot
    starting at ``t_k + a / (read_rate_hz * n_antennas)``.
    ``rssi_noise_db``: commercial readers quote RSSI repeatability of about +-1 dB for a
    static tag (Impinj Speedway Revolution application note "Low Level User Data
    Support", rev. 3.0, 2013), below the several-dB small-scale fading the ray tracer
    itself produces. ``rssi_resolution_db``: the step Impinj Speedway readers report RSSI
    in (same note); 0 disables quantisation. ``anticollision_miss_probability``: slot
    collisions and lost replies in the Gen2 Q algorithm, independent per attempt.
    ``range_margin_db``: added to the free-space link budget (maximum pattern gains) when
    deciding which antenna-tag pairs could possibly be read and so need tracing. The
    two-ray bound (20 log10(2) = 6 dB) is not enough in a corridor: traced on
    ``corridor_lab`` (depth 3, 1e4 rays, a 2-pass tour) gains exceeded that free-space
    reference by up to 2.7 dB below 12 m, 6.8 dB at 12-16 m and 9.2 dB at 16-20 m
    (waveguiding: grazing reflections off both walls, floor and ceiling add nearly in
    phase); 10 dB covers that, and :func:`~pipeline.acquisition.simulate_reads` records
    when a traced gain exceeds it. The power, sensitivity and loss keys are those of
    :class:`propagation.LinkBudget` (defaults and sources there).
    """

    read_rate_hz: float = option(
        4.0, "Read cycles per second; each is a new antenna position to trace (paper_scale: 10)."
    )
    antenna_mode: str = option(
        "round_robin", "Antenna multiplexing: 'round_robin' (one port per cycle) or 'all'."
    )
    rssi_noise_db: float = option(1.0, "Reader RSSI noise standard deviation [dB].")
    rssi_resolution_db: float = option(0.5, "Reader RSSI quantisation step [dB].")
    anticollision_miss_probability: float = option(
        0.05, "Probability that a powered, audible tag is still missed in a cycle."
    )
    tx_power_dbm: float = option(
        LinkBudget.tx_power_dbm,
        "Conducted reader power [dBm] (2 W ERP = 35.15 dBm EIRP with the 8 dBi antenna).",
    )
    tag_sensitivity_dbm: float = option(
        LinkBudget.tag_sensitivity_dbm, "Tag chip sensitivity [dBm] (Monza-4 class)."
    )
    reader_sensitivity_dbm: float = option(
        LinkBudget.reader_sensitivity_dbm, "Reader receiver sensitivity [dBm]."
    )
    polarization_loss_db: float = option(
        LinkBudget.polarization_loss_db, "Polarisation mismatch loss per way [dB] (circular to linear)."
    )
    modulation_loss_db: float = option(LinkBudget.modulation_loss_db, "Backscatter modulation factor M [dB].")
    range_margin_db: float = option(
        10.0, "Margin over the free-space budget when choosing which links can be read and are traced [dB]."
    )

    def __post_init__(self):
        if not self.read_rate_hz > 0:
            raise ConfigError(f"read_rate_hz must be > 0, got {self.read_rate_hz!r}")
        for name in ("rssi_noise_db", "rssi_resolution_db", "polarization_loss_db", "range_margin_db"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if self.antenna_mode not in ANTENNA_MODES:
            raise ConfigError(f"antenna_mode must be 'round_robin' or 'all', got {self.antenna_mode!r}")
        if not 0.0 <= self.anticollision_miss_probability < 1.0:
            raise ConfigError("anticollision_miss_probability must be in [0, 1)")

    def link_budget(self, frequency_hz: float | None = None) -> LinkBudget:
        """The link budget of this reader at the carrier ``frequency_hz`` (default:
        :class:`~propagation.LinkBudget`'s). The read thresholds do not depend on the
        carrier; the free-space range (what is traced) does."""
        kw = {} if frequency_hz is None else {"frequency_hz": float(frequency_hz)}
        return LinkBudget(tx_power_dbm=self.tx_power_dbm,
                          tag_sensitivity_dbm=self.tag_sensitivity_dbm,
                          reader_sensitivity_dbm=self.reader_sensitivity_dbm,
                          polarization_loss_db=self.polarization_loss_db,
                          modulation_loss_db=self.modulation_loss_db, **kw)


_BUDGET_KEYS = ("tx_power_dbm", "tag_sensitivity_dbm", "reader_sensitivity_dbm",
                "polarization_loss_db", "modulation_loss_db")


def reader_metadata(reader: ReaderConfig, budget: LinkBudget) -> dict[str, Any]:
    """The reader as recorded in a read log's metadata: its settings and the whole link
    budget it read with (``budget``: every :class:`~propagation.LinkBudget` field)."""
    out = {f.name: getattr(reader, f.name) for f in dataclasses.fields(reader)
           if f.name not in _BUDGET_KEYS}
    out["budget"] = dataclasses.asdict(budget)
    return out
