"""A robot's static transforms (ROS's ``/tf_static``: where each sensor sits on it) and the rigid transform between two
of its frames. NumPy only.

Each transform says where a child frame sits in its parent (``header.frame_id`` -> ``child_frame_id``: translation m,
rotation as a unit quaternion x, y, z, w): a point p in the child's frame is R p + t in the parent's. The frames form
a tree; ``transform(base, frame)`` composes the chain from ``frame`` up to the root and back down to ``base``, so a
sensor under ``base_link`` and a ``base_footprint`` above it both work. Frame names are compared without a leading
``/`` (ROS 1's ``/base_link`` is ``base_link``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def rotation(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """(3, 3) rotation matrix of a quaternion (normalized first; a zero quaternion is refused with ValueError)."""
    q = np.array([qw, qx, qy, qz], float)
    norm = np.linalg.norm(q)
    if not norm > 0.0 or not np.isfinite(norm):
        raise ValueError(f"quaternion ({qx}, {qy}, {qz}, {qw}) is not a rotation")
    w, x, y, z = q / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def frame_name(name: str) -> str:
    return name.lstrip("/")


@dataclass
class StaticTransforms:
    """The tree of static transforms: ``parent[child]`` and ``pose[child]`` = (R (3, 3), t (3,) m) of the child in its
    parent (module docstring)."""

    parent: dict[str, str] = field(default_factory=dict)
    pose: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    def add(self, parent: str, child: str, translation: tuple[float, float, float],
            quaternion: tuple[float, float, float, float]) -> None:
        """One transform (the last given for a child wins, as in tf)."""
        child = frame_name(child)
        self.parent[child] = frame_name(parent)
        self.pose[child] = (rotation(*quaternion), np.asarray(translation, float))

    def frames(self) -> list[str]:
        return sorted(set(self.parent) | set(self.parent.values()))

    def _to_root(self, frame: str) -> tuple[str, np.ndarray, np.ndarray]:
        """(the root above ``frame``, R, t of ``frame`` in the root)."""
        R, t, seen = np.eye(3), np.zeros(3), {frame}
        while frame in self.parent:
            Rp, tp = self.pose[frame]
            R, t = Rp @ R, Rp @ t + tp
            frame = self.parent[frame]
            if frame in seen:
                raise ValueError(f"the static transforms loop through frame {frame!r}")
            seen.add(frame)
        return frame, R, t

    def transform(self, base: str, frame: str) -> tuple[np.ndarray, np.ndarray] | None:
        """(R, t): a point p in ``frame`` is R p + t in ``base``; None when the two are not in one tree."""
        base, frame = frame_name(base), frame_name(frame)
        if base == frame:
            return np.eye(3), np.zeros(3)
        root_b, Rb, tb = self._to_root(base)
        root_f, Rf, tf = self._to_root(frame)
        if root_b != root_f:
            return None
        return Rb.T @ Rf, Rb.T @ (tf - tb)
