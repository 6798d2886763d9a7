"""The recorded study: the chapter's experiment on a real reader's log (``[recording]``).

With ``recording.reads`` set the study's stages are :data:`RECORDED_STAGES`::

    scene           the building (``scene``) with the recording's tags, split by tag   [scene, recording]
    recording       the log read, its attempts rebuilt -> reads/poses Parquet          [recording, robot, reader]
    training_sets   as simulated, on the recorded poses
    models          as simulated (MCL poses only: a recording knows one pose)
    sim_vs_real     the recorded antenna poses traced in the scene, compared           [reader, tracing]
    calibration     the simulated reader fitted to the log: calibration.json           [reader, robot]
    recorded_eval   every model on the held-out tags' recorded reads, intervals -> metrics.json
    report          report.html

The held-out tags (``recording.heldout_fraction`` of them, drawn from the stream
``stage_rng(cfg, "recording_split")``) are read along the same recorded tour as the
training tags, but no model sees their reads: ``reads.parquet`` holds the training tags'
attempts, ``eval_reads.parquet`` the held-out ones'.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline import runfiles
from pipeline.acquisition import ReadLog
from pipeline.engine.runstore import atomic_write_json, save_npz
from pipeline.engine.study import Stage
from pipeline.recording import RecordingError
from pipeline.recording.attempts import recorded_read_table
from pipeline.recording.config import CALIBRATION_FIELDS, RecordingConfig
from pipeline.recording.lag import pose_lag_profile
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.stages.common import load_scene
from pipeline.studyscene import build_robot, load_study_recording, recorded_scene

__all__ = ["RECORDING_KEYS", "STAGE", "recorded_scene", "stage_recording"]  # recorded_scene: pipeline.studyscene's


def _check_channels(rec, cfg) -> None:
    """The channels the reader reported are channels of the study's reader: the ray tracer
    traces the reader's plan (``reader.region``), so a log from another region stops here.

    Raises
    ------
    pipeline.recording.RecordingError
    """
    f = rec.reads["frequency_hz"].to_numpy(np.float64)
    f = np.unique(f[np.isfinite(f)])
    if not len(f):
        return
    plan = np.asarray(cfg.reader.channel_plan(cfg.frequency_hz).channels_hz, np.float64)
    off = f[np.min(np.abs(f[:, None] - plan[None, :]), axis=1) > 1e3]  # 1 kHz: a channel's own
    if len(off):
        raise RecordingError(
            f"{cfg.recording.reads}: the reader reported {len(off)} channel(s) outside "
            f"reader.region = {cfg.reader.region!r}'s plan (e.g. {off[0] / 1e6:.3f} MHz): set "
            "reader.region (and recording.region) to the region the reader ran")


def stage_recording(ctx) -> dict:
    """Read the recording, rebuild its attempts; write the read logs and the tracks.

    Writes ``reads.parquet`` / ``poses.parquet`` (the training tags' attempts) and their
    ``eval_`` twins (the held-out tags'), ``tour/train_track.npz`` and
    ``tour/eval_track.npz`` (the recorded poses, ``true`` = ``est``), and
    ``recording/import.json`` (what the import counted, :func:`load_recording`, and the
    attempts rule's counts, :func:`~pipeline.recording.attempts.recorded_read_table`).
    """
    cfg = ctx.config
    sc = load_scene(ctx)
    split = ctx.memo["tag_split"]
    rec = ctx.memo.get("recording") or load_study_recording(cfg)  # load_scene read it (recorded_scene)
    _check_channels(rec, cfg)
    mounts = build_robot(cfg).antennas
    table, poses, att_info = recorded_read_table(rec, sc.tags, mounts, cfg.reader,
                                                 frequency_hz=cfg.frequency_hz)
    info = {**rec.info, **att_info}
    if rec.poses is not None:  # a clock offset between reads and poses, estimated, reported

        train = set(np.asarray(sc.tags.ids)[split == "train"].tolist())  # no held-out read
        info["pose_lag"] = pose_lag_profile(rec.reads[rec.reads["epc"].isin(train)], rec.poses,
                                            sc.tags, mounts, rec.info["ports"])
    held = set(np.asarray(sc.tags.ids)[split == "eval"].tolist())
    is_held = table["tag_id"].astype(str).isin(held).to_numpy()
    meta = {"source": "recording", "reads_file": cfg.recording.reads, "format": rec.format,
            "antennas": [a.name for a in mounts], "ports": rec.info["ports"],
            "t0_s": att_info["t0_s"]}
    for prefix, rows in (("", ~is_held), ("eval_", is_held)):
        part = table.loc[rows].reset_index(drop=True)
        part["tag_id"] = part["tag_id"].cat.remove_unused_categories()
        ReadLog(part, poses, meta).write(ctx.staging_dir, prefix=prefix)
        info[f"{prefix or 'train_'}reads"] = int(part["read"].sum())
    t = poses["time_s"].to_numpy(np.float64)
    xyz = poses[["est_x_m", "est_y_m", "est_theta_rad"]].to_numpy(np.float64)
    for name in ("train", "eval"):
        save_npz(ctx.out(runfiles.TRACK.format(tour=name)), t_s=t, true=xyz, est=xyz, odom=xyz,
                 pass_index=np.zeros(len(t), np.int64))
    atomic_write_json(ctx.out(runfiles.RECORDING_IMPORT), info)
    return {k: info[k] for k in ("format", "n_reads_in_file", "n_reads", "n_reads_unknown_epc",
                                 "n_reads_outside_poses", "n_attempts", "n_off_schedule")}


#: The ``[recording]`` keys the import reads: all but the calibration's (a calibration run
#: again with other constructions or resamples keeps the import, traces and models).
RECORDING_KEYS = tuple(f"recording.{f.name}" for f in dataclasses.fields(RecordingConfig)
                       if f.name not in CALIBRATION_FIELDS)

STAGE = Stage("recording", stage_recording, ("seed", *RECORDING_KEYS, "robot", "reader", "frequency_hz"),
              ("scene",), description="read the recording", always=True,
              outputs=STAGE_OUTPUTS["recording"])
