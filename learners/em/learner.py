"""The ``em`` learner plugin: the paper's EM over one or more logs, resumable, with a sanity check."""

from __future__ import annotations

import os
import time
from dataclasses import replace

import numpy as np

from aibo_core.trajectory import Trajectory
from learners.arrays.batch import Batch, make_batch
from learners.base import IterationRecord, LearnResult, ProgressFn
from learners.em import checkpoint
from learners.em import lag as lag_search
from learners.em.accel import Packer
from learners.em.alias import alias_steps, close_call, search
from learners.em.estep import e_step, weighed_on
from learners.em.finish import fisher_scoring
from learners.em.fit import EMState, initial_state, options_json, run, setback_from_best
from learners.em.info import FitInfo, FitTimings
from learners.em.map_check import (
    MapDisagreement,
    exchanges,
    judged,
    lost_warning,
    map_warnings,
    repair_warning,
    tried_exchanges,
)
from learners.em.options import COMPARABLE_IMPROVEMENT, DEFAULT_DEGREE, DEFAULT_GATE, EARLY_STOP, STRICT_PATIENCE, EMOptions
from learners.em.predictive import has_mixture
from learners.em.start import initial_state_candidates
from learners.em.starts import chosen_start_pose, disagreement, pruned_warning, screen
from learners.em.support import (
    StartModelError,
    check_support,
    correlated_size_warnings,
    curve_warnings,
    face_value_warnings,
    mirror_warnings,
    walk_warnings,
    weak_command_warnings,
)
from learners.model.catalogue import OffCenterShrink
from learners.model.catalogue_more import FalseSightings
from learners.model.initial import DEFAULT_INITIAL, InitialState
from learners.model.model import Model, start_model

#: A fit whose smoothed path spends more than this share of poses far outside the field is refused.
MAX_OFF_FIELD = 0.05
OFF_FIELD_MARGIN_MM = 500.0


class EMDivergedError(RuntimeError):
    """EM converged to a world that does not fit the field (usually a bad starting sensor model, or many spurious
    sightings). ``fraction``: the share of smoothed poses off the field."""

    def __init__(self, message: str, fraction: float = float("nan")):
        super().__init__(message)
        self.fraction = fraction


def setback_record(state: EMState) -> dict | None:
    """``FitInfo.setback``, taken when EM stops (before any search or finish replaces its best): the largest fall of
    one EM step anywhere in the fit and from (within 1 nat of) its best, each as nats and 1-based iteration; None
    when EM never fell."""
    if not state.setbacks:
        return None
    nats, iteration = max((ref - ll, it + 1) for it, ref, ll in state.setbacks)
    from_best, at = setback_from_best(state)
    return {"nats": nats, "iteration": iteration, "from_best_nats": from_best, "from_best_iteration": at,
            "iterations": state.iteration}


#: A fall of one EM step from the fit's best larger than this (nats) is warned of (``setback_warnings``):
#: chi-square(1, 0.95) / 2, the drop that bounds a 95% likelihood interval, so the model EM settles at and the one
#: it returns differ by more than an interval's worth of likelihood. None of 40 effect-free 5-minute fits (seeds
#: 1000-1019, both presets) fell from its best at all; docs/results.md "EM that falls from its best" has the fits
#: that do.
SETBACK_WARN_NATS = 1.92


def setback_warnings(setback: dict | None) -> list[str]:
    """A warning when EM fell from its best model by more than ``SETBACK_WARN_NATS`` (``setback_record``): the model
    returned is the most likely iterate, not a point EM holds, and may fall short of the likelihood's maximum."""
    if setback is None or setback["from_best_nats"] <= SETBACK_WARN_NATS:
        return []
    return [f"EM's likelihood fell by {setback['from_best_nats']:.2f} nats in one step from its most likely model "
            f"(iteration {setback['from_best_iteration']} of {setback['iterations']}): the E-step is an approximation "
            "(linearized, or a mixture's weights taken at the smoothed path) that EM does not hold at the model it "
            "returns; that model may fall short of the likelihood's maximum, and a longer fit from it ('aibo learn "
            "LOG --init MODEL --patience 200') may be more likely"]


def spurious_start(start: Model, batch: Batch) -> Model:
    """The start of the refit with spurious sightings (``EMOptions.spurious_refit``): ``start`` with
    ``false_sightings`` (``FalseSightings.start``) and its sensor curve in the paper's basis (cubic in the distance):
    with the inverse basis the refit found the field on 1 of 5 logs of 8-10% spurious sightings (3 and 5 minutes,
    ``aibo``; vx 73% off on that one), with the paper's on 6 of 6 (vx within 3.1-5.6% on 5, 26% on a 3-minute log)
    (docs/results.md, "Spurious sightings: the refit of a wrong world")."""
    sensor = start.sensor if start.sensor.basis == "power" else start.sensor.in_basis("power", DEFAULT_DEGREE["power"])
    return start.with_(sensor=sensor).with_effect(FalseSightings.start(batch))


