"""A ROS bag (ROS 1 ``.bag``, ROS 2 folder with ``.db3`` or ``.mcap``, bare ``.mcap``) -> an aibo-trajectory/2 log.

Read with ``rosbags`` (pure Python, no ROS install; the optional extra ``bags``), imported here only when a bag is
read. Units as ROS has them (REP 103: metres, radians, seconds; x forward, y left, yaw CCW):

- commands: ``geometry_msgs/Twist`` or ``TwistStamped`` (``linear.x`` m/s, ``angular.z`` rad/s), each held until
  the next message; or, for a robot that logged no commands, the measured twist of ``nav_msgs/Odometry`` (said
  so in ``meta["command_source"]``);
- detections, either (a) id, range (m) and bearing (rad, CCW from the heading) as parallel arrays or as a list of
  elements, found by their names (``id``/``ids``, ``range``/``ranges``, ``bearing``/``bearings``, or those given),
  or (b) marker poses in the sensor frame (AprilTag/ALVAR style: an id and a ``pose`` that reaches a
  ``geometry_msgs/Pose``), turned into planar range and bearing: ``optical`` frame (z forward, x right: the camera
  convention) or ``body`` (x forward, y left); a marker with several ids (AprilTag bundles) counts as its first;
- truth (optional): ``PoseStamped``, ``PoseWithCovarianceStamped``, ``Odometry`` or ``TransformStamped``: x, y and
  the yaw of the quaternion; the log's ``pose``, used only to score a fit;
- where the sensor sits (optional): given (``BagOptions.sensor``), or read from ``/tf_static`` (``sensor_from_tf``:
  each detection message's ``header.frame_id`` placed under ``base_frame`` by ``aibo_core.static_tf``, its detections
  moved to the robot's origin, marker poses as 3-D points).

Times: each message's ``header.stamp`` when its type has a header (``time="header"``, the default), else, or with
``time="log"``, the time the bag recorded it. Types the bag does not define come from ``--msg-def`` files or the
standard ROS types (Noetic for ROS 1 bags, Humble for ROS 2). Frames as in ``aibo_core.timed_log``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from .csv_import import check_bearings, dedupe, landmark_index, ordered, read_landmark_map
from .static_tf import StaticTransforms
from .timed_log import LogSourceError, SensorPose, Streams, build
from .trajectory import Trajectory

DEFAULT_NAMES = {"id": ("id", "ids"), "range": ("range", "ranges"), "bearing": ("bearing", "bearings")}
MARKER_FRAMES = ("optical", "body")
TF_STATIC = "/tf_static"
TIME_SOURCES = ("header", "log")


@dataclass
class BagOptions:
    """What to read from a bag: topics (``commands`` or ``odometry`` required), detection field names (None:
    the defaults), the marker frame, the time source, extra message definitions ``(type or None, path)``
    (None: the detections topic's type) and where the sensor sits on the robot (``timed_log.SensorPose``, or with
    ``sensor_from_tf`` the bag's static transforms from ``base_frame`` to each detection message's frame)."""

    detections: str
    commands: str | None = None
    odometry: str | None = None
    truth: str | None = None
    id_field: str | None = None
    range_field: str | None = None
    bearing_field: str | None = None
    marker_frame: str = "optical"
    time: str = "header"
    msg_defs: tuple[tuple[str | None, str], ...] = ()
    sensor: SensorPose = SensorPose()
    sensor_from_tf: bool = False  # the detections' frames placed on the robot by the bag's /tf_static instead
    base_frame: str = "base_link"  # the robot's frame in /tf_static (its origin: the point the commands turn about)


class _Bag:
    """An open bag: topics, types and message iteration, every failure a LogSourceError naming the bag."""

    def __init__(self, path: Path, msg_defs: tuple[tuple[str | None, str], ...], detections_topic: str):
        try:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise LogSourceError(f"{path}: reading bags needs the 'rosbags' package: pip install 'aibo-gym[bags]' "
                                 "(or pip install rosbags)") from None
        if not path.exists():
            raise LogSourceError(f"{path}: no such file or folder (give a ROS 1 .bag, a ROS 2 bag folder or a .mcap)")
        if path.name == "metadata.yaml":
            raise LogSourceError(f"{path}: a ROS 2 bag's metadata file: give the bag's folder, {path.parent}")
        if path.is_dir() and not (path / "metadata.yaml").exists():
            raise LogSourceError(f"{path}: a folder without metadata.yaml is no ROS 2 bag (give the bag's folder, a .bag "
                                 "or a .mcap file)")
        self.path = path
        self.default = get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.ROS2_HUMBLE)
        self.reader = self._call(lambda: AnyReader([path], default_typestore=self.default), "cannot open")
        self._call(self.reader.open, "cannot read")
        self.topics = {name: info for name, info in self.reader.topics.items()}
        self._register(msg_defs, detections_topic)

    def _call(self, fn: Callable[[], Any], what: str) -> Any:
        try:
            return fn()
        except LogSourceError:
            raise
        except Exception as exc:  # rosbags' and the storage libraries' many errors on a damaged bag
            text = " ".join(str(exc).split()) or type(exc).__name__
            raise LogSourceError(f"{self.path}: {what}: {text} (a damaged or truncated bag?)") from None

    def _register(self, msg_defs: tuple[tuple[str | None, str], ...], detections_topic: str) -> None:
        """Types the bag does not define: from ``msg_defs``, else from the standard ROS types."""
        from rosbags.typesys import get_types_from_msg

        store = self.reader.typestore
        typs: dict[str, Any] = {}
        for name, file in msg_defs:
            name = name or (self.topics[detections_topic].msgtype if detections_topic in self.topics else None)
            if name is None:
                continue
            try:
                typs.update(get_types_from_msg(Path(file).read_text(), name))
            except OSError as exc:
                raise LogSourceError(f"--msg-def {file}: cannot read ({exc.strerror or exc})") from None
            except Exception as exc:
                raise LogSourceError(f"--msg-def {file}: not a .msg definition of {name} ({' '.join(str(exc).split())})") from None
        typs.update({k: v for k, v in self.default.fielddefs.items() if k not in store.fielddefs and k not in typs})
        typs = {k: v for k, v in typs.items() if k not in store.fielddefs}
        self._call(lambda: store.register(typs), "cannot register the message types")

    def close(self) -> None:
        self.reader.close()

    def topic_type(self, topic: str, option: str) -> str:
        """The topic's message type; a missing or empty topic is a LogSourceError listing what the bag has."""
        if topic not in self.topics:
            held = ", ".join(f"{n} ({i.msgtype})" for n, i in sorted(self.topics.items())) or "none"
            raise LogSourceError(f"{self.path}: {option} {topic}: no such topic; the bag has: {held}")
        info = self.topics[topic]
        if not info.msgcount:
            raise LogSourceError(f"{self.path}: {option} {topic}: the topic has no messages")
        if info.msgtype not in self.reader.typestore.fielddefs:
            raise LogSourceError(f"{self.path}: {option} {topic}: the bag holds no definition of its type "
                                 f"{info.msgtype}; give it with --msg-def FILE.msg")
        return info.msgtype

    def fields(self, msgtype: str) -> dict[str, tuple]:
        """{field name: (node type, spec)} of a registered type."""
        return dict(self.reader.typestore.fielddefs[msgtype][1])

    def messages(self, topic: str) -> Iterator[tuple[int, Any]]:
        """(log time ns, message) of the topic, in the bag's order."""
        conns = [c for c in self.reader.connections if c.topic == topic]
        it = iter(self.reader.messages(connections=conns))
        while True:
            item = self._call(lambda: next(it, None), f"topic {topic}: cannot read a message")
            if item is None:
                return
            conn, t_ns, raw = item
            yield t_ns, self._call(lambda: self.reader.deserialize(raw, conn.msgtype), f"topic {topic}: cannot decode a message")


