"""ANFIS construction, step-size rule, persistence, robustness and bad input."""

import json

import numpy as np
import pytest

from fuzzymodel import ANFIS, FuzzyModelError, FuzzyModelFileError, gbellmf, update_step_size


def _data(n=300, seed=0):
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(0.2, 5.0, n), rng.uniform(-np.pi, np.pi, n)])
    y = -40.0 - 20.0 * np.log10(X[:, 0]) - 3.0 * X[:, 1] ** 2
    return X, y


def test_grid_partition_is_genfis1_like():
    X, _ = _data()
    model = ANFIS.from_grid(X, n_mfs=[3, 4], mf="bell")
    assert model.n_rules == 12 and model.premise.mf_params.shape == (7, 3)
    # bell MFs evenly spaced over each input's range, a = half spacing, b = 2,
    # so neighbours cross at 0.5 exactly halfway (genfis1; Jang 1993 Sec. VI)
    p = model.premise.mf_params[model.premise.mf_input == 1]
    np.testing.assert_allclose(p[:, 2], np.linspace(0, 1, 4), atol=1e-12)
    np.testing.assert_allclose(p[:, 0], 0.5 / 3, rtol=1e-12)
    np.testing.assert_allclose(p[:, 1], 2.0)
    mid = 0.5 * (p[0, 2] + p[1, 2])
    assert gbellmf(mid, *p[0]) == pytest.approx(0.5) == gbellmf(mid, *p[1])
    # every combination of MFs is one rule, each exactly once
    assert len({tuple(r) for r in model.premise.rules}) == 12
    g = ANFIS.from_grid(X, n_mfs=2, mf="gauss")
    s = g.premise.mf_params[0]
    assert np.exp(-0.5 * (0.5 / s[0]) ** 2) == pytest.approx(0.5)  # gauss crossover 0.5 too


def test_fcm_initial_fis_is_genfis3_like():
    X, y = _data()
    model = ANFIS.from_fcm(X, y, n_clusters=3, rng=np.random.default_rng(4))
    assert model.n_rules == 3 and model.mf_type == "gauss"
    # one MF per input per cluster, rule k uses MF k of each input
    assert model.premise.mf_params.shape == (6, 2)
    assert np.all(model.premise.mf_params[:, 0] > 0)
    # consequents already fitted by LS: better than predicting the mean
    rmse = np.sqrt(np.mean((model.predict(X) - y) ** 2))
    assert rmse < 0.5 * np.std(y)
    again = ANFIS.from_fcm(X, y, n_clusters=3, rng=np.random.default_rng(4))
    np.testing.assert_array_equal(again.premise.mf_params, model.premise.mf_params)


def test_fit_improves_fcm_model_and_keeps_best_checking_epoch():
    X, y = _data(400)
    Xc, yc = _data(200, seed=1)
    model = ANFIS.from_fcm(X, y, n_clusters=4)
    h = model.fit(X, y, epochs=40, X_check=Xc, y_check=yc, step_size=0.05)
    assert h.check_rmse[h.best_epoch] == np.min(h.check_rmse)
    assert h.train_rmse[h.best_epoch] < h.train_rmse[0]
    got = np.sqrt(np.mean((model.predict(Xc) - yc) ** 2))
    assert got == pytest.approx(h.check_rmse[h.best_epoch], rel=1e-9)
    tr = model.provenance["training"]
    assert tr["epochs"] == 40 and tr["best_epoch"] == h.best_epoch


def test_step_size_rule_of_jang():
    # rule 1: four consecutive reductions -> +10 %
    assert update_step_size([5, 4, 3, 2, 1], 0.1) == pytest.approx(0.11)
    # rule 2: two consecutive (increase, reduction) combinations -> -10 %
    assert update_step_size([1, 2, 1, 2, 1], 0.1) == pytest.approx(0.09)
    assert update_step_size([2, 1, 2, 1, 2], 0.1) == pytest.approx(0.09)
    # otherwise unchanged; too short a history changes nothing
    assert update_step_size([5, 4, 3, 3, 2], 0.1) == 0.1
    assert update_step_size([4, 3, 2, 1], 0.1) == 0.1


