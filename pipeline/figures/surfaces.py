"""Model surfaces over (d, alpha): chapter Figs. 4 and 5, and learned vs truth with the difference.

Inputs (run directory):

- ``models/sensor.json`` (``fuzzymodel.SensorModel``): Figs. 4 (SSM) and 5 (TDM);
- ``truth/detection_grid.npz`` (:meth:`pipeline.evaluation.TruthGrid.save`) and
  ``models/sensor.json``: learned vs truth for RSSI [dBm] and detection probability.
  Model values come from the file's ``anfis__fs_dbm`` / ``anfis__fT`` arrays when
  present, else from evaluating the saved model at the cell centres.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline import runfiles
from pipeline.figures.common import deg, load_sensor, new_figure, require, save_figure
from scenes.fileio import read_npz

__all__ = ["fig_learned_vs_truth_detection", "fig_learned_vs_truth_rssi", "fig_ssm_surface",
           "fig_tdm_surface"]

_N = 61  # surface resolution per axis


def _input_box(model) -> tuple[float, float]:
    """Distance span [m] the model was trained on (its input normalisation)."""
    lo = float(model.input_offset[0])
    hi = lo + float(model.input_scale[0])
    return max(lo, 0.05), max(hi, lo + 0.5)


def _surface(run_dir, out_dir, name: str, which: str) -> list[Path]:
    sensor = load_sensor(run_dir, "anfis")
    model = sensor.ssm if which == "fs" else sensor.tdm
    d0, d1 = _input_box(model)
    d = np.linspace(d0, d1, _N)
    a = np.linspace(-np.pi, np.pi, _N)
    D, A = np.meshgrid(d, a, indexing="ij")
    Z = sensor.fs(D, A) if which == "fs" else sensor.fT(D, A)
    fig = new_figure(10.5, 4.2)
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax3.plot_surface(D, deg(A), Z, cmap="viridis", linewidth=0, antialiased=False,
                     rasterized=True)
    ax3.set_xlabel("d [m]")
    ax3.set_ylabel("alpha [deg]")
    zlabel = "fs (normalised RSSI) [-]" if which == "fs" else "fT (detection probability) [-]"
    ax3.set_zlabel("fs [-]" if which == "fs" else "fT [-]")
    ax = fig.add_subplot(1, 2, 2)
    m = ax.pcolormesh(deg(A), D, Z, shading="gouraud", cmap="viridis", vmin=0, vmax=1,
                      rasterized=True)
    ax.contour(deg(A), D, Z, levels=np.linspace(0.1, 0.9, 5), colors="w", linewidths=0.6)
    ax.set_xlabel("alpha [deg]")
    ax.set_ylabel("d [m]")
    fig.colorbar(m, ax=ax, label=zlabel)
    title = ("Fig. 4: RSSI model fs(d, alpha)" if which == "fs"
             else "Fig. 5: tag detection model fT(d, alpha)")
    fig.suptitle(f"{title}, {model.n_rules} rules (FCM + ANFIS)")
    return save_figure(fig, out_dir, name)


def fig_ssm_surface(run_dir, out_dir=None) -> list[Path]:
    """Chapter Fig. 4: SSM input-output surface fs(d, alpha); reads models/sensor.json."""
    return _surface(run_dir, out_dir or Path(run_dir) / "figures", "ssm_surface", "fs")


def fig_tdm_surface(run_dir, out_dir=None) -> list[Path]:
    """Chapter Fig. 5: TDM input-output surface fT(d, alpha); reads models/sensor.json."""
    return _surface(run_dir, out_dir or Path(run_dir) / "figures", "tdm_surface", "fT")


def _truth_and_model(run_dir, key_truth: str, key_model: str):
    path = require(run_dir, runfiles.DETECTION_GRID)
    with read_npz(path) as z:
        for k in ("d_edges_m", "alpha_edges_rad", "d_centres_m", "alpha_centres_rad", key_truth):
            if k not in z.files:
                raise ValueError(f"{path}: missing key {k!r}")
        d_e, a_e = z["d_edges_m"], z["alpha_edges_rad"]
        D, A = np.meshgrid(z["d_centres_m"], z["alpha_centres_rad"], indexing="ij")
        truth = np.array(z[key_truth], dtype=float)
        n_att = z["n_attempts"] if "n_attempts" in z.files else None
        model = np.array(z[f"anfis__{key_model}"], float) if f"anfis__{key_model}" in z.files \
            else None
    if model is None:
        sensor = load_sensor(run_dir, "anfis")
        model = sensor.fs_dbm(D, A) if key_model == "fs_dbm" else sensor.fT(D, A)
    return d_e, a_e, truth, model, n_att


def _three_panels(run_dir, out_dir, name, title, truth, model, d_e, a_e, label, diff_label,
                  vlim, dlim):
    fig = new_figure(12.0, 3.8)
    axes = fig.subplots(1, 3, sharey=True)
    diff = model - truth
    meshes = []
    for ax, Z, t, lim, cmap in (
        (axes[0], truth, "ray-traced truth", vlim, "viridis"),
        (axes[1], model, "learned (FCM + ANFIS, MCL poses)", vlim, "viridis"),
        (axes[2], diff, "learned - truth", (-dlim, dlim), "RdBu_r"),
    ):
        meshes.append(ax.pcolormesh(deg(a_e), d_e, np.ma.masked_invalid(Z), cmap=cmap,
                                    vmin=lim[0], vmax=lim[1], rasterized=True))
        ax.set_title(t)
        ax.set_xlabel("alpha [deg]")
    # truth and model share their colour scale: one bar for both, one for the difference
    fig.colorbar(meshes[1], ax=list(axes[:2]), label=label)
    fig.colorbar(meshes[2], ax=axes[2], label=diff_label)
    axes[0].set_ylabel("d [m]")
    fig.suptitle(title)
    return save_figure(fig, out_dir or Path(run_dir) / "figures", name)


def fig_learned_vs_truth_rssi(run_dir, out_dir=None) -> list[Path]:
    """Learned fs [dBm] vs noise-free ray-traced RSSI per (d, alpha) cell, and their difference.

    Reads truth/detection_grid.npz (rssi_dbm) and models/sensor.json. Cells where no
    link closes are blank.
    """
    d_e, a_e, truth, model, _ = _truth_and_model(run_dir, "rssi_dbm", "fs_dbm")
    model = np.where(np.isfinite(truth), model, np.nan)
    fin = np.concatenate([truth[np.isfinite(truth)], model[np.isfinite(model)]])
    vlim = (float(fin.min()), float(fin.max())) if fin.size else (-80.0, -30.0)
    diff = model - truth
    dl = float(np.nanmax(np.abs(diff))) if np.isfinite(diff).any() else 1.0
    return _three_panels(run_dir, out_dir, "learned_vs_truth_rssi",
                         "RSSI: learned model vs ray-traced truth (true poses, no noise)",
                         truth, model, d_e, a_e, "RSSI [dBm]", "difference [dB]", vlim,
                         max(dl, 1e-3))


def fig_learned_vs_truth_detection(run_dir, out_dir=None) -> list[Path]:
    """Learned fT vs true detection probability per (d, alpha) cell, and their difference.

    Reads truth/detection_grid.npz (p_detect) and models/sensor.json. Cells without
    attempts are blank.
    """
    d_e, a_e, truth, model, _ = _truth_and_model(run_dir, "p_detect", "fT")
    model = np.where(np.isfinite(truth), model, np.nan)
    return _three_panels(run_dir, out_dir, "learned_vs_truth_detection",
                         "Detection probability: learned fT vs link-budget truth",
                         truth, model, d_e, a_e, "P(read) [-]", "difference [-]", (0.0, 1.0),
                         1.0)