def _stamp_ns(msg: Any, log_ns: int, time: str) -> int:
    header = getattr(msg, "header", None)
    if time == "header" and header is not None:
        return int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)
    return int(log_ns)


def _finite(where: str, rows: list[Any], names: tuple[str, ...]) -> np.ndarray:
    """(N, len(names)) float of one value tuple per message; a value that is not finite refused, its message named."""
    values = np.array(rows, float).reshape(-1, len(names))
    bad = ~np.isfinite(values)
    if bad.any():
        i, k = (int(v[0]) for v in np.nonzero(bad))
        raise LogSourceError(f"{where}: message {i + 1}: {names[k]} is {float(values[i, k])!r} (not a finite number)")
    return values


def _read_topic(bag: _Bag, topic: str, option: str, time: str,
                extract: Callable[[Any], Any]) -> tuple[np.ndarray, list[Any]]:
    """(times s (N,), extracted values) of a topic; times must not go back; header stamps must be set."""
    ns, values = [], []
    for log_ns, msg in bag.messages(topic):
        ns.append(_stamp_ns(msg, log_ns, time))
        values.append(extract(msg))
    if not ns:
        raise LogSourceError(f"{bag.path}: {option} {topic}: the topic has no messages")
    t = np.array([n / 10**9 for n in ns])  # Python's int / int: the nearest double to the exact time
    source = "header.stamp" if time == "header" and hasattr(msg, "header") else "log time"
    if source == "header.stamp" and min(ns) == 0:
        raise LogSourceError(f"{bag.path}: {option} {topic}: message {ns.index(0) + 1} has header.stamp 0 (not set by its "
                             "publisher); use --time log for the bag's record times")
    ordered(f"{bag.path}: {option} {topic} ({source})", t, "message")
    return t, values


