"""Timestamped streams of one robot -> an aibo-trajectory/2 log in frames of ``dt`` seconds.

NumPy only. Every importer of a real robot's log (MRCLAM's text files, a ROS bag, the CSV layout) reads its
source into the same streams, all on one clock (s, any epoch):

- commands: (N,) times and (N, 2) ``[v mm/s, omega rad/s]``, each held until the next;
- sightings: (S,) times, (S,) landmark index (-1: an id the map does not hold), (S, 2) ``[range mm, bearing rad]``;
- truth (optional): (M,) times, (M, 3) ``[x m, y m, theta rad]`` (e.g. motion capture).

and ``build`` turns them into a log the way ``aibo import mrclam`` always has: frames from the first command
(``t0``) to the end of the commands (and of the truth, when given); each frame's control the exact average of
the held command over the frame; each sighting at the frame whose end is nearest its time, and its time from that
end kept (``sighting_time``); the truth
interpolated at the frame boundaries (x, y linear, theta unwrapped), poses inside a gap longer than ``GAP_S``
flagged in ``meta["pose_gaps"]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .geometry import wrap
from .trajectory import VELOCITY_CONTROLS, Trajectory

#: A ground-truth interval longer than this (s) is a dropout: poses inside it are flagged.
GAP_S = 0.1
#: Times (s) this close are one time where a frame boundary meets a truth row: t0 + k dt misses a row at the same
#: time by rounding (0 + 3 x 0.1 = 0.30000000000000004; at Unix-epoch times a double's step is 2.4e-7 s).
TIME_SLACK_S = 1e-6


class LogSourceError(ValueError):
    """A robot's log that cannot be imported: one line naming the file (or topic) and what is wrong."""


@dataclass(frozen=True)
class SensorPose:
    """Where the sensor sits on the robot: its origin ``x_mm`` forward and ``y_mm`` left of the robot's origin (the
    point the commands turn about and the truth tracks), its axis ``yaw_rad`` counter-clockwise of the robot's
    heading (REP 103's base frame)."""

    x_mm: float = 0.0
    y_mm: float = 0.0
    yaw_rad: float = 0.0

    def is_origin(self) -> bool:
        return self.x_mm == 0.0 and self.y_mm == 0.0 and self.yaw_rad == 0.0

    def as_meta(self) -> dict[str, float]:
        """The log's ``meta["sensor_pose"]`` (m, m, rad: the units the importers' option takes)."""
        return {"x_m": self.x_mm / 1000.0, "y_m": self.y_mm / 1000.0, "yaw_rad": self.yaw_rad}


def sensor_from_option(x_y_yaw: tuple[float, float, float]) -> SensorPose:
    """The importers' ``--sensor-pose X,Y,YAW`` (m, m, rad) as a ``SensorPose``."""
    return SensorPose(x_mm=1000.0 * x_y_yaw[0], y_mm=1000.0 * x_y_yaw[1], yaw_rad=x_y_yaw[2])


def from_sensor(values: np.ndarray, sensor: SensorPose) -> np.ndarray:
    """(S, 2) ``[range mm, bearing rad]`` measured from ``sensor`` -> the same landmarks' range and bearing from the
    robot's origin (bearing wrapped to [-pi, pi))."""
    r, b = values[:, 0], values[:, 1] + sensor.yaw_rad
    x = sensor.x_mm + r * np.cos(b)
    y = sensor.y_mm + r * np.sin(b)
    return np.stack([np.hypot(x, y), wrap(np.arctan2(y, x))], axis=1)


@dataclass
class Streams:
    """One robot's measurements on one clock (module docstring for units)."""

    command_t: np.ndarray
    commands: np.ndarray
    sighting_t: np.ndarray
    sighting_landmark: np.ndarray
    sighting_value: np.ndarray
    landmarks: np.ndarray
    truth_t: np.ndarray | None = None
    truth: np.ndarray | None = None


def increasing(t: np.ndarray) -> tuple[np.ndarray, int, int]:
    """(mask of rows to keep: times strictly after every kept row before, repeated, backward)."""
    prev = np.maximum.accumulate(np.concatenate([[-np.inf], t[:-1]]))
    keep = t > prev
    return keep, int(np.sum(t == prev)), int(np.sum(t < prev))


def first_backward(t: np.ndarray) -> int | None:
    """Index of the first time earlier than the one before it, or None when ``t`` is non-decreasing."""
    back = np.flatnonzero(np.diff(t) < 0)
    return int(back[0]) + 1 if len(back) else None


