"""A lag between the reader's clock and the poses' clock, estimated from the reads.

A reader logs on its own clock (or the host's, at the time the report arrived); the poses
on the robot's. A constant offset between them moves every read along the tour by the
robot's speed times the offset, which blurs the distance dependence of the RSSI. For a
candidate lag tau the reads are placed at the poses of time ``t + tau``, each read's
distance and bearing to its tag computed from the antenna mounts, and the log-distance
model with the antenna pattern's first two harmonics in the bearing and a per-antenna
offset fitted by least squares (the pattern carries the lag: a misplaced read sees its
tag at the wrong bearing); the lag whose residual is smallest is the estimate.
It is *reported* (``recording/import.json`` ``pose_lag``), never applied: a user who
agrees sets ``recording.time_offset_s``. No lag is reported (``lag_s`` None) from fewer
than :data:`MIN_READS` reads, or where the best lag's residual is not at least
:data:`MIN_GAIN_DB` below zero lag's (a robot standing still fits every lag alike). The
recording stage gives it the training tags' reads only.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.robot.kinematics import antenna_poses

__all__ = ["LAGS_S", "pose_lag_profile"]

#: Candidate lags [s]: +-2 s in 0.1 s steps.
LAGS_S = np.round(np.arange(-2.0, 2.0001, 0.1), 3)
#: Fewest reads a lag is estimated from.
MIN_READS = 50
#: Least improvement of the RSSI residual over zero lag for a lag to be reported [dB].
MIN_GAIN_DB = 0.1


def pose_lag_profile(reads: pd.DataFrame, poses: pd.DataFrame, tags, mounts, ports,
                     lags_s=LAGS_S) -> dict:
    """RSSI residual of the log-distance model at each candidate lag (module doc).

    Parameters
    ----------
    reads : pandas.DataFrame
        ``t_s``, ``antenna_port``, ``rssi_dbm``, ``epc`` (a :class:`~.load.Recording`'s).
    poses : pandas.DataFrame
        ``t_s, x_m, y_m, yaw_rad``.
    tags : scenes.scene.TagSet
        ids = EPCs.
    mounts : list of pipeline.robot.AntennaMount
    ports : list of int
        Reader port of each mount.
    lags_s : array_like
        Candidate lags [s] added to the reads' times.

    Returns
    -------
    dict
        ``lag_s`` (the best; None: none found, module doc), ``rmse_db`` at the best and
        at zero lag (``rmse_db_at_zero``),
        ``profile`` ({lag: rmse}), ``n_reads`` (reads inside the poses' span at every lag).
    """
    t_pose = poses["t_s"].to_numpy(np.float64)
    yaw = np.unwrap(poses["yaw_rad"].to_numpy(np.float64))
    t = reads["t_s"].to_numpy(np.float64)
    lags = np.asarray(lags_s, np.float64)
    keep = (t + lags.min() >= t_pose[0]) & (t + lags.max() <= t_pose[-1])
    t = t[keep]
    ant = np.array([list(ports).index(p) for p in reads["antenna_port"].to_numpy()[keep]], np.int64)
    index = {str(e): j for j, e in enumerate(tags.ids)}
    pos = tags.positions_m[[index[e] for e in reads["epc"].to_numpy()[keep]]]
    rssi = reads["rssi_dbm"].to_numpy(np.float64)[keep]
    profile = {}
    for lag in lags:
        tq = t + lag
        robot = np.column_stack([np.interp(tq, t_pose, poses["x_m"].to_numpy(np.float64)),
                                 np.interp(tq, t_pose, poses["y_m"].to_numpy(np.float64)),
                                 np.interp(tq, t_pose, yaw)])
        a = antenna_poses(robot, list(mounts))[np.arange(len(tq)), ant]
        diff = pos - a[:, :3]
        d = np.maximum(np.linalg.norm(diff, axis=1), 1e-3)
        alpha = np.arctan2(diff[:, 1], diff[:, 0]) - a[:, 3]  # bearing off boresight
        X = np.column_stack([np.ones_like(d), 10 * np.log10(d),
                             *[f(k * alpha) for k in (1, 2) for f in (np.cos, np.sin)],
                             *[(ant == k).astype(float) for k in range(1, len(mounts))]])
        res = rssi - X @ np.linalg.lstsq(X, rssi, rcond=None)[0]
        profile[float(lag)] = float(np.sqrt(np.mean(res ** 2))) if len(res) else float("nan")
    zero = min(profile, key=lambda k: abs(k))
    finite = {k: v for k, v in profile.items() if np.isfinite(v)}
    best = min(finite, key=lambda k: finite[k]) if finite else zero
    n = int(keep.sum())
    found = (n >= MIN_READS and best in finite and zero in finite
             and finite[zero] - finite[best] >= MIN_GAIN_DB)
    return {"lag_s": best if found else None, "rmse_db": profile[best],
            "rmse_db_at_zero": profile[zero], "profile": profile, "n_reads": n}