def _descend(msg: Any, wanted: tuple[str, ...], via: tuple[str, ...]) -> Any:
    """``msg`` or the first object down its ``via`` attributes that has every ``wanted`` attribute."""
    for _ in range(6):
        if all(hasattr(msg, w) for w in wanted):
            return msg
        msg = next((getattr(msg, v) for v in via if hasattr(msg, v)), None)
        if msg is None:
            break
    return None


def _twist(bag: _Bag, option: str, topic: str, msg: Any) -> tuple[float, float]:
    tw = _descend(msg, ("linear", "angular"), ("twist",))
    if tw is None:
        raise LogSourceError(f"{bag.path}: {option} {topic}: type {msg.__msgtype__} holds no twist (linear, angular): "
                             "give geometry_msgs/Twist, TwistStamped or nav_msgs/Odometry")
    return float(tw.linear.x) * 1000.0, float(tw.angular.z)


def _planar_pose(bag: _Bag, topic: str, msg: Any) -> tuple[float, float, float]:
    p = _descend(msg, ("position", "orientation"), ("pose", "transform"))
    if p is None:
        p = _descend(msg, ("translation", "rotation"), ("transform",))
        if p is None:
            raise LogSourceError(f"{bag.path}: --truth {topic}: type {msg.__msgtype__} holds no pose: give "
                                 "geometry_msgs/PoseStamped, TransformStamped or nav_msgs/Odometry")
        pos, q = p.translation, p.rotation
    else:
        pos, q = p.position, p.orientation
    yaw = np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    return float(pos.x), float(pos.y), float(yaw)


@dataclass
class _Layout:
    """Where a detection type keeps id, range and bearing (``kind``: parallel, elements, markers)."""

    kind: str
    items: str | None  # the list field of elements/markers (None: the message itself)
    id: str
    range: str | None = None
    bearing: str | None = None


def _pick(names: dict[str, tuple], given: str | None, key: str) -> str | None:
    if given is not None:
        return given if given in names else None
    return next((n for n in DEFAULT_NAMES[key] if n in names), None)


