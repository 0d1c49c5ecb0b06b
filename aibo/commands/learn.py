"""``aibo learn``: learn action and sensor models from logs and write an aibo-model/1 file."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from aibo.data_errors import naming_files
from aibo.errors import CLIError
from aibo.paths import check_files, checkpoint_path, declared_inputs
from aibo.report import Progress, error_table
from aibo_core import trajectory
from aibo_core.compat import check_compatible
from learners.base import LearnResult, get_learner
from learners.em.alias import fixed_line
from learners.em.bearing_sign import sign_check, sign_warnings
from learners.em.learner import EMDivergedError, check_model_fits, feature_map_for
from learners.em.options import EMOptions
from learners.metrics import model_errors, observed_distance_range, true_height, truth_problem, velocity_errors
from learners.model import io as model_io


def em_options(args) -> EMOptions:
    """Defaults (or the paper's recipe), overridden by every option the user gave."""
    opts = EMOptions.paper() if args.paper_recipe else EMOptions()
    opts.max_iter, opts.seed, opts.estep = args.max_iter, args.seed, args.estep
    if args.patience is not None:
        opts.patience = args.patience
    for name in ("sensor_method", "learn_motion_noise", "accel", "alias_search", "lag_search", "finish", "range_curve",
                 "range_shrink", "face_value_gate", "face_value_start", "map_repair"):
        if getattr(args, name) is not None:
            setattr(opts, name, getattr(args, name))
    if args.gate is not None:
        opts.gate = args.gate if args.gate > 0 else None
    if args.starts is not None:
        opts.starts = args.starts
    if args.sensor_basis is not None:
        opts.basis = args.sensor_basis
    return opts.validate()


def lag_report(info: dict) -> list[str]:
    """One line on the actuation-lag search of a continuous-command fit (``learners.em.lag``)."""
    lag = info.get("lag_search")
    if not lag:
        return []
    grid = ", ".join(f"{g:g}" for g in lag["grid_s"]) + (f" and {lag['below_grid'][0]:g}" if "below_grid" in lag else "")
    if lag["lag_s"] > 0:
        ci = lag.get("interval_95")
        within = (f", 95% interval {ci[0]:.3f}-{ci[1]:.3f} s" + (f" ({lag['interval_note']})" if lag.get("interval_note")
                                                               else "")) if ci else ""
        return [f"actuation lag: {lag['lag_s']:.3f} s kept{within} (+{lag['gain_nats']:.1f} nats over no lag; grid "
                f"{grid} s, refined between them); the model carries it (--no-lag-search: without)"]
    return [f"actuation lag: none significant (grid {grid} s)"]


def make_learner(args):
    cls = get_learner(args.learner)
    if args.learner == "em":
        return cls(em_options(args), checkpoint_path=checkpoint_path(args.out), resume=not args.no_resume)
    return cls()


def scoring_report(info: dict) -> list[str]:
    """One line on the scoring finish (``info["scoring"]``), if it ran."""
    rec = info.get("scoring")
    if not rec:
        return []
    return [f"scoring finish: {len(rec['steps'])} step(s), the likelihood rose by {rec['gain_nats']:.1f} nats over "
            f"EM's stop ({rec.get('stop', rec.get('error', ''))}; {rec['forward_passes']} forward passes)"]


def starts_report(info: dict) -> list[str]:
    """Lines on the screened starts (``info["starts"]``), if there were several."""
    rows = info.get("starts") or []
    if len(rows) < 2:
        return []
    win = next(r for r in rows if r.get("chosen"))
    lines = [f"{len(rows)} starts screened for {win['iterations']} iterations each (sensor curve with distances "
             f"x scale), scored on the same sightings; kept start {win['start']}:"]
    for r in rows:
        what = r["error"] if "error" in r else (f"loglik {r['loglik']:.1f}, {r['behind_nats']:,.1f} nats behind"
                                                 + (f", {r['pruned']:,d} sightings pruned" if "pruned" in r else ""))
        lines.append(f"  start {r['start']} (x{r['distance_scale']:.2g}): {what}{'  <- kept' if r.get('chosen') else ''}")
    return lines


def uncertainty_report(result: LearnResult) -> list[str]:
    """Lines on the standard errors (``info["standard_errors"]``) and the information behind them."""
    se, inf = result.info.get("standard_errors"), result.info.get("information")
    robust = result.info.get("robust_standard_errors") or {}
    if inf and "error" in inf:
        return [inf["error"]]
    if not se or not inf:
        return []
    cond = inf["condition_number"]
    lines = [f"standard errors from the Fisher information ({inf['parameters']} parameters; condition number "
             f"{cond if cond is None else format(cond, '.3g')}, smallest eigenvalue {inf['min_eigenvalue']:.3g} of its correlation "
             f"form; weakest direction: {', '.join(inf['weakest_direction']) or '-'}):"]
    if "action_model.velocities" in se:
        v = np.array(se["action_model.velocities"], dtype=float)
        lines.append("  velocities (RMS over commands): vx {:.2f} mm/s, vy {:.2f} mm/s, vtheta {:.4f} rad/s".format(
            *np.sqrt(np.nanmean(v**2, axis=0))))
    for key in ("sensor_model.sigma_height", "sensor_model.sigma_range_mm", "sensor_model.sigma_angle"):
        if key in se:
            lines.append(f"  {key.split('.')[1]}: "
                         f"{_plus_minus(getattr(result.params.sensor, _SIGMA[key]), se[key], robust.get(key))}")
    for key, err in se.items():  # the effects the fit carries (a range's shrink: EMOptions.range_shrink)
        if not key.startswith("effects."):
            continue
        _, name, pname = key.split(".", 2)
        effect = result.params.effect(name)
        if effect is not None and np.ndim(err) == 0:
            value = float(np.asarray(effect.values()[pname]))
            lines.append(f"  {name}.{pname}: {_plus_minus(value, err, robust.get(key))}")
    lines += _robust_note(se, robust)
    if inf["undetermined"]:
        lines.append(f"  undetermined (no sighting depends on them): {', '.join(inf['undetermined'][:6])}"
                     + (" ..." if len(inf["undetermined"]) > 6 else ""))
    if inf.get("fixed"):
        lines.append(f"  fixed by the model, not estimated (standard error 0): {', '.join(inf['fixed'][:6])}"
                     + (" ..." if len(inf["fixed"]) > 6 else ""))
    return lines


def _plus_minus(value: float, err: float | None, robust: float | None = None) -> str:
    """"value +- standard error (robust R)" as the standard-error lines print it (None: undetermined)."""
    text = f"{value:.4g} +- {'undetermined' if err is None else format(err, '.2g')}"
    return text + (f" (robust {robust:.2g})" if err is not None and robust is not None and robust > err else "")


#: ``aibo learn`` says so when a robust error is more than this many times its Fisher error
ROBUST_RATIO_NOTE = 1.5


def _robust_note(se: dict, robust: dict) -> list[str]:
    """One line when the robust errors (``learners.em.uncertainty``: the larger of the Fisher and the sandwich one)
    exceed the Fisher ones by more than ``ROBUST_RATIO_NOTE`` somewhere: the data vary more than the model says."""
    worst, where = 1.0, ""
    for key, err in se.items():
        if key.startswith("initial_state") or key not in robust:
            continue
        a = np.array(np.ravel(np.array(err, dtype=object)), dtype=float)
        b = np.array(np.ravel(np.array(robust[key], dtype=object)), dtype=float)
        ok = np.isfinite(a) & np.isfinite(b) & (a > 0)
        if a.shape == b.shape and ok.any() and np.max(b[ok] / a[ok]) > worst:
            worst, where = float(np.max(b[ok] / a[ok])), key
    if worst <= ROBUST_RATIO_NOTE:
        return []
    return [f"  robust errors up to {worst:.2g}x the Fisher ones ({where}): these data vary more than the model says "
            "(info[\"robust_standard_errors\"]; quote those)"]


_SIGMA = {"sensor_model.sigma_height": "sigma_size", "sensor_model.sigma_range_mm": "sigma_size",
          "sensor_model.sigma_angle": "sigma_bearing"}


#: The figures ``write_plots`` may draw into ``--plots`` (without a prefix).
PLOT_NAMES = ("loglik.png", "sensor_model.png", "velocity_error.png")


def check_learn_files(args) -> None:
    """Refuse outputs (model, checkpoint, figures) that are an input (logs, --init) or each other."""
    inputs = declared_inputs(args)
    outputs = [("--out", args.out), ("checkpoint", checkpoint_path(args.out))]
    if args.plots:
        outputs += [("--plots figure", Path(args.plots) / name) for name in PLOT_NAMES]
    check_files(inputs, outputs, folders=[("--plots", args.plots)] if args.plots else [])


def check_action_model(action_model: str | None, init, init_path: str, tr) -> None:
    """Refuse (CLIError) an ``--action-model`` other than the one ``--init`` holds: the fit starts from, and keeps,
    the init's (it was overruled without a word)."""
    if action_model is None:
        return
    try:
        wanted = feature_map_for(action_model, tr.discrete, tuple(tr.control_names or ())) or "table"
    except ValueError:
        return  # an action model the log cannot take: the fit says so
    if wanted != init.action.feature_map:
        raise CLIError(f"--action-model {action_model}: --init {init_path} holds a '{init.action.feature_map}' action "
                       "model, which the fit starts from and keeps; leave --action-model out, or start without --init")


def checkpoints_now(learner) -> dict[str, float]:
    """The learner's checkpoint files that exist now, with their modification times (ns)."""
    files = learner.checkpoint_files() if hasattr(learner, "checkpoint_files") else []
    return {p: os.stat(p).st_mtime_ns for p in files if os.path.exists(p)}


def discard_written(learner, before: dict[str, float]) -> None:
    """Delete the checkpoint files the learner wrote since ``before`` (``checkpoints_now``): those of a fit that failed
    with an error, which would stop the next run on the mended log ("checkpoint is for other logs"). A checkpoint of
    an earlier run that this one did not touch is kept (it may resume that run); an interrupted fit keeps its own."""
    for path, mtime in checkpoints_now(learner).items():
        if before.get(path) != mtime:
            os.unlink(path)


def run(args) -> int:
    check_learn_files(args)
    logs = [trajectory.load(p) for p in args.logs]
    for warning in check_compatible(logs, list(args.logs)):
        print(f"aibo: warning: {warning}", file=sys.stderr)
    init = model_io.load_model(args.init) if args.init else None
    if init is not None:
        with naming_files(args.logs, args.init):
            check_model_fits(init, logs)
        check_action_model(args.action_model, init, args.init, logs[0])
    learner = make_learner(args)
    progress = Progress(args.learner)
    before = checkpoints_now(learner)
    try:
        with naming_files(args.logs, args.init):
            result = learner.fit(logs, init=init, progress=progress, action_model=args.action_model)
    except (CLIError, EMDivergedError, FloatingPointError, ValueError):
        discard_written(learner, before)  # a fit that fails for good: resuming it would fail again
        raise
    progress.close()
    if isinstance(getattr(learner, "options", None), EMOptions):  # bearings of the other sign: a second fit to tell
        record = sign_check(logs, result.params, learner.options)
        result.info.warnings = list(result.info.warnings or []) + sign_warnings(record)
        result.info.bearing_sign = record
    model_io.save_result(result, args.out)
    if hasattr(learner, "discard_checkpoint"):
        learner.discard_checkpoint()  # only now that the model is safely on disk
    for warning in result.info.get("warnings", []):
        print(f"aibo: warning: {warning}", file=sys.stderr)
    if result.info.get("resumed_from"):
        print(f"resumed from the checkpoint at iteration {result.info['resumed_from']}")
    print(f"wrote {args.out}: {result.iterations} iterations, converged={result.converged}, "
          f"{result.pruned_observations} sightings pruned as outliers")
    fixed = fixed_line(result.info.get("alias_search") or {})
    for line in starts_report(result.info) + ([fixed] if fixed else []) + lag_report(result.info) + \
            scoring_report(result.info) + uncertainty_report(result):
        print(line)
    if scorable_truth(logs, args.logs, result.params):
        print(error_table({args.learner: model_errors(result.params, logs)}))
    elif all(tr.truth is None and tr.pose is not None and not tr.discrete for tr in logs):
        print_scores(result.params, logs)
    if args.plots:
        write_plots(Path(args.plots), result, logs, start=init)
        print(f"figures in {args.plots}/")
    return 0


def scorable_truth(logs, paths, model) -> bool:
    """Whether every log carries a usable ground truth (``meta["truth"]`` and ``pose``) to score ``model``
    against. A malformed truth is ignored with a one-line note naming the file and the field: ``meta`` is
    free-form, and the fit does not depend on it."""
    if not model.action.discrete or not all(tr.truth is not None and tr.pose is not None for tr in logs):
        return False
    for tr, path in zip(logs, paths):
        problem = truth_problem(tr.truth, len(model.action.weights))
        if problem:
            print(f"aibo: note: {path}: {problem}; the model is not scored against it", file=sys.stderr)
            return False
    return True


def print_scores(model, logs) -> None:
    """A real log with ground truth (e.g. Vicon): the learned model against the commands at face value."""
    from learners.scoring import face_value_model, score, score_table

    try:
        face_value_model(model)
    except ValueError as exc:
        print(f"(no comparison with ground truth: {exc})")
        return
    print(score_table(score(model, logs)))


def write_plots(folder: Path, result: LearnResult, logs, start=None, oracle=None, prefix: str = "") -> list[Path]:
    """Learning curves and sensor models; velocity-error curves when the logs carry truth."""
    from aibo import figures
    from learners.model.sensor import SensorModel

    paths = []
    best = result.info.get("best_iteration")
    if result.loglik:
        paths.append(folder / f"{prefix}{PLOT_NAMES[0]}")
        figures.loglik_curve(paths[-1], result.loglik, best)
    truth = logs[0].truth if logs[0].pose is not None else None
    action = result.params.action
    if truth is not None and truth_problem(truth, len(action.weights) if action.discrete else None) is not None:
        truth = None  # unusable (``scorable_truth`` has said why): no true curves
    d_range = observed_distance_range(logs) if truth else result.params.sensor.distance_range_mm
    start_sensor = start.sensor if start else SensorModel.start(logs[0].sensor_kind)
    curves = {"start": start_sensor, f"learned ({result.learner})": result.params.sensor}
    if oracle is not None:
        curves["oracle"] = oracle.sensor
    if truth:
        curves["true (pinhole)"] = true_height(truth, np.linspace(*d_range, 300))
    paths.append(folder / f"{prefix}{PLOT_NAMES[1]}")
    figures.sensor_models(paths[-1], d_range, curves)
    if truth and result.history and result.params.action.discrete:
        true_vel = np.asarray(truth["velocities"])
        series: dict[str, list[float]] = {"vx": [], "vy": [], "vtheta": []}
        for rec in result.history:
            e = velocity_errors(rec.params.action.velocities, true_vel)
            for k in series:
                series[k].append(e[f"{k}_rel"])
        ref = None
        if oracle is not None:
            e = velocity_errors(oracle.action.velocities, true_vel)
            ref = {k: e[f"{k}_rel"] for k in series}
        paths.append(folder / f"{prefix}{PLOT_NAMES[2]}")
        figures.velocity_error_curves(paths[-1], series, ref)
    return paths
