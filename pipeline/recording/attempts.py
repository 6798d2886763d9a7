"""Read attempts from a real log: what the chapter's detection model counts.

A reader's log holds only reads; a failed attempt leaves no row. The detection model
``fT`` is the share of attempts that read the tag, so the attempts are rebuilt here by
the rule the simulated reader follows (:func:`pipeline.acquisition.read_attempts`), with
the study's ``[reader]`` set to the recording reader's settings:

- **cycles**: read cycles start every ``1 / reader.read_rate_hz`` from the first pose
  (fixed antennas: from the first read);
- **antennas**: with ``reader.antenna_mode = "round_robin"`` cycle ``k`` is antenna
  ``k mod N``'s alone, its slot the whole cycle; with ``"all"`` every antenna has a slot
  in every cycle (antenna ``a`` from ``t_k + a / (rate N)``);
- **an attempt** is one (cycle, antenna, tag) for every tag of the layout, and it
  *read* the tag when the log holds at least one report of that tag on that antenna's
  port whose time falls in the attempt's window: from the slot's start to the next slot
  of the same antenna (round robin: the slot itself; ``all``: the whole cycle, since a
  real reader's port dwells vary within a cycle). Its RSSI is the strongest of those
  reports (the reader reports a *peak* RSSI), its phase, channel and Doppler those of
  that report, its ``seen_count`` the sum of their tag seen counts;
- **off schedule**: in round robin, a report on a port whose antenna has no slot at that
  time belongs to no attempt. It is counted, and more than :data:`MAX_OFF_SCHEDULE` of
  the reads off schedule stops the import: the reader did not run the configured cycle
  (set ``reader.read_rate_hz`` to its antenna cycle, or ``antenna_mode = "all"``).

On a simulated log exported and read back the rule gives exactly the simulated attempts
(``tests/pipeline/test_recorded_study.py``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.acquisition import POSE_COLUMNS, READ_COLUMNS, PoseTrack, read_attempts
from pipeline.acquisition.simulate import _poses_frame
from pipeline.recording.csvformats import RecordingError
from propagation import antenna_frame_angles

__all__ = ["MAX_OFF_SCHEDULE", "TIME_TOLERANCE_S", "recorded_read_table", "recorded_track"]

#: Largest share of reads that may fall outside every attempt window.
MAX_OFF_SCHEDULE = 0.05
#: Slack of an attempt window's edges [s]: timestamps of the 1970 clock carry ~0.2 us of
#: float64 rounding, and readers report whole microseconds.
TIME_TOLERANCE_S = 2e-6


def recorded_track(rec):
    """The robot's poses as a :class:`pipeline.acquisition.PoseTrack` on the recording's
    clock less ``t0`` (the first pose's time; fixed antennas: the robot at the origin from
    the first read to the last), and ``t0`` [s since 1970]."""
    if rec.poses is not None:
        t = rec.poses["t_s"].to_numpy(np.float64)
        xyz = rec.poses[["x_m", "y_m", "yaw_rad"]].to_numpy(np.float64)
        t0 = float(t[0])
        return PoseTrack(t_s=t - t0, true_poses=xyz, est_poses=xyz.copy(),
                         odom_poses=np.full_like(xyz, np.nan)), t0
    t = rec.reads["t_s"].to_numpy(np.float64)
    t0, t1 = float(t[0]), float(t[-1])
    span = np.array([0.0, max(t1 - t0, 1e-3)])
    zero = np.zeros((2, 3))
    return PoseTrack(t_s=span, true_poses=zero, est_poses=zero.copy(),
                     odom_poses=np.full_like(zero, np.nan)), t0


def _windows(att, reader) -> tuple[np.ndarray, np.ndarray]:
    """Start and end of each attempt's window (relative time) [s] (module doc)."""
    if reader.antenna_mode == "round_robin":
        return att.time_s, att.time_s + att.slot_s
    start = att.time_s - att.antenna * att.slot_s  # the cycle's start
    return start, start + 1.0 / reader.read_rate_hz


