"""Robot logs written as ROS bags (rosbags' writers) and as the CSV layout, for the importers' tests.

``Rows``: a robot's raw streams on one clock (commands, detections with landmark ids, truth, the map), either a
slice of MRCLAM Dataset 7 (read with the MRCLAM importer's own functions) or a small synthetic drive. ``write_bag``
writes them in ROS 1, ROS 2 sqlite3 or ROS 2 MCAP, with commands as Twist or TwistStamped and detections as a
custom range/bearing message (parallel arrays or a list of elements) or as marker poses in a camera's optical
frame; truth as PoseStamped. Times are written as the exact decimal the source holds (integer nanoseconds).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path

import numpy as np

from tests._logs import MRCLAM_DATA as DATA

PKG = "aibo_test_msgs"
ARRAYS_MSG = "std_msgs/Header header\nint32[] ids\nfloat64[] ranges\nfloat64[] bearings\n"
ELEMENTS_MSG = ("std_msgs/Header header\nRangeBearing[] detections\n" + "=" * 80 + f"\nMSG: {PKG}/RangeBearing\n"
                "int32 id\nfloat64 range\nfloat64 bearing\n")
MARKERS_MSG = ("std_msgs/Header header\nMarker[] markers\n" + "=" * 80 + f"\nMSG: {PKG}/Marker\n"
               "int32[] id\ngeometry_msgs/PoseStamped pose\n")
DETECTION_TYPES = {"arrays": (f"{PKG}/msg/RangeBearingArray", ARRAYS_MSG),
                   "elements": (f"{PKG}/msg/RangeBearingList", ELEMENTS_MSG),
                   "markers": (f"{PKG}/msg/MarkerArray", MARKERS_MSG)}
FORMATS = ("ros1", "db3", "mcap")
TF_TYPE = "tf2_msgs/msg/TFMessage"


@dataclass
class Rows:
    """Raw streams: commands (N, 3) [t s, v m/s, omega rad/s]; detections (S, 4) [t, id, range m, bearing rad];
    truth (M, 4) [t, x m, y m, theta rad]; landmarks (B, 3) [id, x m, y m]."""

    commands: np.ndarray
    detections: np.ndarray
    truth: np.ndarray
    landmarks: np.ndarray


def mrclam_slice(robot: int = 1, seconds: float = 150.0) -> tuple[Rows, float]:
    """(the first ``seconds`` of an MRCLAM robot's rows, ids mapped to subjects as the importer maps them; the
    ``seconds`` of ``import_robot`` that give the same frames: up to the last command row kept)."""
    from aibo_core.mrclam import _read, file_names

    names = file_names(robot)
    odo = _read(DATA / names["odometry"], "odometry")
    meas = _read(DATA / names["measurement"], "measurement")
    gt = _read(DATA / names["groundtruth"], "groundtruth")
    barcodes = _read(DATA / names["barcodes"], "barcodes").astype(np.int64)
    lm = _read(DATA / names["landmarks"], "landmarks")
    t0 = odo[0, 0]
    odo = odo[odo[:, 0] <= t0 + seconds]
    t_last = odo[-1, 0]
    subject_of = dict(zip(barcodes[:, 1].tolist(), barcodes[:, 0].tolist()))
    meas = meas[(meas[:, 0] >= t0 - 1) & (meas[:, 0] <= t_last + 1)].copy()
    meas[:, 1] = [subject_of.get(int(b), 1000 + int(b)) for b in meas[:, 1]]
    gt = gt[(gt[:, 0] >= t0 - 2) & (gt[:, 0] <= t_last + 2)]
    return Rows(odo, meas, gt, lm), float(t_last - t0)


def drive(seconds: float = 6.0, seed: int = 0, sensor: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Rows:
    """A small synthetic drive: 10 Hz commands, a truth that follows them at 20 Hz, 3 landmarks seen at 5 Hz by a
    sensor at ``sensor`` = (x m forward, y m left, yaw rad) on the robot."""
    rng = np.random.default_rng(seed)
    t = 1000.0 + np.round(np.arange(0.0, seconds, 0.1), 3)
    v, w = rng.uniform(0.05, 0.2, len(t)), rng.uniform(-0.3, 0.3, len(t))
    tt = 1000.0 + np.round(np.arange(0.0, seconds, 0.05), 3)
    th = np.cumsum(np.interp(tt, t, w)) * 0.05
    x, y = np.cumsum(np.interp(tt, t, v) * np.cos(th)) * 0.05, np.cumsum(np.interp(tt, t, v) * np.sin(th)) * 0.05
    lm = np.array([[11, 2.0, 1.0], [12, 3.0, -1.0], [13, 1.0, 2.0]])
    rows = []
    for k in range(0, len(tt), 4):
        c, s = np.cos(th[k]), np.sin(th[k])
        sx, sy = x[k] + c * sensor[0] - s * sensor[1], y[k] + s * sensor[0] + c * sensor[1]
        for ident, lx, ly in lm:
            d = np.hypot(lx - sx, ly - sy)
            b = np.arctan2(ly - sy, lx - sx) - th[k] - sensor[2]
            rows.append([tt[k], ident, d, np.arctan2(np.sin(b), np.cos(b))])
    return Rows(np.column_stack([t, v, w]), np.array(rows), np.column_stack([tt, x, y, th]), lm)


def write_landmarks(path: Path, rows: Rows) -> Path:
    path.write_text("id,x_m,y_m\n" + "".join(f"{int(i)},{float(x)!r},{float(y)!r}\n" for i, x, y in rows.landmarks))
    return path


def write_csv(folder: Path, rows: Rows, truth: bool = True) -> Path:
    """The CSV layout of ``aibo import csv``."""
    folder.mkdir(parents=True, exist_ok=True)
    write_landmarks(folder / "landmarks.csv", rows)
    tables = {"commands": ("t,v_m_s,omega_rad_s", rows.commands), "detections": ("t,id,range_m,bearing_rad", rows.detections)}
    if truth:
        tables["truth"] = ("t,x_m,y_m,theta_rad", rows.truth)
    for name, (head, a) in tables.items():
        lines = [",".join(str(int(v)) if j == 1 and name == "detections" else repr(float(v)) for j, v in enumerate(r)) for r in a]
        (folder / f"{name}.csv").write_text(head + "\n" + "\n".join(lines) + "\n")
    return folder


def ns(t: float) -> int:
    """Integer nanoseconds of the decimal time ``t`` (exact: its shortest repr scaled)."""
    return int(Decimal(repr(float(t))) * 10**9)


class _Store:
    """A typestore of the bag's ROS version with the test's detection types, and message builders."""

    def __init__(self, fmt: str, extra: dict[str, str]):
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.ros1 = fmt == "ros1"
        self.store = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if TF_TYPE not in self.store.types:  # rosbags' ROS 1 store lacks it; ROS 1 bags embed definitions
            extra = {**extra, TF_TYPE: "geometry_msgs/TransformStamped[] transforms\n"}
        for name, text in extra.items():
            self.store.register(get_types_from_msg(text, name))
        self.t = self.store.types

    def header(self, t: float, frame: str = ""):
        sec, nsec = divmod(ns(t), 10**9)
        stamp = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        if self.ros1:
            return self.t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return self.t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def static_transforms(self, t: float, transforms: list[tuple[str, str, tuple, tuple]]):
        """A TFMessage of (parent, child, (x, y, z) m, (qx, qy, qz, qw))."""
        g = self.t
        return g[TF_TYPE](transforms=[g["geometry_msgs/msg/TransformStamped"](
            header=self.header(t, parent), child_frame_id=child, transform=g["geometry_msgs/msg/Transform"](
                translation=g["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=g["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))
            for parent, child, xyz, q in transforms])

    def pose(self, x: float, y: float, z: float, yaw: float):
        g = self.t
        return g["geometry_msgs/msg/Pose"](position=g["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                                           orientation=g["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(yaw / 2),
                                                                                          w=np.cos(yaw / 2)))

    def twist(self, t: float, v: float, w: float, stamped: bool):
        g = self.t
        tw = g["geometry_msgs/msg/Twist"](linear=g["geometry_msgs/msg/Vector3"](x=v, y=0.0, z=0.0),
                                          angular=g["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=w))
        return g["geometry_msgs/msg/TwistStamped"](header=self.header(t), twist=tw) if stamped else tw

    def odometry(self, t: float, v: float, w: float):
        g = self.t
        cov = np.zeros(36)
        return g["nav_msgs/msg/Odometry"](
            header=self.header(t), child_frame_id="base_link",
            pose=g["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(0.0, 0.0, 0.0, 0.0), covariance=cov),
            twist=g["geometry_msgs/msg/TwistWithCovariance"](twist=self.twist(t, v, w, False), covariance=cov))

    def detections(self, kind: str, t: float, group: np.ndarray, frame: str = ""):
        name = DETECTION_TYPES[kind][0]
        h = self.header(t, frame)
        if kind == "arrays":
            return self.t[name](header=h, ids=group[:, 1].astype(np.int32), ranges=group[:, 2].copy(),
                                bearings=group[:, 3].copy())
        if kind == "elements":
            el = self.t[f"{PKG}/msg/RangeBearing"]
            return self.t[name](header=h, detections=[el(id=int(i), range=r, bearing=b) for _, i, r, b in group])
        marker = self.t[f"{PKG}/msg/Marker"]
        ps = self.t["geometry_msgs/msg/PoseStamped"]
        return self.t[name](header=h, markers=[  # optical frame: z forward, x right
            marker(id=np.array([int(i)], np.int32), pose=ps(header=h, pose=self.pose(-r * np.sin(b), 0.0, r * np.cos(b), 0.0)))
            for _, i, r, b in group])

    def serialize(self, msg, msgtype: str) -> bytes:
        return self.store.serialize_ros1(msg, msgtype) if self.ros1 else self.store.serialize_cdr(msg, msgtype)


def bag_path(folder: Path, fmt: str) -> Path:
    return folder / ("robot.bag" if fmt == "ros1" else f"robot_{fmt}")


def write_bag(folder: Path, rows: Rows, fmt: str, detections: str = "arrays", stamped: bool = False,
              odometry: bool = False, truth: bool = True, empty: dict[str, str] | None = None,
              truth_stamps: np.ndarray | None = None, frame: str = "", tf: list | None = None) -> Path:
    """Write ``rows`` as a bag in ``folder`` (topics /cmd_vel, /landmarks, /vicon/pose, with ``odometry`` also
    /odom; ``empty``: {topic: type} of topics without messages; ``truth_stamps``: the truth's header stamps when
    not its record times; ``frame``: the detections' header.frame_id; ``tf``: /tf_static's transforms, one message at
    the start, as ``_Store.static_transforms`` takes them); return the path to give the importer."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    store = _Store(fmt, {name: text for name, text in DETECTION_TYPES.values()})
    path = bag_path(folder, fmt)
    writer = Writer1(path) if fmt == "ros1" else Writer2(
        path, version=9, storage_plugin=StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3)
    twist = "geometry_msgs/msg/TwistStamped" if stamped else "geometry_msgs/msg/Twist"
    det_type = DETECTION_TYPES[detections][0]
    messages = [("/cmd_vel", twist, t, lambda t=t, v=v, w=w: store.twist(t, v, w, stamped)) for t, v, w in rows.commands]
    if odometry:
        messages += [("/odom", "nav_msgs/msg/Odometry", t, lambda t=t, v=v, w=w: store.odometry(t, v, w))
                     for t, v, w in rows.commands]
    for t, group in itertools.groupby(rows.detections, key=lambda r: r[0]):
        g = np.array(list(group))
        messages.append(("/landmarks", det_type, t, lambda t=t, g=g: store.detections(detections, t, g, frame)))
    if tf:
        t0 = float(rows.commands[0, 0])
        messages.append(("/tf_static", TF_TYPE, t0, lambda: store.static_transforms(t0, tf)))
    if truth:
        stamps = rows.truth[:, 0] if truth_stamps is None else truth_stamps
        messages += [("/vicon/pose", "geometry_msgs/msg/PoseStamped", t,
                      lambda s=s, x=x, y=y, th=th: store.t["geometry_msgs/msg/PoseStamped"](
                          header=store.header(s), pose=store.pose(x, y, 0.0, th))) for (t, x, y, th), s in zip(rows.truth, stamps)]
    messages.sort(key=lambda m: m[2])
    with writer:
        conns = {topic: writer.add_connection(topic, msgtype, typestore=store.store) for topic, msgtype in (empty or {}).items()}
        for topic, msgtype, _, _ in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store.store)
        for topic, msgtype, t, build in messages:
            writer.write(conns[topic], ns(t), store.serialize(build(), msgtype))
    if fmt == "mcap":
        return next(path.glob("*.mcap"))  # a bare .mcap file (its folder is a ROS 2 bag too)
    return path
