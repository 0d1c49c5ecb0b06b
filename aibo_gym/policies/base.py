"""Policies as specs ``{name, params}`` (the pattern of :mod:`aibo_gym.effects`), and the base
class of the onboard policies that hold each command for ``hold_s`` seconds.

A policy spec is any of ``"informed"``, ``"sb3:AGENT.zip"``, ``{"name": "informed", "params":
{...}}`` or ``{"informed": {...}}``; :func:`validate_policy` turns it into ``{"name", "params"}``
with every default filled in, and :func:`make_policy` builds it. Each policy class declares
``name``, ``defaults`` (parameter -> default; a value's type is the parameter's type) and
``choices`` (allowed values of string parameters). Errors are one line naming the policy and the
parameter.

A policy is used as ``pol.reset(info)`` after ``env.reset`` and ``a = pol.act(obs, info)`` each
frame. Policies built on :class:`HoldPolicy` see only what the robot knows onboard: the sightings
(``info["sightings"]`` without its ground-truth column, or the observation) and their own commands,
through an :class:`~aibo_gym.policies.onboard.OnboardTracker`; never the true pose.
"""

from __future__ import annotations

import math
import zlib
from typing import Any, ClassVar

import numpy as np

from ..config import make_config
from .onboard import OnboardTracker

POLICIES: dict[str, type] = {}


def register_policy(cls: type) -> type:
    """Class decorator: make ``cls`` available by ``cls.name`` in policy specs."""
    if not getattr(cls, "name", ""):
        raise ValueError(f"policy class {cls.__name__} has no name")
    POLICIES[cls.name] = cls
    return cls


def _coerce(name: str, key: str, default: Any, value: Any, choices: tuple | None) -> Any:
    where = f"policy '{name}': parameter '{key}'"
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{where} must be true or false, got {value!r}")
        return value
    if isinstance(default, (int, float)) or (default is None and key == "hold_s"):
        if value is None and default is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
            raise ValueError(f"{where} must be a finite number, got {value!r}")
        return float(value)
    if not isinstance(value, str):
        raise ValueError(f"{where} must be a string, got {value!r}")
    if choices and value not in choices:
        raise ValueError(f"{where}: invalid value {value!r} (valid choices: {', '.join(map(repr, choices))})")
    return value


def validate_policy(spec: Any) -> dict[str, Any]:
    """``{"name": str, "params": dict}`` with defaults filled; ValueError (one line) otherwise."""
    if isinstance(spec, str):
        if spec.startswith("sb3:"):
            spec = {"name": "sb3", "params": {"path": spec[4:]}}
        else:
            spec = {"name": spec, "params": {}}
    if isinstance(spec, dict) and set(spec) <= {"name", "params"} and "name" in spec:
        name, params = spec["name"], spec.get("params") or {}
    elif isinstance(spec, dict) and len(spec) == 1:
        (name, params), = spec.items()
        params = params or {}
    else:
        raise ValueError(f"policy spec {spec!r}: expected a name, 'sb3:PATH', {{'name': ..., 'params': {{...}}}} or {{name: {{...}}}}")
    if name not in POLICIES:
        raise ValueError(f"policy {name!r} (valid choices: {', '.join(map(repr, POLICIES))}, or 'sb3:AGENT.zip')")
    if not isinstance(params, dict):
        raise ValueError(f"policy '{name}': parameters must be a JSON object, got {params!r}")
    cls = POLICIES[name]
    out = dict(cls.defaults)
    for key, value in params.items():
        if key not in cls.defaults:
            raise ValueError(f"policy '{name}': unknown parameter '{key}' (valid parameters: {', '.join(sorted(cls.defaults))})")
        out[key] = _coerce(name, key, cls.defaults[key], value, getattr(cls, "choices", {}).get(key))
    if name == "sb3" and not out["path"]:
        raise ValueError("policy 'sb3': give the agent file as 'sb3:AGENT.zip' or params {'path': ...}")
    return {"name": name, "params": out}


