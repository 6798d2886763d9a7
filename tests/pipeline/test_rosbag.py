"""ROS 2 bags in and out: the tiny study exported as an MCAP bag reads back as the same
reads and poses as the CSV export; a bag written here with JSON reads and a /tf chain
gives the poses composed by hand (MCAP and sqlite3); bad bags stop with one line naming
the bag and the topic; a bag export runs as a recorded study."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from pipeline.apps.cli import app
from pipeline.apps.export.csv_export import EPOCH_S, epc_of
from pipeline.recording import RecordingConfig, RecordingError, load_recording, read_rosbag
from pipeline.recording.config import recording_overrides
from pipeline.recording.load import READ_FIELDS, detect_format
from pipeline.recording.rosbag import RFID_READ, rfid_typestore

T0 = 1_767_225_600  # the export's clock zero [s since 1970]


@pytest.fixture(scope="module")
def exports(tiny_study, tmp_path_factory):
    """The tiny study exported by the CLI as a bag (``mcap/``) and as CSV (``csv/``)."""
    base = tmp_path_factory.mktemp("bagexp")
    for fmt in ("mcap", "csv"):
        res = CliRunner().invoke(app, ["export", str(tiny_study.run), "--format", fmt,
                                       "--out", str(base / fmt)])
        assert res.exit_code == 0, res.output
    return base


def _sorted(df, cols):
    return df.sort_values(cols, kind="stable").reset_index(drop=True)


def test_mcap_export_reads_back_as_the_run(tiny_study, exports):
    reads, poses = read_rosbag(exports / "mcap" / "bag")
    assert list(reads.columns) == list(READ_FIELDS) and reads["t_s"].is_monotonic_increasing
    sim = pd.read_parquet(tiny_study.run / "reads.parquet")
    sim = sim[sim["read"]]
    want = _sorted(pd.DataFrame({
        "t_s": EPOCH_S + sim["time_s"].to_numpy(np.float64),
        "antenna_port": sim["antenna"].to_numpy(np.int64) + 1,
        "epc": [epc_of(t) for t in sim["tag_id"].astype(str)],
        "rssi_dbm": sim["rssi_dbm"].to_numpy(np.float32),
        "phase_rad": sim["phase_rad"].to_numpy(np.float32),
        "frequency_hz": sim["frequency_hz"].to_numpy(np.float64),
        "doppler_hz": sim["doppler_hz"].to_numpy(np.float32),
        "seen_count": np.maximum(sim["seen_count"].to_numpy(np.int64), 1)}),
        ["t_s", "antenna_port", "epc"])
    got = _sorted(reads, ["t_s", "antenna_port", "epc"])
    assert len(got) == len(want) > 50
    np.testing.assert_allclose(got["t_s"], want["t_s"], rtol=0, atol=1e-6)  # 1 us
    assert (got["antenna_port"] == want["antenna_port"]).all()
    assert (got["epc"] == want["epc"]).all() and (got["seen_count"] == want["seen_count"]).all()
    for c in ("rssi_dbm", "phase_rad", "doppler_hz"):  # float32 in the message
        np.testing.assert_allclose(got[c], want[c].astype(np.float64), rtol=1e-7, atol=0)
    np.testing.assert_array_equal(got["frequency_hz"], want["frequency_hz"])  # float64
    # the same poses as the CSV export's poses.csv (its micrometres and microseconds)
    csv = pd.read_csv(exports / "csv" / "poses.csv")
    assert len(poses) == len(csv) and poses["t_s"].is_monotonic_increasing
    np.testing.assert_allclose(poses[["t_s", "x_m", "y_m"]], csv[["t_s", "x_m", "y_m"]],
                               rtol=0, atol=1.5e-6)
    dyaw = np.angle(np.exp(1j * (poses["yaw_rad"].to_numpy() - csv["yaw_rad"].to_numpy())))
    assert np.max(np.abs(dyaw)) < 1.5e-6
    # /tf (map -> base_link, beside map -> odom) gives the same poses as /amcl_pose
    _, tf = read_rosbag(exports / "mcap" / "bag", pose_topic="/tf")
    np.testing.assert_allclose(tf.to_numpy(), poses.to_numpy(), rtol=0, atol=1e-9)


def test_mcap_export_topics_map_and_folder(tiny_study, exports):
    from rosbags.highlevel import AnyReader

    out = exports / "mcap"
    assert (out / "bag" / "bag.mcap").is_file() and (out / "tags.csv").is_file()
    assert (out / "mounts.toml").is_file()
    def yaw(q):
        return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))

    with AnyReader([out / "bag"]) as rd:
        counts = {c.topic: c.msgcount for c in rd.connections}
        msgs = {}
        for c, _, raw in rd.messages([c for c in rd.connections
                                      if c.topic in ("/map", "/tf", "/odom")]):
            msgs.setdefault(c.topic, []).append(rd.deserialize(raw, c.msgtype))
    track = np.load(tiny_study.run / "tour" / "train_track.npz")
    n_poses = len(track["t_s"])
    assert set(counts) == {"/tf", "/tf_static", "/odom", "/amcl_pose", "/map", "/rfid/reads"}
    assert counts["/tf"] == counts["/odom"] == counts["/amcl_pose"] == n_poses  # no /scan
    assert counts["/tf_static"] == counts["/map"] == 1
    # /tf's map -> odom composed with /odom's pose is the estimated pose (Foxglove's view)
    for tf, od, est in zip(msgs["/tf"], msgs["/odom"], track["est"], strict=True):
        (mo,) = [t.transform for t in tf.transforms if t.child_frame_id == "odom"]
        a, p = yaw(mo.rotation), od.pose.pose.position
        x = mo.translation.x + math.cos(a) * p.x - math.sin(a) * p.y
        y = mo.translation.y + math.sin(a) * p.x + math.cos(a) * p.y
        dyaw = math.remainder(a + yaw(od.pose.pose.orientation) - est[2], 2 * math.pi)
        assert abs(x - est[0]) < 1e-9 and abs(y - est[1]) < 1e-9 and abs(dyaw) < 1e-9
    grid = msgs["/map"][0]
    # /map: 5 cm cells, occupied where the walls at 1 m run (a wall's midpoint), free else
    seg = np.load(tiny_study.run / "scene" / "floorplan.npz")["segments_z100cm"]
    info = grid.info
    cells = grid.data.reshape(info.height, info.width)
    assert info.resolution == pytest.approx(0.05)
    mid = seg.mean(axis=1)
    ij = np.floor((mid - [info.origin.position.x, info.origin.position.y]) / 0.05).astype(int)
    assert (cells[ij[:, 1], ij[:, 0]] == 100).all()
    assert 0.005 < np.mean(cells == 100) < 0.5 and set(np.unique(cells)) == {0, 100}
    # the export again into its own folder replaces the bag; a folder of the user's is refused
    res = CliRunner().invoke(app, ["export", str(tiny_study.run), "--format", "mcap",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == [".rfidstudy-output.json", "bag",
                                                     "mounts.toml", "tags.csv"]
    mine = out.parent / "mine"
    (mine / "bag").mkdir(parents=True)
    res = CliRunner().invoke(app, ["export", str(tiny_study.run), "--format", "mcap",
                                   "--out", str(mine)])
    assert res.exit_code != 0 and "not empty" in res.output and (mine / "bag").is_dir()
    res = CliRunner().invoke(app, ["export", str(tiny_study.run), "--format", "ros",
                                   "--out", str(out.parent / "x")])
    assert res.exit_code != 0 and "one of csv, mcap" in res.output


def _write_bag(path: Path, topics: dict, storage: str = "mcap") -> Path:
    """A bag at ``path``: topics {name: (type, [(bag time [ns], message), ...])}."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = rfid_typestore()
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=8, storage_plugin=plugin) as w:
        for topic, (typ, msgs) in topics.items():
            conn = w.add_connection(topic, typ, typestore=store)
            for ns, msg in msgs:
                w.write(conn, ns, store.serialize_cdr(msg, typ))
    return path


