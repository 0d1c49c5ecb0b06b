"""The learned-model file ``aibo-model/1`` (JSON): write atomically, read back with validation.

Keys (a contract; tools rely on them):

- ``format``: ``"aibo-model/1"``; ``learner``: learner name
- ``action_model.velocities``: 40 rows [vx mm/s, vy mm/s, vtheta rad/s], robot frame (x forward, y left)
- ``action_model.dt``: s per frame; ``action_model.motion_cov``: 3x3 per-frame displacement
  covariance (mm^2, rad^2)
- ``sensor_model.coef``: polynomial in ascending powers of distance in mm (height px = sum coef[k] d^k)
- ``sensor_model.sigma_height`` (px), ``sensor_model.sigma_angle`` (rad),
  ``sensor_model.distance_range_mm`` [min, max]
- ``initial_state``: list (one per log) of {mean [x mm, y mm, theta rad], cov 3x3}
- ``iterations``, ``converged``, ``loglik`` (one per iteration), ``pruned_observations``, ``effects``
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from aibo_core.atomic import atomic_write
from learners.base import LearnResult
from learners.em.params import DEFAULT_INITIAL, N_ACTIONS, ActionModel, InitialState, Params, SensorModel

FORMAT = "aibo-model/1"


class ModelFileError(ValueError):
    """A model file that does not follow aibo-model/1. The message names file and field."""


def _finite(x: Any) -> Any:
    """JSON has no NaN/inf: refuse to write them (no silent NaN)."""
    arr = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise FloatingPointError("refusing to write a model with non-finite values")
    return arr.tolist()


def to_dict(result: LearnResult, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    p = result.params
    doc: dict[str, Any] = {
        "format": FORMAT,
        "learner": result.learner,
        "action_model": {
            "velocities": _finite(p.action.velocities),
            "dt": float(p.action.dt),
            "motion_cov": _finite(p.action.cov),
        },
        "sensor_model": {
            "coef": _finite(p.sensor.coef),
            "sigma_height": float(p.sensor.sigma_height),
            "sigma_angle": float(p.sensor.sigma_angle),
            "distance_range_mm": _finite(p.sensor.distance_range_mm),
        },
        "initial_state": [{"mean": _finite(s.mean), "cov": _finite(s.cov)} for s in p.init],
        "iterations": int(result.iterations),
        "converged": bool(result.converged),
        "loglik": [float(v) for v in result.loglik],
        "pruned_observations": int(result.pruned_observations),
        "effects": {},
        "info": result.info,
    }
    if extra:
        doc.update(extra)
    return doc


def save(result: LearnResult, path: str | os.PathLike, extra: dict[str, Any] | None = None) -> None:
    """Write the model atomically: an existing file is replaced only by a complete new one."""
    text = json.dumps(to_dict(result, extra), indent=1, allow_nan=False)
    atomic_write(path, lambda f: f.write(text.encode()))


def _get(doc: dict, dotted: str, source: str) -> Any:
    node: Any = doc
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            raise ModelFileError(f"{source}: field '{dotted}': missing")
        node = node[part]
    return node


def _array(doc: dict, dotted: str, source: str, shape: tuple | None = None, ndim: int | None = None) -> np.ndarray:
    value = _get(doc, dotted, source)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ModelFileError(f"{source}: field '{dotted}': expected numbers") from None
    if shape is not None and arr.shape != shape:
        raise ModelFileError(f"{source}: field '{dotted}': expected shape {shape}, got {arr.shape}")
    if ndim is not None and arr.ndim != ndim:
        raise ModelFileError(f"{source}: field '{dotted}': expected {ndim}-d array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelFileError(f"{source}: field '{dotted}': non-finite value")
    return arr


def _positive(doc: dict, dotted: str, source: str) -> float:
    v = _array(doc, dotted, source, shape=())
    if not v > 0:
        raise ModelFileError(f"{source}: field '{dotted}': must be > 0, got {float(v)}")
    return float(v)


def load_params(path: str | os.PathLike, n_logs: int | None = None) -> Params:
    """Read a model file as EM parameters (for ``--init``). Raises ModelFileError."""
    source = str(path)
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError:
        raise ModelFileError(f"{source}: file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"{source}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise ModelFileError(f"{source}: top level must be a JSON object")
    fmt = doc.get("format")
    if fmt != FORMAT:
        raise ModelFileError(f"{source}: field 'format': expected '{FORMAT}', got {fmt!r}")
    vel = _array(doc, "action_model.velocities", source, shape=(N_ACTIONS, 3))
    dt = _positive(doc, "action_model.dt", source)
    cov = np.diag(np.square([10.0, 10.0, 0.1]))
    if "motion_cov" in doc["action_model"]:
        cov = _array(doc, "action_model.motion_cov", source, shape=(3, 3))
        if not np.allclose(cov, cov.T) or np.any(np.linalg.eigvalsh(cov) <= 0):
            raise ModelFileError(f"{source}: field 'action_model.motion_cov': not symmetric positive definite")
    coef = _array(doc, "sensor_model.coef", source, ndim=1)
    if coef.size < 1:
        raise ModelFileError(f"{source}: field 'sensor_model.coef': empty")
    sh = _positive(doc, "sensor_model.sigma_height", source)
    sa = _positive(doc, "sensor_model.sigma_angle", source)
    rng = (1275.0, 4175.0)
    if "distance_range_mm" in doc["sensor_model"]:
        r = _array(doc, "sensor_model.distance_range_mm", source, shape=(2,))
        if not r[0] < r[1]:
            raise ModelFileError(f"{source}: field 'sensor_model.distance_range_mm': min must be < max")
        rng = (float(r[0]), float(r[1]))
    init: list[InitialState] = []
    for k, s in enumerate(doc.get("initial_state") or []):
        sub = {"s": s}
        mean = _array(sub, "s.mean", f"{source}: initial_state[{k}]", shape=(3,))
        c = _array(sub, "s.cov", f"{source}: initial_state[{k}]", shape=(3, 3))
        init.append(InitialState(mean, c))
    if n_logs is not None and len(init) != n_logs:
        init = [DEFAULT_INITIAL] * n_logs
    return Params(
        ActionModel(vel * dt, cov, dt),
        SensorModel(coef, sh, sa, rng),
        tuple(init) if init else (DEFAULT_INITIAL,),
    )
