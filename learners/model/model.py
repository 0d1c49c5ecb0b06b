"""The robot model: named components (action, sensor, initial states, effects) and the generic
operations over them: lowering to the inference arrays, packing for acceleration, comparison.

``Model`` is what every learner returns and what ``learners.load_model(path)`` gives back.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterator

import numpy as np

from aibo_core.trajectory import VELOCITY_CONTROLS
from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.sighting_times import at_sighting_times
from learners.model.action import ActionModel, per_component
from learners.model.effects import EffectModel
from learners.model.initial import DEFAULT_INITIAL, InitialState
from learners.model.parameters import Component
from learners.model.sensor import SensorModel


@dataclass(frozen=True)
class Model:
    """lambda = (action model, sensor model, pi per log, effects): everything a learner estimates."""

    action: ActionModel
    sensor: SensorModel
    init: tuple[InitialState, ...]
    effects: tuple[EffectModel, ...] = ()

    def with_(self, **kw) -> "Model":
        return replace(self, **kw)

    def components(self) -> Iterator[tuple[str, Component]]:
        """(name, component) of the parts acceleration extrapolates: action, sensor, effects (the
        initial states come from the last EM step)."""
        yield "action", self.action
        yield "sensor", self.sensor
        for e in self.effects:
            yield f"effects.{e.name}", e

    def effect(self, name: str) -> EffectModel | None:
        return next((e for e in self.effects if e.name == name), None)

    def with_effect(self, effect: EffectModel) -> "Model":
        """The model with ``effect`` added, or replacing the one of the same name (order kept)."""
        names = [e.name for e in self.effects]
        if effect.name in names:
            return replace(self, effects=tuple(effect if e.name == effect.name else e for e in self.effects))
        return replace(self, effects=self.effects + (effect,))

    def without_effect(self, name: str) -> "Model":
        """The model with the effect ``name`` removed (the same model when it has none)."""
        return replace(self, effects=tuple(e for e in self.effects if e.name != name))

    # ------------------------------------------------------------------ inference arrays
    def lower(self, batch: Batch) -> Lowered:
        """The per-frame and per-sighting arrays of this model on ``batch`` (base model, then effects, then each sighting
        predicted at its own time within its frame: ``learners.arrays.sighting_times``)."""
        if len(self.init) != batch.n_logs:
            raise ValueError(f"model has {len(self.init)} initial states for {batch.n_logs} logs")
        commands, scale = self.effective_commands(batch)
        disp = self.action.displacements(commands)
        lo = Lowered.plain(
            disp if scale is None else disp * scale, self.action.cov, self.sensor.basis_id, self.sensor.coef,
            self.sensor.sigma_size, self.sensor.sigma_bearing, np.stack([s.mean for s in self.init]),
            np.stack([s.cov for s in self.init]), batch.n_sightings,
        )
        for e in sorted(self.effects, key=lambda e: e.LOWER_ORDER):  # stable: the order added within one value
            e.lower(lo, batch)
        at_sighting_times(lo, batch, range_sensor=self.sensor.kind == "range_mm")
        return lo

    def effective_commands(self, batch: Batch) -> tuple[np.ndarray, np.ndarray | None]:
        """(commands in force per frame, (N, 3) factor on each component of their displacements or None),
        after the effects that act on commands (a lag) or scale the motion (a fading battery: the same
        factor on the three components; a turn scale: its own per component)."""
        commands = batch.actions if batch.actions is not None else batch.controls
        scale = None
        for e in self.effects:
            commands = e.commands(commands, batch)
            s = e.disp_scale(batch)
            if s is not None:
                s = per_component(s)
                scale = s if scale is None else scale * s
        return commands, scale

    # ------------------------------------------------------------------ packing (SQUAREM)
    def _slots(self, fixed: frozenset[str]) -> list[tuple[int, str, str, Component]]:
        slots = []
        for cname, comp in self.components():
            for pname, p in comp.PARAMS.items():
                if p.trainable and f"{cname}.{pname}" not in fixed:
                    slots.append((p.order, cname, pname, comp))
        return sorted(slots, key=lambda s: s[0])  # stable: declaration order within one order

    def pack(self, fixed: frozenset[str] = frozenset()) -> np.ndarray:
        """The trainable parameters (except ``fixed``, dotted names) as one scaled, unconstrained vector."""
        return np.concatenate([comp.pack_param(pname) for _, _, pname, comp in self._slots(fixed)])

    def packed_layout(self, fixed: frozenset[str] = frozenset()) -> list[tuple[str, str, int]]:
        """(component, parameter, number of entries) of each block of ``pack(fixed)``, in order."""
        return [(cname, pname, len(comp.pack_param(pname))) for _, cname, pname, comp in self._slots(fixed)]

    def packed_held(self, fixed: frozenset[str] = frozenset()) -> np.ndarray:
        """(entries of ``pack(fixed)``,) bool: those the components hold at their value by construction
        (``Component.held``: a unicycle's lateral weights)."""
        return np.concatenate([comp.held(pname) for _, _, pname, comp in self._slots(fixed)])

    def unpack(self, x: np.ndarray, fixed: frozenset[str] = frozenset()) -> "Model":
        """Inverse of ``pack``: this model with the packed parameters read from ``x``."""
        new: dict[str, dict] = {}
        at = 0
        for _, cname, pname, comp in self._slots(fixed):
            value, n = comp.unpack_param(pname, x[at:])
            new.setdefault(cname, {})[pname] = value
            at += n
        if at != len(x):
            raise ValueError(f"packed vector has {len(x)} entries, the model {at}")
        model = self
        for cname, values in new.items():
            comp = dict(self.components())[cname].with_values(**values)
            model = model.with_effect(comp) if cname.startswith("effects.") else replace(model, **{cname: comp})
        return model

    # ------------------------------------------------------------------ printing and comparison
    def describe(self) -> str:
        """Every component's parameters, one per line, with units."""
        lines = []
        for cname, comp in self.components():
            lines += [f"{cname}.{line}" for line in comp.describe()]
        return "\n".join(lines)

    def max_abs_difference(self, other: "Model") -> dict[str, float]:
        """Largest absolute difference per parameter (dotted names) between two models of one structure."""
        mine, theirs = dict(self.components()), dict(other.components())
        if mine.keys() != theirs.keys():
            raise ValueError(f"models differ in components: {sorted(mine)} vs {sorted(theirs)}")
        out = {}
        for cname, comp in mine.items():
            for pname, value in comp.values().items():
                out[f"{cname}.{pname}"] = float(np.max(np.abs(value - theirs[cname].values()[pname]), initial=0.0))
        return out


def default_feature_map(n_controls: int, control_names: tuple[str, ...]) -> str:
    """The action model's feature map for continuous commands when none is asked for: ``unicycle`` for a
    velocity-commanded wheeled robot (controls ``VELOCITY_CONTROLS``, (v mm/s, omega rad/s)): it cannot
    move sideways, and its forward speed does not depend on which way it turns; ``diff_drive`` for two
    other controls; ``linear`` otherwise. (Measured on the five MRCLAM robots against Vicon: ``unicycle``
    beats the commands at face value on forward speed and turn rate on all five; ``diff_drive`` ended in a
    wrong world on robot 4, 25.2 mm/s forward error: docs/results.md. The wheeled simulator's default
    robot is a unicycle too: its weights have no lateral column and no omega terms in the forward row.)"""
    if tuple(control_names) == VELOCITY_CONTROLS:
        return "unicycle"
    return "diff_drive" if n_controls == 2 else "linear"


def start_model(batch: Batch, dt: float, sensor_kind: str = "height_px", n_commands: int | None = None,
                control_names: tuple[str, ...] = (), feature_map: str | None = None, basis: str = "power",
                degree: int = 3) -> Model:
    """The paper's start: no action model (all displacements zero, 10 mm / 10 mm / 0.1 rad noise) and
    a very poor sensor model suited to the sensor kind (``SensorModel.start``)."""
    if batch.actions is not None:
        fmap = feature_map or "table"
        n = n_commands if n_commands is not None else int(batch.actions.max()) + 1
    else:
        fmap = feature_map or default_feature_map(batch.controls.shape[1], control_names)
        from learners.model.action import FEATURE_MAPS

        n = FEATURE_MAPS[fmap][1](batch.controls.shape[1])
        if n < 1:
            raise ValueError(f"feature map '{fmap}' does not take {batch.controls.shape[1]} controls")
    if fmap == "table" and batch.actions is None:
        raise ValueError("a table action model needs discrete actions; use --action-model features")
    return Model(
        ActionModel.zeros(n, dt, fmap, control_names),
        SensorModel.start(sensor_kind, basis, degree),
        tuple(DEFAULT_INITIAL for _ in range(batch.n_logs)),
    )


def paper_start(logs: list, degree: int = 3) -> Model:
    """``start_model`` for a list of logs (aibo_core.trajectory.Trajectory): the paper's start."""
    from learners.arrays.batch import make_batch

    tr = logs[0]
    return start_model(make_batch(logs), tr.dt, tr.sensor_kind, len(tr.attempted) if tr.discrete else None,
                       tuple(tr.control_names or ()), degree=degree)
