"""ANFIS hybrid learning against the examples of Jang (1993), IEEE Trans. SMC 23(3).

Measured on a 2-core CPU (see the final report for the numbers):
Example 1 RMSE 0.105 (LS only) -> 0.007; Example 2 APE 0.03 % / 0.19 %
(paper 0.043 % / 1.066 %); Example 4 checking NDEI 0.0115 (paper 0.007).
"""

import numpy as np
import pytest

from fuzzymodel import ANFIS


def _ape_percent(y, yhat):
    # average percentage error, Jang 1993 eq. 21
    return 100.0 * np.mean(np.abs(y - yhat) / np.abs(y))


def test_example1_sinc_two_inputs():
    # z = sinc(x) sinc(y) = sin(x)/x * sin(y)/y on an 11 x 11 grid over [-10, 10]^2,
    # 4 bell MFs per input: 16 rules, 24 premise + 48 consequent = 72 parameters.
    g = np.linspace(-10.0, 10.0, 11)
    X = np.array(np.meshgrid(g, g, indexing="ij")).reshape(2, -1).T
    z = np.sinc(X[:, 0] / np.pi) * np.sinc(X[:, 1] / np.pi)
    model = ANFIS.from_grid(X, n_mfs=4, mf="bell")
    assert (model.n_rules, model.n_parameters) == (16, 72)
    h = model.fit(X, z, epochs=250, step_size=0.01)
    ls_only = h.train_rmse[0]  # epoch 0 = least squares on the initial premise
    best = h.train_rmse[h.best_epoch]
    # Jang's point: tuning the premise beats consequent-only LS by a wide margin.
    # Measured 0.105 -> 0.0069 (15x); "well below" asserted as at least 5x.
    assert best < ls_only / 5.0
    # the kept model is the best epoch, and predict() reproduces its RMSE
    assert np.sqrt(np.mean((model.predict(X) - z) ** 2)) == pytest.approx(best, rel=1e-9)
    assert h.step_size.shape == (250,) and np.all(np.isnan(h.check_rmse))


def _example2_data(points):
    P = np.array(np.meshgrid(points, points, points, indexing="ij")).reshape(3, -1).T
    return P, (1.0 + P[:, 0] ** 0.5 + P[:, 1] ** -1.0 + P[:, 2] ** -1.5) ** 2


def test_example2_three_input_nonlinear_function():
    Xt, yt = _example2_data(np.arange(1.0, 7.0))  # 216 training points on {1..6}^3
    Xc, yc = _example2_data(np.arange(1.5, 6.0))  # 125 checking points on {1.5..5.5}^3
    model = ANFIS.from_grid(Xt, n_mfs=2, mf="bell")
    assert (model.n_rules, model.n_parameters) == (8, 50)
    model.fit(Xt, yt, epochs=200, step_size=0.1)
    ape_train = _ape_percent(yt, model.predict(Xt))
    ape_check = _ape_percent(yc, model.predict(Xc))
    # Paper: 0.043 % training, 1.066 % checking. Measured ~0.03 % / ~0.2 %. The
    # bounds (0.5 %, 3 %) are ~10x and ~3x the paper's, "same order" with room
    # for different initial step sizes and epoch counts, and still fail for
    # consequent-only LS (one epoch: 4.1 % / 5.2 %).
    assert ape_train < 0.5
    assert ape_check < 3.0


def mackey_glass(t_end: int, tau: float = 17.0, dt: float = 0.1, x0: float = 1.2) -> np.ndarray:
    """x(t) at integer t = 0..t_end of dx/dt = 0.2 x(t-tau)/(1 + x(t-tau)^10) - 0.1 x(t).

    RK4 with step dt, x(0) = x0, x(t < 0) = 0 (Jang 1993, eq. 22); the delayed
    term at the half step is the mean of its neighbours on the dt grid.
    """
    n = int(round(t_end / dt))
    lag = int(round(tau / dt))
    x = np.zeros(n + 1)
    x[0] = x0

    def rate(xt, xl):
        return 0.2 * xl / (1.0 + xl**10) - 0.1 * xt

    for k in range(n):
        xl0 = x[k - lag] if k >= lag else 0.0
        xl1 = x[k - lag + 1] if k + 1 >= lag else 0.0
        xlh = 0.5 * (xl0 + xl1)
        k1 = rate(x[k], xl0)
        k2 = rate(x[k] + 0.5 * dt * k1, xlh)
        k3 = rate(x[k] + 0.5 * dt * k2, xlh)
        k4 = rate(x[k] + dt * k3, xl1)
        x[k + 1] = x[k] + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x[:: int(round(1 / dt))]


def test_example4_mackey_glass_prediction():
    x = mackey_glass(1123)
    t = np.arange(118, 1118)
    X = np.column_stack([x[t - 18], x[t - 12], x[t - 6], x[t]])
    y = x[t + 6]
    Xt, yt, Xc, yc = X[:500], y[:500], X[500:], y[500:]
    model = ANFIS.from_grid(Xt, n_mfs=2, mf="bell")
    assert (model.n_rules, model.n_parameters) == (16, 104)
    h = model.fit(Xt, yt, epochs=100, X_check=Xc, y_check=yc, step_size=0.05)
    ndei = np.sqrt(np.mean((model.predict(Xc) - yc) ** 2)) / np.std(yc)
    assert ndei == pytest.approx(h.check_rmse[h.best_epoch] / np.std(yc), rel=1e-9)
    # Paper: NDEI 0.007 after 500 epochs. Measured 0.0115 here after 100 (the best
    # epoch comes early; 500 epochs do not improve it). The gap is the series,
    # not the learning rule: the same code on the windows t = 1118..2117 and
    # 2118..3117 of this series gives 0.0075 and 0.0071, and holding x(t - tau)
    # constant within each RK4 step gives 0.0094 on this window. Bound 0.014:
    # 2x the paper for that series spread, 20 % above our 0.0115, and below the
    # 0.0159 of consequent-only LS (epoch 0), so the premise tuning must work.
    assert ndei < 0.014
    assert h.check_rmse[h.best_epoch] < h.check_rmse[0]  # training helped the checking set
