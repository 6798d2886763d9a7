"""Ablations of the chapter's own model (Cicirelli, Milella & Di Paola 2011).

The chapter builds each of its two Takagi-Sugeno systems (SSM: normalised RSSI; TDM:
detection ratio per cell) by FCM clustering (MATLAB ``genfis3``) and trains it with
ANFIS (Jang 1993). Two ablations isolate the two steps; both return a
``fuzzymodel.SensorModel`` (which saves itself), fitted on the same training sets
(``training/ssm_est.parquet``, ``training/tdm_est.parquet``) with the same subsampling
(``max_samples``, SSM only) and the same training / checking split as
``pipeline.stages.models._fit``:

``"fcm_only"``
    The initial FIS straight from FCM, no ANFIS epochs: ``ANFIS.from_fcm`` on the
    training part of the split, whose consequents are the least-squares solution for the
    FCM premise (as ``genfis3`` computes them). The premise is never tuned, so this
    measures what hybrid learning adds.
``"anfis_gridinit"``
    ANFIS from a grid partition (MATLAB ``genfis1``: ``ANFIS.from_grid``, ``n_mfs``
    membership functions per input of family ``mf``; default 2 bell MFs per input, the
    genfis1 default, i.e. 4 rules), then trained exactly as the chapter's model (same
    epochs, step size, checking set, best checking epoch kept). This measures what the
    FCM initialisation adds.
"""

from __future__ import annotations

import numpy as np

from fuzzymodel import ANFIS, SensorModel

__all__ = ["ABLATIONS", "fit_ablation", "train_check_split"]

#: Names of the ablations.
ABLATIONS = ("fcm_only", "anfis_gridinit")
_INPUTS = ["d_m", "alpha_rad"]


def train_check_split(X, y, frac: float, rng: np.random.Generator):
    """A random ``frac`` of the samples as ANFIS checking data (the models stage's rule too).

    Returns ``(X_train, y_train, X_check, y_check)``; the checking pair is ``None`` when
    ``frac`` leaves no checking sample or fewer than 2 training samples.
    """
    n = len(y)
    n_check = int(round(frac * n))
    if n_check < 1 or n - n_check < 2:
        return X, y, None, None
    perm = rng.permutation(n)
    c, t = perm[:n_check], perm[n_check:]
    return X[t], y[t], X[c], y[c]


def _fit_one(kind: str, ts, rng, epochs: int, n_clusters: int, fcm_exponent: float,
             check_fraction: float, max_samples: int, step_size: float, n_mfs, mf: str) -> ANFIS:
    X, y = np.asarray(ts.X, float), np.asarray(ts.y, float)
    if ts.kind == "ssm" and max_samples and len(y) > max_samples:
        keep = np.sort(rng.choice(len(y), max_samples, replace=False))
        X, y = X[keep], y[keep]
    Xt, yt, Xc, yc = train_check_split(X, y, check_fraction, rng)
    if kind == "fcm_only":
        model = ANFIS.from_fcm(Xt, yt, n_clusters=n_clusters, m=fcm_exponent, rng=rng,
                               input_names=_INPUTS)
        model.provenance["ablation"] = ("fcm_only: genfis3-style FIS, consequents by least "
                                        "squares, no ANFIS training")
        return model
    model = ANFIS.from_grid(Xt, n_mfs=n_mfs, mf=mf, input_names=_INPUTS)
    model.fit(Xt, yt, epochs=epochs, X_check=Xc, y_check=yc, step_size=step_size)
    model.provenance["ablation"] = "anfis_gridinit: genfis1-style grid partition, ANFIS-trained"
    return model


def fit_ablation(kind: str, ssm_set, tdm_set, rng: np.random.Generator, epochs: int = 100, *,
                 n_clusters: int = 3, fcm_exponent: float = 2.0, check_fraction: float = 0.2,
                 max_samples: int = 0, step_size: float = 0.01, n_mfs=2,
                 mf: str = "bell") -> SensorModel:
    """Fit one ablation (see module doc) for SSM and TDM.

    Parameters
    ----------
    kind : {"fcm_only", "anfis_gridinit"}
    ssm_set, tdm_set : pipeline.acquisition.TrainingSet
        The SSM (kind "ssm", with ``rssi_range_dbm``) and TDM (kind "tdm") sets.
    rng : numpy.random.Generator
        Drives subsampling, the split and the FCM start, SSM first, then TDM.
    epochs : int
        ANFIS epochs ("anfis_gridinit" only).
    n_clusters, fcm_exponent : FCM rules and fuzzifier ("fcm_only").
    check_fraction, max_samples, step_size : as ``training.*`` in the study config.
    n_mfs, mf : grid partition of "anfis_gridinit" (per input; ``"bell"`` or ``"gauss"``).

    Returns
    -------
    fuzzymodel.SensorModel
        With the SSM set's RSSI range.
    """
    if kind not in ABLATIONS:
        raise ValueError(f"unknown ablation {kind!r}; expected one of {ABLATIONS}")
    if getattr(ssm_set, "kind", None) != "ssm" or getattr(tdm_set, "kind", None) != "tdm":
        raise ValueError(f"fit_ablation: need an 'ssm' and a 'tdm' TrainingSet, got "
                         f"{getattr(ssm_set, 'kind', None)!r} and {getattr(tdm_set, 'kind', None)!r}")
    if ssm_set.rssi_range_dbm is None:
        raise ValueError("fit_ablation: the SSM training set has no rssi_range_dbm")
    args = (rng, int(epochs), int(n_clusters), float(fcm_exponent), float(check_fraction),
            int(max_samples), float(step_size), n_mfs, mf)
    ssm = _fit_one(kind, ssm_set, *args)
    tdm = _fit_one(kind, tdm_set, *args)
    return SensorModel(ssm, tdm, rssi_range_dbm=tuple(ssm_set.rssi_range_dbm))