def _ns(t_s: float) -> int:
    return T0 * 10**9 + round(t_s * 1e9)


def _json(ns_obj):
    S = rfid_typestore().types["std_msgs/msg/String"]
    return ("std_msgs/msg/String",
            [(_ns(t), S(data=o if isinstance(o, str) else json.dumps(o))) for t, o in ns_obj])


def _tf(edges):
    """TFMessage messages: edges [(t [s after T0], parent, child, x, y, yaw)]."""
    T = rfid_typestore().types
    g = "geometry_msgs/msg/"
    msgs = []
    for t, parent, child, x, y, yaw in edges:
        ns = _ns(t)
        hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=ns // 10**9, nanosec=ns % 10**9), frame_id=parent)
        tr = T[g + "Transform"](translation=T[g + "Vector3"](x=x, y=y, z=0.0),
                                rotation=T[g + "Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2),
                                                             w=math.cos(yaw / 2)))
        msgs.append((ns, T["tf2_msgs/msg/TFMessage"](transforms=[T[g + "TransformStamped"](
            header=hdr, child_frame_id=child, transform=tr)])))
    return "tf2_msgs/msg/TFMessage", msgs


_READS = [  # (bag time [s after T0], JSON object)
    (9.0, {"t_s": T0 + 11.5, "epc": "e2801160", "antenna": 2, "rssi_dbm": -61.5,
           "phase_rad": 1.0, "frequency_hz": 866.9e6, "doppler_hz": -2.5, "seen_count": 3}),
    (10.5, {"epc": "AB", "antenna": 1, "rssi_dbm": -70}),  # time: the bag's
    (10.75, {"epc": "CD", "antenna": 1, "rssi_dbm": -72.0}),  # not in the tag layout
    (20.0, {"epc": "AB", "antenna": 1, "rssi_dbm": -71.0}),  # after the last pose
]
_TFS = [(10.0, "map", "odom", 1.0, 0.0, 0.0), (12.0, "map", "odom", 1.0, 0.0, math.pi / 2),
        (10.0, "odom", "base_link", 0.0, 0.0, 0.0), (11.0, "odom", "/base_link", 1.0, 0.0, 0.0),
        (12.0, "odom", "base_link", 2.0, 1.0, 0.0), (12.0, "odom", "base_link", 2.0, 1.0, 0.0),
        (13.0, "odom", "base_link", 3.0, 1.0, 0.0),  # after map -> odom's last stamp: dropped
        (11.0, "base_link", "laser", 0.2, 0.0, 0.0)]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_json_reads_and_tf_chain_by_hand(tmp_path, storage):
    bag = _write_bag(tmp_path / "bag", {"/rfid/json": _json(_READS), "/tf": _tf(_TFS)}, storage)
    reads, poses = read_rosbag(bag, reads_topic="/rfid/json", pose_topic="/tf")
    # in time order: the bag's time where the object has no t_s; NaN / 1 where no key
    assert reads["t_s"].tolist() == [T0 + 10.5, T0 + 10.75, T0 + 11.5, T0 + 20.0]
    assert reads["epc"].tolist() == ["AB", "CD", "E2801160", "AB"]
    first = reads.iloc[2]
    assert (first["antenna_port"], first["rssi_dbm"], first["phase_rad"], first["frequency_hz"],
            first["doppler_hz"], first["seen_count"]) == (2, -61.5, 1.0, 866.9e6, -2.5, 3)
    ab = reads.iloc[0]
    assert ab["rssi_dbm"] == -70.0 and ab["seen_count"] == 1
    assert ab[["phase_rad", "frequency_hz", "doppler_hz"]].isna().all()
    # map -> odom (interpolated: yaw pi/4 at 11 s) composed with odom -> base_link, by hand:
    # 10 s: (1, 0, 0); 11 s: (1 + cos 45, sin 45, pi/4); 12 s: (1 - 1, 0 + 2, pi/2)
    r = math.sqrt(0.5)
    want = [[T0 + 10.0, 1.0, 0.0, 0.0], [T0 + 11.0, 1.0 + r, r, math.pi / 4],
            [T0 + 12.0, 0.0, 2.0, math.pi / 2]]
    np.testing.assert_allclose(poses.to_numpy(), want, rtol=0, atol=1e-9)
    # through [recording]: auto-detected, the unknown EPC and the late read counted
    tags = tmp_path / "tags.csv"
    tags.write_text("epc,x_m,y_m,z_m\nAB,1,2,1\nE2801160,2,2,1\n")
    rcfg = RecordingConfig(reads=str(bag), tags=str(tags), reads_topic="/rfid/json",
                           pose_topic="/tf")
    rec = load_recording(rcfg, n_mounts=2)
    assert rec.format == "rosbag" and detect_format(bag) == "rosbag"
    assert rec.info["n_reads_unknown_epc"] == 1 and rec.info["unknown_epcs"] == {"CD": 1}
    assert rec.info["n_reads_outside_poses"] == 1 and rec.reads["epc"].tolist() == ["AB", "E2801160"]
    np.testing.assert_allclose(rec.poses.to_numpy(), want, atol=1e-9)
    # a poses CSV, where set, replaces the bag's poses (its pose topic is then not read)
    pcsv = tmp_path / "poses.csv"
    pcsv.write_text(f"t_s,x_m,y_m,yaw_rad\n{T0 + 10},0,0,0\n{T0 + 30},5,0,0\n")
    rec = load_recording(RecordingConfig(reads=str(bag), tags=str(tags), reads_topic="/rfid/json",
                                         pose_topic="/nowhere", poses=str(pcsv)), n_mounts=2)
    assert rec.poses["x_m"].tolist() == [0.0, 5.0] and rec.info["n_reads_outside_poses"] == 0


