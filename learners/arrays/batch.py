"""Several logs flattened into one set of arrays, so inference never loops over logs in Python.

Log k has T_k frames and T_k + 1 poses. Frames of all logs are concatenated
(``frame_start[k]:frame_start[k+1]``); poses likewise (``pose_start[k] = frame_start[k] + k``).
Frame i of log k moves pose ``pose_start[k] + i`` to ``pose_start[k] + i + 1``; its sightings,
``sight_start[i]:sight_start[i+1]`` (CSR, any number per frame), are of that second pose.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from aibo_core.geometry import wrap
from aibo_core.trajectory import Trajectory


@dataclass(frozen=True)
class Batch:
    """The data of one fit: commands per frame, sightings per frame (CSR)."""

    frame_start: np.ndarray  # (L+1,) int64
    dt: float  # s per frame
    actions: np.ndarray | None  # (N,) int64 discrete command per frame, or None
    controls: np.ndarray | None  # (N, k) float continuous command per frame, or None
    sight_start: np.ndarray  # (N+1,) int64: sightings of frame i are sight_start[i]:sight_start[i+1]
    sight_landmark: np.ndarray  # (S,) int64 index into ``landmarks``
    sight_xy: np.ndarray  # (S, 2) float: position (mm) of the landmark seen
    sight_value: np.ndarray  # (S, 2) float: [size measurement, bearing rad]
    used: np.ndarray  # (S,) bool: takes part (not pruned)
    landmarks: np.ndarray  # (B, 2) float mm
    head_pan: np.ndarray | None = None  # (N,) rad, or None (fixed camera)
    field: np.ndarray | None = None  # (2,) field length and width (mm, origin at the centre) shared by the logs, or None
    #: (S,) s after its frame's end each sighting was made (negative: before it; the logs' ``sighting_time``, 0 for a
    #: log without it), None: every sighting at its frame's end
    sight_time: np.ndarray | None = None
    #: rad: the bearing noise the image angle's expectation is taken with (``learners.model.catalogue.expected_phi2``)
    #: during one EM fit, held there so that EM stays EM (``EMState.angle_noise``); None: the model's own
    angle_noise: float | None = None

    @property
    def n_logs(self) -> int:
        return len(self.frame_start) - 1

    @property
    def n_frames(self) -> int:
        return int(self.frame_start[-1])

    @property
    def n_sightings(self) -> int:
        return int(self.sight_start[-1])

    @property
    def pose_start(self) -> np.ndarray:
        """(L+1,) offsets into pose arrays; log k's poses are pose_start[k]:pose_start[k+1]."""
        return self.frame_start + np.arange(len(self.frame_start))

    @cached_property
    def frame_to_pose(self) -> np.ndarray:
        """(N,) index of the pose at the START of each frame (its end pose is this + 1)."""
        seg = np.repeat(np.arange(self.n_logs), np.diff(self.frame_start))
        return np.arange(self.n_frames) + seg

    @cached_property
    def sight_frame(self) -> np.ndarray:
        """(S,) batch frame of each sighting."""
        return np.repeat(np.arange(self.n_frames), np.diff(self.sight_start))

    @cached_property
    def sight_pose(self) -> np.ndarray:
        """(S,) index of the pose each sighting is of (the end pose of its frame)."""
        return self.frame_to_pose[self.sight_frame] + 1

    @cached_property
    def log_first_frame(self) -> np.ndarray:
        """(N,) batch index of the first frame of each frame's log."""
        return np.repeat(self.frame_start[:-1], np.diff(self.frame_start))

    @cached_property
    def frame_time(self) -> np.ndarray:
        """(N,) time (s) at the start of each frame since the start of its log."""
        return (np.arange(self.n_frames) - self.log_first_frame) * self.dt

    @cached_property
    def command_start(self) -> np.ndarray:
        """(N,) frame (batch index) at which the command in force at each frame started (per log)."""
        cmds = self.actions if self.actions is not None else self.controls
        change = np.ones(self.n_frames, dtype=bool)
        if self.n_frames > 1:
            same = cmds[1:] == cmds[:-1]
            change[1:] = ~(same if same.ndim == 1 else same.all(axis=1))
        change[self.frame_start[:-1][np.diff(self.frame_start) > 0]] = True
        return np.maximum.accumulate(np.where(change, np.arange(self.n_frames), 0))

    @cached_property
    def sight_log(self) -> np.ndarray:
        """(S,) log of each sighting."""
        return np.searchsorted(self.frame_start, self.sight_frame, side="right") - 1

    @cached_property
    def image_angle(self) -> np.ndarray:
        """(S,) rad: each sighting's measured position in the image, its bearing - the head pan (wrapped); with no
        head pan (a camera fixed to the body) the bearing itself."""
        if self.head_pan is None:
            return np.asarray(self.sight_value[:, 1], float)
        return wrap(self.sight_value[:, 1] - self.head_pan[self.sight_frame])

    def with_used(self, used: np.ndarray) -> "Batch":
        return replace(self, used=np.asarray(used, dtype=bool))

    def with_angle_noise(self, sigma_bearing: float | None) -> "Batch":
        return replace(self, angle_noise=None if sigma_bearing is None else float(sigma_bearing))

    def holding_angle_noise(self, sigma_bearing: float) -> "Batch":
        """This batch with ``angle_noise`` held at ``sigma_bearing`` (rad) unless it holds one already: what a
        computation that varies a model's parameters needs (its information, scoring steps), as EM holds it."""
        return self if self.angle_noise is not None else self.with_angle_noise(sigma_bearing)


