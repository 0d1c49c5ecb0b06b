"""Which logs may be learned together: one robot, one sensor, one command table, one frame rate."""

from __future__ import annotations

import json
from typing import Any, Iterator

import numpy as np

from .trajectory import Trajectory, _fail

#: ``meta["config"]`` keys that tell which simulated robot and noise made a log.
ROBOT_META_KEYS = ("robot_seed", "velocities", "noise", "sigma_height", "sigma_angle", "slip_std",
                   "big_slip_prob", "big_slip_std")


def check_compatible(logs: list[Trajectory], sources: list[str]) -> list[str]:
    """Refuse logs that cannot be learned together; return warnings about doubtful mixes.

    Every log is compared with the first: the command kind, ``attempted`` (or ``control_names``),
    ``sensor_kind``, ``dt`` and ``landmarks`` must agree (else TrajectoryError naming both files
    and the field). A warning (one line per log) says when ``meta["config"]`` records another
    robot or other noise settings (``ROBOT_META_KEYS``, compared only where both logs record them).
    """
    warnings = []
    for tr, source in zip(logs[1:], sources[1:]):
        for key, detail in _differences(logs[0], tr):
            _fail(source, key, f"differs from {sources[0]} ({detail}); learn only from logs of one robot, "
                  "command table, sensor and landmark layout")
        meta = _meta_differences(logs[0].meta, tr.meta)
        if meta:
            warnings.append(f"{source}: meta.config differs from {sources[0]} in {', '.join(meta)}: the logs "
                            "may come from different robots or noise settings, and the model learned is a mix")
    return warnings


def _differences(a: Trajectory, b: Trajectory) -> Iterator[tuple[str, str]]:
    """(field, detail) pairs of the properties in which ``b`` cannot be learned together with ``a``."""
    if a.discrete != b.discrete:
        yield ("actions" if a.discrete else "controls"), "discrete commands in one, continuous in the other"
    elif a.discrete and not _same(a.attempted, b.attempted, 1e-9):
        yield "attempted", "another command table"
    elif not a.discrete and a.control_names != b.control_names:
        yield "control_names", f"{list(b.control_names)} vs {list(a.control_names)}"
    if a.sensor_kind != b.sensor_kind:
        yield "sensor_kind", f"{b.sensor_kind!r} vs {a.sensor_kind!r}"
    if not np.isclose(a.dt, b.dt, rtol=1e-9, atol=0):
        yield "dt", f"{b.dt:g} s vs {a.dt:g} s"
    if not _same(a.landmarks, b.landmarks, 1e-6):
        yield "landmarks", "other landmark positions"


def _same(x: np.ndarray, y: np.ndarray, tol: float) -> bool:
    """Same shape and values within ``tol`` (relative, and absolute in the arrays' units)."""
    return np.shape(x) == np.shape(y) and bool(np.allclose(x, y, rtol=tol, atol=tol))


def _meta_differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """``key (b's vs a's)`` for each ROBOT_META_KEYS entry recorded differently in two logs' meta."""
    ca, cb = a.get("config"), b.get("config")
    if not isinstance(ca, dict) or not isinstance(cb, dict):
        return []
    return [f"{key} ({_brief(cb[key])} vs {_brief(ca[key])})" for key in ROBOT_META_KEYS
            if key in ca and key in cb and ca[key] != cb[key]]


def _brief(value: Any, width: int = 30) -> str:
    """``value`` as JSON, cut to ``width`` characters."""
    text = json.dumps(value)
    return text if len(text) <= width else text[: width - 3] + "..."