def _rfid_bag(path):
    T = rfid_typestore().types
    hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=T0, nanosec=0),
                                   frame_id="rfid_antenna_1")
    msg = T[RFID_READ](header=hdr, epc="ab", antenna=1, rssi_dbm=-60.0, phase_rad=0.5,
                       frequency_hz=866.3e6, doppler_hz=float("nan"), seen_count=0)
    return _write_bag(path, {"/rfid/reads": (RFID_READ, [(_ns(0), msg)]),
                             "/tf": _tf(_TFS), "/empty": ("std_msgs/msg/String", [])})


@pytest.mark.parametrize("case, words", [
    ("no_reads_topic", r"no reads topic '/rfid/nothing'; the bag has /empty \(std_msgs/msg/String\), "
     r"/rfid/reads \(rfidstudy_msgs/msg/RfidRead\), /tf \(tf2_msgs/msg/TFMessage\)"),
    ("no_pose_topic", r"no pose topic '/amcl_pose'; the bag has .*/tf \(tf2_msgs/msg/TFMessage\)"),
    ("wrong_type", r"topic /tf: type tf2_msgs/msg/TFMessage is not one a reads topic may have"),
    ("empty_topic", r"topic /empty \(std_msgs/msg/String\) has no messages"),
    ("not_object", r"topic /rfid/json, message 2: not a JSON object"),
    ("no_key", r"topic /rfid/json, message 3: no key 'rssi_dbm' \(the keys are antenna, epc\)"),
    ("bad_port", r"topic /rfid/json, message 1: antenna 0 is not a reader port"),
    ("no_chain", r"topic /tf: no transform map -> base_link, nor map -> odom and odom -> base_link; "
     r"the bag's transforms are odom->base_link"),
    ("empty_folder", r"not a ROS 2 bag: the folder has no metadata.yaml"),
    ("missing", r"no such ROS 2 bag"),
    ("garbage", r"cannot open the ROS 2 bag"),
])
def test_bad_bags(tmp_path, case, words):
    bag, kw = tmp_path / "bag", {}
    ok = {"epc": "AB", "antenna": 1, "rssi_dbm": -70}
    if case in ("no_reads_topic", "no_pose_topic", "wrong_type", "empty_topic"):
        _rfid_bag(bag)
        kw = {"no_reads_topic": {"reads_topic": "/rfid/nothing", "pose_topic": "/tf"},
              "no_pose_topic": {},
              "wrong_type": {"reads_topic": "/tf"},
              "empty_topic": {"reads_topic": "/empty"}}[case]
    elif case in ("not_object", "no_key", "bad_port"):
        msgs = {"not_object": [ok, "[1, 2]"], "no_key": [ok, ok, {"epc": "AB", "antenna": 1}],
                "bad_port": [{**ok, "antenna": 0}]}[case]
        _write_bag(bag, {"/rfid/json": _json([(float(i), m) for i, m in enumerate(msgs)])})
        kw = {"reads_topic": "/rfid/json", "pose_topic": ""}
    elif case == "no_chain":
        _write_bag(bag, {"/rfid/json": _json([(0.0, ok)]), "/tf": _tf(_TFS[2:4])})
        kw = {"reads_topic": "/rfid/json", "pose_topic": "/tf"}
    elif case == "empty_folder":
        bag.mkdir()
    elif case == "garbage":
        bag = tmp_path / "reads.mcap"
        bag.write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match=words) as exc:
        read_rosbag(bag, **kw)
    assert str(bag) in str(exc.value) and "\n" not in str(exc.value)


