"""The log file every learner reads: ``aibo-trajectory/2`` (a NumPy ``.npz``).

This module is the contract between robots (simulated or real) and learners. It depends on NumPy
only. ``aibo-trajectory/1`` files still load (converted on read); ``save`` writes ``/2``.

Keys (T frames, S sightings, B landmarks, A discrete commands, k control dimensions):

=================  ===============  ========================================================
key                shape, type      meaning
=================  ===============  ========================================================
format             str              ``"aibo-trajectory/2"``
dt                 float            seconds per frame (> 0)
actions            (T,) int         discrete command per frame (with ``attempted``);
                                    absent when ``controls`` is given
attempted          (A, 3) float     with ``actions``: attempted normalized velocities
controls           (T, k) float     continuous command per frame, held during the frame
control_names      (k,) str         names with units, e.g. ``["v_mm_s", "omega_rad_s"]``
sighting_frame     (S,) int         frame at whose end each sighting was made (non-decreasing;
                                    several may share a frame)
sighting_landmark  (S,) int         index into ``landmarks``
sighting_value     (S, 2) float     [size measurement (> 0), bearing rad (CCW from the body's
                                    heading, wrapped to [-pi, pi])]
sighting_time      (S,) float       optional: when each sighting was made, s after its frame's
                                    end (negative: before it; |t| <= dt); absent: at the end
sensor_kind        str              ``"height_px"`` (pinhole height, px) or ``"range_mm"``
landmarks          (B, 2) float     landmark positions, mm
head_pan           (T,) float       optional: head pan at the end of each frame, rad
field              (2,) float       optional: field length and width, mm, origin at the centre
pose               (T+1, 3) float   optional: true pose (x mm, y mm, theta rad), pose[0] at start
meta               str              optional JSON object: generator, seed, config, ``truth``
=================  ===============  ========================================================
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from dataclasses import field as dataclass_field
from typing import Any

import numpy as np

from .atomic import save_npz
from .npzfile import FileFormatError, Header, fail, read_npz

FORMAT = "aibo-trajectory/2"
FORMAT_V1 = "aibo-trajectory/1"
SENSOR_KINDS = ("height_px", "range_mm")
#: ``control_names`` of commands that are velocities (forward mm/s, turn rad/s): their face value is a motion
VELOCITY_CONTROLS = ("v_mm_s", "omega_rad_s")
#: The largest |command| of each velocity column: 100 m/s and 100 rad/s, beyond any ground robot (a unit's mistake or a
#: corrupt value: one command of 1e9 mm/s made the filter's covariance overflow with no field named).
MAX_VELOCITY_COMMAND = (1e5, 100.0)
#: The frame length's bounds (s): 10 kHz to one frame in 10 s; outside them the log's time unit is wrong (33.3 is a
#: 30 Hz frame in milliseconds).
MIN_DT_S, MAX_DT_S = 1e-4, 10.0
KEYS = ("format", "dt", "actions", "attempted", "controls", "control_names", "sighting_frame",
        "sighting_landmark", "sighting_value", "sighting_time", "sensor_kind", "landmarks", "head_pan", "field", "pose", "meta")
KEYS_V1 = ("format", "dt", "actions", "obs", "beacon", "head_pan", "beacons", "field", "attempted", "pose", "meta")
#: Most frames, sightings, landmarks, commands or control dimensions a log may declare.
MAX_ROWS = 2**31 - 1


class TrajectoryError(FileFormatError):
    """A log that does not follow aibo-trajectory/2 (or /1). The message names file and field."""


@dataclass
class Trajectory:
    """One log: T frames of commands and S sightings (see the module docstring for units)."""

    dt: float
    landmarks: np.ndarray
    sighting_frame: np.ndarray
    sighting_landmark: np.ndarray
    sighting_value: np.ndarray
    sensor_kind: str = "height_px"
    actions: np.ndarray | None = None
    attempted: np.ndarray | None = None
    controls: np.ndarray | None = None
    control_names: tuple[str, ...] | None = None
    head_pan: np.ndarray | None = None
    field: np.ndarray | None = None
    pose: np.ndarray | None = None
    meta: dict[str, Any] = dataclass_field(default_factory=dict)
    #: (S,) s after the end of its frame each sighting was made (negative: before it), None: every one at the end
    sighting_time: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(len(self.actions) if self.actions is not None else len(self.controls))

    @property
    def n_sightings(self) -> int:
        return int(len(self.sighting_frame))

    @property
    def discrete(self) -> bool:
        """True for discrete commands (``actions``), False for continuous ones (``controls``)."""
        return self.actions is not None

    @property
    def truth(self) -> dict[str, Any] | None:
        """Ground truth of a simulated log (``meta["truth"]``), or None for real/blind logs."""
        return self.meta.get("truth")

    def with_sightings(self, keep: np.ndarray) -> "Trajectory":
        """The same log with only the sightings ``keep`` (a boolean mask or increasing indices) and every per-sighting
        array subset alike. ``self`` is not changed."""
        times = None if self.sighting_time is None else self.sighting_time[keep]
        return replace(self, sighting_frame=self.sighting_frame[keep], sighting_landmark=self.sighting_landmark[keep],
                       sighting_value=self.sighting_value[keep], sighting_time=times)

    def validate(self, source: str = "<trajectory>") -> "Trajectory":
        """Check shapes, dtypes and ranges; raise TrajectoryError naming ``source`` and the field."""
        _validate(self, source)
        return self


def _fail(source: str, key: str, what: str):
    fail(source, key, what, TrajectoryError)


def _check_array(source: str, key: str, a: np.ndarray, shape: tuple, kind: str = "fiu") -> None:
    if a.dtype.kind not in kind:
        _fail(source, key, f"expected {'integers' if kind == 'iu' else 'numbers'}, got dtype {a.dtype}")
    if a.shape != shape:
        _fail(source, key, f"expected shape {shape}, got {a.shape}")
    if kind != "iu" and a.size and not np.isfinite(a).all():
        _fail(source, key, f"non-finite value at index {np.argwhere(~np.isfinite(a))[0].tolist()}")


def _check_index(source: str, key: str, a: np.ndarray, shape: tuple, lo: int, hi: int) -> None:
    _check_array(source, key, a, shape, "iu")
    out = (a < lo) | (a > hi)
    if np.any(out):
        i = int(np.argmax(out))
        _fail(source, key, f"value {int(a[i])} at index {i} outside {lo}..{hi}")


def _validate(tr: Trajectory, source: str) -> None:
    if not (isinstance(tr.dt, (int, float)) and np.isfinite(tr.dt) and tr.dt > 0):
        _fail(source, "dt", f"must be a positive number of seconds, got {tr.dt}")
    if not MIN_DT_S <= tr.dt <= MAX_DT_S:
        _fail(source, "dt", f"{tr.dt:g} s per frame is outside {MIN_DT_S:g}..{MAX_DT_S:g} s (dt is seconds, not "
                            "milliseconds)")
    if (tr.actions is None) == (tr.controls is None):
        _fail(source, "actions", "a log has either 'actions' (discrete) or 'controls' (continuous), exactly one")
    T = _check_commands(tr, source)
    L = np.asarray(tr.landmarks)
    if L.ndim != 2 or L.shape[1] != 2 or L.shape[0] < 1:
        _fail(source, "landmarks", f"expected shape (B, 2) with B >= 1, got {L.shape}")
    _check_array(source, "landmarks", L, L.shape)
    S = np.shape(tr.sighting_frame)[0] if np.ndim(tr.sighting_frame) == 1 else -1
    if S < 0:
        _fail(source, "sighting_frame", f"expected shape (S,), got {np.shape(tr.sighting_frame)}")
    _check_index(source, "sighting_frame", tr.sighting_frame, (S,), 0, T - 1)
    if S > 1 and np.any(np.diff(tr.sighting_frame) < 0):
        i = int(np.argmax(np.diff(tr.sighting_frame) < 0)) + 1
        _fail(source, "sighting_frame", f"must be non-decreasing (index {i} goes back)")
    _check_index(source, "sighting_landmark", tr.sighting_landmark, (S,), 0, L.shape[0] - 1)
    _check_array(source, "sighting_value", tr.sighting_value, (S, 2))
    if S and np.any(tr.sighting_value[:, 0] <= 0):
        i = int(np.argmax(tr.sighting_value[:, 0] <= 0))
        _fail(source, "sighting_value", f"size measurement {tr.sighting_value[i, 0]} at row {i} must be > 0")
    if S and np.any(np.abs(tr.sighting_value[:, 1]) > np.pi + 1e-9):
        i = int(np.argmax(np.abs(tr.sighting_value[:, 1]) > np.pi + 1e-9))
        _fail(source, "sighting_value", f"bearing {tr.sighting_value[i, 1]} rad at row {i} is not wrapped to [-pi, pi]")
    if tr.sighting_time is not None:
        _check_array(source, "sighting_time", tr.sighting_time, (S,))
        if S and np.any(np.abs(tr.sighting_time) > tr.dt * (1 + 1e-9)):
            i = int(np.argmax(np.abs(tr.sighting_time) > tr.dt * (1 + 1e-9)))
            _fail(source, "sighting_time", f"{tr.sighting_time[i]} s at row {i} is more than a frame ({tr.dt} s) from "
                                           "its frame's end")
    if tr.sensor_kind not in SENSOR_KINDS:
        _fail(source, "sensor_kind", f"{tr.sensor_kind!r} (valid choices: {', '.join(SENSOR_KINDS)})")
    if tr.head_pan is not None:
        _check_array(source, "head_pan", tr.head_pan, (T,))
    if tr.field is not None:
        _check_array(source, "field", tr.field, (2,))
        if np.any(tr.field <= 0):
            _fail(source, "field", f"length and width must be positive, got {tr.field.tolist()}")
    if tr.pose is not None:
        _check_array(source, "pose", tr.pose, (T + 1, 3))
    if not isinstance(tr.meta, dict):
        _fail(source, "meta", "must be a JSON object")


def _check_commands(tr: Trajectory, source: str) -> int:
    """Validate actions + attempted, or controls + control_names; return T."""
    if tr.actions is not None:
        if np.ndim(tr.actions) != 1 or len(tr.actions) < 1:
            _fail(source, "actions", f"expected shape (T,) with T >= 1, got {np.shape(tr.actions)}")
        if tr.attempted is None:
            _fail(source, "attempted", "missing (required with 'actions')")
        A = np.shape(tr.attempted)[0] if np.ndim(tr.attempted) == 2 else 0
        _check_array(source, "attempted", tr.attempted, (max(A, 1), 3))
        _check_index(source, "actions", tr.actions, (len(tr.actions),), 0, A - 1)
        return len(tr.actions)
    C = np.asarray(tr.controls)
    if C.ndim != 2 or C.shape[0] < 1 or C.shape[1] < 1:
        _fail(source, "controls", f"expected shape (T, k) with T, k >= 1, got {C.shape}")
    _check_array(source, "controls", C, C.shape)
    names = tr.control_names
    if names is None or len(names) != C.shape[1] or not all(isinstance(n, str) and n for n in names):
        _fail(source, "control_names", f"expected {C.shape[1]} non-empty names (one per control column), got {names!r}")
    if len(set(names)) != len(names):
        _fail(source, "control_names", f"a name repeated: {list(names)!r}")
    if set(names) == set(VELOCITY_CONTROLS) and tuple(names) != VELOCITY_CONTROLS:
        _fail(source, "control_names", f"velocity commands' columns are {', '.join(VELOCITY_CONTROLS)} in that order, "
                                       f"got {', '.join(names)}")
    if tuple(names) == VELOCITY_CONTROLS:
        for k, (name, limit) in enumerate(zip(names, MAX_VELOCITY_COMMAND)):
            beyond = np.abs(C[:, k]) > limit
            if beyond.any():
                i = int(np.argmax(beyond))
                _fail(source, "controls", f"{name} {C[i, k]:g} at row {i} is beyond {limit:g} (a velocity command in "
                                          f"{name.split('_', 1)[1].replace('_', '/')})")
    return C.shape[0]


# --------------------------------------------------------------------------- reading


def _as_str(source: str, key: str, value: np.ndarray) -> str:
    if value.dtype.kind not in "US" or value.shape != ():
        _fail(source, key, f"expected a string, got dtype {value.dtype} shape {value.shape}")
    return str(value)


def _header_check(source: str, allowed: tuple[str, ...]):
    """Checks of the declared shapes, before any data is read."""

    def check(headers: dict[str, Header]) -> None:
        if "format" not in headers:
            held = ", ".join(sorted(headers)[:5]) + (", ..." if len(headers) > 5 else "")
            _fail(source, "format", f"missing: not an aibo-trajectory log (its members: {held or 'none'})")
        for key in headers:
            if key not in allowed:
                _fail(source, key, f"unknown key (allowed: {', '.join(allowed)})")
        for key, (shape, _) in headers.items():
            if any(n > MAX_ROWS for n in shape):
                _fail(source, key, f"declares shape {shape}: more than {MAX_ROWS} rows")
        rows = {key: shape[0] for key, (shape, _) in headers.items() if shape and key in _FRAME_KEYS}
        T = rows.get("actions", rows.get("controls"))
        for key, n in rows.items():
            want = T + 1 if key == "pose" else T
            if T is not None and n != want:
                _fail(source, key, f"declares {n} rows but the log has {T} frames ({want} expected)")
        sizes = {key: headers[key][0][0] for key in ("sighting_frame", "sighting_landmark", "sighting_value",
                                                       "sighting_time", "obs", "beacon") if key in headers and headers[key][0]}
        if len(set(sizes.values())) > 1:
            _fail(source, sorted(sizes)[-1], f"declared lengths disagree: {sizes}")

    return check


_FRAME_KEYS = ("actions", "controls", "head_pan", "pose", "obs", "beacon")


def load(path: str | os.PathLike) -> Trajectory:
    """Read and validate an aibo-trajectory/2 (or /1, converted) file. Raises TrajectoryError."""
    source = str(path)
    data = read_npz(path, _header_check(source, tuple(dict.fromkeys(KEYS + KEYS_V1))), TrajectoryError)
    if "format" not in data:
        _fail(source, "format", "missing")
    fmt = _as_str(source, "format", data["format"])
    if fmt not in (FORMAT, FORMAT_V1):
        _fail(source, "format", f"expected '{FORMAT}' (or '{FORMAT_V1}'), got '{fmt}'")
    allowed = KEYS if fmt == FORMAT else KEYS_V1
    for key in data:
        if key not in allowed:
            _fail(source, key, f"unknown key in {fmt} (allowed: {', '.join(allowed)})")
    dt = data.get("dt")
    if dt is None or dt.shape != () or dt.dtype.kind not in "fiu":
        _fail(source, "dt", "missing" if dt is None else f"expected a scalar number, got shape {dt.shape}")
    meta = _read_meta(source, data)
    tr = _from_v1(source, data, meta) if fmt == FORMAT_V1 else _from_v2(source, data, meta)
    tr.validate(source)
    return _canonical(tr)


def _read_meta(source: str, data: dict[str, np.ndarray]) -> dict[str, Any]:
    if "meta" not in data:
        return {}
    text = _as_str(source, "meta", data["meta"])
    try:
        meta = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        _fail(source, "meta", f"not valid JSON ({getattr(exc, 'msg', exc)})")
    if not isinstance(meta, dict):
        _fail(source, "meta", "must be a JSON object")
    return meta


def _require(source: str, data: dict[str, np.ndarray], keys: tuple[str, ...]) -> None:
    for key in keys:
        if key not in data:
            _fail(source, key, "missing")


def _from_v2(source: str, data: dict[str, np.ndarray], meta: dict[str, Any]) -> Trajectory:
    _require(source, data, ("sighting_frame", "sighting_landmark", "sighting_value", "sensor_kind", "landmarks"))
    names = data.get("control_names")
    if names is not None:
        if names.dtype.kind not in "US" or names.ndim != 1:
            _fail(source, "control_names", f"expected (k,) strings, got dtype {names.dtype} shape {names.shape}")
        names = tuple(str(n) for n in names)
    return Trajectory(
        dt=float(data["dt"]), landmarks=data["landmarks"], sighting_frame=data["sighting_frame"],
        sighting_landmark=data["sighting_landmark"], sighting_value=data["sighting_value"],
        sensor_kind=_as_str(source, "sensor_kind", data["sensor_kind"]), actions=data.get("actions"),
        attempted=data.get("attempted"), controls=data.get("controls"), control_names=names,
        head_pan=data.get("head_pan"), field=data.get("field"), pose=data.get("pose"), meta=meta,
        sighting_time=data.get("sighting_time"),
    )


def _from_v1(source: str, data: dict[str, np.ndarray], meta: dict[str, Any]) -> Trajectory:
    """aibo-trajectory/1 (one optional sighting per frame: ``obs`` NaN rows, ``beacon`` -1) to /2."""
    _require(source, data, ("actions", "obs", "beacon", "head_pan", "beacons", "field", "attempted"))
    obs, beacon = data["obs"], data["beacon"]
    T = len(data["actions"]) if data["actions"].ndim == 1 else -1
    if beacon.dtype.kind not in "iu" or beacon.shape != (T,):
        _fail(source, "beacon", f"expected ({T},) integers, got dtype {beacon.dtype} shape {beacon.shape}")
    if obs.dtype.kind != "f" or obs.shape != (T, 2) or np.isinf(obs).any():
        _fail(source, "obs", f"expected ({T}, 2) floats (NaN rows where none), got {obs.dtype} {obs.shape}")
    seen = beacon >= 0
    mismatch = seen == np.isnan(obs).any(axis=1)
    if np.any(mismatch):
        i = int(np.argmax(mismatch))
        what = "NaN sighting for a seen beacon" if seen[i] else "a sighting where beacon is -1"
        _fail(source, "obs", f"row {i}: {what} (obs must be NaN exactly where beacon == -1)")
    frames = np.flatnonzero(seen)
    return Trajectory(
        dt=float(data["dt"]), landmarks=data["beacons"], sighting_frame=frames, sighting_landmark=beacon[frames],
        sighting_value=obs[frames], sensor_kind="height_px", actions=data["actions"], attempted=data["attempted"],
        head_pan=data["head_pan"], field=data["field"], pose=data.get("pose"), meta=meta,
    )


def _canonical(tr: Trajectory) -> Trajectory:
    """Arrays in their canonical dtypes (int64 indices, float64 values)."""
    f64 = {k: np.asarray(getattr(tr, k), dtype=np.float64) for k in
           ("landmarks", "sighting_value", "sighting_time", "attempted", "controls", "head_pan", "field", "pose")
           if getattr(tr, k) is not None}
    i64 = {k: np.asarray(getattr(tr, k), dtype=np.int64) for k in ("sighting_frame", "sighting_landmark", "actions")
           if getattr(tr, k) is not None}
    return replace(tr, dt=float(tr.dt), **f64, **i64)


# --------------------------------------------------------------------------- writing


def to_arrays(tr: Trajectory) -> dict[str, np.ndarray]:
    """The ``.npz`` members of ``tr`` (aibo-trajectory/2), canonical dtypes, fixed key order."""
    tr = _canonical(tr)
    arrays: dict[str, Any] = {"format": np.array(FORMAT), "dt": np.array(tr.dt)}
    for key in KEYS[2:-1]:
        value = getattr(tr, key)
        if value is None:
            continue
        if key == "control_names":
            value = np.array(list(value), dtype=str)
        elif key == "sensor_kind":
            value = np.array(value)
        arrays[key] = value
    if tr.meta:
        arrays["meta"] = np.array(json.dumps(tr.meta, sort_keys=True))
    return arrays


def save(tr: Trajectory, path: str | os.PathLike) -> None:
    """Validate and write ``tr`` as aibo-trajectory/2, atomically (any existing file stays on failure)."""
    tr.validate(str(path))
    save_npz(path, to_arrays(tr))


def blind(tr: Trajectory) -> Trajectory:
    """The same log as a real robot would have it: no ``pose``, and nothing in meta that names what the
    simulator hid: no ``truth`` and no ``config["effects"]`` (the rest of the config, e.g. the field and
    the camera, stays: a real robot's owner knows those). ``tr`` is not changed."""
    meta = {k: v for k, v in tr.meta.items() if k != "truth"}
    if isinstance(meta.get("config"), dict):
        meta["config"] = {k: v for k, v in meta["config"].items() if k != "effects"}
    return replace(tr, pose=None, meta=meta)


def sightings_per_frame(tr: Trajectory) -> np.ndarray:
    """(T,) number of sightings at the end of each frame."""
    return np.bincount(tr.sighting_frame, minlength=tr.n_frames)


def head(tr: Trajectory, k: int) -> Trajectory:
    """The first ``k`` frames of ``tr`` (copies) with their sightings; ``pose`` keeps k + 1 rows."""
    if not 1 <= k <= tr.n_frames:
        raise ValueError(f"k must be in 1..{tr.n_frames}, got {k}")
    n = int(np.searchsorted(tr.sighting_frame, k))
    cut = {key: getattr(tr, key)[:k].copy() for key in ("actions", "controls", "head_pan") if getattr(tr, key) is not None}
    return replace(tr.with_sightings(np.arange(n)), pose=None if tr.pose is None else tr.pose[: k + 1].copy(), **cut)