def _layout_of(bag: _Bag, topic: str, msgtype: str, opts: BagOptions) -> _Layout:
    """Find id, range and bearing (or a marker pose) in the type's fields, then in those of a list field's element."""
    given = {"id": opts.id_field, "range": opts.range_field, "bearing": opts.bearing_field}

    def match(fields: dict[str, tuple], items: str | None) -> _Layout | None:
        found = {k: _pick(fields, given[k], k) for k in given}
        if all(found.values()):
            return _Layout("parallel" if items is None else "elements", items, found["id"], found["range"], found["bearing"])
        if found["id"] and "pose" in fields:
            return _Layout("markers", items, found["id"])
        return None

    fields = bag.fields(msgtype)
    layout = match(fields, None)
    for name, (node, spec) in fields.items():
        if layout is not None:
            break
        if int(node) in (3, 4) and int(spec[0][0]) == 2:  # ARRAY or SEQUENCE of a message type
            element = spec[0][1]
            if element in bag.reader.typestore.fielddefs:
                layout = match(bag.fields(element), name)
    if layout is None:
        names = {k: given[k] or "/".join(DEFAULT_NAMES[k]) for k in given}
        raise LogSourceError(f"{bag.path}: --detections {topic}: cannot read detections from type {msgtype} (fields: "
                             f"{', '.join(fields)}): expected fields {names['id']}, {names['range']} and {names['bearing']} "
                             "(or an id and a pose), in the message or in a list of elements; name others with --id-field, "
                             "--range-field, --bearing-field")
    return layout


#: A detection without an id or a position: counted as an unknown id.
_NO_ID = -(2**62)


def _frame_id(obj: Any) -> str:
    """The ``header.frame_id`` of a message (or a PoseStamped), "" where it has none."""
    header = getattr(obj, "header", None)
    return str(getattr(header, "frame_id", "") or "")


def _marker(elem: Any, layout: _Layout) -> tuple[int, float, float, float, str]:
    """(id, x, y, z m in the marker's frame, that frame's name where its pose carries one)."""
    ident = np.atleast_1d(getattr(elem, layout.id))
    p = _descend(elem.pose, ("position",), ("pose",))
    if p is None or len(ident) == 0:
        return _NO_ID, 0.0, 0.0, 0.0, ""
    return ident[0], float(p.position.x), float(p.position.y), float(p.position.z), _frame_id(elem.pose)


def _marker_range_bearing(x: float, y: float, z: float, frame: str) -> tuple[float, float]:
    """Planar range and bearing of a marker at (x, y, z) in the sensor frame (``--marker-frame``)."""
    forward, left = (z, -x) if frame == "optical" else (x, y)
    return float(np.hypot(forward, left)), float(np.arctan2(left, forward))


def _detections(bag: _Bag, topic: str, layout: _Layout, msg: Any) -> list[tuple]:
    """The message's detections: (id, range m, bearing rad) or, for marker poses, ``_marker``'s (id, x, y, z, frame);
    each id as the message holds it (``_landmark_ids`` checks them)."""
    if layout.kind == "parallel":
        ids, r, b = (np.atleast_1d(np.asarray(getattr(msg, f))) for f in (layout.id, layout.range, layout.bearing))
        if not len(ids) == len(r) == len(b):
            raise LogSourceError(f"{bag.path}: --detections {topic}: a message holds {len(ids)} ids, {len(r)} ranges and "
                                 f"{len(b)} bearings: the arrays must be parallel")
        return [(i, float(x), float(y)) for i, x, y in zip(ids, r, b)]
    elems = getattr(msg, layout.items) if layout.items else [msg]
    if layout.kind == "elements":
        return [(np.atleast_1d(getattr(e, layout.id))[0], float(getattr(e, layout.range)),
                 float(getattr(e, layout.bearing))) for e in elems]
    return [_marker(e, layout) for e in elems]


def _placer(bag: _Bag, opts: BagOptions, tf: StaticTransforms) -> Callable[[str], tuple[np.ndarray, np.ndarray]]:
    """frame name -> (R, t) taking its points into ``opts.base_frame`` (``StaticTransforms.transform``), each frame's
    chain composed once; a detection without a frame, or a frame the transforms do not join, is a LogSourceError."""
    placed: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def place(frame: str) -> tuple[np.ndarray, np.ndarray]:
        if frame not in placed:
            if not frame:
                raise LogSourceError(f"{bag.path}: --detections {opts.detections}: a message has no header.frame_id, so "
                                     "--sensor-pose tf cannot place it on the robot; give --sensor-pose X,Y,YAW")
            found = tf.transform(opts.base_frame, frame)
            if found is None:
                raise LogSourceError(f"{bag.path}: --sensor-pose tf: no static transform joins --base-frame "
                                     f"{opts.base_frame} and the detections' frame {frame} in {TF_STATIC} (frames there: "
                                     f"{', '.join(tf.frames()) or 'none'})")
            placed[frame] = found
        return placed[frame]

    return place


