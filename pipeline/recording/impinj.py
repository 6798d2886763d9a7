"""Reads as an Impinj reader reports them: a CSV of LLRP tag reports with Impinj's extensions.

Impinj Speedway / R700 readers report per tag (LLRP ``TagReportData`` with the Impinj
extensions enabled, as ItemTest exports them and as sllurp's ``--impinj-reports`` asks
for them) the raw values below; the Octane SDK gives the same quantities converted, under
its own names. :func:`read_impinj_csv` takes either name for each field (one per
file) and converts to SI:

====================  ===============================  =================================
field                 raw column (unit)                Octane SDK column (unit)
====================  ===============================  =================================
EPC                   ``EPC`` (hex)                    ``Epc``
antenna port          ``AntennaPort`` (1-based)        ``AntennaPortNumber``
time                  ``LastSeenTimestampUTC`` [us     ``LastSeenTime`` [us since 1970];
                      since 1970]; else                else ``FirstSeenTime``
                      ``FirstSeenTimestampUTC``
peak RSSI             ``ImpinjPeakRSSI`` [0.01 dBm]    ``PeakRssiInDbm`` [dBm]
                      or ``PeakRSSI`` [whole dBm]
phase                 ``ImpinjRFPhaseAngle`` [0-4095   ``PhaseAngleInRadians`` [rad]
                      = 0-2 pi]
channel               ``ChannelIndex`` [1-based into   ``ChannelInMhz`` [MHz]
                      the region's channel table]
Doppler               ``ImpinjRFDopplerFrequency``     ``RfDopplerFrequency`` [Hz]
                      [1/16 Hz, signed]
seen count            ``TagSeenCount``                 ``TagSeenCount``
====================  ===============================  =================================

Only EPC, port, a time and a peak RSSI are required; a missing optional field is NaN
(``seen_count`` 1). The channel index becomes a frequency by the region's channel
table (:data:`pipeline.acquisition.channels.REGIONS`, ascending as Impinj readers list
them: ETSI 865.7-867.5 MHz, FCC 902.75-927.25 MHz); an index outside it stops the
import. The raw phase 0-4095 maps onto [0, 2 pi) in steps of 2 pi / 4096
(Impinj, "Speedway Revolution Reader Application Note: Low Level User Data Support",
rev. 3.0, 2013: the 12-bit ``RFPhaseAngle``; the 1/16 Hz ``RFDopplerFrequency``; the
0.01 dBm ``PeakRSSI``).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.acquisition.channels import REGIONS
from pipeline.recording.csvformats import RecordingError, _number, _rows, _write_csv, sorted_by_time
from pipeline.recording.units import DOPPLER_STEPS_PER_HZ, PHASE_STEPS, channel_frequency_hz

__all__ = ["IMPINJ_FIELDS", "PHASE_STEPS", "channel_frequency_hz", "impinj_header",
           "read_impinj_csv", "write_impinj_csv"]

#: field -> ((column, scale to SI), ...) in order of preference; scale None: special.
IMPINJ_FIELDS: dict[str, tuple[tuple[str, float | None], ...]] = {
    "epc": (("EPC", None), ("Epc", None)),
    "antenna_port": (("AntennaPort", None), ("AntennaPortNumber", None)),
    "t_s": (("LastSeenTimestampUTC", 1e-6), ("LastSeenTime", 1e-6),
            ("FirstSeenTimestampUTC", 1e-6), ("FirstSeenTime", 1e-6)),
    "rssi_dbm": (("ImpinjPeakRSSI", 0.01), ("PeakRssiInDbm", 1.0), ("PeakRSSI", 1.0)),
    "phase_rad": (("ImpinjRFPhaseAngle", 2.0 * math.pi / PHASE_STEPS),
                  ("PhaseAngleInRadians", 1.0)),
    "frequency_hz": (("ChannelIndex", None), ("ChannelInMhz", 1e6)),
    "doppler_hz": (("ImpinjRFDopplerFrequency", 1.0 / DOPPLER_STEPS_PER_HZ),
                   ("RfDopplerFrequency", 1.0)),
    "seen_count": (("TagSeenCount", 1.0),),
}
_REQUIRED = ("epc", "antenna_port", "t_s", "rssi_dbm")


def impinj_header(path: str | Path) -> list[str]:
    """The header fields of a CSV file (stripped); [] for an empty or unreadable one."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            return [h.strip() for h in next(csv.reader(fh), [])]
    except (OSError, csv.Error, UnicodeDecodeError):
        return []