def make_batch(logs: list[Trajectory]) -> Batch:
    """Concatenate logs (same dt, same landmarks, same kind of command) into a Batch."""
    if not logs:
        raise ValueError("no logs given")
    dts = {round(tr.dt, 12) for tr in logs}
    if len(dts) > 1:
        raise ValueError(f"all logs must share one dt, got {sorted(dts)}")
    if len({tr.discrete for tr in logs}) > 1:
        raise ValueError("all logs must have the same kind of command (discrete actions or continuous controls)")
    landmarks = logs[0].landmarks
    for tr in logs[1:]:
        if tr.landmarks.shape != landmarks.shape or not np.array_equal(tr.landmarks, landmarks):
            raise ValueError("all logs must share the same landmarks")
    lengths = [tr.n_frames for tr in logs]
    frame_start = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    counts = np.concatenate([np.bincount(tr.sighting_frame, minlength=tr.n_frames) for tr in logs])
    sight_landmark = np.concatenate([tr.sighting_landmark for tr in logs]).astype(np.int64)
    has_pan = all(tr.head_pan is not None for tr in logs)
    return Batch(
        frame_start=frame_start,
        dt=float(logs[0].dt),
        actions=np.concatenate([tr.actions for tr in logs]).astype(np.int64) if logs[0].discrete else None,
        controls=None if logs[0].discrete else np.concatenate([tr.controls for tr in logs]).astype(np.float64),
        sight_start=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        sight_landmark=sight_landmark,
        sight_xy=np.ascontiguousarray(landmarks[sight_landmark], dtype=np.float64),
        sight_value=np.concatenate([tr.sighting_value for tr in logs]).astype(np.float64).reshape(-1, 2),
        used=np.ones(len(sight_landmark), dtype=bool),
        landmarks=np.asarray(landmarks, dtype=np.float64),
        head_pan=np.concatenate([tr.head_pan for tr in logs]).astype(np.float64) if has_pan else None,
        field=_shared_field(logs),
        sight_time=_sighting_times(logs),
    )


def _sighting_times(logs: list[Trajectory]) -> np.ndarray | None:
    """(S,) the logs' ``sighting_time`` concatenated (0 for a log without it), None when no log has it."""
    if all(tr.sighting_time is None for tr in logs):
        return None
    return np.concatenate([np.zeros(tr.n_sightings) if tr.sighting_time is None else np.asarray(tr.sighting_time, float)
                           for tr in logs])


def _shared_field(logs: list[Trajectory]) -> np.ndarray | None:
    """The logs' field (2,) if every log has the same one, else None."""
    fields = [tr.field for tr in logs]
    if any(f is None for f in fields) or any(not np.array_equal(f, fields[0]) for f in fields[1:]):
        return None
    return np.asarray(fields[0], dtype=np.float64)
