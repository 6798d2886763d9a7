"""A run's training tour as a ROS 2 bag (:func:`export_mcap`; the reader is :mod:`.rosbag`).

Each message is stamped (header and bag time alike) on the CSV export's clock,
:data:`.runtour.EPOCH_S` + the tour's time, in whole nanoseconds. Frames: ``map`` (the
scene frame), ``odom``, ``base_link`` (the robot base), ``rfid_antenna_<port>`` (a
reader antenna, port = the study's antenna index + 1, at its mount: x, y, z, yaw, and
the tilt as a negative pitch, ROS's pitch being nose down). The bag is written in MCAP
storage, rosbag2 metadata version 8, with ``rosbags``' ROS 2 Humble message definitions
(:func:`.rosbag.rfid_typestore`); ``/map`` and ``/tf_static`` are offered latched
(transient local), as ``map_server`` and ``static_transform_publisher`` offer them.
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import numpy as np

from pipeline import runfiles
from pipeline.apps.export.runtour import EPOCH_S, run_tour, write_layout
from pipeline.outdirs import check_output_dir, mark_output_dir
from pipeline.recording.rosbag import RFID_READ, TOPICS, rfid_typestore
from pipeline.runpaths import inside
from scenes.fileio import read_npz

__all__ = ["MAP_HEIGHT_KEY", "MAP_MARGIN_M", "MAP_RESOLUTION_M", "export_mcap", "occupancy_grid",
           "write_bag"]

#: Cell size of ``/map`` [m].
MAP_RESOLUTION_M = 0.05
#: Free border around the walls in ``/map`` [m].
MAP_MARGIN_M = 0.5
#: The floor plan ``/map`` rasterises: ``scene/floorplan.npz``'s walls cut at 1 m.
MAP_HEIGHT_KEY = "segments_z100cm"
_NS = 1_000_000_000


def occupancy_grid(segments: np.ndarray, resolution_m: float = MAP_RESOLUTION_M,
                   margin_m: float = MAP_MARGIN_M):
    """Wall segments rasterised: every cell a segment passes through is occupied.

    Parameters
    ----------
    segments : numpy.ndarray
        (k, 2, 2) wall segments [m], k >= 1.
    resolution_m, margin_m : float
        Cell size and free border [m].

    Returns
    -------
    grid : numpy.ndarray
        (height, width) int8: 100 occupied, 0 free (the plan knows only walls); row 0 is
        the lowest y, column 0 the lowest x (``nav_msgs/OccupancyGrid``'s order).
    origin_m : numpy.ndarray
        (2,) x, y of cell (0, 0)'s outer corner [m].
    """
    seg = np.asarray(segments, np.float64).reshape(-1, 2, 2)
    lo = seg.reshape(-1, 2).min(axis=0) - margin_m
    hi = seg.reshape(-1, 2).max(axis=0) + margin_m
    w, h = (np.ceil((hi - lo) / resolution_m).astype(int) + 1).tolist()
    grid = np.zeros((h, w), np.int8)
    step = resolution_m / 4.0
    for a, b in seg:  # points a quarter cell apart along each wall
        n = int(math.ceil(float(np.linalg.norm(b - a)) / step)) + 1
        p = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
        ij = np.floor((p - lo) / resolution_m).astype(int)
        grid[np.clip(ij[:, 1], 0, h - 1), np.clip(ij[:, 0], 0, w - 1)] = 100
    return grid, lo


class _Bag:
    """Messages gathered per topic, written in time order."""

    def __init__(self):
        self.store = rfid_typestore()
        self.T = self.store.types
        self.msgs: list[tuple[int, int, str, object]] = []  # (ns, order, topic, msg)

    def stamp(self, ns: int):
        return self.T["builtin_interfaces/msg/Time"](sec=int(ns // _NS), nanosec=int(ns % _NS))

    def header(self, ns: int, frame: str):
        return self.T["std_msgs/msg/Header"](stamp=self.stamp(ns), frame_id=frame)

    def pose(self, x: float, y: float, z: float, yaw: float, pitch: float = 0.0):
        cz, sz, cp, sp = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(pitch / 2), math.sin(pitch / 2)
        g = "geometry_msgs/msg/"
        return (self.T[g + "Vector3"](x=float(x), y=float(y), z=float(z)),
                self.T[g + "Quaternion"](x=-sz * sp, y=cz * sp, z=sz * cp, w=cz * cp))

    def pose_msg(self, x, y, yaw):
        v, q = self.pose(x, y, 0.0, yaw)
        g = "geometry_msgs/msg/"
        return self.T[g + "PoseWithCovariance"](
            pose=self.T[g + "Pose"](position=self.T[g + "Point"](x=v.x, y=v.y, z=v.z),
                                    orientation=q), covariance=np.zeros(36))

    def transform(self, ns, parent, child, *pose):
        v, q = self.pose(*pose)
        g = "geometry_msgs/msg/"
        return self.T[g + "TransformStamped"](header=self.header(ns, parent), child_frame_id=child,
                                              transform=self.T[g + "Transform"](translation=v,
                                                                                rotation=q))

    def add(self, topic: str, ns: int, msg) -> None:
        self.msgs.append((int(ns), len(self.msgs), topic, msg))

    def write(self, path: Path) -> None:
        from rosbags.interfaces import (
            Qos,
            QosDurability,
            QosHistory,
            QosLiveliness,
            QosReliability,
            QosTime,
        )
        from rosbags.rosbag2 import StoragePlugin, Writer

        zero = QosTime(0, 0)
        latched = [Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE,
                       QosDurability.TRANSIENT_LOCAL, zero, zero, QosLiveliness.AUTOMATIC, zero,
                       False)]
        types = {t: typ for t, typ, _ in TOPICS}
        used = {t for _, _, t, _ in self.msgs}
        with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
            conns = {t: w.add_connection(t, types[t], typestore=self.store,
                                         offered_qos_profiles=latched
                                         if t in ("/map", "/tf_static") else ())
                     for t, _, _ in TOPICS if t in used}
            for ns, _, topic, msg in sorted(self.msgs, key=lambda m: (m[0], m[1])):
                w.write(conns[topic], ns, self.store.serialize_cdr(msg, types[topic]))


def _fill(bag: _Bag, tour, segments) -> None:
    """Every topic's messages from the run (module doc of :mod:`.rosbag`, ``TOPICS``)."""
    T = bag.T
    epoch_ns = int(round(EPOCH_S)) * _NS
    ns = epoch_ns + np.round(tour.t_s * 1e9).astype(np.int64)
    est, odom = tour.est, tour.odom
    has_odom = np.all(np.isfinite(odom), axis=1)
    tf = "tf2_msgs/msg/TFMessage"
    for k in range(len(ns)):
        x, y, yaw = est[k]
        trs = [bag.transform(ns[k], "map", "base_link", x, y, 0.0, yaw)]
        bag.add("/amcl_pose", ns[k], T["geometry_msgs/msg/PoseWithCovarianceStamped"](
            header=bag.header(ns[k], "map"), pose=bag.pose_msg(x, y, yaw)))
        if has_odom[k]:  # map -> odom = est o odom^-1: /odom then shows in the map frame
            ox, oy, oyaw = odom[k]
            dyaw = yaw - oyaw
            c, s = math.cos(dyaw), math.sin(dyaw)
            trs.append(bag.transform(ns[k], "map", "odom", x - (c * ox - s * oy),
                                     y - (s * ox + c * oy), 0.0, dyaw))
            vec = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            bag.add("/odom", ns[k], T["nav_msgs/msg/Odometry"](
                header=bag.header(ns[k], "odom"), child_frame_id="base_link",
                pose=bag.pose_msg(ox, oy, oyaw),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](linear=vec, angular=vec),
                    covariance=np.zeros(36))))
        bag.add("/tf", ns[k], T[tf](transforms=trs))
    mounts = tour.config.robot.antennas
    bag.add("/tf_static", ns[0], T[tf](transforms=[
        bag.transform(ns[0], "base_link", f"rfid_antenna_{i + 1}", a.x_m, a.y_m, a.z_m,
                      math.radians(a.yaw_deg), -math.radians(a.tilt_deg))
        for i, a in enumerate(mounts)]))
    if len(segments):
        grid, origin = occupancy_grid(segments)
        v, q = bag.pose(origin[0], origin[1], 0.0, 0.0)
        g = "geometry_msgs/msg/"
        bag.add("/map", ns[0], T["nav_msgs/msg/OccupancyGrid"](
            header=bag.header(ns[0], "map"),
            info=T["nav_msgs/msg/MapMetaData"](
                map_load_time=bag.stamp(ns[0]), resolution=MAP_RESOLUTION_M,
                width=grid.shape[1], height=grid.shape[0],
                origin=T[g + "Pose"](position=T[g + "Point"](x=v.x, y=v.y, z=0.0),
                                     orientation=q)),
            data=grid.reshape(-1)))
    r = tour.reads
    rns = epoch_ns + np.round(r["time_s"].to_numpy(np.float64) * 1e9).astype(np.int64)
    port = r["antenna"].to_numpy(np.int64) + 1
    cols = [r[c].to_numpy(np.float64) for c in ("rssi_dbm", "phase_rad", "frequency_hz",
                                                "doppler_hz")]
    seen = np.maximum(r["seen_count"].to_numpy(np.int64), 1)
    Read = T[RFID_READ]
    for k, tag in enumerate(r["tag_id"].astype(str)):
        bag.add("/rfid/reads", rns[k], Read(
            header=bag.header(rns[k], f"rfid_antenna_{port[k]}"), epc=tour.epc(tag),
            antenna=int(port[k]), rssi_dbm=cols[0][k], phase_rad=cols[1][k],
            frequency_hz=cols[2][k], doppler_hz=cols[3][k], seen_count=int(seen[k])))