def stage_checkpoint(path: str | os.PathLike | None, stage: str) -> str | None:
    """The checkpoint of one stage of a fit beside ``path`` (``PATH.STAGE.npz``): "held" for the held-curve stage of
    ``range_curve`` "freed" ("held_face_value" for its second start, ``EMOptions.face_value_start``), "spurious-1" and
    "spurious-2" for the refit with spurious sightings, "map_repaired" for the fit on the repaired logs
    (``EMOptions.map_repair``)
    (``EMOptions.spurious_refit``). Kept apart, so a resumed run finishes the stage it stopped in from its own and
    resumes the next from its."""
    return None if path is None else f"{os.fspath(path)}.{stage}.npz"


def field_warnings(frac: float) -> list[str]:
    """The warning of a fit that ``check_field=False`` let through in a world that does not fit the field."""
    if frac <= MAX_OFF_FIELD:
        return []
    return [f"a wrong world? {frac:.0%} of smoothed poses lie more than {OFF_FIELD_MARGIN_MM:.0f} mm outside the "
            "field: the sensor curve implies wrong beacon distances"]


def off_field_fraction(mu: np.ndarray, field: np.ndarray, margin: float = OFF_FIELD_MARGIN_MM) -> float:
    """Share of poses (x, y in mm) further than ``margin`` outside the field rectangle."""
    half = np.asarray(field, float) / 2 + margin
    return float(np.mean((np.abs(mu[:, 0]) > half[0]) | (np.abs(mu[:, 1]) > half[1])))