def held_average(t: np.ndarray, c: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Average over [edges[k], edges[k+1]) of the piecewise-constant command (c[j] from t[j] on)."""
    cum = np.concatenate([np.zeros((1, c.shape[1])), np.cumsum(c[:-1] * np.diff(t)[:, None], axis=0)])
    j = np.clip(np.searchsorted(t, edges, side="right") - 1, 0, len(t) - 1)
    integral = cum[j] + c[j] * (edges - t[j])[:, None]
    return np.diff(integral, axis=0) / np.diff(edges)[:, None]


def nearest_frame_end(t: np.ndarray, t0: float, dt: float) -> np.ndarray:
    """(S,) int: the frame whose end (``t0 + (k + 1) dt``) is nearest each time (may be outside the log)."""
    return np.rint((t - t0) / dt).astype(np.int64) - 1


def after_frame_end(t: np.ndarray, frame: np.ndarray, t0: float, dt: float) -> np.ndarray:
    """(S,) s from the end of ``frame`` to each time ``t`` (negative: before it): the log's ``sighting_time``, within
    +-dt / 2 for the nearest frame end. The learner predicts each sighting at that time (``learners.arrays.
    sighting_times``), not at the frame's end: at 0.3 rad/s a sighting 50 ms early is 15 mrad off in bearing."""
    return np.asarray(t, float) - (t0 + (np.asarray(frame) + 1) * dt)


def runs(idx: np.ndarray) -> list[list[int]]:
    """Sorted indices as [first, last] runs of consecutive values."""
    if len(idx) == 0:
        return []
    cut = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[idx[0]], idx[cut + 1]])
    ends = np.concatenate([idx[cut], [idx[-1]]])
    return [[int(a), int(b)] for a, b in zip(starts, ends)]


