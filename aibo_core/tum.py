"""Poses in the TUM trajectory format, the one ``evo_ape`` / ``evo_rpe`` and most SLAM benchmarks read.

NumPy only. One pose per line, ``timestamp x y z qx qy qz qw``: seconds, metres, a unit quaternion (x, y, z, w);
``#`` lines are comments. A planar pose ``[x mm, y mm, theta rad]`` is ``z = 0`` and a rotation by theta about z.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from .atomic import atomic_write
from .trajectory import Trajectory


def frame_times(tr: Trajectory) -> np.ndarray:
    """(T+1,) s: the times of the log's frame boundaries (pose k at ``t0 + k dt``), on the clock the log was
    imported from (``meta["t0_s"]``, or an MRCLAM log's ``source.t0_unix_s``; 0 for a simulated log)."""
    t0 = tr.meta.get("t0_s", tr.meta.get("source", {}).get("t0_unix_s", 0.0))
    return float(t0) + tr.dt * np.arange(tr.n_frames + 1)


def tum_text(t: np.ndarray, pose: np.ndarray, comment: str = "") -> str:
    """The poses (N, 3) [x mm, y mm, theta rad] at times ``t`` (N,) s as TUM lines (full double precision)."""
    half = pose[:, 2] / 2.0
    cols = [pose[:, 0] / 1000.0, pose[:, 1] / 1000.0, np.zeros(len(t)), np.zeros(len(t)), np.zeros(len(t)),
            np.sin(half), np.cos(half)]
    head = "".join(f"# {line}\n" for line in comment.splitlines()) + "# timestamp x y z qx qy qz qw\n"
    body = "".join(f"{ti:.9f} " + " ".join(f"{c:.17g}" for c in row) + "\n"
                   for ti, row in zip(t, np.stack(cols, axis=1)))
    return head + body


def write_tum(path: str | os.PathLike, t: np.ndarray, pose: np.ndarray, comment: str = "") -> None:
    """Write ``tum_text`` to ``path`` atomically."""
    data = tum_text(t, pose, comment).encode()

    def write(f: Any) -> None:
        f.write(data)

    atomic_write(path, write)