def plausible_area(tr: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """(centre, size) in mm of the rectangle a log's poses should stay in: the field when the log
    has one; otherwise the landmarks' bounding box grown on every side by half its larger side
    (real logs carry no field; the landmarks are what the robot walks among)."""
    if tr.field is not None:
        return np.zeros(2), np.asarray(tr.field, float)
    lo, hi = tr.landmarks.min(axis=0), tr.landmarks.max(axis=0)
    grow = max(float((hi - lo).max()), 1000.0)
    return (lo + hi) / 2, hi - lo + grow


#: ``--action-model`` choices: table (discrete), features (diff_drive for (v, omega), else linear), unicycle
ACTION_MODELS = ("table", "features", "unicycle")


def feature_map_for(action_model: str | None, discrete: bool, control_names: tuple[str, ...]) -> str | None:
    """The feature map ``--action-model`` asks for (None: the start model's default), or a ValueError naming
    why it does not fit the log (``discrete``: the log's commands are indices; ``control_names``: otherwise)."""
    if action_model not in (None, *ACTION_MODELS):
        raise ValueError(f"unknown action model {action_model!r} (valid choices: {', '.join(ACTION_MODELS)})")
    if action_model == "table" and not discrete:
        raise ValueError("this log has continuous commands ('controls'): use --action-model features")
    if action_model in ("features", "unicycle") and discrete:
        raise ValueError(f"--action-model {action_model} needs continuous commands ('controls'); this log has "
                         "discrete actions (use --action-model table)")
    if action_model == "unicycle" and len(control_names) != 2:
        raise ValueError(f"--action-model unicycle needs two controls (v, omega); this log has {len(control_names)}")
    if action_model in (None, "table"):
        return None
    if action_model == "unicycle":
        return "unicycle"
    return "diff_drive" if len(control_names) == 2 else "linear"


#: The two kinds of commands, as a model's and a log's errors name them.
COMMAND_KINDS = {True: "discrete commands (actions)", False: "velocity commands (controls)"}


def check_model_fits(model: Model, logs: list[Trajectory], batch: Batch | None = None) -> None:
    """Refuse (StartModelError: one line naming the model's field and the log's) a model that does not describe
    these logs: the other kind of commands or another number of them, another sensor, other control names, an effect
    the logs cannot support (``EffectModel.NEEDS``), or effect parameters of another shape than the logs need (e.g.
    one height scale per landmark). For a start model (``aibo learn --init``) and a fitted one (``aibo export tum``)."""
    tr = logs[0]
    act = model.action
    if act.discrete != tr.discrete:
        raise StartModelError(f"a model of {COMMAND_KINDS[act.discrete]}, the log holds {COMMAND_KINDS[tr.discrete]}",
                              "action_model.feature_map", "actions" if tr.discrete else "controls")
    if tr.discrete and len(act.weights) != len(tr.attempted):
        raise StartModelError(f"the model has {len(act.weights)} commands, the log {len(tr.attempted)}",
                              "action_model.velocities", "attempted")
    if model.sensor.kind != tr.sensor_kind:
        raise StartModelError(f"the model's sensor measures {model.sensor.kind}, the log's {tr.sensor_kind}",
                              "sensor_model.kind", "sensor_kind")
    if not tr.discrete and tuple(act.control_names) != tuple(tr.control_names or ()):
        raise StartModelError(f"{list(act.control_names)}, but the log's controls are {list(tr.control_names or ())}",
                              "action_model.control_names", "control_names")
    batch = batch if batch is not None else make_batch(logs)
    for effect in model.effects:
        lacking = [need for need in effect.NEEDS if any(getattr(t, need) is None for t in logs)]
        if lacking:
            raise StartModelError(f"needs the log's {', '.join(lacking)}, which the log(s) lack",
                                  f"effects.{effect.name}", lacking[0])
        neutral = type(effect).start(batch).values()
        for key, value in effect.values().items():
            if value.shape != neutral[key].shape:
                raise StartModelError(f"shape {value.shape}, these logs need {neutral[key].shape} "
                                      f"({effect.PARAMS[key].unit})", f"effects.{effect.name}.parameters.{key}")


def face_value_gate(batch: Batch, start: Model, gate: float) -> np.ndarray | None:
    """The sightings (bool mask over the batch) the first-iteration gate prunes when judged under the commands'
    face value (v = v_cmd, omega = omega_cmd, range = distance; ``learners.scoring.face_value_model``), or None when
    the model has no face value (discrete commands, other controls, a height sensor).

    Why: the paper's gate is judged at the start model, whose velocities are zero. On a simulated log with a known
    start that is harmless; on a real log the start pose is an estimate (MRCLAM robot 3: 0.9 m and 0.7 rad off) and a
    robot standing still cannot follow the sightings of one that drives: the gate pruned 1585 of robot 3's 2204
    sightings (robots 1, 2, 4, 5: 1-14) and every start then fitted the sightings a wrong world explains. Under the
    face value robot 3 loses 87 (the others 0-2). The stretched starts of ``learners.em.starts`` gated themselves
    (30-75% pruned) and, at the time, were compared on the sightings no start pruned, a subset chosen by the wrong
    worlds (now they are scored on the same sightings: ``learners.em.starts.gated_score``)."""
    from learners.scoring import face_value_model

    try:
        face = face_value_model(start)
    except ValueError:
        return None
    post = e_step(face, batch, "compiled", gate)
    return np.asarray(batch.used, bool) & (post.mahal2 > gate)


#: nats by which the fit from the face value must beat the paper start's to be kept (``EMOptions.face_value_start``).
#: Fits of one world from the two starts end within 3.5 nats of each other (28 of 30 MRCLAM Dataset 6 and 7 fits: whole
#: logs and halves); the two wrong worlds measured were 106 and 415 nats less likely. Within the margin the paper's
#: start is kept, so where it finds the world nothing changes.
FACE_START_MARGIN_NATS = 5.0


def face_value_start(start: Model) -> Model | None:
    """``start`` (the paper's: velocities zero) with its velocities at the commands' face value (vx = v, vtheta =
    omega; ``learners.scoring.face_value_model``), everything else kept; None when the model has no face value
    (discrete commands, other controls). ``EMOptions.face_value_start``.

    Why: from the paper's start EM can settle in a wrong world where the sightings are sparse. MRCLAM Dataset 6's robot
    1 (another run of the Dataset 7 robots, never used to choose a default), the first half of its log: 613 sightings
    in 376 s, none for most of 125 s; from the paper's start the held-curve fit turned at 2.6 times the true turn
    rate's error (smoothed pose 2.3 m off), 238 nats less likely than the fit warm-started from the whole log's
    model; from the face value it found the world (0.20 m) (docs/results.md, "A second start at the face value")."""
    from learners.scoring import face_value_model  # the scoring layer imports the learners' arrays: here

    try:
        return start.with_(action=face_value_model(start).action)
    except ValueError:
        return None


def stands_still(start: Model) -> bool:
    """Whether ``start`` predicts no motion at all (every action weight 0: the paper's start, ``start_model``), the
    start the face-value gate stands in for (``face_value_gate``).

    A start that moves (a fitted model: ``--init``, ``aibo diagnose``'s final fit and profiles, the calibrated check's
    refits) is judged by EM's own first-iteration gate, at itself (the paper's rule; issue 33). The face value strips
    a start's effects and keeps its noise, and a fitted model's noise is what its effects leave: with ``landmark_bias``
    the bias states carry the range errors and the range sigma shrinks (MRCLAM robot 2, the search's model: 14 mm
    beside a bias of sigma_rel 0.045, about 160 mm at 3.5 m). Measured on the five MRCLAM robots' whole logs, from the
    model ``aibo diagnose``'s search hands its final fit: under its face value the gate pruned 222 / 1088 / 1166 /
    252 / 866 sightings (9 / 28 / 26 / 14 / 25%), of them 170 / 963 / 1012 / 101 / 727 for the bias states alone
    (the model without ``landmark_bias``); the model itself prunes 0 / 1 / 0 / 4 / 1. Against Vicon the pruned
    sightings were honest (relative range errors at most 11-13%, as the kept ones'; bearing errors alike): the
    passes with the largest biases, so the whole-log fit met a tamer sensor than the search had named (robot 2:
    sigma_rel 0.030 against 0.045, with a warning that the fits disagree; now 0.048). The calibrated check's replicas
    lost 30-44% of their training sightings the same way (robots 1 and 2), which widened the replicas' spread."""
    return not np.any(start.action.weights)


def fit_options(opts: EMOptions, batch: Batch, start: Model) -> tuple[EMOptions, Batch, int | None]:
    """(the options of this fit, its batch, sightings pruned by the face-value gate (None: not applied)). A start with
    effects and the default stop rule is fitted to the strict one (0.1 nat, patience 50).

    A range sensor (``range_mm``) with ``range_curve="held"`` keeps its start's curve (range = distance), as any fit
    with ``hold_curve`` does (``aibo diagnose``'s final fit from learn's model, its first stage); with
    "held" or "freed" it screens no stretched starts (they differ only in the curve; "freed" from a start that stands
    still is two fits, ``EMLearner._freed``). With ``face_value_gate``, continuous (v, omega)
    commands and a start that stands still (the paper's, ``stands_still``), the outlier gate is judged once under the
    commands' face value (``face_value_gate``) and EM runs without its own first-iteration gate, so every start sees
    the same sightings; a start that moves (a warm start) is judged by EM's first-iteration gate, at itself."""
    if opts.range_curve != "free" and start.sensor.kind == "range_mm":
        opts = replace(opts, hold_curve=opts.hold_curve or opts.range_curve == "held", starts=1)
    if start.effects and (opts.min_improvement, opts.patience) == EARLY_STOP:
        # The default early stop (EMOptions.patience) rests on base models; EM moves an effect's parameters slowly (on
        # the 10-minute log of tests/test_landmark_bias.py it stopped landmark_bias at tau_s 12.6 s for 8, where the
        # 0.1-nat rule reaches 8.05 s), so with effects the defaults mean the strict stop. Explicit rules are kept
        # (the discrepancy search's: 0.1 nat, patience 15).
        opts = replace(opts, min_improvement=COMPARABLE_IMPROVEMENT, patience=STRICT_PATIENCE)
    pruned = None
    if opts.face_value_gate and opts.gate is not None and batch.controls is not None and stands_still(start):
        out = face_value_gate(batch, start, opts.gate)
        if out is not None:
            batch = batch.with_used(np.asarray(batch.used, bool) & ~out)
            opts, pruned = replace(opts, gate=None), int(out.sum())
    return opts, batch, pruned


class EMLearner:
    """Maximum-likelihood action and sensor models by EM (Stronger & Stone).

    Arguments: ``options`` (EMOptions), ``checkpoint_path`` (write the state there every
    ``checkpoint_every`` iterations and resume from it when it matches), ``check_field``
    (refuse a result whose smoothed path leaves the field).
    """

    name = "em"

    def __init__(self, options: EMOptions | None = None, checkpoint_path: str | os.PathLike | None = None,
                 resume: bool = True, checkpoint_every: int = 20, check_field: bool = True):
        self.options = (options or EMOptions()).validate()
        self.checkpoint_path = checkpoint_path
        self.resume = resume
        self.checkpoint_every = checkpoint_every
        self.check_field = check_field

    def start_params(self, logs: list[Trajectory], init: Model | None, batch: Batch,
                     action_model: str | None = None, initial: tuple[InitialState, ...] | None = None) -> Model:
        """``init`` fitted to these logs (dt, number of logs, sensor degree), or the paper's start
        (``start_model``: zero velocities, a very poor sensor line suited to the sensor kind) with
        each log's start-pose belief ``initial`` (one per log), by default from ``initial_state_candidates`` (the
        simulator's start when the log says it; for a real log, an estimate from its first sightings, the candidate the
        whole log agrees with under the commands' face value: ``chosen_start_pose``)."""
        tr = logs[0]
        names = tuple(tr.control_names or ())
        n_commands = len(tr.attempted) if tr.discrete else None
        fmap = feature_map_for(action_model, tr.discrete, names)
        basis = self.options.sensor_basis(tr.sensor_kind, init.sensor.basis if init else None)
        degree = self.options.sensor_degree(basis)
        if init is not None:
            check_model_fits(init, logs, batch)
        if init is None:
            paper = start_model(batch, tr.dt, tr.sensor_kind, n_commands, names, fmap, basis, degree)
            start = paper.with_(init=initial or tuple(chosen_start_pose(t, paper, initial_state_candidates(t))
                                                      for t in logs))
        else:
            start = init
        start = start.with_(sensor=start.sensor.in_basis(basis, degree))
        if init is None and tr.sensor_kind == "range_mm" and self.options.range_shrink:
            start = start.with_effect(OffCenterShrink(0.0))  # a range is depth (EMOptions.range_shrink)
        if len(start.init) != len(logs):
            start = replace(start, init=tuple(start.init[0] if len(start.init) == 1 else DEFAULT_INITIAL
                                              for _ in logs))
        if not np.isclose(start.action.dt, tr.dt):
            weights = start.action.weights / start.action.dt * tr.dt
            start = replace(start, action=replace(start.action, weights=weights, dt=tr.dt))
        # a noise mixture's weights of another batch (a model fitted on the training halves, warm-starting the fit
        # on the whole logs) are computed on this one: without them the first E-step takes every sighting at full
        # weight and spurious ones drag the path (docs/results.md, "Spurious sightings: the search's second start")
        return start if init is None else weighed_on(start, batch)

    def fit(self, logs: list[Trajectory], init: Model | None = None, progress: ProgressFn | None = None,
            action_model: str | None = None, initial: tuple[InitialState, ...] | None = None) -> LearnResult:
        """Fit by EM. The checkpoint (if any) is left in place: the caller deletes it once the model
        is safely written (``discard_checkpoint``), so a failed final write loses nothing. ``initial``: the
        logs' start-pose beliefs for the paper's start (``start_params``; ignored with ``init``)."""
        batch = make_batch(logs)
        sightings = int(np.count_nonzero(batch.used))
        start = self.start_params(logs, init, batch, action_model, initial)
        try:
            result = self._fit_from(logs, batch, start, progress)
        except EMDivergedError as wrong:
            if not (self.options.spurious_refit and init is None and start.effect("false_sightings") is None):
                raise
            result = self._spurious_refit(logs, batch, start, progress, wrong)
        heavy = pruned_warning(result.pruned_observations, sightings)
        if heavy:
            result.info.warnings = [heavy] + list(result.info.warnings or [])
        tries = exchanges([MapDisagreement(**d) for d in result.info.map_check or []])
        if self.options.map_repair and tries:
            return self._map_repaired(logs, batch, init, progress, action_model, result, tries)
        return result

    def _map_repaired(self, logs: list[Trajectory], batch: Batch, init: Model | None, progress: ProgressFn | None,
                      action_model: str | None, first: LearnResult, tries: list[list[list[int]]]) -> LearnResult:
        """``EMOptions.map_repair``: the fit made again, as ``fit`` makes it (its own checkpoint stage,
        "map_repaired"), on the logs with the ids of the pairs of the first fit's map check that are or may be swapped
        exchanged (``map_check.exchanges``, in order; ``map_check.repaired``; the start-pose beliefs found again
        from their sightings), the first that explains the logs better kept (``map_check.exchange_holds``): its info
        keeps the first fit's findings (``map_check``; the refit's own check is among its warnings), says what was
        repaired (``map_repair``) and carries the first fit's warnings on the map, then the refit's own. Where none
        holds, the first fit is returned with a line that says what was tried (its ``map_repair``'s "held" false)."""
        gate = self.options.gate or DEFAULT_GATE
        said = map_warnings([MapDisagreement(**d) for d in first.info.map_check])
        learner = EMLearner(replace(self.options, map_repair=False),
                            stage_checkpoint(self.checkpoint_path, "map_repaired"), self.resume, self.checkpoint_every,
                            self.check_field)

        def fit(fixed: list[Trajectory]) -> tuple[LearnResult, Model]:
            result = learner.fit(fixed, init, progress, action_model)
            return result, result.params

        records, result, _ = tried_exchanges(logs, tries, judged(first.params, batch, gate).left_out, gate, fit)
        if result is not None:
            result.info.warnings = said + [repair_warning(records[-1])] + list(result.info.warnings or [])
            result.info.map_check, result.info.map_repair = first.info.map_check, records[-1]
            return result
        first.info.warnings = said + [repair_warning(r) for r in records] + [
            w for w in first.info.warnings or [] if w not in said]
        first.info.map_repair = records[0]
        return first

    def fit_in_field(self, logs: list[Trajectory], action_model: str | None = None,
                     initial: tuple[InitialState, ...] | None = None) -> tuple[LearnResult, LearnResult | None]:
        """(the fit from the paper's start, its refit with spurious sightings or None) for a learner that
        ``check_field=False`` lets end in a wrong world: one that ends there (more than ``MAX_OFF_FIELD`` of its
        smoothed poses off the field) is refitted as ``aibo learn`` refits it (``EMOptions.spurious_refit``,
        :meth:`_spurious_refit`), and the refit is returned where it found the field."""
        first = self.fit(logs, action_model=action_model, initial=initial)
        wrong = first.info.off_field_fraction
        if self.check_field or not (self.options.spurious_refit and wrong > MAX_OFF_FIELD):
            return first, None
        batch = make_batch(logs)
        start = self.start_params(logs, None, batch, action_model, initial)
        refit = self._spurious_refit(logs, batch, start, None, EMDivergedError("a wrong world", wrong))
        return first, (refit if refit.info.off_field_fraction <= MAX_OFF_FIELD else None)

    def _fit_from(self, logs: list[Trajectory], batch: Batch, start: Model, progress: ProgressFn | None) -> LearnResult:
        """``_fit_once``, or for a range sensor's curve ``"freed"`` from a start that stands still, ``_freed``."""
        if self.options.range_curve == "freed" and start.sensor.kind == "range_mm" and stands_still(start):
            return self._freed(logs, batch, start, progress)
        return self._fit_once(logs, batch, start, progress)

    def _freed(self, logs: list[Trajectory], batch: Batch, start: Model, progress: ProgressFn | None) -> LearnResult:
        """``EMOptions.range_curve`` "freed": the fit with the curve held at the start's (its own checkpoint beside the
        fit's, no standard errors), then from its result the fit with the curve free, one start (the held fit found the
        world; stretched starts differ only in the curve). Both stages are the whole fit: the first gated under the
        commands' face value, the second a warm start under the given options, gated at the held fit, its curve free and
        one start (``fit_options``). With ``EMOptions.face_value_start`` the held stage is fitted from the commands' face
        value too, kept where clearly more likely (``_more_likely_held``). The lag and alias searches run in the held
        stage (the free one starts with what they kept) and their records are carried over: the actuation lag and its
        interval are the held curve's, not profiled again under the freed one."""
        given, path = self.options, self.checkpoint_path
        try:
            self.options = replace(given, range_curve="held", uncertainty=False)
            self.checkpoint_path = stage_checkpoint(path, "held")
            held = self._fit_once(logs, batch, start, progress)
            starts = None
            if given.face_value_start and (face := face_value_start(start)) is not None:
                self.checkpoint_path = stage_checkpoint(path, "held_face_value")
                held, starts = self._more_likely_held(logs, batch, start, held, face, progress)
            self.options, self.checkpoint_path = given, path
            freed = self._fit_once(logs, batch, weighed_on(held.params, batch), progress)
        finally:
            self.options, self.checkpoint_path = given, path
        for name in ("alias_search", "lag_search"):  # run in the held stage; the free one starts with their result
            if getattr(freed.info, name) is None and getattr(held.info, name) is not None:
                setattr(freed.info, name, getattr(held.info, name))
                setattr(freed.info.timings, name, getattr(held.info.timings, name))
        freed.info.held_curve_fit = {"iterations": held.iterations, "loglik": float(max(held.loglik)),
                                     "curve": [float(c) for c in held.params.sensor.coef],
                                     "pruned": held.pruned_observations}
        if starts is not None:
            freed.info.held_curve_fit["starts"] = starts
        return freed

    def _more_likely_held(self, logs: list[Trajectory], batch: Batch, start: Model, held: LearnResult, face: Model,
                          progress: ProgressFn | None) -> tuple[LearnResult, dict]:
        """(``held``, the held-curve fit from the paper's ``start``, or the same fit from ``face`` where that is more
        than ``FACE_START_MARGIN_NATS`` more likely; the record): ``EMOptions.face_value_start``. Both fits see the same
        sightings (gated as the paper's start is, ``fit_options``) and are scored by one E-step each of their models on
        them, the curve held at the same start's: their likelihoods compare. A fit from the face value that fails
        (diverges, ends in a wrong world) is not kept, with why."""
        _, gated, _ = fit_options(self.options, batch, start)  # the sightings both fits saw (the face-value gate once)

        def score(result: LearnResult) -> float:  # nats of those sightings under the fit's model (one E-step, ungated)
            return float(e_step(result.params, gated, self.options.estep).loglik)

        record: dict = {"paper": score(held)}
        try:
            other = self._fit_once(logs, batch, face, progress, gate_as=start)
        except (EMDivergedError, FloatingPointError, np.linalg.LinAlgError) as failed:
            record.update(face_value=None, kept="paper", why=f"the fit from the face value failed: {failed}")
            return held, record
        record["face_value"] = score(other)
        kept = other if record["face_value"] > record["paper"] + FACE_START_MARGIN_NATS else held
        record["kept"] = "face value" if kept is other else "paper"
        return kept, record

    def _fit_once(self, logs: list[Trajectory], batch: Batch, start: Model, progress: ProgressFn | None,
                  gate_as: Model | None = None) -> LearnResult:
        """``_fit`` with this start's options (``fit_options``; ``gate_as``'s where given: the sightings and stop rule
        of another start) and the face-value gate's count."""
        given = self.options
        try:
            self.options, batch, face_pruned = fit_options(given, batch, start if gate_as is None else gate_as)
            result = self._fit(logs, batch, start, progress)
        finally:
            self.options = given
        if face_pruned is not None:
            result.pruned_observations += face_pruned
            result.info.face_value_gate_pruned = face_pruned
        return result

    def _spurious_refit(self, logs: list[Trajectory], batch: Batch, start: Model, progress: ProgressFn | None,
                        wrong: EMDivergedError) -> LearnResult:
        """The fit again from ``start`` with a share of spurious sightings in the model (``EMOptions.spurious_refit``,
        ``spurious_start``: the paper's basis), then, from there, in ``start``'s basis (its first-iteration gate then
        judges the sightings at a model that fits the field); each checkpointed apart (``stage_checkpoint``). A
        wrong world again raises, saying both."""
        path = self.checkpoint_path
        try:
            self.checkpoint_path = stage_checkpoint(path, "spurious-1")
            result = self._fit_from(logs, batch, spurious_start(start, batch), progress)
            if result.params.sensor.basis != start.sensor.basis:
                basis = start.sensor.basis
                sensor = result.params.sensor.in_basis(basis, self.options.sensor_degree(basis))
                self.checkpoint_path = stage_checkpoint(path, "spurious-2")
                result = self._fit_from(logs, batch, result.params.with_(sensor=sensor), progress)
        except EMDivergedError as again:
            raise EMDivergedError(f"{wrong} Fitted again with a share of spurious sightings in the model "
                                  f"(false_sightings): {again.fraction:.0%} off the field.", again.fraction) from None
        finally:
            self.checkpoint_path = path
        rate = float(result.params.effect("false_sightings").rate)
        result.info.spurious_refit = {"off_field_fraction": float(wrong.fraction)}
        result.info.warnings = [
            f"the fit ended in a wrong world ({wrong.fraction:.0%} of the smoothed poses off the field) until spurious "
            f"sightings were modelled: fitted again from the same start with false_sightings, then gated at that fit "
            f"({result.pruned_observations} sightings set aside) and fitted again, {rate:.1%} of the rest spurious; "
            "the sensor reports landmarks that are not there, or sightings far off; `aibo diagnose` tests that "
            "against the other effects"] + list(result.info.warnings or [])
        return result

    def _fit(self, logs: list[Trajectory], batch: Batch, start: Model, progress: ProgressFn | None) -> LearnResult:
        undetermined = check_support(batch, start)
        fp = checkpoint.fingerprint(batch, start, options_json(self.options)) if self.checkpoint_path else ""
        history: list[IterationRecord] = []

        def record(iteration: int, loglik: float, seconds: float, params: Model) -> None:
            history.append(IterationRecord(iteration, loglik, seconds, params))
            if progress is not None:
                progress(history[-1])

        state, resumed_from = self._load_or_start(batch, start, fp, record)

        def on_iteration(st: EMState, params: Model, loglik: float) -> None:
            record(st.iteration, loglik, st.seconds[-1], params)

        last_saved = [state.iteration]

        def on_cycle(st: EMState) -> None:
            if self.checkpoint_path and st.iteration - last_saved[0] >= self.checkpoint_every:
                checkpoint.save(self.checkpoint_path, st, fp)
                last_saved[0] = st.iteration

        state = run(batch, state, self.options, on_iteration, on_cycle, switch=self._switches(batch, start))
        setback = setback_record(state)  # EM's own: the searches and the finish below may replace its best
        # the sightings the fit applied (first-iteration outliers pruned), the image angle's noise it held
        used = batch.with_used(state.used).with_angle_noise(state.angle_noise)
        alias = self._alias_search(used, state)
        lag = self._lag_search(used, state)
        scoring = self._finish(used, state)
        times = FitTimings(
            # the first iteration carries the one-time numba compile or cache load: reported apart
            first_iteration=float(state.seconds[0]) if state.seconds else 0.0,
            per_iteration=float(np.median(state.seconds[1:])) if len(state.seconds) > 1 else 0.0)
        off_field = self._check(used, state.best, logs)
        # the map judged by the fitted model on every sighting (the first gate's pruning was the start model's view)
        judgement = judged(state.best, batch, self.options.gate or DEFAULT_GATE)
        mapped = judgement.found
        info = FitInfo(state.best_iteration + 1, resumed_from, self.options.__dict__.copy(),
                       off_field_fraction=off_field, map_check=[d.to_dict() for d in mapped],
                       lost_track=[st.to_dict() for st in judgement.lost],
                       undetermined=undetermined,  # parameters the data did not determine (kept at their start)
                       starts=state.starts or None, timings=times,
                       # E-steps of the whole fit: the winner's, and the other starts' screening
                       iterations_all_starts=state.iteration + sum(
                           r["iterations"] for r in state.starts if not r.get("chosen")),
                       setback=setback)
        for name, record in (("alias_search", alias), ("lag_search", lag)):
            if record is not None:
                setattr(times, name, record.pop("seconds"))
                setattr(info, name, record)
                info.iterations_all_starts += record["iterations"]
        if scoring is not None:
            times.scoring = scoring.seconds
            info.scoring = {**scoring.record, "forward_passes": scoring.passes}
        if self.options.uncertainty and scoring is not None and scoring.uncertainty is not None:
            self._set_uncertainty(info, scoring.uncertainty, 0.0, 0.0, state.best, used)  # at the returned model
        elif self.options.uncertainty:
            self._uncertainty(info, state.best, used)
        split = disagreement(state.starts)
        se = (info.standard_errors or {}).get("action_model.velocities")
        close = close_call(alias, None if se is None else np.asarray(se, float)) if alias else ""
        info.warnings = curve_warnings(state.best) + face_value_warnings(state.best, batch.controls) + \
            mirror_warnings(state.best, batch.controls) + (
            [split] if split else []) + ([close] if close else []) + field_warnings(info.off_field_fraction) + \
            weak_command_warnings(state.best, se) + walk_warnings(state.best, logs) + \
            correlated_size_warnings(state.best, used) + \
            map_warnings(mapped) + lost_warning(judgement.lost) + \
            setback_warnings(None if scoring is not None and scoring.record["converged"] else setback) + (
            [f"{len(undetermined)} parameter(s) not determined by the data (e.g. {undetermined[0]}): kept at their "
             "start values"] if undetermined else [])
        converged = state.converged and (scoring is None or scoring.record["converged"])
        return LearnResult("em", state.best, state.iteration, converged, list(state.loglik),
                           state.pruned, history, info)

    def _alias_search(self, batch: Batch, state: EMState) -> dict | None:
        """The heading-alias search (``learners.em.alias``) on the fit's sightings ``batch``, after the fit of a
        command table, when enabled: ``state.best`` is replaced by a more likely alias; returns the search's
        record (None: not run)."""
        if not self.options.alias_search or batch.actions is None or not state.best.action.discrete:
            return None
        found = search(batch, state.best, state.best_loglik, self.options)
        if found.record["changed"]:
            state.best, state.best_loglik = found.best, found.loglik
        return {**found.record, "seconds": found.seconds}

    def _lag_search(self, batch: Batch, state: EMState) -> dict | None:
        """The actuation-lag search (``learners.em.lag``) on the fit's sightings ``batch`` after the fit of a
        continuous-command log, when enabled: ``state.best`` gains the lag when it is significant; returns the
        search's record (None: not run)."""
        if not lag_search.applies(batch, state.best, self.options):
            return None
        found = lag_search.search(batch, state.best, state.best_loglik, self.options)
        state.best, state.best_loglik = found.best, found.loglik
        return {**found.record, "seconds": found.seconds}

    def _finishes(self, model: Model) -> bool:
        """Whether the scoring finish applies: asked for, and the likelihood is the Gaussian filter's (a
        mixture effect such as ``false_sightings`` has another one; EM then keeps its own stop)."""
        return self.options.finish == "scoring" and not has_mixture(model)

    def _switches(self, batch: Batch, start: Model) -> bool:
        """Whether EM may stop early for the finish: not when the alias search will compare EM fits (it
        measured its candidates against EM's own fixed point; ``learners.em.alias``)."""
        if not self._finishes(start):
            return False
        return not (self.options.alias_search and batch.actions is not None and start.action.discrete
                    and alias_steps(batch.actions, batch.frame_start))

    def _finish(self, batch: Batch, state: EMState):
        """The scoring finish (``learners.em.finish``) from ``state.best``, which it replaces; None when it
        does not apply."""
        if not self._finishes(state.best):
            return None
        done = fisher_scoring(state.best, batch, Packer(self.options).fixed)
        state.best, state.best_loglik = done.model, done.loglik
        return done

    def _uncertainty(self, info: FitInfo, best: Model, batch: Batch) -> None:
        """Fill ``info``'s ``standard_errors`` and ``information`` (module uncertainty) at ``best``; on a
        failure, ``information`` holds the error."""
        from learners.em import second_thread
        from learners.em.uncertainty import parameter_uncertainty
        from learners.inference.kernels import release_scratch

        release_scratch()  # EM's work arrays (1,000,000 frames: 171 MiB), made again if another fit runs
        second_thread.release_scratch()  # and the sensor update's, made on the M-step's second thread
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            unc = parameter_uncertainty(best, batch, Packer(self.options).fixed)
        except (FloatingPointError, np.linalg.LinAlgError, ValueError) as exc:
            info.information = {"error": f"standard errors not computed: {str(exc)[:200]}"}
            return
        self._set_uncertainty(info, unc, time.perf_counter() - t0, time.process_time() - c0, best, batch)

    @staticmethod
    def _set_uncertainty(info: FitInfo, unc, seconds: float, cpu_seconds: float, best: Model, batch: Batch) -> None:
        """Put ``unc``'s standard errors and information summary into ``info``, with the effects' parameters the
        filter's information leaves undetermined taken from their own likelihood (``fill_conditional_errors``: listed
        in ``information["conditional"]``, no longer ``undetermined``); its cost (s) into the timings."""
        from learners.em.uncertainty import fill_conditional_errors

        info.standard_errors, info.information = dict(unc.standard_errors), unc.summary()
        info.robust_standard_errors = dict(unc.robust_standard_errors or {})
        filled = fill_conditional_errors(best, batch, info.standard_errors, info.robust_standard_errors)
        if filled:
            info.information["conditional"] = filled
            info.information["undetermined"] = [u for u in info.information["undetermined"]
                                                if not any(u.startswith(key) for key in filled)]
        info.timings.uncertainty, info.timings.uncertainty_cpu = seconds, cpu_seconds

    def checkpoint_files(self) -> list[str]:
        """Every file a fit may checkpoint to: its stages' (the spurious-sighting refits, the held fits of the lag
        search, the map repair's fit and its stages), existing or not; [] without a checkpoint."""
        if not self.checkpoint_path:
            return []
        stages = (self.checkpoint_path, stage_checkpoint(self.checkpoint_path, "spurious-1"),
                  stage_checkpoint(self.checkpoint_path, "spurious-2"))
        paths = [p for stage in stages for p in (stage, stage_checkpoint(stage, "held"),
                                                 stage_checkpoint(stage, "held_face_value"))]
        if self.options.map_repair:  # the repaired logs' fit and its stages
            paths += EMLearner(replace(self.options, map_repair=False),
                               stage_checkpoint(self.checkpoint_path, "map_repaired")).checkpoint_files()
        return [p for p in paths if p]

    def discard_checkpoint(self) -> None:
        """Delete the checkpoint (call after the model is on disk)."""
        for path in self.checkpoint_files():
            if os.path.exists(path):
                os.unlink(path)

    def _load_or_start(self, batch: Batch, start: Model, fp: str, record) -> tuple[EMState, int]:
        """(state to continue, iteration it was resumed from: 0 for a fresh start). A fresh start with
        ``options.starts`` > 1 is the winner of the screening (``learners.em.starts``), whose iterations
        are then passed to ``record(iteration, loglik, seconds, params)``."""
        if self.checkpoint_path and self.resume:
            saved = checkpoint.load(self.checkpoint_path, fp)
            if saved is not None:
                return saved, saved.iteration
        if self.options.starts > 1:
            state, state.starts, iterations = screen(batch, start, self.options)
            if self.checkpoint_path:  # the screening is saved: a resumed fit continues the winner
                checkpoint.save(self.checkpoint_path, state, fp)
            for it in iterations:
                record(*it)
            return state, 0
        return initial_state(start, batch, self.options), 0

    def _check(self, batch: Batch, best: Model, logs: list[Trajectory]) -> float:
        post = e_step(best, batch, self.options.estep)
        fracs = []
        for tr, a, b in zip(logs, batch.pose_start[:-1], batch.pose_start[1:]):
            centre, size = plausible_area(tr)
            fracs.append(off_field_fraction(post.mu_gamma[a:b, :2] - centre, size))
        frac = max(fracs)
        if self.check_field and frac > MAX_OFF_FIELD:
            raise EMDivergedError(
                f"EM converged to a world that does not fit the field: {frac:.0%} of smoothed poses lie more "
                f"than {OFF_FIELD_MARGIN_MM:.0f} mm outside it. The starting sensor model probably implies "
                "wrong beacon distances; start from a better one (--init MODEL.json).", frac
            )
        return frac