def _on_the_robot(place: Callable[[str], tuple[np.ndarray, np.ndarray]], frame: str, marker: bool,
                  det: tuple) -> tuple[int, float, float]:
    """(id, range m, bearing rad) from the robot's origin of a detection in ``frame`` (its marker pose's own frame
    first; ``place``: ``_placer``'s): a marker's point as given, a range and bearing as a point in the frame's x-y
    plane."""
    ident, point = det[0], (det[1:4] if marker else (det[1] * np.cos(det[2]), det[1] * np.sin(det[2]), 0.0))
    if ident == _NO_ID:
        return _NO_ID, 0.0, 0.0
    R, t = place(det[4] if marker and det[4] else frame)
    x, y, _ = R @ np.asarray(point, float) + t
    return ident, float(np.hypot(x, y)), float(np.arctan2(y, x))


def _read_detections(bag: _Bag, opts: BagOptions, tf: StaticTransforms | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times s (S,), ids (S,), [range m, bearing rad] (S, 2)): every detection, its message's time; with ``tf``,
    from the robot's origin (``_on_the_robot``), else as the sensor measured it (marker poses by ``--marker-frame``)."""
    topic = opts.detections
    layout = _layout_of(bag, topic, bag.topic_type(topic, "--detections"), opts)
    marker = layout.kind == "markers"
    place = None if tf is None else _placer(bag, opts, tf)

    def extract(msg: Any) -> list[tuple[int, float, float]]:
        dets = _detections(bag, topic, layout, msg)
        if place is not None:
            return [_on_the_robot(place, _frame_id(msg), marker, d) for d in dets]
        return [(d[0], *_marker_range_bearing(*d[1:4], opts.marker_frame)) if marker else d for d in dets]

    t, per_msg = _read_topic(bag, topic, "--detections", opts.time, extract)
    counts = [len(d) for d in per_msg]
    rows = [d for ds in per_msg for d in ds]
    if not rows:
        raise LogSourceError(f"{bag.path}: --detections {topic}: {len(per_msg)} messages but not one detection")
    message = np.repeat(np.arange(1, len(per_msg) + 1), counts)  # each detection's message, counted from 1
    where = f"{bag.path}: --detections {topic}"
    ids = _landmark_ids(where, [r[0] for r in rows], message)
    values = np.array([r[1:] for r in rows], dtype=float)
    for k, name in enumerate(("range", "bearing")):
        if not np.isfinite(values[:, k]).all():
            i = int(np.argmin(np.isfinite(values[:, k])))
            raise LogSourceError(f"{where}: message {message[i]}: a {name} of {float(values[i, k])!r} (not a finite "
                                 "number)")
    check_bearings(where, values[:, 1], lambda i: f"message {message[i]}")
    return np.repeat(t, counts), ids, values


def _plain(v: Any) -> Any:
    """A NumPy scalar as the Python value it holds (for messages: 11.7, not np.float64(11.7))."""
    return v.item() if isinstance(v, np.generic) else v


def _landmark_ids(where: str, raw: list[Any], message: np.ndarray) -> np.ndarray:
    """(S,) int64: the detections' ids as the messages hold them (integers, integral floats, or strings of integers;
    ``_NO_ID`` kept); any other one refused, its message named."""
    out = np.empty(len(raw), dtype=np.int64)
    for i, v in enumerate(raw):
        try:
            x = float(v) if isinstance(v, (str, bytes, np.str_)) else v
            if isinstance(x, (float, np.floating)) and not (math.isfinite(x) and x == round(x)):
                raise ValueError
            out[i] = int(x)
        except (TypeError, ValueError, OverflowError):
            raise LogSourceError(f"{where}: message {message[i]}: the id {_plain(v)!r} is not an integer (landmark ids are "
                                 "the map's integers)") from None
    return out


