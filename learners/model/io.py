"""The model file ``aibo-model/1`` (JSON): each component writes and reads its own section.

Keys (a contract; tools rely on them; later keys only ever added):

- ``format``: ``"aibo-model/1"``; ``learner``: learner name
- ``action_model``: ``feature_map`` (``table``, ``diff_drive``, ``unicycle``, ``linear``), ``dt`` (s per frame),
  ``motion_cov`` (3x3 per-frame displacement covariance, mm^2 and rad^2); for ``table``:
  ``velocities`` (one row per command: [vx mm/s, vy mm/s, vtheta rad/s], robot frame, x forward,
  y left); otherwise ``weights`` (F rows: velocity per unit feature) and ``control_names``
- ``sensor_model``: ``kind`` (``height_px`` or ``range_mm``), ``basis`` (``power`` or
  ``inverse``), ``coef`` (of f in that basis, distance in mm), ``sigma_height`` (px, height
  sensors) or ``sigma_range_mm`` (range sensors), ``sigma_angle`` (rad), ``distance_range_mm``
- ``initial_state``: list (one per log) of {mean [x mm, y mm, theta rad], cov 3x3}
- ``effects``: list of {name, parameters}
- ``iterations``, ``converged``, ``loglik`` (one per iteration), ``pruned_observations``, ``info``
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from aibo_core.atomic import atomic_write
from learners.model.action import PAPER_MOTION_STD, ZERO_OUTPUTS, ActionModel
from learners.model.effects import effect_from_json
from learners.model.initial import DEFAULT_INITIAL, InitialState
from learners.model.model import Model
from learners.model.parameters import as_numbers
from learners.model.sensor import NODE_RANGE_MM, SensorModel

FORMAT = "aibo-model/1"
#: Largest per-frame motion variances a model file may hold: (10 m)^2, (10 m)^2, pi^2 rad^2.
MAX_MOTION_VAR = np.array([1e8, 1e8, np.pi**2])
MAX_JSON_BYTES = 256 * 2**20


class ModelFileError(ValueError):
    """A model file that does not follow aibo-model/1. The message names file and field."""


def finite(x: Any) -> Any:
    """JSON has no NaN/inf: refuse to write them (no silent NaN)."""
    arr = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise FloatingPointError("refusing to write a model with non-finite values")
    return arr.tolist()


def model_to_json(model: Model) -> dict[str, Any]:
    """The model's sections of the file (no run information)."""
    a, s = model.action, model.sensor
    action: dict[str, Any] = {"feature_map": a.feature_map, "dt": float(a.dt), "motion_cov": finite(a.cov)}
    if a.discrete:
        action["velocities"] = finite(a.velocities)
    else:
        action["weights"] = finite(a.weights / a.dt)
        action["control_names"] = list(a.control_names)
    sigma_key = "sigma_height" if s.kind == "height_px" else "sigma_range_mm"
    sensor = {"kind": s.kind, "basis": s.basis, "coef": finite(s.coef), sigma_key: float(s.sigma_size),
              "sigma_angle": float(s.sigma_bearing), "distance_range_mm": finite(s.distance_range_mm)}
    return {
        "action_model": action,
        "sensor_model": sensor,
        "initial_state": [{"mean": finite(i.mean), "cov": finite(i.cov)} for i in model.init],
        "effects": [e.to_json() for e in model.effects],
    }


