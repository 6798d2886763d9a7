"""Synthetic reads tables with the contract's columns, from a closed-form RSSI.

A normal module (not conftest.py) so test files import it by a unique name.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["gain_for_rssi", "synthetic_reads"]


def gain_for_rssi(budget, rssi_dbm):
    """One-way gain [dB] whose noise-free reader RSSI is `rssi_dbm`.

    P_rx = P_tx + 2 G + M - 2 L_pol is affine in G with slope 2 (docs/physics.md).
    """
    return (np.asarray(rssi_dbm, float) - budget.reader_rssi_dbm(np.float64(0.0))) / 2.0


def synthetic_reads(rssi_of, budget, rng, n=4000, d_max_m=3.5, miss_probability=0.0,
                    est_noise_m=0.0):
    """Attempts at random (d, alpha) with gain from the closed-form RSSI `rssi_of(d, alpha)`.

    Antenna at the origin looking along +x (yaw 0), tags in the horizontal plane, so
    d and alpha are the polar coordinates of the tag; `read` is the noise-free link
    closing and surviving the anti-collision miss probability.
    """
    d = rng.uniform(0.2, d_max_m, n)
    a = rng.uniform(-np.pi, np.pi, n)
    rssi = rssi_of(d, a)
    g = gain_for_rssi(budget, rssi)
    closed = np.asarray(budget.detected(g), bool)
    read = closed & (rng.random(n) >= miss_probability)
    df = pd.DataFrame({
        "time_s": np.arange(n) * 0.01, "cycle": np.arange(n) // 10,
        "antenna": np.zeros(n, dtype=np.int8), "tag_id": [f"t{i % 7}" for i in range(n)],
        "read": read, "rssi_dbm": np.where(read, rssi, np.nan),
        "true_ant_x_m": 0.0, "true_ant_y_m": 0.0, "true_ant_z_m": 1.0, "true_ant_yaw_rad": 0.0,
        "est_ant_x_m": 0.0, "est_ant_y_m": 0.0, "est_ant_z_m": 1.0, "est_ant_yaw_rad": 0.0,
        "d_true_m": d, "alpha_true_rad": a,
        "d_est_m": d + rng.normal(0, est_noise_m, n) if est_noise_m else d,
        "alpha_est_rad": a, "gain_db": g, "tag_power_dbm": budget.tag_power_dbm(g),
        "powered": budget.tag_power_dbm(g) >= budget.tag_sensitivity_dbm, "in_range": True,
    })
    return df
