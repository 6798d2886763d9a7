"""draw_all on a small fake run directory written with the project's own writers."""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
import pytest

from fuzzymodel import ANFIS, SensorModel, normalise_rssi
from pipeline.acquisition.readlog import POSE_COLUMNS, READ_COLUMNS, ReadLog
from pipeline.evaluation import (
    CellGrid,
    DetectionComparison,
    LogDistanceModel,
    ModelMetrics,
    RhoPoints,
    RssiComparison,
    StudyMetrics,
    TruthGrid,
    error_stats,
    fig7_errors,
    fit_baselines,
    write_json_atomic,
    write_parquet_atomic,
    write_tags,
)
from pipeline.figures import FIGURES, draw_all

RANGE = (-90.0, -10.0)
GRID = CellGrid(3.0, 0.25, 30.0)
TRUTH = LogDistanceModel(p0_dbm=-45.0, n=4.0, coefficients=(8.0,))
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _poses(n, rng, t0=0.0):
    t = t0 + np.arange(n) * 0.5
    x = np.linspace(0.5, 9.5, n)
    y = 1.2 + 0.2 * np.sin(x)
    th = np.zeros(n)
    e = rng.normal(0, 0.05, (n, 3))
    return pd.DataFrame({"time_s": t, "true_x_m": x, "true_y_m": y, "true_theta_rad": th,
                         "odom_x_m": x + 3 * e[:, 0], "odom_y_m": y + 3 * e[:, 1],
                         "odom_theta_rad": th + 3 * e[:, 2], "est_x_m": x + e[:, 0],
                         "est_y_m": y + e[:, 1], "est_theta_rad": th + e[:, 2]})[list(POSE_COLUMNS)]


def _reads(poses, tags_xyz, rng):
    """One attempt per pose and tag, antenna at the robot pose, closed-form RSSI."""
    rows = []
    for _, p in poses.iterrows():
        for k, tag in enumerate(tags_xyz):
            dx, dy = tag[0] - p.true_x_m, tag[1] - p.true_y_m
            d = float(np.hypot(dx, dy))
            a = float(np.arctan2(dy, dx) - p.true_theta_rad)
            ex, ey = tag[0] - p.est_x_m, tag[1] - p.est_y_m
            rssi = float(TRUTH.predict_dbm(d, a))
            read = rssi > -75 and rng.random() < 0.9
            rows.append({
                "time_s": p.time_s, "cycle": int(_), "antenna": 0, "tag_id": f"T{k}",
                "read": read, "rssi_dbm": rssi + rng.normal(0, 1) if read else np.nan,
                "frequency_hz": 866.3e6, "phase_rad": rng.uniform(0, 2 * np.pi) if read else np.nan,
                "doppler_hz": 0.0 if read else np.nan, "seen_count": int(read),
                "true_ant_x_m": p.true_x_m, "true_ant_y_m": p.true_y_m, "true_ant_z_m": 1.0,
                "true_ant_yaw_rad": p.true_theta_rad, "est_ant_x_m": p.est_x_m,
                "est_ant_y_m": p.est_y_m, "est_ant_z_m": 1.0, "est_ant_yaw_rad": p.est_theta_rad,
                "d_true_m": d, "alpha_true_rad": a, "d_est_m": float(np.hypot(ex, ey)),
                "alpha_est_rad": float(np.arctan2(ey, ex) - p.est_theta_rad),
                "gain_db": (rssi - 15.0) / 2, "tag_power_dbm": (rssi + 5) / 2,
                "rx_power_dbm": rssi, "powered": rssi > -75, "in_range": True})
    return pd.DataFrame(rows)[list(READ_COLUMNS)]


def _sensor(reads):
    rd = reads[reads["read"] & (reads["d_est_m"] < 3.0)]
    X = rd[["d_est_m", "alpha_est_rad"]].to_numpy()
    y = normalise_rssi(rd["rssi_dbm"], RANGE)
    ssm = ANFIS.from_fcm(X, y, n_clusters=3, rng=np.random.default_rng(0))
    ssm.fit(X, y, epochs=3)
    D, A = GRID.centre_mesh()
    Xc = np.column_stack([D.ravel(), A.ravel()])
    tdm = ANFIS.from_fcm(Xc, np.exp(-D.ravel() / 2), n_clusters=3, rng=np.random.default_rng(0))
    return SensorModel(ssm, tdm, RANGE)


