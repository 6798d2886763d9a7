"""ROS 2 bags in and out, with ``rosbags`` (pure Python: no ROS install; MCAP and sqlite3).

**Reading** (:func:`read_rosbag`): a bag is its folder (``metadata.yaml`` and its
``.mcap`` or ``.db3`` files) or one ``.mcap`` / ``.db3`` file. Two topics are read:

- the reads (``recording.reads_topic``, default ``/rfid/reads``), of either type

  - ``rfidstudy_msgs/msg/RfidRead`` (:data:`RFID_READ`, the definition
    ``pipeline/recording/rfidmsg/RfidRead.msg``): ``header`` (the report's time),
    ``epc``, ``antenna`` (1-based port), ``rssi_dbm``, ``phase_rad``, ``frequency_hz``,
    ``doppler_hz`` (NaN where unknown), ``seen_count`` (0 counts as 1);
  - ``std_msgs/msg/String`` carrying one JSON object per read, with the keys of
    :data:`JSON_KEYS`;

- the poses (``recording.pose_topic``, default ``/amcl_pose``; ``""`` = none, fixed
  antennas): ``geometry_msgs/msg/PoseWithCovarianceStamped`` (as ``amcl`` publishes),
  ``geometry_msgs/msg/PoseStamped`` or ``nav_msgs/msg/Odometry``: x, y and the yaw of
  the quaternion; or ``tf2_msgs/msg/TFMessage`` (``/tf``): the transform ``map ->
  base_link``, else the chain ``map -> odom -> base_link`` composed in the plane at the
  times of ``odom -> base_link`` (``map -> odom`` interpolated linearly between its
  stamps, the yaw the short way; held constant where it has one stamp or comes from
  ``/tf_static``; outside its stamps a pose is dropped: tf2 does not extrapolate either).

Times are the messages' header stamps (``sec + nanosec``) in seconds since 1970; a
message without a header (``String``) or with a zero stamp takes the time the bag
recorded it. Reads are returned in time order; poses strictly increasing in time (a
repeated stamp is dropped).

**Writing** (:func:`.rosbag_export.export_mcap`, ``rfidstudy export RUN --format mcap``):
a finished simulated study's training tour as a bag in MCAP storage that Foxglove and
``ros2 bag`` (Iron and later: metadata version 8) open; see :data:`TOPICS`. There is no ``/scan``:
a run stores no laser scans.

Every error is one line naming the bag and the topic (:class:`.csvformats.RecordingError`).
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.recording.csvformats import POSE_COLUMNS, READ_FIELDS, RecordingError

__all__ = ["JSON_KEYS", "MSG_FILE", "POSE_TYPES", "READ_TYPES", "RFID_READ", "TOPICS",
           "read_rosbag", "rfid_typestore"]

#: The project's message type for one tag report.
RFID_READ = "rfidstudy_msgs/msg/RfidRead"
#: Its definition (ROS 2 ``.msg``), shipped with the package.
MSG_FILE = Path(__file__).parent / "rfidmsg" / "RfidRead.msg"
#: Message types a reads topic may have.
READ_TYPES = (RFID_READ, "std_msgs/msg/String")
#: Message types a pose topic may have.
POSE_TYPES = ("geometry_msgs/msg/PoseWithCovarianceStamped", "geometry_msgs/msg/PoseStamped",
              "nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage")
#: Keys of a JSON read (``std_msgs/msg/String``): (key, unit, default; None = required).
JSON_KEYS = (("t_s", "s since 1970 (UTC)", "the time the bag recorded the message"),
             ("epc", "hex digits (str)", None),
             ("antenna", "reader port, 1-based (int)", None),
             ("rssi_dbm", "dBm", None),
             ("phase_rad", "rad", "NaN"),
             ("frequency_hz", "Hz", "NaN"),
             ("doppler_hz", "Hz", "NaN"),
             ("seen_count", "reports (int)", "1"))
#: Topics :func:`.rosbag_export.export_mcap` writes: (topic, type, content).
TOPICS = (("/tf", "tf2_msgs/msg/TFMessage", "map -> base_link at every estimated pose; "
           "map -> odom where the odometry is known (so /odom shows in the map)"),
          ("/tf_static", "tf2_msgs/msg/TFMessage", "base_link -> rfid_antenna_<port>: the mounts"),
          ("/odom", "nav_msgs/msg/Odometry", "the odometry poses in frame odom (where finite; "
           "twist zero)"),
          ("/amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped",
           "the estimated (MCL) poses in frame map (covariance zero)"),
          ("/map", "nav_msgs/msg/OccupancyGrid", "the scene's walls at 1 m, 5 cm cells, once"),
          ("/rfid/reads", RFID_READ, "every read of the training tour, frame "
           "rfid_antenna_<port>"))

_TF = "tf2_msgs/msg/TFMessage"
_HEX = set("0123456789ABCDEF")
_NS = 1_000_000_000


@functools.cache
def rfid_typestore():
    """The ROS 2 Humble typestore with :data:`RFID_READ` registered."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(MSG_FILE.read_text(encoding="utf-8"), RFID_READ))
    return store