def policy_label(spec: Any) -> str:
    """A short name for tables: the policy name, ``sb3:FILE`` for agents."""
    s = validate_policy(spec)
    if s["name"] == "sb3":
        return "sb3:" + str(s["params"]["path"]).replace("\\", "/").rsplit("/", 1)[-1]
    return s["name"]


def make_policy(spec: Any, config: dict[str, Any] | None, seed: int | None):
    """The policy of ``spec`` for the env ``config``, with its own RNG seeded by ``seed``."""
    s = validate_policy(spec)
    return POLICIES[s["name"]](config, seed=seed, **s["params"])


def sightings_of(obs: np.ndarray, info: dict[str, Any] | None, n_beacons: int) -> list[tuple[int, float, float]]:
    """The frame's sightings as (beacon, height px, angle rad): all of ``info["sightings"]`` (the
    sensor readings; its ``spurious`` column is never read) or else the observation's one."""
    if info is not None and "sightings" in info:
        s = info["sightings"]
        return [(int(s["beacon"][j]), float(s["height"][j]), float(s["angle"][j])) for j in range(int(s["count"]))]
    b = n_beacons
    if obs[b + 2] > 0.5:
        return [(int(np.argmax(obs[:b])), float(obs[b]), float(obs[b + 1]))]
    return []


class HoldPolicy:
    """Base of the onboard policies: every ``hold_s`` seconds :meth:`choose` picks a command.

    Subclasses set ``name``, ``defaults`` (must include ``hold_s`` and ``margin_mm``) and
    implement :meth:`choose` from ``self.tracker`` (the onboard state).
    """

    name: ClassVar[str] = ""
    defaults: ClassVar[dict[str, Any]] = {"hold_s": 5.0, "margin_mm": 300.0}
    choices: ClassVar[dict[str, tuple]] = {}

    def __init__(self, config: dict[str, Any] | None, seed: int | None = None, **params: Any) -> None:
        self.params = validate_policy({"name": self.name, "params": params})["params"]
        self.cfg = make_config(config)
        self.tracker = OnboardTracker(self.cfg)
        self.n_beacons = len(self.cfg["beacons"])
        self.dt = float(self.cfg["dt"])
        hold = self.params.get("hold_s")
        self.set_hold(5.0 if hold is None else hold)
        self.margin = float(self.params["margin_mm"])
        self.rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(zlib.crc32(self.name.encode()),)))
        self._action: int | None = None
        self._left = 0

    def set_hold(self, hold_s: float) -> None:
        if not hold_s > 0:
            raise ValueError(f"policy '{self.name}': hold_s must be positive seconds, got {hold_s!r}")
        self.hold_s = float(hold_s)
        self.hold_frames = max(1, int(round(self.hold_s / self.dt)))

    def reset(self, info: dict[str, Any] | None = None) -> None:
        self.tracker.reset()
        self._action, self._left = None, 0

    def observe(self, obs: np.ndarray, info: dict[str, Any] | None = None) -> None:
        """Account for the frame the last command produced (its sightings); nothing before the first."""
        if self._action is not None:
            self.tracker.step(self._action, sightings_of(obs, info, self.n_beacons))

    def act(self, obs: np.ndarray, info: dict[str, Any] | None = None) -> int:
        self.observe(obs, info)
        if self._left <= 0:
            self.begin_hold()
        self._left -= 1
        return self._action

    def begin_hold(self) -> int:
        """Choose the next command and start holding it for ``hold_s`` (what :meth:`act` does every hold)."""
        self._action = int(self.choose())
        self._left = self.hold_frames
        return self._action

    @property
    def pose_estimate(self) -> np.ndarray:
        return self.tracker.ekf.pose

    @property
    def counts(self) -> np.ndarray:
        return self.tracker.counts

    def candidates(self, xy: np.ndarray) -> np.ndarray:
        """The commands whose predicted paths stay ``margin_mm`` inside the field (else the least bad)."""
        viol = self.tracker.violation(xy, self.margin)
        safe = viol <= 0.0
        return np.flatnonzero(safe) if safe.any() else np.flatnonzero(viol == viol.min())

    def choose(self) -> int:  # pragma: no cover - abstract
        raise NotImplementedError