def test_rfid_read_message_and_overrides(tmp_path):
    bag = _rfid_bag(tmp_path / "rec" / "bag")
    reads, poses = read_rosbag(bag, pose_topic="")
    assert poses is None and reads.iloc[0]["epc"] == "AB" and reads.iloc[0]["t_s"] == T0
    assert reads.iloc[0]["seen_count"] == 1 and np.isnan(reads.iloc[0]["doppler_hz"])
    assert reads.iloc[0]["frequency_hz"] == 866.3e6
    # --recording: an export folder (bag/ + tags.csv), the bag itself, one .mcap file
    (tmp_path / "rec" / "tags.csv").write_text("epc,x_m,y_m,z_m\nAB,1,2,1\n")
    sets = {s.split("=", 1)[0]: json.loads(s.split("=", 1)[1])
            for s in recording_overrides(tmp_path / "rec")}
    assert sets == {"recording.reads": str(bag.resolve()), "recording.format": "rosbag",
                    "recording.tags": str((tmp_path / "rec" / "tags.csv").resolve())}
    assert [s.split("=", 1)[0] for s in recording_overrides(bag)] == [
        "recording.reads", "recording.format", "recording.tags"]
    assert recording_overrides(bag / "bag.mcap") == [
        f"recording.reads={json.dumps(str((bag / 'bag.mcap').resolve()))}"]
    assert detect_format(bag / "bag.mcap") == "rosbag"


