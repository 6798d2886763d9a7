"""Reads, poses and tags as CSV files: the layouts, readers, writers and time alignment.

**Reads: the CSV ``sllurp log`` writes** (sllurp, ``sllurp/verb/log.py``, ``CsvLogger``):
``csv.writer(dialect="excel")`` (CRLF line ends), one header row
``timestamp,reader,antenna,rssi,epc`` and one row per tag report:

===========  ============================================================================
timestamp    seconds since 1970 (UTC): the host's clock at the report, or with
             ``--reader-timestamp`` the reader's ``LastSeenTimestampUTC`` [us] / 1e6
reader       ``host:port`` of the reader
antenna      the reader's antenna port (LLRP ``AntennaID``, 1-based)
rssi         LLRP ``PeakRSSI``: whole dBm (a signed byte)
epc          the EPC as sllurp gives it: hex digits
===========  ============================================================================

sllurp writes the file once, when the inventory ends (a killed logger leaves none), and
only reads: a failed attempt is no row. :func:`read_sllurp_csv` returns the rows as they
are, with ``t_s`` the timestamp; ``rssi_dbm`` is the value as written (whole dBm).

sllurp's own logger writes no more columns (sllurp 2.x ``CsvLogger``; its
``--impinj-reports`` is an option of ``sllurp inventory``, which prints the reports to
its log). Users who want phase and channel add Impinj's report fields to the logger's
rows; such a file (e.g. a public R420 project's: ``timestamp,reader,antenna,rssi,epc,
phase_angle,channel_index,doppler_frequency``) is read with those columns in the
reader's raw units (:mod:`.units`): ``phase_angle`` 0-4095 -> rad (x 2 pi / 4096),
``channel_index`` 1-based -> Hz by the region's table, ``doppler_frequency`` 1/16 Hz ->
Hz. A row leaving one empty gets NaN there.

**Poses**: header ``t_s,x_m,y_m,yaw_rad`` (the robot base in the scene frame; the
localisation's estimate, as a real robot has it). **Tags**: header ``epc,x_m,y_m,z_m``
and optionally ``nx,ny,nz`` (the normal into free space).

Every reader stops at the first row it cannot take with one line naming ``file:line``
and the column; reads out of time order are sorted (counted); an empty file is an error.
Hand-written with the standard ``csv`` module rather than ``pandas.read_csv``: the
errors must name the line of the file, which pandas does not report for a bad value.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.recording.units import DOPPLER_STEPS_PER_HZ, PHASE_STEPS, channel_frequency_hz
from scenes.fileio import atomic_output

__all__ = ["POSE_COLUMNS", "READ_FIELDS", "SLLURP_COLUMNS", "SLLURP_IMPINJ_COLUMNS", "TAG_COLUMNS", "RecordingError", "align_reads",
           "read_poses_csv", "read_sllurp_csv", "read_tags_csv", "write_poses_csv",
           "write_sllurp_csv", "write_tags_csv"]

#: Columns of a recording's reads (:attr:`.load.Recording.reads`).
READ_FIELDS = ("t_s", "antenna_port", "rssi_dbm", "epc", "phase_rad", "frequency_hz",
               "doppler_hz", "seen_count")

#: Header of the CSV ``sllurp log`` writes.
SLLURP_COLUMNS = ("timestamp", "reader", "antenna", "rssi", "epc")
#: Impinj report fields users add to sllurp's logger (module doc), raw units.
SLLURP_IMPINJ_COLUMNS = ("phase_angle", "channel_index", "doppler_frequency")
#: Header of a poses CSV.
POSE_COLUMNS = ("t_s", "x_m", "y_m", "yaw_rad")
#: Header of a tag layout CSV (``nx, ny, nz`` optional).
TAG_COLUMNS = ("epc", "x_m", "y_m", "z_m")

#: Largest file read [bytes] (a recording of hours is tens of MB).
MAX_BYTES = 2 << 30


class RecordingError(ValueError):
    """A recording file that cannot be read; the message names the file, line and column."""


def _rows(path: Path, header: tuple[str, ...], optional: tuple[str, ...] = ()):
    """(line number, row dict) of a CSV whose header holds ``header`` (in any order)."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    if path.stat().st_size > MAX_BYTES:
        raise RecordingError(f"{path}: larger than {MAX_BYTES >> 30} GiB")
    with open(path, newline="", encoding="utf-8-sig") as fh:
        rd = csv.reader(fh)
        try:
            head = next(rd)
        except StopIteration:
            raise RecordingError(f"{path}: empty file (expected the header "
                                 f"{','.join(header)})") from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise RecordingError(f"{path}:1: not a CSV header ({exc})") from None
        head = [h.strip() for h in head]
        missing = [c for c in header if c not in head]
        if missing:
            raise RecordingError(f"{path}:1: missing column {missing[0]!r}; the header is "
                                 f"{','.join(head)[:120]}, expected {','.join(header)}")
        cols = {c: head.index(c) for c in (*header, *optional) if c in head}
        try:
            for row in rd:
                if not row or all(not v.strip() for v in row):
                    continue
                if len(row) < len(head):
                    raise RecordingError(f"{path}:{rd.line_num}: {len(row)} fields, the header "
                                         f"has {len(head)}")
                yield rd.line_num, {c: row[i].strip() for c, i in cols.items()}
        except (csv.Error, UnicodeDecodeError) as exc:
            raise RecordingError(f"{path}:{rd.line_num}: not CSV ({exc})") from None