def _static_transforms(bag: _Bag) -> StaticTransforms:
    """The bag's ``/tf_static`` (every message's transforms; refused when the bag has no such topic)."""
    bag.topic_type(TF_STATIC, "--sensor-pose tf")
    tf = StaticTransforms()
    for _, msg in bag.messages(TF_STATIC):
        for ts in getattr(msg, "transforms", []):
            tr, q = ts.transform.translation, ts.transform.rotation
            try:
                tf.add(ts.header.frame_id, ts.child_frame_id, (tr.x, tr.y, tr.z), (q.x, q.y, q.z, q.w))
            except ValueError as exc:
                raise LogSourceError(f"{bag.path}: {TF_STATIC}: the transform to {ts.child_frame_id}: {exc}") from None
    return tf


def read_streams(path: str | os.PathLike, landmarks_csv: str | os.PathLike,
                 opts: BagOptions) -> tuple[Streams, dict[str, Any]]:
    """The bag's streams (``aibo_core.timed_log``) and the log's meta (source, topics, counts)."""
    if opts.marker_frame not in MARKER_FRAMES or opts.time not in TIME_SOURCES:
        raise LogSourceError(f"marker frame {opts.marker_frame!r} / time {opts.time!r}: expected one of "
                             f"{MARKER_FRAMES} / {TIME_SOURCES}")
    if (opts.commands is None) == (opts.odometry is None):
        raise LogSourceError("give the commands topic (--commands) or, for a robot that logged none, --odometry (one of them)")
    map_ids, landmarks = read_landmark_map(landmarks_csv)
    path = Path(path)
    bag = _Bag(path, opts.msg_defs, opts.detections)
    try:
        option, topic = ("--commands", opts.commands) if opts.commands else ("--odometry", opts.odometry)
        bag.topic_type(topic, option)
        cmd_t, cmds = _read_topic(bag, topic, option, opts.time, lambda m: _twist(bag, option, topic, m))
        cmds = _finite(f"{bag.path}: {option} {topic}", cmds, ("linear.x", "angular.z"))
        cmd_t, cmds, repeated = dedupe(cmd_t, cmds)
        tf = _static_transforms(bag) if opts.sensor_from_tf else None
        det_t, ids, values = _read_detections(bag, opts, tf)
        truth_t = truth = None
        if opts.truth:
            bag.topic_type(opts.truth, "--truth")
            truth_t, poses = _read_topic(bag, opts.truth, "--truth", opts.time, lambda m: _planar_pose(bag, opts.truth, m))
            poses = _finite(f"{bag.path}: --truth {opts.truth}", poses, ("x", "y", "yaw"))
            truth_t, truth, truth_rep = dedupe(truth_t, poses)
        types = {t: bag.topics[t].msgtype for t in (topic, opts.detections, opts.truth) if t}
    finally:
        bag.close()
    lm = landmark_index(ids, map_ids)
    streams = Streams(command_t=cmd_t, commands=cmds, sighting_t=det_t, sighting_landmark=lm,
                      sighting_value=values * [1000.0, 1.0], landmarks=landmarks, truth_t=truth_t, truth=truth)
    dropped = {"command_messages_repeated": repeated}
    if opts.truth:
        dropped["truth_messages_repeated"] = truth_rep
    meta = {"generator": "aibo_core.rosbag_import",
            "source": {"bag": path.resolve().name, "topics": types, "time": opts.time,
                       "marker_frame": opts.marker_frame, "landmarks": Path(landmarks_csv).name},
            "command_source": "commands" if opts.commands else "odometry (measured velocities, not commands)",
            "landmark_ids": map_ids.tolist(), "dropped": dropped,
            "unknown_ids": sorted({int(i) for i in ids[lm < 0] if i > _NO_ID})}
    if tf is not None:
        meta["sensor_pose"] = {"from": TF_STATIC, "base_frame": opts.base_frame}
    return streams, meta


def import_bag(path: str | os.PathLike, landmarks_csv: str | os.PathLike, opts: BagOptions, dt: float) -> Trajectory:
    """The bag as an aibo-trajectory/2 log in frames of ``dt`` s (module docstring)."""
    streams, meta = read_streams(path, landmarks_csv, opts)
    return build(streams, dt, meta, str(path), opts.sensor)