def test_save_load_round_trip_is_exact_and_readable(tmp_path):
    X, y = _data()
    model = ANFIS.from_grid(X, n_mfs=3, mf="bell", input_names=["d_m", "alpha_rad"])
    model.fit(X, y, epochs=5)
    path = model.save(tmp_path / "m" / "ssm.json")
    back = ANFIS.load(path)
    # JSON floats round-trip exactly (repr), so predictions agree bit for bit
    np.testing.assert_array_equal(back.predict(X), model.predict(X))
    doc = json.loads(path.read_text())
    assert doc["inputs"][0]["name"] == "d_m"
    assert set(doc["rules"][0]["if"]) == {"d_m", "alpha_rad"}
    assert doc["provenance"]["training"]["epochs"] == 5
    assert "package_version" in doc["provenance"]["training"]
    # the input-unit view of rule 0 reproduces its output in input units
    r = doc["rules"][0]["then_in_input_units"]
    x0 = X[0]
    u0 = (x0 - model.input_offset) / model.input_scale
    lin_u = model.consequents[0, :-1] @ u0 + model.consequents[0, -1]
    assert np.dot(r["coefficients"], x0) + r["constant"] == pytest.approx(lin_u, rel=1e-10)
    assert not list(path.parent.glob(".*.tmp"))  # atomic write leaves no temp file


def test_load_errors_name_file_and_key(tmp_path):
    X, y = _data()
    model = ANFIS.from_grid(X, 2)
    path = model.save(tmp_path / "a.json")
    doc = json.loads(path.read_text())
    doc["rules"][1]["if"]["x1"] = "mf9"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(FuzzyModelFileError, match=r"bad.json: rules\[1\].if: input 'x1' has no MF 'mf9'"):
        ANFIS.load(bad)
    doc = json.loads(path.read_text())
    doc["inputs"][0]["colour"] = "red"
    bad.write_text(json.dumps(doc))
    with pytest.raises(FuzzyModelFileError, match=r"inputs\[0\]: unknown key 'colour'"):
        ANFIS.load(bad)
    bad.write_text("{not json")
    with pytest.raises(FuzzyModelFileError, match="bad.json: not valid JSON"):
        ANFIS.load(bad)


def test_bad_input_raises_named_errors():
    X, y = _data(100)
    model = ANFIS.from_grid(X, 2)
    Xn = X.copy()
    Xn[7, 0] = np.inf
    with pytest.raises(FuzzyModelError, match="row 7, column 0"):
        model.fit(Xn, y)
    yn = y.copy()
    yn[3] = np.nan
    with pytest.raises(FuzzyModelError, match="y holds 1 non-finite"):
        model.fit(X, yn)
    with pytest.raises(FuzzyModelError, match="y has 99 samples but the inputs have 100"):
        model.fit(X, y[:-1])
    with pytest.raises(FuzzyModelError, match="3 features"):
        model.predict(np.ones((4, 3)))
    with pytest.raises(FuzzyModelError, match="X_check has 1 features"):
        model.fit(X, y, X_check=X[:, :1], y_check=y)
    with pytest.raises(FuzzyModelError, match="both X_check and y_check"):
        model.fit(X, y, X_check=X)
    big = ANFIS.from_grid(X, 4)  # 16 rules: 24 + 48 = 72 parameters
    with pytest.raises(FuzzyModelError, match="50 samples, fewer than the model's 72 parameters"):
        big.fit(X[:50], y[:50])
    with pytest.raises(FuzzyModelError, match="more than the 5 samples"):
        ANFIS.from_fcm(X[:5], y[:5], n_clusters=6)
    with pytest.raises(FuzzyModelError, match="unknown mf 'tri'"):
        ANFIS.from_grid(X, 2, mf="tri")


def test_rank_deficient_least_squares_does_not_blow_up():
    rng = np.random.default_rng(5)
    x = rng.uniform(0, 1, 200)
    # duplicated input and an exactly collinear one: the LS regressors are rank deficient
    X = np.column_stack([x, x, 2.0 * x + 1.0])
    y = np.sin(3 * x)
    model = ANFIS.from_grid(X, n_mfs=2, mf="gauss")
    h = model.fit(X, y, epochs=20, step_size=0.05)
    assert np.all(np.isfinite(h.train_rmse))
    # bounded coefficients (min-norm solution, no 1/0 blow-up) and a good fit of a
    # function of x alone: sin(3x) on [0, 1] with 8 local linear rules.
    assert np.abs(model.consequents).max() < 1e3
    assert h.train_rmse[h.best_epoch] < 0.05
    # a constant input column (zero range) is accepted as well
    Xc = np.column_stack([x, np.full_like(x, 2.0)])
    h2 = ANFIS.from_grid(Xc, 2).fit(Xc, y, epochs=5)
    assert np.all(np.isfinite(h2.train_rmse))


def test_predict_far_outside_training_range_stays_finite():
    X, y = _data()
    model = ANFIS.from_grid(X, 3, mf="gauss")
    model.fit(X, y, epochs=3)
    # every Gaussian underflows at d = 1e4 m; soft-max of log-strengths keeps it defined
    out = model.predict(np.array([[1e4, 0.0], [-1e4, 100.0]]))
    assert np.all(np.isfinite(out))
