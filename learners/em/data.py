"""Several logs flattened into one set of arrays, so inference never loops over logs in Python.

Log k has T_k frames and T_k + 1 poses. Frames of all logs are concatenated
(``frame_start[k]:frame_start[k+1]``); poses likewise (``pose_start[k] = frame_start[k] + k``).
Frame i of log k moves pose ``pose_start[k] + i`` to ``pose_start[k] + i + 1`` and its
sighting (if any) is of that second pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aibo_core.trajectory import Trajectory


@dataclass
class Batch:
    actions: np.ndarray  # (N,) int64
    obs: np.ndarray  # (N, 2) float: height px, angle rad; NaN when none
    beacon_xy: np.ndarray  # (N, 2) float: position (mm) of the beacon seen; NaN when none
    used: np.ndarray  # (N,) bool: a sighting that takes part (seen and not pruned)
    frame_start: np.ndarray  # (S+1,) int64
    dt: float

    @property
    def n_logs(self) -> int:
        return len(self.frame_start) - 1

    @property
    def n_frames(self) -> int:
        return int(self.frame_start[-1])

    @property
    def pose_start(self) -> np.ndarray:
        """(S+1,) offsets into pose arrays; log k's poses are pose_start[k]:pose_start[k+1]."""
        return self.frame_start + np.arange(len(self.frame_start))

    @property
    def frame_to_pose(self) -> np.ndarray:
        """(N,) index of the pose at the START of each frame (its end pose is this + 1)."""
        seg = np.repeat(np.arange(self.n_logs), np.diff(self.frame_start))
        return np.arange(self.n_frames) + seg

    def with_used(self, used: np.ndarray) -> "Batch":
        return Batch(self.actions, self.obs, self.beacon_xy, used, self.frame_start, self.dt)


def make_batch(logs: list[Trajectory]) -> Batch:
    """Concatenate logs (all with the same dt) into a Batch."""
    if not logs:
        raise ValueError("no logs given")
    dts = {round(tr.dt, 12) for tr in logs}
    if len(dts) > 1:
        raise ValueError(f"all logs must share one dt, got {sorted(dts)}")
    lengths = [tr.n_frames for tr in logs]
    frame_start = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    beacon_xy, obs = [], []
    for tr in logs:
        xy = np.full((tr.n_frames, 2), np.nan)
        z = np.full((tr.n_frames, 2), np.nan)
        xy[tr.sighting_frame] = tr.landmarks[tr.sighting_landmark]
        z[tr.sighting_frame] = tr.sighting_value
        beacon_xy.append(xy)
        obs.append(z)
    obs = np.concatenate(obs)
    return Batch(
        actions=np.concatenate([tr.actions for tr in logs]).astype(np.int64),
        obs=obs,
        beacon_xy=np.concatenate(beacon_xy),
        used=~np.isnan(obs).any(axis=1),
        frame_start=frame_start,
        dt=float(logs[0].dt),
    )