def _open(path: Path):
    """An open ``rosbags`` AnyReader of the bag, or a one-line RecordingError."""
    from rosbags.highlevel import AnyReader

    if not path.exists():
        raise RecordingError(f"{path}: no such ROS 2 bag (file or folder)")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise RecordingError(f"{path}: not a ROS 2 bag: the folder has no metadata.yaml (a bag is "
                             "a folder with metadata.yaml and its .mcap or .db3 files)")
    try:
        rd = AnyReader([path], default_typestore=rfid_typestore())
        rd.open()
    except Exception as exc:  # rosbags raises several kinds (ReaderError, YAML, KeyError ...)
        text = " ".join(str(exc).split())[:200]
        raise RecordingError(f"{path}: cannot open the ROS 2 bag ({type(exc).__name__}: "
                             f"{text})") from None
    return rd


def _topic(rd, path, topic, allowed, what):
    """The connections of ``topic`` and its type, checked against ``allowed``."""
    conns = [c for c in rd.connections if c.topic == topic]
    if not conns:
        have = ", ".join(f"{c.topic} ({c.msgtype})" for c in
                         sorted({(c.topic, c.msgtype): c for c in rd.connections}.values(),
                                key=lambda c: c.topic))
        raise RecordingError(f"{path}: no {what} topic {topic!r}; the bag has "
                             f"{have or 'no topics'} (set recording.{what}_topic)")
    types = sorted({c.msgtype for c in conns})
    if len(types) > 1:
        raise RecordingError(f"{path}: topic {topic} holds messages of {len(types)} types "
                             f"({', '.join(types)}); one type per topic")
    bad = [t for t in types if t not in allowed]
    if bad:
        raise RecordingError(f"{path}: topic {topic}: type {bad[0]} is not one a {what} topic "
                             f"may have ({', '.join(allowed)})")
    return conns, types[0]


def _messages(rd, path, topic, conns):
    """(index from 1, bag time [ns], message) of a topic; an empty topic is an error."""
    n = 0
    for conn, ns, raw in rd.messages(connections=conns):
        n += 1
        try:
            msg = rd.deserialize(raw, conn.msgtype)
        except Exception as exc:  # a corrupt or mistyped message
            raise RecordingError(f"{path}: topic {topic}, message {n}: cannot be decoded as "
                                 f"{conn.msgtype} ({' '.join(str(exc).split())[:120]})") from None
        yield n, ns, msg
    if n == 0:
        raise RecordingError(f"{path}: topic {topic} ({conns[0].msgtype}) has no messages")


def _stamp_ns(header, bag_ns: int) -> int:
    ns = int(header.stamp.sec) * _NS + int(header.stamp.nanosec)
    return ns if ns else int(bag_ns)


def _json_read(path, topic, n, bag_ns, text):
    where = f"{path}: topic {topic}, message {n}"
    try:
        obj = json.loads(text)
    except ValueError as exc:
        raise RecordingError(f"{where}: not JSON ({exc})") from None
    if not isinstance(obj, dict):
        raise RecordingError(f"{where}: not a JSON object (one object per read: keys "
                             f"{', '.join(k for k, *_ in JSON_KEYS)})")
    missing = [k for k, _, dflt in JSON_KEYS if dflt is None and k not in obj]
    if missing:
        raise RecordingError(f"{where}: no key {missing[0]!r} (the keys are "
                             f"{', '.join(sorted(obj))[:120] or 'none'})")

    def num(key, default=math.nan):
        v = obj.get(key)
        if v is None:
            return default
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise RecordingError(f"{where}: key {key!r}: {v!r:.30} is not a number")
        return float(v)

    t = num("t_s", bag_ns / _NS)
    return (t, obj["antenna"], num("rssi_dbm"), obj["epc"], num("phase_rad"),
            num("frequency_hz"), num("doppler_hz"), obj.get("seen_count", 1))