def truth_at(t: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, theta: np.ndarray,
             edges: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
    """((T+1, 3) pose [x mm, y mm, theta rad] at the frame boundaries ``edges`` (s), ``pose_gaps``): the truth
    rows (strictly increasing times ``t``, s) interpolated, x and y linearly, theta unwrapped; gaps longer than
    ``GAP_S`` inside the span and the poses inside them counted and flagged, as are poses before the first or after
    the last truth row (held at it)."""
    pose = np.stack([np.interp(edges, t, x_m) * 1000.0, np.interp(edges, t, y_m) * 1000.0,
                     wrap(np.interp(edges, t, np.unwrap(theta)))], axis=1)
    gdt = np.diff(t)
    in_span = (t[1:] > edges[0]) & (t[:-1] < edges[-1])
    gaps = np.flatnonzero((gdt > GAP_S) & in_span)
    j = np.searchsorted(t, edges, side="right") - 1
    out_of_span = (edges < t[0] - TIME_SLACK_S) | (edges > t[-1] + TIME_SLACK_S)  # held at the first or last row
    flagged = np.flatnonzero(out_of_span | ((j >= 0) & (j < len(gdt)) & (gdt[np.clip(j, 0, len(gdt) - 1)] > GAP_S)
                                            & (edges > t[np.clip(j, 0, len(t) - 1)])))
    outside = int(out_of_span.sum())
    gaps_meta = {"threshold_s": GAP_S, "count": int(len(gaps)),
                 "longest_s": float(gdt[gaps].max()) if len(gaps) else 0.0,
                 "total_s": float(gdt[gaps].sum()) if len(gaps) else 0.0,
                 "poses_flagged": int(len(flagged)), "flagged_runs": runs(flagged),
                 "poses_outside_groundtruth": outside}
    return pose, gaps_meta


def pose_valid(tr: Trajectory) -> np.ndarray:
    """(T+1,) bool: poses not flagged as inside a ground-truth gap (``meta["pose_gaps"]``)."""
    ok = np.ones(tr.n_frames + 1, bool)
    for a, b in tr.meta.get("pose_gaps", {}).get("flagged_runs", []):
        ok[a: b + 1] = False
    return ok


def frame_count(s: Streams, dt: float) -> int:
    """Frames of ``dt`` from the first command to the last command (and the last truth row, when given)."""
    t_end = float(s.command_t[-1]) if s.truth_t is None else min(float(s.command_t[-1]), float(s.truth_t[-1]))
    return int(np.floor((t_end - float(s.command_t[0])) / dt + 1e-9))


def _some(ids: list[int], at_most: int = 5) -> str:
    """The first ``at_most`` of ``ids``, comma-separated, "..." after them where there are more."""
    return ", ".join(str(i) for i in ids[:at_most]) + (", ..." if len(ids) > at_most else "")


def none_usable(s: Streams, unknown: np.ndarray, bad_range: np.ndarray, inside: np.ndarray, edges: np.ndarray,
                meta: dict[str, Any]) -> str:
    """Why not one of the streams' sightings is in the log: the counts by cause (the ids seen and the map's, from
    ``meta``'s ``unknown_ids`` and ``landmark_ids`` where the importer gives them), the detections' and the frames'
    time spans when they miss each other (another clock, most likely; for a bag's header stamps, ``--time log``)."""
    bad_range, outside = ~unknown & bad_range, ~unknown & ~bad_range & ~inside
    why = []
    if unknown.any():
        ids = (f" (ids {_some(meta['unknown_ids'])}; the map's {_some(meta['landmark_ids'])})"
               if meta.get("unknown_ids") and meta.get("landmark_ids") is not None else "")
        why.append(f"{int(unknown.sum())} of ids the map does not hold{ids}")
    if bad_range.any():
        why.append(f"{int(bad_range.sum())} with a range <= 0")
    if outside.any():
        why.append(f"{int(outside.sum())} outside the commands' span {edges[0]:.6g}-{edges[-1]:.6g} s (the detections' "
                   f"times {s.sighting_t.min():.6g}-{s.sighting_t.max():.6g} s: another clock, or another unit?)"
                   + ("; --time log takes every topic's record times"
                      if meta.get("source", {}).get("time") == "header" else ""))
    return f"none of the {len(unknown)} detections can be used: " + ", ".join(why)


def build(s: Streams, dt: float, meta: dict[str, Any], source: str, sensor: SensorPose = SensorPose()) -> Trajectory:
    """The log of ``s`` in frames of ``dt`` s (module docstring). ``meta`` gets ``t0_s`` (the first command's
    time), ``dropped`` counts (sightings of ids not in the map, with non-positive ranges, outside the span; the
    caller's own counts kept), ``sensor_pose`` and, with truth, ``pose_gaps``. ``sensor``: where the sightings were
    measured from (their ranges checked as measured, then moved to the robot's origin). ``source`` names the input in
    validation errors. Raises LogSourceError when the commands span no frame or not one sighting can be used (each
    cause counted), TrajectoryError on a log that fails validation."""
    t0 = float(s.command_t[0])
    T = frame_count(s, dt)
    if T < 1:
        raise LogSourceError(f"{source}: the commands (and truth) span less than one frame of {dt:g} s")
    edges = t0 + dt * np.arange(T + 1)
    controls = held_average(s.command_t, s.commands, edges)
    frame = nearest_frame_end(s.sighting_t, t0, dt)
    unknown = s.sighting_landmark < 0
    measured = s.sighting_value
    bad_range = ~unknown & ~(measured[:, 0] > 0)
    if not sensor.is_origin():
        measured = from_sensor(measured, sensor)
    inside = (frame >= 0) & (frame < T)
    use = ~unknown & ~bad_range & inside
    if len(use) and not use.any():
        raise LogSourceError(f"{source}: {none_usable(s, unknown, bad_range, inside, edges, meta)}")
    order = np.flatnonzero(use)[np.argsort(frame[use], kind="stable")]
    values = np.stack([measured[order, 0], wrap(measured[order, 1])], axis=1)
    meta = dict(meta)
    meta["t0_s"] = t0
    meta.setdefault("sensor_pose", sensor.as_meta())  # an importer that placed the sightings itself says how
    meta["dropped"] = {**meta.get("dropped", {}), "sightings_unknown_id": int(unknown.sum()),
                       "sightings_nonpositive_range": int(bad_range.sum()),
                       "sightings_outside_span": int((~unknown & ~bad_range & ~inside).sum())}
    pose = None
    if s.truth_t is not None:
        pose, meta["pose_gaps"] = truth_at(s.truth_t, s.truth[:, 0], s.truth[:, 1], s.truth[:, 2], edges)
    tr = Trajectory(dt=float(dt), landmarks=np.asarray(s.landmarks, float), sighting_frame=frame[order],
                    sighting_landmark=s.sighting_landmark[order].astype(np.int64), sighting_value=values,
                    sighting_time=after_frame_end(s.sighting_t[order], frame[order], t0, dt),
                    sensor_kind="range_mm", controls=controls, control_names=VELOCITY_CONTROLS, pose=pose, meta=meta)
    return tr.validate(source)