def _metrics(names):
    rng = np.random.default_rng(4)
    models = {}
    for i, n in enumerate(names):
        r = rng.normal(-60, 5, 50)
        models[n] = ModelMetrics(
            rssi=RssiComparison(error_stats(r + 2 * (i + 1), r), 50, 3.0),
            detection=DetectionComparison(error_stats(rng.random(20), rng.random(20)), 20, 5,
                                          0.1 * (i + 1), 0.05, 0.2, 100),
            rho=None, fig7=None)
    return StudyMetrics(models=models, localisation_split=None, truth={})


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    rng = np.random.default_rng(0)
    run = tmp_path_factory.mktemp("run")
    tags = np.array([[1.0, 0.0, 1.0], [3.0, 2.4, 1.0], [5.0, 0.0, 0.5], [7.0, 2.4, 1.5],
                     [9.0, 0.0, 1.0]])
    write_tags(run / "scene" / "tags.parquet", [f"T{k}" for k in range(5)], tags)
    walls = np.array([[[0, 0], [10, 0]], [[0, 2.4], [10, 2.4]], [[0, 0], [0, 2.4]],
                      [[10, 0], [10, 2.4]]], float)
    np.savez(run / "scene" / "floorplan.npz", heights_m=np.array([1.0]),
             route_m=np.array([[0.5, 1.2], [9.5, 1.2]]), segments_z100cm=walls)
    poses = _poses(40, rng)
    eval_poses = _poses(20, rng, t0=100.0)
    reads = _reads(poses, tags, rng)
    eval_reads = _reads(eval_poses, tags, rng)
    ReadLog(reads, poses).write(run)
    ReadLog(eval_reads, eval_poses).write(run, prefix="eval_")
    sensor = _sensor(reads)
    sensor.save(run / "models" / "sensor.json")
    fit_baselines(reads, RANGE, GRID).save(run / "models" / "baselines.json")
    # truth grid from arrays (a TruthGrid is a plain dataclass; the values are synthetic)
    D, A = GRID.centre_mesh()
    n_att = rng.integers(0, 40, GRID.shape)
    p = np.where(n_att > 0, np.clip(1.2 - D / 2.5, 0, 1), np.nan)
    TruthGrid(GRID, n_att, np.round(np.nan_to_num(p) * n_att).astype(int), n_att // 2, p,
              np.where(n_att > 0, TRUTH.predict_dbm(D, A), np.nan), 0.0).save(
        run / "truth" / "detection_grid.npz")
    d = np.linspace(0.25, 3.0, 8)
    a = np.radians(np.linspace(-90, 90, 9))
    Dg, Ag = np.meshgrid(d, a, indexing="ij")
    pose = np.array([2.0, 1.2, 1.0, 0.0, 0.0, 0.0])
    pts = np.column_stack([2.0 + (Dg * np.cos(Ag)).ravel(), 1.2 + (Dg * np.sin(Ag)).ravel(),
                           np.ones(Dg.size)])
    rho = np.clip(1 - Dg / 3, 0, 1).ravel() * (np.cos(Ag).ravel() > 0.3)
    RhoPoints(pose, pts, Dg.ravel(), Ag.ravel(), np.full(Dg.size, -40.0), rho,
              (rho > 0).astype(float), rho, RANGE, Dg.shape).save(
        run / "truth" / "rho_points_00.npz")
    fig7_errors(eval_reads, pd.read_parquet(run / "scene" / "tags.parquet"), sensor,
                pose_times_s=eval_poses["time_s"]).write_table(run / "truth" / "fig7_errors.parquet")
    write_json_atomic(_metrics(["anfis", "anfis_truepose", "baselines"]).to_dict(),
                      run / "metrics.json")
    # per-site errors as the evaluation writes them (SiteComparison.per_site); synthetic
    xs = np.arange(0.25, 10.0, 0.5)
    site = pd.DataFrame({"x_m": np.r_[xs, xs], "y_m": np.r_[np.full(xs.size, 0.005),
                                                           np.full(xs.size, 2.395)],
                         "z_m": 1.0, "nx": 0.0, "ny": np.r_[np.ones(xs.size), -np.ones(xs.size)]})
    site["site"] = np.arange(len(site))
    site["material"] = "brick"
    site["n_poses"] = 3
    site["rho_true_mean"] = 0.2
    site["rho_model_mean"] = 0.2 + 0.1 * np.sin(site["x_m"])
    site["rho_error_mean"] = site["rho_model_mean"] - site["rho_true_mean"]
    site["rho_abs_error_mean"] = site["rho_error_mean"].abs()
    site["obstructed_fraction"] = (site["x_m"] > 8).astype(float)
    write_parquet_atomic(site, run / "truth" / "site_errors.parquet")
    # downstream errors as the downstream stage writes them; synthetic
    write_parquet_atomic(pd.DataFrame({"model": np.repeat(["anfis", "oracle"], 8),
                                       "tag_id": [f"E{i:02d}" for i in range(8)] * 2,
                                       "error_m": np.r_[rng.gamma(2, 0.3, 8), rng.gamma(2, 0.1, 8)]}),
                         run / "downstream" / "tag_errors.parquet")
    t = np.arange(0, 40, 0.25)
    write_parquet_atomic(pd.DataFrame({"model": np.repeat(["anfis"], len(t)), "t_s": t,
                                       "error_m": 5 * np.exp(-t / 5) + 0.2}),
                         run / "downstream" / "robot_error.parquet")
    # a planar field written by propagation.RssiField.save (values: a closed-form falloff)
    from propagation import RssiField

    x = np.linspace(0.05, 9.95, 100)
    y = np.linspace(0.05, 2.35, 24)
    X, Y = np.meshgrid(x, y)
    gain = 10 ** ((-40 - 20 * np.log10(np.hypot(X - 2.0, Y - 1.2) + 0.1)) / 10)
    gain[0, :5] = 0.0  # no ray arrived
    RssiField(antenna_pose=pose, frequency_hz=865e6, plane_gain=gain,
              plane_centers_m=np.stack([X, Y, np.ones_like(X)], axis=-1),
              wall_gain=np.zeros(0), wall_centers_m=np.zeros((0, 3)),
              wall_normals=np.zeros((0, 3)), cell_size_m=0.1, plane_height_m=1.0,
              samples_per_tx=1000, max_depth=3).save(run / "fields" / "field_00.npz")
    return run