def _number(path, line, col, text, *, integer=False) -> float:
    try:
        v = int(text) if integer else float(text)
    except ValueError:
        raise RecordingError(f"{path}:{line}: column {col!r}: {text[:30]!r} is not "
                             f"{'an integer' if integer else 'a number'}") from None
    if not math.isfinite(v):
        raise RecordingError(f"{path}:{line}: column {col!r}: {text[:30]!r} is not finite")
    return v


def read_sllurp_csv(path: str | Path, region: str = "") -> pd.DataFrame:
    """The reads of a ``sllurp log`` CSV (module doc).

    Parameters
    ----------
    region : str
        The channel table a ``channel_index`` column refers to (``recording.region``).

    Returns
    -------
    pandas.DataFrame
        ``t_s`` [s since 1970], ``reader`` (str), ``antenna_port`` (int, 1-based),
        ``rssi_dbm`` (float64), ``epc`` (str, upper-case hex), ``phase_rad`` [0, 2 pi),
        ``frequency_hz``, ``doppler_hz`` (float64; NaN without the Impinj columns), in
        time order.

    Raises
    ------
    RecordingError
        Naming ``file:line`` and the column: a missing column, a value that is no number,
        a port below 1, an EPC that is not hex, a phase outside 0-4095, a channel index
        outside the region's table (or no region); an empty file. An EPC written as Python
        bytes (``b'3034...'``, as sllurp on Python 3 does) is taken as its hex digits; rows
        out of time order are sorted and counted (``attrs["n_reordered"]``).
    """
    out = {"t_s": [], "reader": [], "antenna_port": [], "rssi_dbm": [], "epc": [],
           "phase_rad": [], "frequency_hz": [], "doppler_hz": []}
    for line, r in _rows(path, SLLURP_COLUMNS, optional=SLLURP_IMPINJ_COLUMNS):
        t = _number(path, line, "timestamp", r["timestamp"])
        port = int(_number(path, line, "antenna", r["antenna"], integer=True))
        if port < 1:
            raise RecordingError(f"{path}:{line}: column 'antenna': port {port}; LLRP ports "
                                 "start at 1")
        epc = r["epc"]
        if len(epc) > 3 and epc[:2] in ("b'", 'b"') and epc[-1] == epc[1]:
            epc = epc[2:-1]  # sllurp on Python 3 writes the EPC's bytes repr: b'3034...'
        epc = epc.upper()
        if not epc or any(ch not in "0123456789ABCDEF" for ch in epc):
            raise RecordingError(f"{path}:{line}: column 'epc': {r['epc'][:40]!r} is not hex")
        out["t_s"].append(t)
        out["reader"].append(r["reader"])
        out["antenna_port"].append(port)
        out["rssi_dbm"].append(_number(path, line, "rssi", r["rssi"]))
        out["epc"].append(epc)
        _impinj_fields(path, line, r, region, out)
    if not out["t_s"]:
        raise RecordingError(f"{path}: no reads after the header")
    df = pd.DataFrame({"t_s": np.asarray(out["t_s"], np.float64), "reader": out["reader"],
                       "antenna_port": np.asarray(out["antenna_port"], np.int64),
                       "rssi_dbm": np.asarray(out["rssi_dbm"], np.float64), "epc": out["epc"],
                       **{c: np.asarray(out[c], np.float64)
                          for c in ("phase_rad", "frequency_hz", "doppler_hz")}})
    # the host's clock at each report batch: batches of several ports interleave (a real
    # R420 log does), so the rows are sorted by time and the reordered ones counted
    return sorted_by_time(df)