class _Reader:
    """Typed access to a parsed model file; every error names the file and the dotted field."""

    def __init__(self, doc: dict, source: str):
        self.doc, self.source = doc, source

    def fail(self, dotted: str, what: str):
        raise ModelFileError(f"{self.source}: field '{dotted}': {what}")

    def get(self, dotted: str, default: Any = KeyError) -> Any:
        node: Any = self.doc
        for part in dotted.split("."):
            if isinstance(node, list) and part.isdigit() and int(part) < len(node):
                node = node[int(part)]
            elif isinstance(node, dict) and part in node:
                node = node[part]
            elif default is KeyError:
                self.fail(dotted, "missing")
            else:
                return default
        return node

    def array(self, dotted: str, shape: tuple | None = None, ndim: int | None = None, default: Any = KeyError):
        value = self.get(dotted, default)
        try:
            arr = as_numbers(value)
        except (ValueError, RecursionError) as err:
            self.fail(dotted, str(err) if isinstance(err, ValueError) else "expected numbers")
        if shape is not None and arr.shape != shape:
            self.fail(dotted, f"expected shape {shape}, got {arr.shape}")
        if ndim is not None and arr.ndim != ndim:
            self.fail(dotted, f"expected a {ndim}-d array, got shape {arr.shape}")
        return arr

    def positive(self, dotted: str, default: Any = KeyError, limit: float = 1e12) -> float:
        v = self.array(dotted, shape=(), default=default)
        if not 0 < v < limit:
            self.fail(dotted, f"must be > 0 and < {limit:g}, got {float(v)}")
        return float(v)

    def spd(self, dotted: str, default: Any = KeyError) -> np.ndarray:
        cov = self.array(dotted, shape=(3, 3), default=default)
        try:
            spd = np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(0.5 * (cov + cov.T)) > 0)
            np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            spd = False
        if not spd:
            self.fail(dotted, "not symmetric positive definite")
        return cov

    def choice(self, dotted: str, choices: tuple[str, ...], default: str) -> str:
        value = self.get(dotted, default)
        if value not in choices:
            self.fail(dotted, f"{value!r} (valid choices: {', '.join(choices)})")
        return value


def _action(r: _Reader) -> ActionModel:
    fmap = r.choice("action_model.feature_map", ("table", "diff_drive", "unicycle", "linear"), "table")
    dt = r.positive("action_model.dt", limit=3600.0)
    cov = r.spd("action_model.motion_cov", default=np.diag(np.square(PAPER_MOTION_STD)).tolist())
    if np.any(np.diag(cov) > MAX_MOTION_VAR):
        r.fail("action_model.motion_cov", f"a per-frame standard deviation above {np.sqrt(MAX_MOTION_VAR[0]):g} mm "
               f"or {np.pi:.4g} rad (diagonal {np.diag(cov).tolist()}): no robot moves that unpredictably in a frame")
    if fmap == "table":
        vel = r.array("action_model.velocities", ndim=2)
        if vel.shape[1] != 3 or len(vel) < 1:
            r.fail("action_model.velocities", f"expected rows [vx, vy, vtheta], got shape {vel.shape}")
        return ActionModel(vel * dt, cov, dt)
    names = r.get("action_model.control_names")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        r.fail("action_model.control_names", "expected a list of names")
    weights = r.array("action_model.weights", ndim=2)
    if weights.shape[1] != 3:
        r.fail("action_model.weights", f"expected rows of 3 velocities, got shape {weights.shape}")
    held = list(ZERO_OUTPUTS.get(fmap, ()))
    if np.any(weights[:, held] != 0):
        r.fail("action_model.weights", f"a {fmap} model holds columns {held} at 0")
    return ActionModel(weights * dt, cov, dt, fmap, tuple(names))


def _sensor(r: _Reader) -> SensorModel:
    kind = r.choice("sensor_model.kind", ("height_px", "range_mm"), "height_px")
    basis = r.choice("sensor_model.basis", ("power", "inverse"), "power")
    coef = r.array("sensor_model.coef", ndim=1)
    if not 1 <= coef.size <= 12:
        r.fail("sensor_model.coef", f"expected 1 to 12 coefficients, got {coef.size}")
    sigma = r.positive("sensor_model.sigma_height" if kind == "height_px" else "sensor_model.sigma_range_mm")
    rng = r.array("sensor_model.distance_range_mm", shape=(2,), default=list(NODE_RANGE_MM))
    if not 0 <= rng[0] < rng[1]:
        r.fail("sensor_model.distance_range_mm", "expected 0 <= min < max")
    return SensorModel(coef, sigma, r.positive("sensor_model.sigma_angle", limit=10.0),
                       (float(rng[0]), float(rng[1])), basis, kind)


