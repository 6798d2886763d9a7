"""Benchmark: epochs per second of ANFIS hybrid learning, ours vs a PyPI peer.

Workload: 12,395 two-input samples (the training-set size of Cicirelli et al.
2011), synthetic (d [m], alpha [rad]) -> normalised RSSI with a log-distance
law, an antenna-pattern term and 2 dB noise. Each epoch of both
implementations does the same work: a full-batch least-squares fit of the
first-order consequents, then one gradient step on the Gaussian premise
parameters (Jang 1993 hybrid rule). Two model sizes: 3 rules (one per FCM
cluster) and 9 rules (3 x 3 grid).

Peer: ``anfis-toolbox`` (``ANFISRegressor(optimizer="hybrid")``, full batch),
from the optional ``bench`` extra. Per-epoch time is taken as
``(t(E epochs) - t(1 epoch)) / (E - 1)`` for both, which removes model
construction (FCM, grid) from the figure; best of `REPEATS` runs, because the
machine may be shared.

Run: ``.venv/bin/python bench/anfis.py [--epochs 40] [--repeats 3]``
"""

from __future__ import annotations

import argparse
import platform
import time
import warnings

import numpy as np

from fuzzymodel import ANFIS, normalise_rssi

N_SAMPLES = 12_395
RSSI_RANGE_DBM = (-80.0, -30.0)


def synthetic_rssi(rng: np.random.Generator, n: int = N_SAMPLES):
    d = rng.uniform(0.3, 6.0, n)
    alpha = rng.uniform(-np.pi, np.pi, n)
    rssi_dbm = -38.0 - 25.0 * np.log10(d) - 12.0 * (1.0 - np.cos(alpha)) + rng.normal(0, 2.0, n)
    return np.column_stack([d, alpha]), normalise_rssi(rssi_dbm, RSSI_RANGE_DBM)


def _ours(X, y, n_rules, epochs):
    if n_rules == 3:
        model = ANFIS.from_fcm(X, y, n_clusters=3, rng=np.random.default_rng(0))
    else:
        model = ANFIS.from_grid(X, n_mfs=3, mf="gauss")
    t0 = time.perf_counter()
    h = model.fit(X, y, epochs=epochs, step_size=0.01)
    return time.perf_counter() - t0, float(h.train_rmse[-1])


def _peer(X, y, n_rules, epochs):
    from anfis_toolbox import ANFISRegressor

    kw = dict(n_mfs=3, mf_type="gaussian", optimizer="hybrid", epochs=epochs,
              learning_rate=0.01, batch_size=None, random_state=0, verbose=False)
    if n_rules == 3:
        kw.update(init="fcm", rules=[(0, 0), (1, 1), (2, 2)])
    else:
        kw.update(init="grid")
    reg = ANFISRegressor(**kw)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reg.fit(X, y)
    dt = time.perf_counter() - t0
    rmse = float(np.sqrt(np.mean((reg.predict(X) - y) ** 2)))
    return dt, rmse


def per_epoch(fn, X, y, n_rules, epochs, repeats):
    """Best-of-`repeats` seconds per epoch, by differencing E and 1 epochs."""
    best = np.inf
    rmse = np.nan
    for _ in range(repeats):
        t_many, rmse = fn(X, y, n_rules, epochs)
        t_one, _ = fn(X, y, n_rules, 1)
        best = min(best, (t_many - t_one) / (epochs - 1))
    return best, rmse


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    try:
        import anfis_toolbox

        peer_version = anfis_toolbox.__version__
    except ImportError:
        peer_version = None
    X, y = synthetic_rssi(np.random.default_rng(2011))
    print(f"ANFIS hybrid-rule benchmark: {X.shape[0]} samples x {X.shape[1]} inputs, "
          f"{args.epochs} epochs, best of {args.repeats}; numpy {np.__version__}, "
          f"python {platform.python_version()}, {platform.machine()}")
    print(f"peer: anfis-toolbox {peer_version or '(not installed: pip install .[bench])'}")
    header = (f"{'rules':>5} | {'ours ep/s':>10} | {'peer ep/s':>10} | {'ours/peer':>9} | "
              f"{'ours RMSE':>9} | {'peer RMSE':>9}")
    print(header)
    print("-" * len(header))
    for n_rules in (3, 9):
        t_ours, r_ours = per_epoch(_ours, X, y, n_rules, args.epochs, args.repeats)
        if peer_version is not None:
            t_peer, r_peer = per_epoch(_peer, X, y, n_rules, args.epochs, args.repeats)
            ratio = t_peer / t_ours
            peer_cols = f"{1 / t_peer:10.1f} | {ratio:9.1f} | {r_ours:9.4f} | {r_peer:9.4f}"
        else:
            peer_cols = f"{'-':>10} | {'-':>9} | {r_ours:9.4f} | {'-':>9}"
        print(f"{n_rules:5d} | {1 / t_ours:10.1f} | {peer_cols}")
    print("ours/peer = speed ratio (peer seconds per epoch / ours); RMSE on normalised RSSI "
          "after the last epoch.")


if __name__ == "__main__":
    main()
