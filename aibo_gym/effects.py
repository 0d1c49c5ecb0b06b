"""Optional real-world effects: ONE extension point at motion and at sensing.

An effect is a small class with two hooks, both no-ops by default:

* ``motion(disp, action, pose, rng) -> disp``: change the robot-frame displacement of one frame
  (``disp`` = ndarray (3,): mm, mm, rad per frame, slip noise already added; ``pose`` = ndarray (3,)
  pose at the start of the frame, mm, mm, rad).
* ``sense(height, angle, distance, rng) -> (height, angle)``: change one sighting
  (height px, angle rad, true distance mm) before it is reported.

Effects are enabled by name through the env config, e.g.
``config={"effects": {"height_bias": {"offset_px": 2.0}}}``; they run in the order given.
Register a new one with :func:`register_effect`. ``rng`` is the env's episode RNG: an effect
that draws from it stays seeded but shifts the random stream of later frames. The validated parameters (defaults filled in)
are recorded in the log's ``meta["truth"]["effects"]``.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np


class Effect:
    """Base class: subclasses set ``name`` and ``defaults`` (parameter -> default value)."""

    name: ClassVar[str] = ""
    defaults: ClassVar[dict[str, Any]] = {}

    def __init__(self, **params: Any) -> None:
        self.params = validate_params(self.name, type(self).defaults, params)

    def motion(self, disp: np.ndarray, action: int, pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Return the (possibly changed) robot-frame displacement of this frame (mm, mm, rad)."""
        return disp

    def sense(self, height: float, angle: float, distance: float, rng: np.random.Generator) -> tuple[float, float]:
        """Return the (possibly changed) sighting: height px, angle rad."""
        return height, angle


EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make ``cls`` available by ``cls.name`` in the ``effects`` config."""
    if not cls.name:
        raise ValueError(f"effect class {cls.__name__} has no name")
    EFFECTS[cls.name] = cls
    return cls


@register_effect
class HeightBias(Effect):
    """Adds a constant ``offset_px`` (px) to every beacon height (a miscalibrated camera)."""

    name = "height_bias"
    defaults = {"offset_px": 0.0}

    def sense(self, height: float, angle: float, distance: float, rng: np.random.Generator) -> tuple[float, float]:
        return height + self.params["offset_px"], angle


@register_effect
class Drift(Effect):
    """Adds a constant robot-frame displacement ``disp`` (mm, mm, rad per frame) to every frame."""

    name = "drift"
    defaults = {"disp": [0.0, 0.0, 0.0]}

    def motion(self, disp: np.ndarray, action: int, pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return disp + np.asarray(self.params["disp"])


def _coerce(effect: str, key: str, default: Any, value: Any) -> Any:
    """Check ``value`` has the shape of ``default`` (a number or a list of numbers)."""
    def number(v: Any) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
            raise ValueError(f"effect '{effect}': parameter '{key}' must be a finite number, got {v!r}")
        return float(v)

    if isinstance(default, list):
        if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != len(default):
            raise ValueError(
                f"effect '{effect}': parameter '{key}' must be a list of {len(default)} numbers, got {value!r}"
            )
        return [number(v) for v in value]
    return number(value)


def validate_params(name: str, defaults: dict[str, Any], params: dict[str, Any] | None) -> dict[str, Any]:
    """Defaults merged with ``params``; an unknown parameter raises ValueError naming the valid ones."""
    params = {} if params is None else params
    if not isinstance(params, dict):
        raise ValueError(f"effect '{name}': parameters must be a dict, got {params!r}")
    out = {k: (list(v) if isinstance(v, list) else v) for k, v in defaults.items()}
    for key, value in params.items():
        if key not in defaults:
            valid = ", ".join(sorted(defaults)) or "(none)"
            raise ValueError(f"effect '{name}': unknown parameter '{key}' (valid parameters: {valid})")
        out[key] = _coerce(name, key, defaults[key], value)
    return out


def validate_effects(spec: Any) -> dict[str, dict[str, Any]]:
    """Validate an ``effects`` config value ``{name: {param: value}}``; return it with defaults filled."""
    if spec is None:
        return {}
    if not isinstance(spec, dict):
        raise ValueError(f"config key 'effects': expected a dict {{name: {{params}}}}, got {spec!r}")
    out: dict[str, dict[str, Any]] = {}
    for name, params in spec.items():
        if name not in EFFECTS:
            valid = ", ".join(sorted(EFFECTS))
            raise ValueError(f"config key 'effects': unknown effect '{name}' (valid choices: {valid})")
        out[name] = validate_params(name, EFFECTS[name].defaults, params)
    return out


def build_effects(spec: dict[str, dict[str, Any]]) -> tuple[list[Effect], list[Effect]]:
    """Instantiate the effects of a validated spec; return (motion effects, sensing effects)."""
    effects = [EFFECTS[name](**params) for name, params in spec.items()]
    motion = [e for e in effects if type(e).motion is not Effect.motion]
    sense = [e for e in effects if type(e).sense is not Effect.sense]
    return motion, sense
