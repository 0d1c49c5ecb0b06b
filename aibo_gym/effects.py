"""Optional real-world effects: ONE extension point at motion and at sensing.

An effect is a small class (subclass of :class:`Effect`) with three hooks, all no-ops by default:

* ``reset(rng)``: called at every env reset with the effect's OWN random stream (see below);
  clear any state here.
* ``motion(m, frame) -> Motion``: change this frame's motion (:class:`~aibo_gym.context.Motion`:
  robot-frame ``disp``, its driving ``velocity``, a world-frame offset ``world``) before the walls.
* ``sense(sightings, frame) -> list[Sighting]``: change, drop or create sightings
  (:class:`~aibo_gym.context.Sighting`); a frame may end with 0, 1 or several.

``frame`` is the frame's :class:`~aibo_gym.context.Frame` (index, time, commands, poses, head pan,
wall contact, field, dt). Effects are enabled by name through the env config, e.g.
``config={"effects": {"height_bias": {"offset_px": 2.0}}}``, and run in the order given (the motion hooks
by ``motion_order`` first: an effect that follows the command in force, ``response_time``, after a lag); their
validated parameters (defaults filled in) are recorded in the log's ``meta["truth"]["effects"]``.
Register a new one with :func:`register_effect`; the simulator twins of the effect catalogue live
in :mod:`aibo_gym.catalogue`.

Random streams: an effect never draws from the env's RNG, so enabling it leaves the base noise of
a seed unchanged. At reset it gets ``np.random.default_rng([entropy, episode, crc32(name)])``:
``entropy`` is the env's seed entropy (``env.np_random_seed``), ``episode`` counts the resets
since the last seeded one (0 at ``reset(seed=...)``).

Parameters: a number, a list of a fixed length (the length of its default), or, for names in
``per_beacon``, one number per beacon (the default ``[]`` is filled with the neutral value when
the env config is made). ``bounds`` gives inclusive ranges. Errors are one line naming the effect,
the parameter and what is wrong.
"""

from __future__ import annotations

import math
import zlib
from typing import Any, ClassVar

import numpy as np

from .context import Frame, Motion, Sighting


class Effect:
    """Base class: subclasses set ``name``, ``defaults`` (parameter -> default value) and override hooks."""

    name: ClassVar[str] = ""
    defaults: ClassVar[dict[str, Any]] = {}
    per_beacon: ClassVar[dict[str, float]] = {}  # list parameters of one value per beacon -> neutral value
    bounds: ClassVar[dict[str, tuple[float, float]]] = {}  # inclusive (low, high) per parameter
    #: motion hooks run by this, then in config order: 1 for an effect that reads ``Motion.command`` as a lag left it
    motion_order: ClassVar[int] = 0

    def __init__(self, params: dict[str, Any] | None = None, cfg: dict[str, Any] | None = None) -> None:
        self.params = validate_params(type(self), params)
        self.cfg = cfg if cfg is not None else {}
        self.rng = np.random.default_rng(0)

    @classmethod
    def finalize(cls, params: dict[str, Any], cfg: dict[str, Any]) -> dict[str, Any]:
        """Check ``params`` against the full env config; fill per-beacon defaults. One-line ValueError."""
        out = dict(params)
        n = len(cfg["beacons"])
        for key, neutral in cls.per_beacon.items():
            if not out[key]:
                out[key] = [neutral] * n
            elif len(out[key]) != n:
                raise ValueError(
                    f"effect '{cls.name}': parameter '{key}' must have one value per beacon ({n} beacons), "
                    f"got {len(out[key])}"
                )
        return out

    def reset(self, rng: np.random.Generator) -> None:
        """Start an episode with this effect's own random stream."""
        self.rng = rng

    def capacity(self, n: int) -> int:
        """Most sightings :meth:`sense` can return when given ``n``."""
        return n

    def motion(self, m: Motion, frame: Frame) -> Motion:
        """Return the (possibly changed) motion of this frame."""
        return m

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        """Return the (possibly changed, dropped or extended) sightings of this frame."""
        return sightings


EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make ``cls`` available by ``cls.name`` in the ``effects`` config."""
    if not cls.name:
        raise ValueError(f"effect class {cls.__name__} has no name")
    EFFECTS[cls.name] = cls
    return cls


@register_effect
class HeightBias(Effect):
    """Adds a constant ``offset_px`` (px) to every beacon height (a miscalibrated camera).

    Residual signature: a constant mean in the height residuals.
    """

    name = "height_bias"
    defaults = {"offset_px": 0.0}

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        for s in sightings:
            s.height = s.height + self.params["offset_px"]
        return sightings


@register_effect
class Drift(Effect):
    """Adds a constant robot-frame displacement ``disp`` (mm, mm, rad per frame) to every frame.

    Residual signature: a constant mean in the robot-frame motion residuals.
    """

    name = "drift"
    defaults = {"disp": [0.0, 0.0, 0.0]}

    def motion(self, m: Motion, frame: Frame) -> Motion:
        m.disp = m.disp + np.asarray(self.params["disp"])
        return m


# ---------------------------------------------------------------- validation
def _number(effect: str, key: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
        raise ValueError(f"effect '{effect}': parameter '{key}' must be a finite number, got {v!r}")
    return float(v)


def _coerce(cls: type[Effect], key: str, value: Any) -> Any:
    """``value`` checked against the shape of the default (a number or a list of numbers) and the bounds."""
    default = cls.defaults[key]
    if isinstance(default, list):
        fixed = key not in cls.per_beacon
        if not isinstance(value, (list, tuple, np.ndarray)) or (fixed and len(value) != len(default)):
            want = f"a list of {len(default)} numbers" if fixed else "a list of one number per beacon"
            raise ValueError(f"effect '{cls.name}': parameter '{key}' must be {want}, got {value!r}")
        values = [_number(cls.name, key, v) for v in value]
    else:
        values = [_number(cls.name, key, value)]
    lo, hi = cls.bounds.get(key, (-math.inf, math.inf))
    for v in values:
        if not lo <= v <= hi:
            raise ValueError(f"effect '{cls.name}': parameter '{key}' must be in [{lo:g}, {hi:g}], got {value!r}")
    return values if isinstance(default, list) else values[0]


def validate_params(cls: type[Effect], params: dict[str, Any] | None) -> dict[str, Any]:
    """Defaults merged with ``params``; an unknown parameter raises ValueError naming the valid ones."""
    params = {} if params is None else params
    if not isinstance(params, dict):
        raise ValueError(f"effect '{cls.name}': parameters must be a dict, got {params!r}")
    out = {k: (list(v) if isinstance(v, list) else v) for k, v in cls.defaults.items()}
    for key, value in params.items():
        if key not in cls.defaults:
            valid = ", ".join(sorted(cls.defaults)) or "(none)"
            raise ValueError(f"effect '{cls.name}': unknown parameter '{key}' (valid parameters: {valid})")
        out[key] = _coerce(cls, key, value)
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
        out[name] = validate_params(EFFECTS[name], params)
    return out


def finalize_effects(spec: dict[str, dict[str, Any]], cfg: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """A validated ``effects`` spec checked against the full config (beacons, walls, camera)."""
    return {name: EFFECTS[name].finalize(params, cfg) for name, params in spec.items()}


# ---------------------------------------------------------------- the chain run by the env
class EffectChain:
    """The enabled effects of one env, in config order, with their motion and sensing hooks."""

    def __init__(self, cfg: dict[str, Any], sensor_capacity: int = 1) -> None:
        """``sensor_capacity``: most sightings the env's sensor reports in a frame before the effects."""
        self.effects = [EFFECTS[name](params, cfg) for name, params in cfg["effects"].items()]
        self.motion_effects = sorted((e for e in self.effects if type(e).motion is not Effect.motion),
                                     key=lambda e: e.motion_order)  # stable: config order within one order
        self.sense_effects = [e for e in self.effects if type(e).sense is not Effect.sense]
        self.max_sightings = sensor_capacity
        for e in self.sense_effects:
            self.max_sightings = e.capacity(self.max_sightings)

    def reset(self, entropy: int, episode: int) -> None:
        """Give each effect its own stream: ``default_rng([entropy, episode, crc32(name)])``."""
        for e in self.effects:
            e.reset(np.random.default_rng([entropy, episode, zlib.crc32(e.name.encode())]))

    def move(self, m: Motion, frame: Frame) -> Motion:
        """Run the motion hooks in order."""
        for e in self.motion_effects:
            m = e.motion(m, frame)
        return m

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        """Run the sensing hooks in order; more sightings than ``max_sightings`` is an error."""
        for e in self.sense_effects:
            sightings = e.sense(sightings, frame)
        if len(sightings) > self.max_sightings:
            names = ", ".join(e.name for e in self.sense_effects)
            raise RuntimeError(
                f"effects ({names}) returned {len(sightings)} sightings at frame {frame.index}, more than their "
                f"declared capacity {self.max_sightings} (override Effect.capacity)"
            )
        return sightings