def _initial(r: _Reader) -> tuple[InitialState, ...]:
    states = r.get("initial_state", [])
    if not isinstance(states, list):
        r.fail("initial_state", "expected a list")
    return tuple(InitialState(r.array(f"initial_state.{k}.mean", shape=(3,)), r.spd(f"initial_state.{k}.cov"))
                 for k in range(len(states)))


def model_from_json(doc: Any, source: str) -> Model:
    """A Model from a parsed model file; raises ModelFileError naming ``source`` and the field."""
    if not isinstance(doc, dict):
        raise ModelFileError(f"{source}: top level must be a JSON object")
    if doc.get("format") != FORMAT:
        raise ModelFileError(f"{source}: field 'format': expected '{FORMAT}', got {doc.get('format')!r}")
    r = _Reader(doc, source)
    for section in ("action_model", "sensor_model"):
        if not isinstance(r.get(section), dict):
            r.fail(section, "expected a JSON object")
    effects = r.get("effects", [])
    if effects == {}:  # files written before effects existed
        effects = []
    if not isinstance(effects, list):
        r.fail("effects", "expected a list of {name, parameters}")
    try:
        fx = tuple(effect_from_json(e, source) for e in effects)
    except ValueError as exc:
        raise ModelFileError(str(exc)) from None
    names = [e.name for e in fx]
    for name in names:
        if names.count(name) > 1:
            r.fail("effects", f"effect '{name}' is listed {names.count(name)} times (each effect at most once)")
    return Model(_action(r), _sensor(r), _initial(r) or (DEFAULT_INITIAL,), fx)


def read_json(path: str | os.PathLike) -> Any:
    """Parse a JSON file; one-line ModelFileError for anything unreadable."""
    source = str(path)
    try:
        if os.path.getsize(path) > MAX_JSON_BYTES:
            raise ModelFileError(f"{source}: larger than {MAX_JSON_BYTES // 2**20} MiB: not a model file")
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise ModelFileError(f"{source}: file not found") from None
    except IsADirectoryError:
        raise ModelFileError(f"{source}: is a folder, not a model file") from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError, ValueError) as exc:
        raise ModelFileError(f"{source}: not valid JSON ({str(exc)[:200]})") from None


def load_model(path: str | os.PathLike) -> Model:
    """The model stored in a model file (public API). Raises ModelFileError naming the file and field."""
    return model_from_json(read_json(path), str(path))


def save_model(path: str | os.PathLike, model: Model, run: dict[str, Any]) -> None:
    """Write ``model`` plus run information (``learner``, ``iterations``, ...) atomically."""
    doc = {"format": FORMAT, **run, **model_to_json(model)}
    text = json.dumps(doc, indent=1, allow_nan=False)
    atomic_write(path, lambda f: f.write(text.encode()))


def run_record(result) -> dict[str, Any]:
    """A LearnResult's run information for the model file. Wall-clock timings are left out (a learner
    keeps them apart, as ``learners.em.info.FitInfo.timings``), so the same inputs and seed give the same
    model bytes."""
    info = result.info.to_dict(timings=False) if hasattr(result.info, "to_dict") else dict(result.info)
    return {"learner": result.learner, "iterations": int(result.iterations), "converged": bool(result.converged),
            "loglik": [float(v) for v in result.loglik], "pruned_observations": int(result.pruned_observations),
            "info": info}


def save_result(result, path: str | os.PathLike) -> None:
    """Write a LearnResult's model and run information (``run_record``) atomically."""
    save_model(path, result.params, run_record(result))
