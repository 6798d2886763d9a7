"""Fuzzy C-Means: recovery, reproducibility, agreement with scikit-fuzzy, errors."""

import numpy as np
import pytest
import skfuzzy

from fuzzymodel import FuzzyModelError, fcm

TRUE_CENTERS = np.array([[0.0, 0.0], [5.0, 5.0], [0.0, 8.0]])


def _blobs(rng, n_per=80, spread=0.4):
    return np.vstack([c + rng.normal(0, spread, size=(n_per, 2)) for c in TRUE_CENTERS])


def test_recovers_well_separated_clusters():
    X = _blobs(np.random.default_rng(1))
    res = fcm(X, n_clusters=3, rng=np.random.default_rng(7))
    order = np.argsort(res.centers[:, 0] * 100 + res.centers[:, 1])
    truth = TRUE_CENTERS[np.argsort(TRUE_CENTERS[:, 0] * 100 + TRUE_CENTERS[:, 1])]
    # blobs of 80 points with sigma 0.4: the sample mean is off by ~0.4/sqrt(80)
    # = 0.045 per axis, and fuzzy pull between clusters adds a few hundredths.
    np.testing.assert_allclose(res.centers[order], truth, atol=0.15)
    assert res.converged
    np.testing.assert_allclose(res.memberships.sum(axis=1), 1.0, rtol=1e-12)
    # crisp-ish partition of separated blobs: coefficient near 1 (>= 1/c always)
    assert res.partition_coefficient > 0.85
    # the objective of alternating optimisation never increases (Bezdek 1981)
    assert np.all(np.diff(res.objective) <= 1e-9 * res.objective[0])


def test_reproducible_with_same_rng_and_different_with_another():
    X = _blobs(np.random.default_rng(2))
    a = fcm(X, 3, rng=np.random.default_rng(11))
    b = fcm(X, 3, rng=np.random.default_rng(11))
    c = fcm(X, 3, rng=np.random.default_rng(12))
    np.testing.assert_array_equal(a.memberships, b.memberships)
    np.testing.assert_array_equal(a.objective, b.objective)
    assert not np.array_equal(a.objective, c.objective)


def test_does_not_touch_numpy_global_generator():
    # the point of this test is NumPy's legacy global state, hence the noqa
    before = np.random.get_state()  # noqa: NPY002
    fcm(_blobs(np.random.default_rng(3)), 3, rng=np.random.default_rng(0))
    after = np.random.get_state()  # noqa: NPY002
    assert before[0] == after[0] and before[2:] == after[2:]
    np.testing.assert_array_equal(before[1], after[1])


def test_matches_scikit_fuzzy_from_same_initial_partition():
    X = _blobs(np.random.default_rng(4), spread=1.5)
    u0 = np.random.default_rng(5).random((X.shape[0], 3))
    u0 /= u0.sum(axis=1, keepdims=True)
    ours = fcm(X, 3, m=2.0, tol=1e-6, max_iter=200, initial_memberships=u0)
    cntr, u, _, d, jm, p, fpc = skfuzzy.cluster.cmeans(X.T, 3, 2.0, 1e-6, 200, init=u0.T)
    # same update equations, same float64 arithmetic up to summation order
    np.testing.assert_allclose(ours.centers, cntr, rtol=1e-9)
    np.testing.assert_allclose(ours.memberships, u.T, atol=1e-9)
    assert ours.n_iter == p
    assert ours.partition_coefficient == pytest.approx(fpc, rel=1e-9)


def test_errors_name_the_problem():
    X = _blobs(np.random.default_rng(6), n_per=2)
    rng = np.random.default_rng(0)
    with pytest.raises(FuzzyModelError, match="more than the 6 samples"):
        fcm(X, n_clusters=7, rng=rng)
    bad = X.copy()
    bad[3, 1] = np.nan
    with pytest.raises(FuzzyModelError, match="row 3, column 1"):
        fcm(bad, 2, rng=rng)
    with pytest.raises(FuzzyModelError, match="2-D"):
        fcm(X[:, 0], 2, rng=rng)
    with pytest.raises(FuzzyModelError, match="m must be > 1"):
        fcm(X, 2, m=1.0, rng=rng)
    with pytest.raises(FuzzyModelError, match="rng"):
        fcm(X, 2)
    assert issubclass(FuzzyModelError, ValueError)
