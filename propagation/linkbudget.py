"""Passive UHF RFID backscatter link budget (monostatic, reciprocal channel).

With g the one-way channel gain from the ray tracer (linear, both antenna patterns
included; G(g) = 10 log10 g):

* power at the tag:       P_tag = P_tx + G(g) - L_pol                 [dBm]
* the tag answers only if P_tag >= tag_sensitivity_dbm;
* power at the reader:    P_rx  = P_tx + 2 G(g) + M - 2 L_pol         [dBm]
* a read needs P_rx >= reader_sensitivity_dbm as well.

(Nikitin & Rao, "Antennas and propagation in UHF RFID systems", IEEE RFID 2008; Griffin &
Durgin, "Complete link budgets for backscatter-radio and RFID systems", IEEE APM 2009.)
Passive UHF is forward-link limited: with the defaults the tag threshold sets the range.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from propagation.analytic import wavelength_m

__all__ = ["LinkBudget"]


@dataclass(frozen=True)
class LinkBudget:
    """RFID link budget (the study sets powers, sensitivities and losses in its [reader] table).

    Attributes
    ----------
    frequency_hz : float
        Carrier, Hz. Default 865 MHz (ETSI EN 302 208 band 865-868 MHz).
    tx_power_dbm : float
        Conducted reader power at the antenna port, dBm. Default 27.15 dBm so that the
        8 dBi antenna radiates 2 W ERP = 33 dBm ERP = 35.15 dBm EIRP, the ETSI EN 302 208
        limit (ERP = EIRP - 2.15 dB).
    reader_antenna_gain_dbi : float
        Peak gain of the reader antenna, dBi. Default 8 dBi: the 3GPP TR 38.901 Table 7.3-1
        element (Sionna ``tr38901``) used as the patch-like reader antenna. Documents the
        pattern used in tracing; the traced gain already contains it.
    tag_antenna_gain_dbi : float
        Peak tag gain, dBi. Default 2.15 dBi (half-wave dipole, Sionna ``hw_dipole``).
    tag_sensitivity_dbm : float
        Chip read sensitivity, dBm. Default -18 dBm (Impinj Monza 4 datasheet: -17.4 dBm
        read sensitivity with a dipole; "Monza-4 class").
    reader_sensitivity_dbm : float
        Reader receive sensitivity, dBm. Default -80 dBm (docs/physics.md; the Impinj Speedway
        R420 datasheet gives -84 dBm, so -80 dBm is a conservative value).
    polarization_loss_db : float
        Polarisation mismatch per way *not* in the traced gain, dB. Default 0: the tracer
        applies the reader's polarisation (``TraceOptions.reader_polarization``, circular
        by default) and the tag dipole's to every path, so the circular-to-linear
        mismatch (3.01 dB on a line-of-sight path) is inside ``g`` (a V trace with a fixed
        3 dB here stands for a circular reader right on the direct path only, not after
        reflections). Set 3 dB only for gains traced with a linear reader that stands for a
        circular one.
    modulation_loss_db : float
        Backscatter modulation factor M = |Gamma_1 - Gamma_2|^2 / 4, dB (negative).
        Default -6 dB: ASK between a matched (Gamma = 0) and a shorted (Gamma = -1) chip
        state, |0 - (-1)|^2 / 4 = 1/4 (Nikitin & Rao 2008). Open and short states would
        give |1 - (-1)|^2 / 4 = 1, 0 dB: the most a passive tag can backscatter.
    """

    frequency_hz: float = 865e6
    tx_power_dbm: float = 27.15
    reader_antenna_gain_dbi: float = 8.0
    tag_antenna_gain_dbi: float = 2.15
    tag_sensitivity_dbm: float = -18.0
    reader_sensitivity_dbm: float = -80.0
    polarization_loss_db: float = 0.0
    modulation_loss_db: float = -6.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"LinkBudget.{f.name} must be a finite number, got {v!r}")
        if self.frequency_hz <= 0:
            raise ValueError(f"LinkBudget.frequency_hz must be > 0, got {self.frequency_hz!r}")
        if self.polarization_loss_db < 0:
            raise ValueError(f"LinkBudget.polarization_loss_db must be >= 0, got {self.polarization_loss_db!r}")
        if self.modulation_loss_db > 0:
            raise ValueError(f"LinkBudget.modulation_loss_db must be <= 0 dB, got {self.modulation_loss_db!r}")

    def tag_power_dbm(self, gain_db):
        """Power reaching the tag chip, P_tx + G - L_pol [dBm], same shape as ``gain_db``."""
        return self.tx_power_dbm + np.asarray(gain_db, dtype=float) - self.polarization_loss_db

    def reader_rssi_dbm(self, gain_db):
        """Backscattered power at the reader, P_tx + 2 G + M - 2 L_pol [dBm]."""
        g = np.asarray(gain_db, dtype=float)
        return self.tx_power_dbm + 2.0 * g + self.modulation_loss_db - 2.0 * self.polarization_loss_db

    def powered(self, gain_db):
        """The tag chip turns on: tag_power_dbm >= tag_sensitivity_dbm (bool array)."""
        return self.tag_power_dbm(gain_db) >= self.tag_sensitivity_dbm

    def detected(self, gain_db):
        """Both thresholds met: tag powered and reader_rssi_dbm >= reader_sensitivity_dbm."""
        return self.powered(gain_db) & (self.reader_rssi_dbm(gain_db) >= self.reader_sensitivity_dbm)

    def min_gain_db(self) -> float:
        """Smallest one-way gain that still gives a read (both thresholds) [dB]."""
        g_tag = self.tag_sensitivity_dbm - self.tx_power_dbm + self.polarization_loss_db
        g_rdr = (self.reader_sensitivity_dbm - self.tx_power_dbm - self.modulation_loss_db
                 + 2.0 * self.polarization_loss_db) / 2.0
        return float(max(g_tag, g_rdr))

    def max_range_m(self, margin_db: float = 6.0) -> float:
        """Free-space range beyond which no tag can be read, with both peak gains [m].

        Solves Friis ``G_r + G_t + 20 log10(lambda / 4 pi d) = min_gain_db - margin_db``:
        multipath can add up to about +6 dB over free space (two equal in-phase rays), which
        ``margin_db`` covers. Used to skip tracing links that cannot be read.
        """
        g_needed = self.min_gain_db() - float(margin_db)
        budget = self.reader_antenna_gain_dbi + self.tag_antenna_gain_dbi - g_needed
        return float(wavelength_m(self.frequency_hz) / (4.0 * np.pi) * 10.0 ** (budget / 20.0))