def read_impinj_csv(path: str | Path, region: str = "") -> pd.DataFrame:
    """The reads of an Impinj CSV (module doc), converted to SI.

    Parameters
    ----------
    path : str or Path
    region : str
        The channel plan a ``ChannelIndex`` column is read with (``"ETSI"``, ``"FCC"``).

    Returns
    -------
    pandas.DataFrame
        ``t_s`` [s since 1970], ``antenna_port`` (int), ``rssi_dbm``, ``epc`` (upper-case
        hex), ``phase_rad`` in [0, 2 pi), ``frequency_hz``, ``doppler_hz`` (NaN where the
        file has no such column), ``seen_count`` (int), in file order.

    Raises
    ------
    RecordingError
        Naming ``file:line`` and the column: no EPC / port / time / RSSI column, a value
        that is no number, a port below 1, an EPC that is not hex, a channel index outside
        the region's table; an empty file. Rows out of time order are sorted (a reader
        reports in report order) and counted: ``attrs["n_reordered"]``.
    """
    head = impinj_header(path)
    cols: dict[str, tuple[str, float | None]] = {}
    for field, options in IMPINJ_FIELDS.items():
        got = next(((c, s) for c, s in options if c in head), None)
        if got is not None:
            cols[field] = got
        elif field in _REQUIRED:
            raise RecordingError(f"{path}:1: no {field} column: expected one of "
                                 f"{', '.join(c for c, _ in options)}; the header is "
                                 f"{','.join(head)[:120]}")
    names = tuple(c for c, _ in cols.values())
    out: dict[str, list] = {k: [] for k in cols}
    for line, r in _rows(path, names):
        for field, (col, scale) in cols.items():
            text = r[col]
            if field == "epc":
                epc = text.upper()
                if not epc or any(ch not in "0123456789ABCDEF" for ch in epc):
                    raise RecordingError(f"{path}:{line}: column {col!r}: {text[:40]!r} is not hex")
                out[field].append(epc)
                continue
            if field in ("antenna_port", "seen_count") or col == "ChannelIndex":
                v = _number(path, line, col, text, integer=True)
                if v < 1:
                    raise RecordingError(f"{path}:{line}: column {col!r}: {v} is below 1")
                if col == "ChannelIndex":
                    try:
                        v = channel_frequency_hz(int(v), region)
                    except ValueError as exc:
                        raise RecordingError(f"{path}:{line}: column {col!r}: {exc}") from None
                out[field].append(v)
                continue
            v = _number(path, line, col, text) * scale if text else float("nan")
            if field == "t_s" and not text:
                raise RecordingError(f"{path}:{line}: column {col!r}: empty")
            out[field].append(v)
    if not out["t_s"]:
        raise RecordingError(f"{path}: no reads after the header")
    n = len(out["t_s"])
    frame = {
        "t_s": np.asarray(out["t_s"], np.float64),
        "antenna_port": np.asarray(out["antenna_port"], np.int64),
        "rssi_dbm": np.asarray(out["rssi_dbm"], np.float64),
        "epc": out["epc"],
    }
    for field in ("phase_rad", "frequency_hz", "doppler_hz"):
        frame[field] = np.asarray(out[field], np.float64) if field in out else np.full(n, np.nan)
    frame["phase_rad"] = np.mod(frame["phase_rad"], 2.0 * np.pi)
    frame["seen_count"] = (np.asarray(out["seen_count"], np.int64) if "seen_count" in out
                           else np.ones(n, np.int64))
    df = pd.DataFrame(frame)
    # a reader's reports come in report order, not LastSeen order (a tag report summarises
    # sightings; several antennas' reports interleave): sorted by time, the reordered counted
    return sorted_by_time(df)


def write_impinj_csv(reads: pd.DataFrame, path: str | Path, region: str) -> Path:
    """Write ``reads`` (the columns :func:`read_impinj_csv` returns) in the raw layout:
    microsecond timestamps, RSSI in 0.01 dBm, the 12-bit phase, the channel index in
    ``region``'s table (a frequency not in it is an error), Doppler in 1/16 Hz; an unknown
    (NaN) phase or Doppler is an empty field. Atomic.

    Raises
    ------
    ValueError
        A frequency that is not one of the region's channels.
    """
    table = np.asarray(sorted(REGIONS[region].channels_hz), np.float64)
    f = reads["frequency_hz"].to_numpy(np.float64)
    idx = np.searchsorted(table, f)
    idx = np.clip(idx, 0, len(table) - 1)
    if len(f) and not np.allclose(table[idx], f, rtol=0, atol=1.0):
        bad = f[~np.isclose(table[idx], f, rtol=0, atol=1.0)][0]
        raise ValueError(f"{bad:.0f} Hz is not a channel of {region}")
    def steps(values, scale, modulo=None):  # whole raw steps; "" where unknown (NaN)
        v = np.asarray(values, np.float64) * scale
        v = np.mod(v, modulo) if modulo else v
        return ["" if not np.isfinite(x) else int(round(x)) % modulo if modulo else int(round(x))
                for x in v]

    phase = steps(np.mod(reads["phase_rad"].to_numpy(np.float64), 2 * np.pi),
                  PHASE_STEPS / (2 * np.pi), PHASE_STEPS)
    dop = steps(reads["doppler_hz"], DOPPLER_STEPS_PER_HZ)
    header = ("EPC", "AntennaPort", "LastSeenTimestampUTC", "ImpinjPeakRSSI", "ImpinjRFPhaseAngle",
              "ChannelIndex", "ImpinjRFDopplerFrequency", "TagSeenCount")
    rows = ((e, int(a), int(round(t * 1e6)), int(round(s * 100.0)), p, int(i) + 1, d, int(c))
            for e, a, t, s, p, i, d, c in zip(
                reads["epc"], reads["antenna_port"], reads["t_s"].to_numpy(np.float64),
                reads["rssi_dbm"].to_numpy(np.float64), phase, idx, dop, reads["seen_count"],
                strict=True))
    return _write_csv(path, header, rows)