def recorded_read_table(rec, tags, mounts, reader, *, frequency_hz: float):
    """The recording as the study's read table: one row per attempt (module doc).

    Parameters
    ----------
    rec : Recording
    tags : scenes.scene.TagSet
        The layout (ids = EPCs), :func:`~.load.recorded_tagset`.
    mounts : list of pipeline.robot.AntennaMount
        The robot's antennas; mount k is on port ``rec.info["ports"][k]``.
    reader : pipeline.acquisition.ReaderConfig
    frequency_hz : float
        The carrier of an attempt whose report gives no channel (and of the failed ones).

    Returns
    -------
    reads : pandas.DataFrame
        Columns :data:`pipeline.acquisition.READ_COLUMNS`, attempt-major; the poses are
        the recorded ones in both the ``true_`` and ``est_`` columns (a recording knows
        one pose), the traced columns (``gain_db``, ``tag_power_dbm``, ``rx_power_dbm``)
        NaN, ``powered`` = ``read``, ``in_range`` True.
    poses : pandas.DataFrame
        :data:`pipeline.acquisition.POSE_COLUMNS` of the track.
    info : dict
        ``t0_s``, ``n_attempts``, ``n_reads`` (attempts that read), ``n_reports_used``,
        ``n_off_schedule``, ``slot_s``.

    Raises
    ------
    RecordingError
        More than :data:`MAX_OFF_SCHEDULE` of the reports off schedule.
    """
    track, t0 = recorded_track(rec)
    att = read_attempts(track, list(mounts), reader, frequency_hz=frequency_hz)
    n, m = len(att.time_s), len(tags)
    ports = list(rec.info["ports"])
    port_to_ant = {p: k for k, p in enumerate(ports)}
    tag_index = {str(e): j for j, e in enumerate(tags.ids)}
    r = rec.reads
    t_rel = r["t_s"].to_numpy(np.float64) - t0
    ant = np.array([port_to_ant[p] for p in r["antenna_port"].tolist()], np.int64)
    tag = np.array([tag_index[e] for e in r["epc"].tolist()], np.int64)
    start, end = _windows(att, reader)
    row = np.full(len(r), -1, np.int64)
    for a in range(len(mounts)):  # each report -> the latest attempt of its antenna
        rows_a = np.flatnonzero(att.antenna == a)
        sel = np.flatnonzero(ant == a)
        if not len(rows_a) or not len(sel):
            continue
        j = np.searchsorted(start[rows_a], t_rel[sel] + TIME_TOLERANCE_S, side="right") - 1
        ok = j >= 0
        jj = rows_a[np.clip(j, 0, None)]
        ok &= t_rel[sel] < end[jj] - TIME_TOLERANCE_S
        row[sel[ok]] = jj[ok]
    used = row >= 0
    n_off = int((~used).sum())
    if len(r) and n_off > MAX_OFF_SCHEDULE * len(r):
        raise RecordingError(
            f"{n_off} of {len(r)} reads ({100 * n_off / len(r):.0f} %) fall in no attempt of the "
            f"configured cycle (reader.read_rate_hz = {reader.read_rate_hz}, antenna_mode = "
            f"{reader.antenna_mode!r}): set read_rate_hz to the reader's antenna cycle, or "
            "antenna_mode = \"all\" (docs/recordings.md, 'Attempts')")
    flat = row[used] * m + tag[used]
    rssi = r["rssi_dbm"].to_numpy(np.float64)[used]
    # strongest report per attempt: sort by (attempt, rssi) and keep each attempt's last
    order = np.lexsort((rssi, flat))
    last = np.r_[flat[order][1:] != flat[order][:-1], True]
    best = np.flatnonzero(used)[order[last]]
    cells = flat[order[last]]
    read = np.zeros(n * m, bool)
    read[cells] = True
    out_rssi = np.full(n * m, np.nan, np.float32)
    out_rssi[cells] = r["rssi_dbm"].to_numpy(np.float64)[best]
    freq = np.repeat(att.frequency_hz, m).astype(np.float64)
    f_rep = r["frequency_hz"].to_numpy(np.float64)[best]
    freq[cells] = np.where(np.isfinite(f_rep), f_rep, freq[cells])
    phase = np.full(n * m, np.nan, np.float32)
    phase[cells] = r["phase_rad"].to_numpy(np.float64)[best]
    dop = np.full(n * m, np.nan, np.float32)
    dop[cells] = r["doppler_hz"].to_numpy(np.float64)[best]
    seen = np.bincount(flat, weights=r["seen_count"].to_numpy(np.float64)[used], minlength=n * m)
    geo = antenna_frame_angles(att.est_antenna, tags.positions_m)
    rep = np.repeat
    cols = {
        "time_s": rep(att.time_s, m), "cycle": rep(att.cycle, m), "antenna": rep(att.antenna, m),
        "tag_id": pd.Categorical.from_codes(np.tile(np.arange(m), n),
                                            categories=[str(i) for i in tags.ids]),
        "read": read, "rssi_dbm": out_rssi, "frequency_hz": freq, "phase_rad": phase,
        "doppler_hz": dop, "seen_count": seen.astype(np.int16),
    }
    for prefix in ("true", "est"):
        for j, name in enumerate(("x_m", "y_m", "z_m", "yaw_rad")):
            cols[f"{prefix}_ant_{name}"] = rep(att.est_antenna[:, j], m)
    d, a = geo.d_m.reshape(-1), geo.alpha_rad.reshape(-1)
    cols.update(d_true_m=d, alpha_true_rad=a, d_est_m=d, alpha_est_rad=a,
                gain_db=np.full(n * m, np.nan), tag_power_dbm=np.full(n * m, np.nan),
                rx_power_dbm=np.full(n * m, np.nan), powered=read, in_range=np.ones(n * m, bool))
    table = pd.DataFrame(cols, columns=list(READ_COLUMNS)).astype(READ_COLUMNS)
    poses = _poses_frame(track).astype(POSE_COLUMNS)
    info = {"t0_s": t0, "n_attempts": int(n * m), "n_reads": int(read.sum()),
            "n_reports_used": int(used.sum()), "n_off_schedule": n_off,
            "slot_s": float(att.slot_s), "n_cycles": int(att.cycle.max(initial=-1) + 1)}
    return table, poses, info