def write_bag(run_dir: str | Path, out_dir: str | Path) -> list[Path]:
    """:func:`export_mcap` (its docstring)."""
    out = check_output_dir(out_dir, "export", ["bag", "tags.csv", "mounts.toml"])
    tour = run_tour(run_dir)
    try:
        with read_npz(inside(Path(run_dir), runfiles.FLOORPLAN)) as z:
            segments = np.asarray(z[MAP_HEIGHT_KEY], np.float64) if MAP_HEIGHT_KEY in z \
                else np.zeros((0, 2, 2))
    except OSError as exc:
        raise ValueError(f"{run_dir}: cannot read the run's floor plan ({exc})") from None
    bag = _Bag()
    _fill(bag, tour, segments)
    out.mkdir(parents=True, exist_ok=True)
    stage = out / f".bag-{os.getpid()}.partial"
    shutil.rmtree(stage, ignore_errors=True)
    try:  # written beside the folder, then moved in: never a half-written bag
        bag.write(stage / "bag")
        old = out / "bag"
        if old.exists():  # an earlier export's bag (check_output_dir: the marker lists it)
            old.rename(stage / "old")
        (stage / "bag").rename(old)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    files = [out / "bag", *write_layout(tour, out)]
    mark_output_dir(out, "export", files)
    return files


def export_mcap(run_dir: str | Path, out_dir: str | Path) -> list[Path]:
    """Write a finished simulated run's training tour as a ROS 2 bag in MCAP storage.

    Writes ``out_dir/bag/`` (``metadata.yaml``, ``bag.mcap``) with the topics of
    :data:`.rosbag.TOPICS` (no ``/scan``: a run stores no laser scans), on the clock of the CSV
    export (:data:`.runtour.EPOCH_S` + the tour's time) with its EPCs (:func:`.runtour.epc_of`),
    and beside it ``tags.csv`` and ``mounts.toml`` as :func:`.export.export_csv` writes
    them, so that the folder is a complete recording (``rfidstudy run STUDY --recording
    out_dir``). ``out_dir`` must be new, empty, or an earlier export
    (:func:`pipeline.outdirs.check_output_dir`); the bag is written beside it and moved
    into place, so a failed export leaves no half-written bag.

    Returns
    -------
    list of Path
        ``out_dir/bag``, ``out_dir/tags.csv``, ``out_dir/mounts.toml``.

    Raises
    ------
    pipeline.config.ConfigError
        ``out_dir`` may not be written.
    ValueError
        A run file is missing or unreadable (named).
    """
    return write_bag(run_dir, out_dir)
