"""RFID SensorModel: normalisation, clipping, broadcasting, rho = fs * fT, JSON."""

import numpy as np
import pytest

from fuzzymodel import (
    ANFIS,
    FuzzyModelError,
    FuzzyModelFileError,
    SensorModel,
    denormalise_rssi,
    normalise_rssi,
    wrap_angle,
)

RANGE = (-75.0, -35.0)


@pytest.fixture(scope="module")
def sensor():
    rng = np.random.default_rng(0)
    d = rng.uniform(0.3, 6.0, 600)
    a = rng.uniform(-np.pi, np.pi, 600)
    X = np.column_stack([d, a])
    rssi = -40.0 - 20.0 * np.log10(d) - 8.0 * (1 - np.cos(a)) + rng.normal(0, 1, 600)
    detect = 1.0 / (1.0 + np.exp(3.0 * (d - 4.0))) * (np.cos(a) > -0.2)
    ssm = ANFIS.from_fcm(X, normalise_rssi(rssi, RANGE), n_clusters=4, input_names=["d_m", "alpha_rad"])
    ssm.fit(X, normalise_rssi(rssi, RANGE), epochs=10)
    tdm = ANFIS.from_grid(X, 3, mf="gauss", input_names=["d_m", "alpha_rad"])
    tdm.fit(X, detect, epochs=10)
    return SensorModel(ssm=ssm, tdm=tdm, rssi_range_dbm=RANGE)


def test_normalise_round_trip_and_clip():
    r = np.array([-90.0, -75.0, -55.0, -35.0, -20.0])
    np.testing.assert_allclose(normalise_rssi(r, RANGE), [0, 0, 0.5, 1, 1])
    raw = normalise_rssi(r, RANGE, clip=False)
    np.testing.assert_allclose(denormalise_rssi(raw, RANGE), r, rtol=1e-14)
    with pytest.raises(FuzzyModelError, match="lo < hi"):
        normalise_rssi(r, (-30.0, -80.0))


def test_wrap_angle_half_open_interval():
    w = wrap_angle([np.pi, -np.pi, 3 * np.pi, 0.1 - 2 * np.pi])
    np.testing.assert_allclose(w, [np.pi, np.pi, np.pi, 0.1], atol=1e-12)
    # one ulp above pi: np.mod rounds pi - a up to 2 pi, which would give -pi
    just_above = np.nextafter(np.pi, 4.0)
    w = wrap_angle(np.array([just_above, -just_above]))
    assert np.all((w > -np.pi) & (w <= np.pi)), w
    assert np.isscalar(wrap_angle(3 * np.pi)) and wrap_angle(3 * np.pi) == np.pi


def test_wrap_angle_of_an_angle_does_not_depend_on_its_batch():
    # an in-range angle comes back bit for bit, whether or not its batch needed wrapping
    # (pi - mod(pi - a, 2 pi) moves 0.3 by 1.7e-16 and 1e-17 to 0)
    a = np.array([0.3, -2.9, 1e-17])
    assert np.array_equal(wrap_angle(a), a)
    assert np.array_equal(wrap_angle(np.append(a, 7.0))[:3], a)


def test_ranges_broadcasting_and_rho(sensor):
    d = np.linspace(0.1, 10.0, 7)[:, None]  # beyond the training range on both ends
    a = np.linspace(-np.pi, np.pi, 5)[None, :]
    fs, ft, rho = sensor.fs(d, a), sensor.fT(d, a), sensor.rho(d, a)
    assert fs.shape == ft.shape == rho.shape == (7, 5)
    assert fs.min() >= 0 and fs.max() <= 1 and ft.min() >= 0 and ft.max() <= 1
    np.testing.assert_allclose(rho, fs * ft, rtol=1e-15)
    np.testing.assert_allclose(sensor.fs_dbm(d, a), RANGE[0] + fs * (RANGE[1] - RANGE[0]))
    # scalar in, scalar-shaped out; alpha and alpha + 2 pi are the same bearing
    assert np.shape(sensor.rho(1.0, 0.0)) == ()
    assert sensor.fs(2.0, 0.3 + 2 * np.pi) == pytest.approx(sensor.fs(2.0, 0.3), rel=1e-12)
    # the learned RSSI falls with distance in front of the antenna (log-distance truth)
    assert sensor.fs_dbm(0.5, 0.0) > sensor.fs_dbm(4.0, 0.0) + 10.0


def test_save_load_round_trip(sensor, tmp_path):
    path = sensor.save(tmp_path / "sensor.json")
    back = SensorModel.load(path)
    d, a = np.meshgrid(np.linspace(0.3, 6, 9), np.linspace(-3, 3, 4))
    np.testing.assert_array_equal(back.rho(d, a), sensor.rho(d, a))
    assert back.rssi_range_dbm == RANGE
    path.write_text(path.read_text().replace('"rssi_range_dbm"', '"rssi_span"'))
    with pytest.raises(FuzzyModelFileError, match="sensor.json: missing key 'rssi_range_dbm'"):
        SensorModel.load(path)


def test_needs_two_input_models(sensor):
    X = np.random.default_rng(1).random((50, 3))
    three = ANFIS.from_grid(X, 2)
    with pytest.raises(FuzzyModelError, match="tdm must have 2 inputs"):
        SensorModel(sensor.ssm, three, RANGE)
