"""Sample-weighted ANFIS (weighted least squares, weighted gradient) and weighted FCM.

The tag-detection model's samples are detection ratios per (d, alpha) cell, each
backed by n+ + n- read attempts; these tests check that the weights act as the
number of attempts would (repeated samples), and that they matter where they should.
"""

import copy

import numpy as np
import pytest

from fuzzymodel import ANFIS, FuzzyModelError, fcm


def _truth(d, a):
    """A detection-probability-like surface over (d [m], alpha [rad])."""
    return 1.0 / (1.0 + np.exp(4.0 * (d - 1.6))) * (1.0 - 0.2 * (2.0 * a / np.pi) ** 2)


def _tdm_like():
    """108 well-observed cells (200 attempts) on the truth, and 24 cells with 1-2
    attempts and extreme ratios (1.0 or 0.5) far out, where the truth is near 0."""
    d = np.arange(0.125, 3.0, 0.25)
    a = np.deg2rad(np.arange(-85.0, 90.0, 20.0))
    D, A = np.meshgrid(d, a, indexing="ij")
    Xg = np.column_stack([D.ravel(), A.ravel()])
    yg = _truth(Xg[:, 0], Xg[:, 1])
    dl = np.arange(2.25, 2.9, 0.25)
    al = np.deg2rad(np.arange(-75.0, 80.0, 20.0))
    DL, AL = np.meshgrid(dl, al, indexing="ij")
    Xl = np.column_stack([DL.ravel(), AL.ravel()])
    yl = np.ones(len(Xl))
    wl = np.ones(len(Xl))
    yl[::3], wl[::3] = 0.5, 2.0  # one read in two attempts
    X = np.vstack([Xg, Xl])
    y = np.r_[yg, yl]
    w = np.r_[np.full(len(yg), 200.0), wl]
    return X, y, w, Xg, yg


def _data(n=200, seed=0):
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(0.2, 3.0, n), rng.uniform(-1.5, 1.5, n)])
    y = _truth(X[:, 0], X[:, 1]) + 0.05 * rng.standard_normal(n)
    return X, y


def test_weighted_fit_follows_well_observed_cells_unweighted_does_not():
    X, y, w, Xg, yg = _tdm_like()
    far = Xg[:, 0] > 2.1  # the well-observed cells beside the low-evidence ones
    out = {}
    for name, sw in (("unweighted", None), ("weighted", w)):
        m = ANFIS.from_fcm(X, y, n_clusters=4, rng=np.random.default_rng(1), sample_weight=sw)
        m.fit(X, y, epochs=30, step_size=0.05, sample_weight=sw)
        p = m.predict(Xg)
        out[name] = (np.sqrt(np.mean((p - yg) ** 2)), np.abs(p - yg)[far].max())
    # weighted: within 0.03 of the truth everywhere it was well observed
    assert out["weighted"][0] < 0.02 and out["weighted"][1] < 0.03
    # unweighted: 24 cells of 1-2 attempts drag the far region up by > 0.2
    assert out["unweighted"][1] > 0.2 and out["unweighted"][0] > 0.1


def test_equal_weights_give_the_unweighted_fit():
    X, y = _data()
    Xc, yc = _data(80, seed=1)
    a = ANFIS.from_fcm(X, y, n_clusters=3, rng=np.random.default_rng(2))
    b = ANFIS.from_fcm(X, y, n_clusters=3, rng=np.random.default_rng(2),
                       sample_weight=np.full(len(y), 3.7))
    np.testing.assert_allclose(b.premise.mf_params, a.premise.mf_params, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.consequents, a.consequents, rtol=0, atol=1e-9)
    ha = a.fit(X, y, epochs=25, X_check=Xc, y_check=yc, step_size=0.05)
    hb = b.fit(X, y, epochs=25, X_check=Xc, y_check=yc, step_size=0.05,
               sample_weight=np.full(len(y), 3.7), check_sample_weight=np.full(len(yc), 0.4))
    np.testing.assert_allclose(hb.train_rmse, ha.train_rmse, rtol=0, atol=1e-9)
    np.testing.assert_allclose(hb.check_rmse, ha.check_rmse, rtol=0, atol=1e-9)
    np.testing.assert_allclose(hb.step_size, ha.step_size, rtol=0, atol=1e-12)
    assert hb.best_epoch == ha.best_epoch
    np.testing.assert_allclose(b.premise.mf_params, a.premise.mf_params, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.consequents, a.consequents, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.predict(Xc), a.predict(Xc), rtol=0, atol=1e-9)
    assert b.provenance["training"]["weighted"] and not a.provenance["training"]["weighted"]