def sorted_by_time(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` in ``t_s`` order (a stable sort), ``attrs["n_reordered"]`` the rows that came
    earlier than one before them (a reader's report batches interleave)."""
    t = df["t_s"].to_numpy()
    n_back = int(np.sum(t < np.maximum.accumulate(t)))
    if n_back:
        df = df.sort_values("t_s", kind="stable").reset_index(drop=True)
    df.attrs["n_reordered"] = n_back
    return df


def _impinj_fields(path, line, r, region, out) -> None:
    """A sllurp row's Impinj columns (module doc) into ``out``, in SI; NaN where absent."""
    phase = freq = doppler = math.nan
    if r.get("phase_angle", "").strip():
        raw = _number(path, line, "phase_angle", r["phase_angle"], integer=True)
        if not 0 <= raw < PHASE_STEPS:
            raise RecordingError(f"{path}:{line}: column 'phase_angle': {raw:.0f} is outside "
                                 f"0-{PHASE_STEPS - 1} (Impinj's 12-bit phase)")
        phase = raw * 2.0 * math.pi / PHASE_STEPS
    if r.get("channel_index", "").strip():
        index = int(_number(path, line, "channel_index", r["channel_index"], integer=True))
        try:
            freq = channel_frequency_hz(index, region)
        except ValueError as exc:
            raise RecordingError(f"{path}:{line}: column 'channel_index': {exc}") from None
    if r.get("doppler_frequency", "").strip():
        doppler = _number(path, line, "doppler_frequency", r["doppler_frequency"]) / DOPPLER_STEPS_PER_HZ
    out["phase_rad"].append(phase)
    out["frequency_hz"].append(freq)
    out["doppler_hz"].append(doppler)


def _write_csv(path, header, rows) -> Path:
    """``header`` then ``rows`` as CSV (excel dialect, CRLF), atomically (a half-written
    file never appears)."""
    path = Path(path)
    with atomic_output(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, dialect="excel")
        w.writerow(header)
        w.writerows(rows)
    return path


def write_sllurp_csv(reads: pd.DataFrame, path: str | Path) -> Path:
    """Write ``reads`` (``t_s``, ``reader``, ``antenna_port``, ``rssi_dbm``, ``epc``) as
    ``sllurp log`` does: the excel dialect (CRLF), its header, RSSI in whole dBm (LLRP's
    ``PeakRSSI`` is a signed byte), the timestamp with microseconds. Atomic."""
    rows = ((f"{float(t):.6f}", rd, int(a), int(round(float(s))), e)
            for t, rd, a, s, e in zip(reads["t_s"], reads["reader"], reads["antenna_port"],
                                      reads["rssi_dbm"], reads["epc"], strict=True))
    return _write_csv(path, SLLURP_COLUMNS, rows)


def read_poses_csv(path: str | Path) -> pd.DataFrame:
    """Poses ``t_s, x_m, y_m, yaw_rad`` (module doc), strictly increasing in time.

    Raises
    ------
    RecordingError
        Naming ``file:line`` and the column; fewer than two poses.
    """
    rows, last = [], -math.inf
    for line, r in _rows(path, POSE_COLUMNS):
        v = [_number(path, line, c, r[c]) for c in POSE_COLUMNS]
        if v[0] <= last:
            raise RecordingError(f"{path}:{line}: column 't_s': {v[0]} does not follow "
                                 f"{last}: time must increase")
        last = v[0]
        rows.append(v)
    if len(rows) < 2:
        raise RecordingError(f"{path}: {len(rows)} pose(s); at least two to interpolate between")
    return pd.DataFrame(np.asarray(rows, np.float64), columns=list(POSE_COLUMNS))


def write_poses_csv(poses: pd.DataFrame, path: str | Path) -> Path:
    """Write ``t_s, x_m, y_m, yaw_rad`` (microsecond and micrometre precision). Atomic."""
    rows = ([f"{v:.6f}" for v in row] for row in poses[list(POSE_COLUMNS)].to_numpy(np.float64))
    return _write_csv(path, POSE_COLUMNS, rows)


def read_tags_csv(path: str | Path) -> pd.DataFrame:
    """The tag layout ``epc, x_m, y_m, z_m`` (and ``nx, ny, nz`` where given).

    Raises
    ------
    RecordingError
        Naming ``file:line`` and the column; an EPC listed twice.
    """
    rows, seen = [], {}
    for line, r in _rows(path, TAG_COLUMNS, ("nx", "ny", "nz")):
        epc = r["epc"].upper()
        if epc in seen:
            raise RecordingError(f"{path}:{line}: column 'epc': {epc[:40]} is listed twice "
                                 f"(line {seen[epc]} too)")
        seen[epc] = line
        row = {"epc": epc, **{c: _number(path, line, c, r[c]) for c in TAG_COLUMNS[1:]}}
        for c in ("nx", "ny", "nz"):
            row[c] = _number(path, line, c, r[c]) if r.get(c) else float("nan")
        rows.append(row)
    if not rows:
        raise RecordingError(f"{path}: no tags after the header")
    return pd.DataFrame(rows)


def write_tags_csv(tags: pd.DataFrame, path: str | Path) -> Path:
    """Write ``epc, x_m, y_m, z_m, nx, ny, nz``. Atomic."""
    cols = [*TAG_COLUMNS, "nx", "ny", "nz"]
    rows = ([r["epc"], *(f"{float(r[c]):.6f}" for c in cols[1:])] for _, r in tags.iterrows())
    return _write_csv(path, cols, rows)


def align_reads(reads: pd.DataFrame, poses: pd.DataFrame) -> tuple[pd.DataFrame, int]:
    """Each read with the robot's pose at its time, linearly interpolated (the yaw
    unwrapped first, so a turn through +-pi interpolates the short way).

    A read outside the poses' time span has no pose: it is dropped and counted, never
    extrapolated.

    Returns
    -------
    aligned : pandas.DataFrame
        ``reads`` (the ones within the span) with ``x_m``, ``y_m``, ``yaw_rad`` added.
    n_dropped : int
        Reads outside the span.
    """
    t = poses["t_s"].to_numpy(np.float64)
    tr = reads["t_s"].to_numpy(np.float64)
    inside = (tr >= t[0]) & (tr <= t[-1])
    out = reads.loc[inside].copy()
    yaw = np.unwrap(poses["yaw_rad"].to_numpy(np.float64))
    for col, v in (("x_m", poses["x_m"].to_numpy(np.float64)),
                   ("y_m", poses["y_m"].to_numpy(np.float64)), ("yaw_rad", yaw)):
        out[col] = np.interp(tr[inside], t, v)
    out["yaw_rad"] = (out["yaw_rad"] + np.pi) % (2 * np.pi) - np.pi
    return out.reset_index(drop=True), int((~inside).sum())