@pytest.mark.parallel
def test_draw_all_writes_every_figure_and_side_by_side_the_same_bytes(run_dir, tmp_path,
                                                                      monkeypatch):
    # --basetemp keeps them for a look; otherwise tmp_path. (How fast is bench's business:
    # a wall-clock bound here would assert a fact of the machine, not of the code.)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")  # as the figures stage runs
    out = tmp_path / "figs"
    two = draw_all(run_dir, out_dir=out, workers=2)  # side by side, forked
    names = {p.stem for p in two}
    assert names == set(FIGURES)
    for name in FIGURES:
        png, pdf = out / f"{name}.png", out / f"{name}.pdf"
        assert png.read_bytes()[:8] == PNG_MAGIC, name
        assert png.stat().st_size > 5000, name
        assert pdf.read_bytes()[:5] == b"%PDF-", name
    assert not list(out.glob(".*tmp*"))  # no temporary files left
    # drawn one after the other in this process: the same bytes (every PNG: a figure drawn
    # differently in a forked process shows in its pixels; one PDF: its dates and fonts)
    from pipeline.figures.common import FigureOutput

    one = draw_all(run_dir, out_dir=tmp_path / "one", workers=1,
                   output=FigureOutput(formats=("png",)))
    assert [p.name for p in one] == [p.name for p in two if p.suffix == ".png"]
    for a in one:
        assert a.read_bytes() == (out / a.name).read_bytes(), a.name
    pdf = draw_all(run_dir, out_dir=tmp_path / "pdf", names=["ssm_surface"], workers=1,
                   output=FigureOutput(formats=("pdf",)))
    assert [p.read_bytes() for p in pdf] == [(out / "ssm_surface.pdf").read_bytes()]


def test_draw_all_skips_figures_with_missing_inputs(run_dir, tmp_path, caplog):
    partial = tmp_path / "partial"
    partial.mkdir()
    for rel in ("models/sensor.json", "poses.parquet"):
        (partial / rel).parent.mkdir(parents=True, exist_ok=True)
        (partial / rel).write_bytes((run_dir / rel).read_bytes())
    with caplog.at_level(logging.WARNING, logger="pipeline.figures"):
        paths = draw_all(partial)
    assert {p.stem for p in paths} == {"ssm_surface", "tdm_surface", "mcl_error"}
    assert all(p.parent == partial / "figures" for p in paths)
    assert "figure baselines skipped" in caplog.text and "metrics.json" in caplog.text


def test_fig7_falls_back_to_computing_from_reads(run_dir, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(run_dir, copy)
    (copy / "truth" / "fig7_errors.parquet").unlink()
    paths = draw_all(copy, names=["fig7_error"])
    assert [p.suffix for p in paths] == [".png", ".pdf"]


def test_draw_all_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        draw_all(tmp_path / "nope")
    with pytest.raises(ValueError, match="unknown figure.*'fig99'"):
        draw_all(tmp_path, names=["fig99"])


@pytest.mark.parallel
def test_a_failing_figure_fails_draw_all_from_a_worker(run_dir, tmp_path, monkeypatch):
    def broken(run_dir, out_dir=None):
        raise RuntimeError("broken figure")

    monkeypatch.setitem(FIGURES, "baselines", broken)
    with pytest.raises(RuntimeError, match="broken figure"):  # two figures: two workers
        draw_all(run_dir, out_dir=tmp_path / "x", names=["scene_top_view", "baselines"],
                 workers=2)