def _check_read(path, topic, n, row):
    """A read row with its port, EPC, RSSI and seen count checked and typed."""
    t, port, rssi, epc, phase, freq, dop, seen = row
    where = f"{path}: topic {topic}, message {n}"
    if isinstance(port, bool) or not isinstance(port, int | float) or port != int(port) or port < 1:
        raise RecordingError(f"{where}: antenna {port!r:.20} is not a reader port (1-based)")
    e = str(epc).upper() if isinstance(epc, str) else ""
    if not e or not set(e) <= _HEX:
        raise RecordingError(f"{where}: epc {epc!r:.40} is not hex")
    if not (math.isfinite(t) and math.isfinite(rssi)):
        raise RecordingError(f"{where}: time {t} or rssi_dbm {rssi} is not finite")
    if isinstance(seen, bool) or not isinstance(seen, int | float) or seen != int(seen) or seen < 0:
        raise RecordingError(f"{where}: seen_count {seen!r:.20} is not a count")
    return t, int(port), float(rssi), e, phase, freq, dop, max(int(seen), 1)


def _reads(rd, path, topic) -> pd.DataFrame:
    conns, _ = _topic(rd, path, topic, READ_TYPES, "reads")
    rows = []
    for n, ns, m in _messages(rd, path, topic, conns):
        if hasattr(m, "data"):  # std_msgs/String: one JSON object
            row = _json_read(path, topic, n, ns, m.data)
        else:
            row = (_stamp_ns(m.header, ns) / _NS, m.antenna, float(m.rssi_dbm), m.epc,
                   float(m.phase_rad), float(m.frequency_hz), float(m.doppler_hz), m.seen_count)
        rows.append(_check_read(path, topic, n, row))
    df = pd.DataFrame(rows, columns=list(READ_FIELDS)).astype(
        {"t_s": np.float64, "antenna_port": np.int64, "rssi_dbm": np.float64, "epc": object,
         "phase_rad": np.float64, "frequency_hz": np.float64, "doppler_hz": np.float64,
         "seen_count": np.int64})
    return df.sort_values("t_s", kind="stable").reset_index(drop=True)


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _track(rows) -> np.ndarray:
    """(n, 4) t, x, y, yaw sorted by time, a repeated time dropped."""
    a = np.asarray(rows, np.float64).reshape(-1, 4)
    a = a[np.argsort(a[:, 0], kind="stable")]
    keep = np.r_[True, np.diff(a[:, 0]) > 0]
    return a[keep]


def _at(edge: tuple[np.ndarray, bool], t: np.ndarray):
    """(x, y, yaw) of a transform at times ``t`` and where it is known."""
    a, static = edge
    if static or len(a) == 1:
        return np.broadcast_to(a[-1, 1:], (len(t), 3)), np.ones(len(t), bool)
    inside = (t >= a[0, 0]) & (t <= a[-1, 0])
    yaw = np.unwrap(a[:, 3])
    v = np.column_stack([np.interp(t, a[:, 0], a[:, 1]), np.interp(t, a[:, 0], a[:, 2]),
                         np.interp(t, a[:, 0], yaw)])
    return v, inside


