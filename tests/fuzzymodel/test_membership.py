"""Membership functions: closed-form values and derivatives against finite differences."""

import numpy as np
import pytest

from fuzzymodel import (
    ANFIS,
    FuzzyModelError,
    gaussmf,
    gaussmf_grad,
    gbellmf,
    gbellmf_grad,
    log_membership,
    membership,
    membership_grad,
)


def test_gauss_closed_form():
    # mu(c) = 1, mu(c +- sigma) = exp(-1/2) exactly (definition); 1e-15 = rounding.
    x = np.array([2.0, 2.5, 1.5])
    np.testing.assert_allclose(gaussmf(x, 0.5, 2.0), [1.0, np.exp(-0.5), np.exp(-0.5)], rtol=1e-15)


def test_bell_closed_form():
    # Jang 1993 eq. 18: mu(c) = 1, mu(c +- a) = 1/2 for every b, mu(c + 2a) = 1/(1 + 4^b).
    for b in (0.7, 2.0, 5.0):
        x = np.array([3.0, 4.0, 2.0, 5.0])
        expect = [1.0, 0.5, 0.5, 1.0 / (1.0 + 4.0**b)]
        np.testing.assert_allclose(gbellmf(x, 1.0, b, 3.0), expect, rtol=1e-14)


def _fd(fun, params, h=1e-6):
    # central differences, one parameter at a time
    out = []
    for k in range(len(params)):
        p1, p2 = list(params), list(params)
        p1[k] += h
        p2[k] -= h
        out.append((fun(*p1) - fun(*p2)) / (2 * h))
    return np.stack(out, axis=-1)


@pytest.mark.parametrize(
    ("fun", "grad", "params"),
    [(gaussmf, gaussmf_grad, (0.7, 0.3)), (gbellmf, gbellmf_grad, (0.8, 1.7, -0.2)),
     (gbellmf, gbellmf_grad, (1.3, 0.6, 0.4))],
)
def test_mf_derivatives_match_finite_differences(fun, grad, params):
    x = np.linspace(-3, 3, 37) + 0.013  # avoid x == c where d/db has a log singularity
    num = _fd(lambda *p: fun(x, *p), params)
    # central-difference truncation O(h^2 f''') ~ 1e-12 and rounding eps/h ~ 1e-10:
    # 1e-7 absolute is far above both and far below any real derivative error.
    np.testing.assert_allclose(grad(x, *params), num, atol=1e-7)


def test_generic_interface_matches_named_functions():
    x = np.linspace(-2, 2, 9)
    np.testing.assert_allclose(membership("bell", x, [0.5, 2.0, 0.1]), gbellmf(x, 0.5, 2.0, 0.1))
    np.testing.assert_allclose(membership_grad("gauss", x, [0.5, 0.1]), gaussmf_grad(x, 0.5, 0.1))


def test_log_membership_stays_finite_where_mu_underflows():
    # exp(-0.5 * 1e4) underflows to 0, the log does not: ANFIS relies on this.
    val = log_membership("gauss", np.array([100.0]), [1.0, 0.0])
    assert np.isfinite(val).all() and val[0] == pytest.approx(-5000.0)


def test_unknown_family_is_named():
    with pytest.raises(FuzzyModelError, match="triangle"):
        membership("triangle", 0.0, [1.0, 2.0])
    with pytest.raises(FuzzyModelError, match="last axis 3"):
        membership("bell", 0.0, [1.0, 2.0])


@pytest.mark.parametrize("mf", ["gauss", "bell"])
def test_anfis_premise_gradient_matches_finite_differences(mf):
    rng = np.random.default_rng(3)
    X = rng.uniform(-1, 1, size=(60, 2))
    y = np.sin(2 * X[:, 0]) * X[:, 1] + 0.3
    model = ANFIS.from_grid(X, n_mfs=3, mf=mf)
    model.fit(X, y, epochs=1)  # non-trivial consequents from one LS step
    p = model.premise.mf_params
    p += rng.normal(0, 0.05, size=p.shape)  # move off the symmetric grid
    analytic = model.premise_gradient(X, y)

    def err():
        r = y - model.predict(X)
        return r @ r

    assert analytic.error == pytest.approx(err(), rel=1e-12)
    h = 1e-6
    num = np.empty_like(p)
    for idx in np.ndindex(p.shape):
        old = p[idx]
        p[idx] = old + h
        e1 = err()
        p[idx] = old - h
        e2 = err()
        p[idx] = old
        num[idx] = (e1 - e2) / (2 * h)
    # central differences: truncation ~h^2 and rounding ~eps*E/h ~ 1e-10*E;
    # rtol 1e-5 of the largest component leaves a wide margin over both.
    np.testing.assert_allclose(analytic.gradient, num, rtol=1e-5, atol=1e-5 * np.abs(num).max())