def test_weighted_least_squares_matches_numpy_lstsq_on_scaled_rows():
    X, y = _data(150, seed=3)
    w = np.random.default_rng(4).uniform(0.0, 10.0, len(y))
    w[:5] = 0.0  # zero weights take no part
    model = ANFIS.from_fcm(X, y, n_clusters=3, rng=np.random.default_rng(5))
    # one epoch: the forward pass only (weighted LS with the initial premise)
    h = model.fit(X, y, epochs=1, sample_weight=w)
    # design matrix from the public API: the output is linear in the consequents
    probe = copy.deepcopy(model)
    cols = []
    for j in range(model.consequents.size):
        e = np.zeros(model.consequents.size)
        e[j] = 1.0
        probe.consequents = e.reshape(model.consequents.shape)
        cols.append(probe.predict(X))
    A = np.column_stack(cols)
    s = np.sqrt(w)
    theta, *_ = np.linalg.lstsq(A * s[:, None], y * s, rcond=None)
    np.testing.assert_allclose(model.consequents.ravel(), theta, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(model.predict(X), A @ theta, rtol=0, atol=1e-10)
    r = y - model.predict(X)
    assert h.train_rmse[0] == pytest.approx(np.sqrt(np.sum(w * r * r) / np.sum(w)), rel=1e-10)
    # zero-weight samples do not move the solution
    keep = w > 0
    other = copy.deepcopy(probe)
    other.fit(X[keep], y[keep], epochs=1, sample_weight=w[keep])
    np.testing.assert_allclose(other.consequents, model.consequents, rtol=0, atol=1e-9)


def test_integer_weights_act_as_repeated_samples():
    X, y = _data(120, seed=6)
    k = np.random.default_rng(7).integers(1, 4, len(y))
    Xr, yr = np.repeat(X, k, axis=0), np.repeat(y, k)
    base = ANFIS.from_fcm(X, y, n_clusters=3, rng=np.random.default_rng(8))
    g_w = base.premise_gradient(X, y, sample_weight=k)
    g_r = base.premise_gradient(Xr, yr)
    assert g_w.error == pytest.approx(g_r.error, rel=1e-10)
    np.testing.assert_allclose(g_w.gradient, g_r.gradient, rtol=1e-9, atol=1e-10)
    a, b = copy.deepcopy(base), copy.deepcopy(base)
    ha = a.fit(X, y, epochs=15, step_size=0.05, sample_weight=k)
    hb = b.fit(Xr, yr, epochs=15, step_size=0.05)
    np.testing.assert_allclose(ha.train_rmse, hb.train_rmse, rtol=1e-8)
    np.testing.assert_allclose(a.predict(X), b.predict(X), rtol=0, atol=1e-8)


def test_weighted_fcm_is_fcm_on_repeated_samples():
    X, _ = _data(60, seed=9)
    k = np.random.default_rng(10).integers(1, 5, len(X))
    u0 = np.random.default_rng(11).random((len(X), 3))
    wtd = fcm(X, 3, tol=1e-9, max_iter=500, initial_memberships=u0, sample_weight=k)
    rep = fcm(np.repeat(X, k, axis=0), 3, tol=1e-9, max_iter=500,
              initial_memberships=np.repeat(u0, k, axis=0))
    np.testing.assert_allclose(wtd.centers, rep.centers, rtol=0, atol=1e-8)
    np.testing.assert_allclose(wtd.memberships, rep.memberships[np.cumsum(k) - 1], atol=1e-8)
    assert wtd.partition_coefficient == pytest.approx(rep.partition_coefficient, rel=1e-8)
    # unit weights are plain FCM
    plain = fcm(X, 3, initial_memberships=u0)
    ones = fcm(X, 3, initial_memberships=u0, sample_weight=np.ones(len(X)))
    np.testing.assert_allclose(ones.centers, plain.centers, rtol=0, atol=1e-12)


def test_bad_weights_raise_named_errors():
    X, y = _data(60)
    model = ANFIS.from_fcm(X, y, n_clusters=2, rng=np.random.default_rng(0))
    w = np.ones(len(y))
    for bad, msg in ((w[:-1], "sample_weight has 59 weights"),
                     (np.where(np.arange(60) == 4, np.nan, w), "non-finite.*index 4"),
                     (np.where(np.arange(60) == 7, -1.0, w), ">= 0.*index 7"),
                     (np.zeros(60), "all zero"),
                     (np.ones((60, 1)), "1-D")):
        with pytest.raises(FuzzyModelError, match=msg):
            model.fit(X, y, epochs=2, sample_weight=bad)
        with pytest.raises(FuzzyModelError, match="sample_weight"):
            ANFIS.from_fcm(X, y, n_clusters=2, sample_weight=bad)
    with pytest.raises(FuzzyModelError, match="check_sample_weight given without"):
        model.fit(X, y, epochs=2, check_sample_weight=w)
    with pytest.raises(FuzzyModelError, match="check_sample_weight has 3"):
        model.fit(X, y, epochs=2, X_check=X[:5], y_check=y[:5], check_sample_weight=w[:3])
    few = np.zeros(60)
    few[:5] = 1.0  # 5 samples of positive weight, 14 parameters
    with pytest.raises(FuzzyModelError, match="5 samples of positive weight"):
        model.fit(X, y, epochs=2, sample_weight=few)