def _tf_poses(rd, path, topic, conns) -> np.ndarray:
    """map -> base_link from the TF messages (module doc)."""
    want = {("map", "base_link"), ("map", "odom"), ("odom", "base_link")}
    edges: dict = {}
    seen: set = set()
    static = [c for c in rd.connections if c.topic == "/tf_static" and c.msgtype == _TF]
    for tp, cs, is_static in ((topic, conns, False), ("/tf_static", static, True)):
        if not cs:
            continue
        for _, ns, m in _messages(rd, path, tp, cs):
            for tr in m.transforms:
                key = (tr.header.frame_id.strip("/"), tr.child_frame_id.strip("/"))
                seen.add(key)
                if key in want:
                    v, q = tr.transform.translation, tr.transform.rotation
                    edges.setdefault((key, is_static), []).append(
                        (_stamp_ns(tr.header, ns) / _NS, v.x, v.y, _yaw(q)))
    got = {}
    for (key, is_static), rows in edges.items():
        if key not in got or is_static:
            got[key] = (_track(rows), is_static)
    if ("map", "base_link") in got:
        return got[("map", "base_link")][0]
    if ("map", "odom") not in got or ("odom", "base_link") not in got:
        have = ", ".join(f"{p}->{c}" for p, c in sorted(seen))[:200]
        raise RecordingError(f"{path}: topic {topic}: no transform map -> base_link, nor map -> "
                             f"odom and odom -> base_link; the bag's transforms are "
                             f"{have or 'none'}")
    mo, ob = got[("map", "odom")], got[("odom", "base_link")]
    lead = ob if len(ob[0]) > 1 and not ob[1] else mo
    t = lead[0][:, 0]
    (a, ka), (b, kb) = _at(mo, t), _at(ob, t)
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    out = np.column_stack([t, a[:, 0] + c * b[:, 0] - s * b[:, 1],
                           a[:, 1] + s * b[:, 0] + c * b[:, 1], a[:, 2] + b[:, 2]])
    return out[ka & kb]


def _poses(rd, path, topic) -> pd.DataFrame:
    conns, typ = _topic(rd, path, topic, POSE_TYPES, "pose")
    if typ == _TF:
        a = _tf_poses(rd, path, topic, conns)
    else:
        rows = []
        for _, ns, m in _messages(rd, path, topic, conns):
            p = m.pose.pose if hasattr(m.pose, "covariance") else m.pose  # PoseStamped: Pose
            rows.append((_stamp_ns(m.header, ns) / _NS, p.position.x, p.position.y,
                         _yaw(p.orientation)))
        a = _track(rows)
    if len(a) < 2 or not np.isfinite(a).all():
        raise RecordingError(f"{path}: topic {topic}: {len(a)} pose(s) with finite values; at "
                             "least two to interpolate between")
    a[:, 3] = (a[:, 3] + np.pi) % (2 * np.pi) - np.pi
    return pd.DataFrame(a, columns=list(POSE_COLUMNS))


def read_rosbag(path: str | Path, *, reads_topic: str = "/rfid/reads",
                pose_topic: str = "/amcl_pose") -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """The reads and the robot's poses in a ROS 2 bag (module doc).

    Parameters
    ----------
    path : path
        The bag's folder, or one ``.mcap`` / ``.db3`` file.
    reads_topic : str
        Topic of the reads: ``rfidstudy_msgs/msg/RfidRead`` or ``std_msgs/msg/String``
        (one JSON object per read, :data:`JSON_KEYS`).
    pose_topic : str
        Topic of the robot base's pose in the map (:data:`POSE_TYPES`; ``/tf``: the
        transform chain map -> base_link); ``""``: no poses (fixed antennas).

    Returns
    -------
    reads : pandas.DataFrame
        :data:`pipeline.recording.load.READ_FIELDS`, in time order: ``t_s`` [s since 1970],
        ``antenna_port`` (1-based), ``rssi_dbm`` [dBm], ``epc`` (upper-case hex),
        ``phase_rad`` [rad], ``frequency_hz`` [Hz], ``doppler_hz`` [Hz] (NaN where unknown),
        ``seen_count``.
    poses : pandas.DataFrame or None
        ``t_s, x_m, y_m, yaw_rad`` [s since 1970, m, m, rad in [-pi, pi)], time strictly
        increasing; None without ``pose_topic``.

    Raises
    ------
    RecordingError
        One line naming the bag and the topic: a bag that cannot be opened; a topic the
        bag has not (its topics and types listed) or of another type; an empty topic; a
        message that is no JSON object or lacks a key, a port below 1, an EPC that is not
        hex (naming the message, counted from 1); fewer than two poses.
    """
    path = Path(path).expanduser()
    rd = _open(path)
    try:
        reads = _reads(rd, path, reads_topic)
        poses = _poses(rd, path, pose_topic) if pose_topic else None
    finally:
        rd.close()
    return reads, poses