def _run(tiny_study, out, *args):
    cache = tiny_study.config.tracing.cache_dir
    return CliRunner().invoke(app, ["run", "configs/tiny.toml", "--out", str(out), "--no-progress",
                                    "--set", f"tracing.cache_dir={json.dumps(cache)}", *args])


def test_recorded_study_on_the_bag_export(tiny_study, exports, tmp_path):
    out = tmp_path / "run"
    # the bag is read by the recording stage; what follows it is the CSV's recorded study
    # (test_recorded_study.py): here without the construction fit, the calibration's
    # intervals and the held-out tags' localisation (100 s of the 120 this took)
    res = _run(tiny_study, out, "--recording", str(exports / "mcap"),
               "--set", "recording.calibrate_constructions=0", "--set", "downstream.enabled=false",
               "--set", "recording.calibration_resamples=0")
    assert res.exit_code == 0, res.output
    met = json.loads((out / "metrics.json").read_text())
    assert met["source"] == "recording"
    imp = json.loads((out / "recording" / "import.json").read_text())
    assert imp["format"] == "rosbag" and imp["n_reads_unknown_epc"] == 0
    assert imp["n_off_schedule"] == 0 and imp["n_reads"] == imp["n_reads_in_file"]
    # the bag's reads rebuild the simulated attempts: the same outcome of each, and the
    # RSSI the message carries (float32, not sllurp's whole dBm)
    sim = pd.read_parquet(tiny_study.run / "reads.parquet").assign(
        tag_id=lambda d: [epc_of(t) for t in d["tag_id"].astype(str)])
    rec = pd.concat([pd.read_parquet(out / "reads.parquet"),
                     pd.read_parquet(out / "eval_reads.parquet")], ignore_index=True)
    rec["tag_id"] = rec["tag_id"].astype(str)
    m = sim.merge(rec, on=["cycle", "antenna", "tag_id"], how="outer", suffixes=("_sim", "_rec"),
                  indicator=True)
    assert (m["_merge"] == "both").all() and (m["read_sim"] == m["read_rec"]).all()
    got = m[m["read_rec"]]
    np.testing.assert_allclose(got["rssi_dbm_rec"], got["rssi_dbm_sim"], rtol=1e-6)
