"""The simulated reader's configuration: the study's ``[reader]`` section.

:class:`ReaderConfig` is both what ``[reader]`` of a study TOML is read into and what
:func:`pipeline.acquisition.simulate_reads` consumes; its link-budget keys build a
:class:`propagation.LinkBudget` at the carrier frequency (:meth:`ReaderConfig.link_budget`),
and their defaults are that class's.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from pipeline.acquisition.channels import REGIONS, channel_plan
from pipeline.acquisition.gen2 import Gen2Config
from pipeline.configschema import ConfigError, option, section
from propagation.linkbudget import LinkBudget
from scenes.materials import MATERIALS

__all__ = ["ANTENNA_MODES", "INVENTORY_MODES", "METAL_TAG_TYPES", "POSE_SOURCES", "ReaderConfig",
           "reader_metadata"]

#: How the reader multiplexes its antenna ports, see :class:`ReaderConfig`.
ANTENNA_MODES = ("round_robin", "all")
#: How misses between powered, audible tags arise, see :class:`ReaderConfig`.
INVENTORY_MODES = ("fixed", "gen2")
#: What a tag on a detuning material is (``ReaderConfig.metal_tag_type``).
METAL_TAG_TYPES = ("on_metal", "dipole")
#: Which antenna poses the training sets use: MCL estimates or ground truth.
POSE_SOURCES = ("est", "true")
#: Accepted conducted reader power [dBm]. The upper end is the largest power any UHF RFID
#: regulation lets a reader radiate, even before its antenna's gain: FCC 15.247 allows
#: 1 W conducted into up to 6 dBi, 4 W = 36 dBm EIRP; ETSI EN 302 208 allows 2 W ERP =
#: 35.15 dBm EIRP. The lower end, 1 mW, is already ~20 dB below any reader's setting
#: (commercial readers go down to about 10 dBm) and powers a -18 dBm tag chip only within
#: a few tens of centimetres. Values in between beyond the region's limit are allowed
#: (what-if studies) and logged at the reads stage.
TX_POWER_RANGE_DBM = (0.0, 36.0)


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
    collisions and lost replies lumped into one probability, independent per attempt
    (``inventory = "fixed"`` only).
    ``range_margin_db``: added to the free-space link budget (maximum pattern gains) when
    deciding which antenna-tag pairs could possibly be read and so need tracing. The
    two-ray bound (20 log10(2) = 6 dB) is not enough in a corridor: traced on
    ``corridor_lab`` (depth 3, 1e4 rays, a 2-pass tour) gains exceeded that free-space
    reference by up to 2.7 dB below 12 m, 6.8 dB at 12-16 m and 9.2 dB at 16-20 m
    (waveguiding: grazing reflections off both walls, floor and ceiling add nearly in
    phase); 10 dB covers that, and :func:`~pipeline.acquisition.simulate_reads` records
    when a traced gain exceeds it. The power, sensitivity and loss keys are those of
    :class:`propagation.LinkBudget` (defaults and sources there).

    ``region``: the regulatory channel plan (:mod:`pipeline.acquisition.channels`):
    ``"ETSI"`` (EN 302 208: 865.7, 866.3, 866.9, 867.5 MHz, 2 W ERP, at most 4 s per
    channel), ``"FCC"`` (15.247: 50 channels 902.75-927.25 MHz, 4 W EIRP, 0.4 s) or
    ``"none"`` (every attempt at the study's carrier ``frequency_hz``: a reader that
    does not hop). The reader hops in a pseudo-random order drawn once per read
    log; every attempt records its channel (``frequency_hz`` column). One trace at the
    study's carrier serves every channel (the path delays give each channel's phase). The
    power is not changed by the region: for FCC set ``tx_power_dbm = 28`` (36 dBm EIRP
    with the 8 dBi antenna); a budget above the region's limit is logged.
    ``phase_noise_rad``: phase-based RFID localisation work with Impinj readers models the
    reported phase with a Gaussian noise of about 0.1 rad at good SNR (e.g. Buffi, Nepa &
    Lombardini, "A phase-based technique for localization of UHF-RFID tags moving on a
    conveyor belt", IEEE Sensors J. 15(1), 2015); ``phase_resolution_rad``: Impinj readers
    report the phase in 12 bits (Speedway "Low Level User Data Support" note).
    ``phase_power_shift_rad``, ``phase_power_span_db``: a tag's backscatter phase moves
    with the power its chip absorbs; Megalou et al. (IEEE RFID-TA 2021) measured 100
    degrees across a tag's incident powers, here a ramp over the first
    ``phase_power_span_db`` above the tag's threshold (:mod:`pipeline.acquisition.phase`).
    Every tag also has a reflection phase offset of its own (uniform, drawn per read log).
    ``inventory``: ``"gen2"`` (the default) runs the EPC Gen2 Q algorithm for the
    antenna's dwell in each slot (:mod:`pipeline.acquisition.gen2`, ``[reader.gen2]``):
    reads (``seen_count``) and misses follow from the tags in the field and the link
    budget, and the truth, evaluation and localisation stages miss a closing tag with
    ``1 - p_singulated(n)``, ``n`` the tags whose links close in that antenna slot
    (:mod:`pipeline.acquisition.singulation`); ``"fixed"`` (no Gen2 inventory)
    misses a powered, audible tag with ``anticollision_miss_probability`` per
    attempt, independently, and the truth with that constant. Tag population (:mod:`pipeline.acquisition.population`):
    a 1 dB spread of chip sensitivity and of backscatter among tags of one model is an
    assumption of the order of tag-to-tag spreads in tag benchmarks; a metal detuning
    loss of ~10 dB is Griffin & Durgin's (2009) order of magnitude for a dipole tag on
    metal. All three default to 0: the held-out truth (``pipeline.evaluation.truth``)
    judges detection with the nominal budget, so with spreads on it is the nominal tag's
    truth, not each tag's.
    """

    read_rate_hz: float = option(
        4.0, "Read cycles per second; each is a new antenna position to trace (paper_scale: 10). "
        "A cycle shorter than 1 ms holds no EPC Gen2 single-tag slot (3.7 ms at the default "
        "link, pipeline.acquisition.gen2).", max=1_000)
    antenna_mode: str = option(
        "round_robin", "Antenna multiplexing: 'round_robin' (one port per cycle) or 'all'."
    )
    rssi_noise_db: float = option(1.0, "Reader RSSI noise standard deviation [dB].")
    rssi_resolution_db: float = option(0.5, "Reader RSSI quantisation step [dB].")
    anticollision_miss_probability: float = option(
        0.05, "Probability that a powered, audible tag is still missed in a cycle ('fixed' inventory)."
    )
    tx_power_dbm: float = option(
        LinkBudget.tx_power_dbm,
        "Conducted reader power [dBm] (2 W ERP = 35.15 dBm EIRP with the 8 dBi antenna), in "
        f"[{TX_POWER_RANGE_DBM[0]:g}, {TX_POWER_RANGE_DBM[1]:g}]; above the region's EIRP limit "
        "is logged.",
    )
    tag_sensitivity_dbm: float = option(
        LinkBudget.tag_sensitivity_dbm, "Tag chip sensitivity [dBm] (Monza-4 class)."
    )
    reader_sensitivity_dbm: float = option(
        LinkBudget.reader_sensitivity_dbm, "Reader receiver sensitivity [dBm]."
    )
    polarization_loss_db: float = option(
        LinkBudget.polarization_loss_db,
        "Polarisation mismatch per way not in the traced gain [dB] (default 0: "
        "tracing.reader_polarization is traced, its mismatch with the tag dipole included)."
    )
    modulation_loss_db: float = option(LinkBudget.modulation_loss_db, "Backscatter modulation factor M [dB].")
    range_margin_db: float = option(
        10.0, "Margin over the free-space budget when choosing which links can be read and are traced [dB]."
    )
    region: str = option("ETSI", "Regulatory channel plan: 'ETSI' (4 channels), 'FCC' (50, hopping) or 'none'.")
    channels_hz: tuple[float, ...] = option(
        (), "Channel centres [Hz] replacing the region's (each inside its band); empty: the region's.")
    channel_dwell_s: float | None = option(
        None, "Time on one channel before hopping [s]; default the region's maximum (ETSI 4, FCC 0.4).")
    phase_noise_rad: float = option(0.1, "Standard deviation of the reported phase's noise [rad].")
    phase_resolution_rad: float = option(
        2.0 * math.pi / 4096, "Reported phase quantisation step [rad] (Impinj: 12 bits); 0: none.")
    phase_power_shift_rad: float = option(
        math.radians(100.0), "Tag chip's backscatter phase shift from its threshold to "
        "phase_power_span_db above it [rad] (Megalou et al. 2021: 100 degrees); 0: none.")
    phase_power_span_db: float = option(
        20.0, "Absorbed power above the tag's threshold over which that shift builds up [dB].")
    doppler_noise_hz: float = option(0.0, "Standard deviation of the reported Doppler's noise [Hz].")
    inventory: str = option(
        "gen2", "Misses: 'gen2' (Q-algorithm inventory) or 'fixed' (anticollision_miss_probability).")
    gen2: Gen2Config = option(factory=Gen2Config, doc="EPC Gen2 link timing and Q algorithm.")
    tag_sensitivity_spread_db: float = option(
        0.0, "Standard deviation of each tag's chip sensitivity around tag_sensitivity_dbm [dB].")
    tag_modulation_spread_db: float = option(
        0.0, "Standard deviation of each tag's modulation factor around modulation_loss_db [dB].")
    metal_tag_type: str = option(
        "on_metal", "What a tag stuck on a detuning material (a rack's metal beam) is: 'on_metal', "
                    "an on-metal tag type (its own ground plane, tuned for metal: no detuning "
                    "loss; what inventory on metal shelving uses), or 'dipole', a plain dipole "
                    "inlay, which loses metal_detuning_loss_db (docs/physics.md: a dipole flush "
                    "on metal is effectively dead).")
    metal_detuning_loss_db: float = option(
        10.0, "Tag gain penalty of a 'dipole' tag on a detuning material [dB] (Griffin & "
              "Durgin 2009: ~10); not applied to 'on_metal' tags.")
    detuning_materials: tuple[str, ...] = option(
        ("metal",), "Surface materials that detune a tag stuck on them.")

    def __post_init__(self):
        if not self.read_rate_hz > 0:
            raise ConfigError(f"read_rate_hz must be > 0, got {self.read_rate_hz!r}")
        lo, hi = TX_POWER_RANGE_DBM
        if not math.isfinite(self.tx_power_dbm):
            raise ConfigError(f"reader.tx_power_dbm must be a finite power in [{lo:g}, {hi:g}] dBm, "
                              f"got {self.tx_power_dbm!r}")
        if not lo <= self.tx_power_dbm <= hi:
            raise ConfigError(f"reader.tx_power_dbm = {self.tx_power_dbm!r} dBm: outside [{lo:g}, {hi:g}] "
                              "dBm (36 dBm = 4 W EIRP, the most any UHF RFID regulation allows; "
                              "ETSI EN 302 208: 35.15 dBm EIRP)")
        for name in ("rssi_noise_db", "rssi_resolution_db", "polarization_loss_db", "range_margin_db"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if self.antenna_mode not in ANTENNA_MODES:
            raise ConfigError(f"antenna_mode must be 'round_robin' or 'all', got {self.antenna_mode!r}")
        if not 0.0 <= self.anticollision_miss_probability < 1.0:
            raise ConfigError("anticollision_miss_probability must be in [0, 1)")
        if self.region not in REGIONS:
            raise ConfigError(f"region must be one of {sorted(REGIONS)}, got {self.region!r}")
        channel_plan(self.region, self.channels_hz, self.channel_dwell_s)  # checks, naming the key
        if not self.phase_power_span_db > 0:
            raise ConfigError(f"phase_power_span_db must be > 0, got {self.phase_power_span_db!r}")
        for name in ("phase_noise_rad", "phase_resolution_rad", "phase_power_shift_rad",
                     "doppler_noise_hz",
                     "tag_sensitivity_spread_db", "tag_modulation_spread_db", "metal_detuning_loss_db"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if self.metal_tag_type not in METAL_TAG_TYPES:
            raise ConfigError(f"metal_tag_type must be one of {', '.join(map(repr, METAL_TAG_TYPES))}, "
                              f"got {self.metal_tag_type!r}")
        if self.inventory not in INVENTORY_MODES:
            raise ConfigError(f"inventory must be 'fixed' or 'gen2', got {self.inventory!r}")

        unknown = [m for m in self.detuning_materials if m not in MATERIALS]
        if unknown:
            raise ConfigError(f"detuning_materials: unknown material(s) {unknown}; the library "
                              f"has {', '.join(sorted(MATERIALS))}")
        if self.inventory == "gen2" and self.antenna_mode == "round_robin":
            try:  # a dwell that cannot fit: named error
                self.gen2.dwell_s(1.0 / self.read_rate_hz)
            except ConfigError as exc:
                raise ConfigError(f"reader.read_rate_hz = {self.read_rate_hz!r} gives antenna slots of "
                                  f"{1.0 / self.read_rate_hz:.4g} s: {exc}; lower read_rate_hz or the "
                                  "gen2 timing") from None

    def antenna_slot_s(self, n_antennas: int) -> float:
        """One antenna's time slot in a read cycle [s]: ``1 / read_rate_hz`` with
        ``"round_robin"``, that divided by ``n_antennas`` with ``"all"``."""
        return 1.0 / self.read_rate_hz / (1 if self.antenna_mode == "round_robin" else int(n_antennas))

    def channel_plan(self, frequency_hz: float | None = None):
        """The reader's channels (:func:`pipeline.acquisition.channels.channel_plan`), in
        listed order; ``frequency_hz`` is the carrier of region ``"none"``."""
        return channel_plan(self.region, self.channels_hz, self.channel_dwell_s, frequency_hz)

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
    out["gen2"] = dataclasses.asdict(reader.gen2)
    out["channels_hz"] = list(reader.channels_hz)
    out["detuning_materials"] = list(reader.detuning_materials)
    out["budget"] = dataclasses.asdict(budget)
    return out
