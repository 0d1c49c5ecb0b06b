"""``aibo diagnose``: calibrate, find where model and data disagree, name the missing effect, show the gap shrink."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from aibo import diagnose_report as fig
from aibo.data_errors import naming_files
from aibo.errors import CLIError
from aibo.paths import check_files, check_replaceable, declared_inputs
from aibo.report import for_terminal
from aibo_core import trajectory
from aibo_core.atomic import atomic_folder, finite_json, write_json
from aibo_core.compat import check_compatible
from aibo_core.workers import process_pool
from learners.arrays.batch import Batch, make_batch
from learners.discrepancy.checks import RobustLikelihoodRatio
from learners.discrepancy.effect_sizes import base_shift, holds_off, read_with_care
from learners.discrepancy.final import plausible_diagnosis
from learners.discrepancy.innovation_shape import innovation_shape, shape_text
from learners.discrepancy.score import (
    GAP_METRIC,
    MOTION_GAP_METRIC,
    MOTION_WORSE_Z,
    WHITENESS_METRIC,
    motion_score,
    motion_trade,
    score,
)
from learners.discrepancy.search import OUTLIER_SHARE, search
from learners.discrepancy.signatures import probe_signature, signatures
from learners.discrepancy.statistics import plain_reading
from learners.em.bearing_sign import sign_warnings
from learners.em.learner import feature_map_for
from learners.em.map_check import map_warnings, repair_warning
from learners.em.options import DEFAULT_GATE, EMOptions
from learners.em.support import TESTS_BIAS
from learners.model.catalogue import CHANGE_SIGNATURE
from learners.model.effects import EFFECT_MODELS
from learners.model.io import save_result
from learners.model.model import Model
from learners.scoring import NOISE_KEYS, command_feedback, motion_noise_scores

FIGURES = ("signatures.png", "gap.png", "calibrated.png", "innovations.png")
#: Every file of a diagnosis: the --out folder holds these and nothing else (it is replaced whole).
OUTPUTS = ("report.json", "model.json", "report.html", *FIGURES)


#: ``--candidates`` keywords: the whole catalogue, and the effects tried without the option (``DEFAULT_CANDIDATE``).
ALL, DEFAULTS = "all", "defaults"


def candidate_names(arg: str) -> list[str]:
    """The names of a ``--candidates`` value as given (comma-separated, spaces and empty names dropped)."""
    return [n.strip() for n in arg.split(",") if n.strip()]


def candidates(arg: str | None) -> list[str]:
    """The effects to try: the catalogue's default candidates (``EffectModel.DEFAULT_CANDIDATE``), or the
    comma-separated names given, where "all" stands for every effect of the catalogue and "defaults" for the default
    candidates (``--candidates defaults,heavy_tailed_noise``)."""
    defaults = sorted(n for n, cls in EFFECT_MODELS.items() if cls.DEFAULT_CANDIDATE)
    if arg is None:
        return defaults
    names = candidate_names(arg)
    if not names:
        raise CLIError(f"--candidates {arg!r}: no effect named (give comma-separated names, or leave the option out "
                       "for the default candidates)")
    if len(set(names)) != len(names):
        raise CLIError(f"--candidates {arg!r}: an effect is named twice")
    unknown = [n for n in names if n not in EFFECT_MODELS and n not in (ALL, DEFAULTS)]
    if unknown:
        raise CLIError(f"--candidates: unknown effect {unknown[0]!r} (valid choices: {ALL}, {DEFAULTS}, "
                       f"{', '.join(sorted(EFFECT_MODELS))})")
    expanded = {ALL: sorted(EFFECT_MODELS), DEFAULTS: defaults}
    return list(dict.fromkeys(x for n in names for x in expanded.get(n, [n])))


def run(args) -> int:
    out = Path(args.out)
    names = candidates(args.candidates)
    check_files(declared_inputs(args), [("--out file", out / f) for f in OUTPUTS], folders=[("--out", out)])
    check_replaceable("--out", out, OUTPUTS)
    logs = [trajectory.load(p) for p in args.logs]
    for warning in check_compatible(logs, list(args.logs)):
        print(f"aibo: warning: {warning}", file=sys.stderr)
    for path, tr in zip(args.logs, logs):
        try:
            feature_map_for(args.action_model, tr.discrete, tr.control_names)
        except ValueError as err:
            raise CLIError(f"--action-model {args.action_model}: log {path}: {err}") from None
        if args.tracked_replicas:
            from aibo_gym.collect_wheeled import TRACKED_CONTROLS

            if tr.discrete or tuple(tr.control_names or ()) != TRACKED_CONTROLS:
                raise CLIError(f"--tracked-replicas: log {path}: its commands are {_commands(tr)}, and the replays "
                               f"steer only {', '.join(TRACKED_CONTROLS)} commands")
    t0 = time.perf_counter()
    # the search tries actuation_lag itself, as a candidate; --restricted-noise and the variances' restricted step act
    # in the final fit only
    opts = EMOptions(seed=args.seed, lag_search=False, restricted_noise=args.restricted_noise,
                     restricted_variances=not args.maximum_likelihood_variances)
    lines: list[str] = []

    def say(line: str) -> None:  # the page keeps the line whole; a terminal gets it wrapped (``for_terminal``)
        print(for_terminal(line), flush=True)
        lines.append(line)

    say(f"diagnosing {len(logs)} log(s), {sum(tr.n_frames for tr in logs)} frames; candidates: {', '.join(names)}")
    with process_pool(args.jobs) as pool:  # the search's workers, then the final fit's starts side by side
        with naming_files(args.logs):
            found = search(logs, names, opts, jobs=args.jobs, progress=say, action_model=args.action_model,
                           pool=pool, max_rounds=args.rounds)
        logs = found["logs"]  # outliers set aside, as in every score of the search
        seconds = {"search": time.perf_counter() - t0}
        # the whole-log fit and the named effects' intervals (learners.discrepancy.final), without an effect it made
        # implausible (then the search's model without it is the one scored below)
        found, final = plausible_diagnosis(found, opts, say, pool if args.jobs > 1 else None)
    seconds.update(final.seconds)
    before, after = score(found["base"], logs), score(found["model"], logs)
    motion = motion_gaps(found["base"], found["model"], logs)
    sig_before, sig_after = signatures(found["base"], logs), signatures(found["model"], logs)
    report = _report(found, final.effects, before, after, sig_before)
    batch = make_batch(logs)
    for e in report["effects"]:  # what the report says about each effect's values (also among its warnings)
        e["warnings"] = (negligible_when_final(final.result.params, [e], logs) + read_with_care(e)
                         + off_held([e], batch))
    report.update(motion)
    report["final_fit_starts"] = final.starts
    # where the diagnosed model lost track of the robot on the logs (learners.em.map_check.lost_track; [] none)
    report["lost_track"] = final.result.info.get("lost_track")
    report["restricted_noise"] = final.result.info.restricted_noise  # None unless --restricted-noise
    if report["restricted_noise"]:
        say(fig.restricted_text(report["restricted_noise"]))
    # None unless a named effect has variance parameters (a bias process's sd and correlation time)
    report["restricted_variances"] = final.result.info.restricted_variances
    if report["restricted_variances"]:
        say(fig.restricted_variances_text(report["restricted_variances"]))
    truth = against_ground_truth(found["base"], final.result.params, logs)
    if truth:
        report["against_ground_truth"] = truth
    say("")
    say(f"named effects, in order: {', '.join(e['name'] for e in report['effects']) or 'none'}")
    for e in report["effects"]:
        interval = fig.interval_text(e["intervals"])
        step = "" if interval else fig.grid_note(e["name"])  # an interval states the grid's step itself
        say(f"  {e['name']}: {fig.short(e['parameters'])}{step}{'; ' + interval if interval else ''}"
            + (f" ({fig.READ_WITH_CARE})" if e["warnings"] else ""))
    if report["base_change"]:
        say(f"  {fig.shift_text(report['base_change'])}")
    say(f"  {fig.starts_text(final.starts)}")
    for name, note in {c["name"]: c["note"] for c in report["candidates"] if not c["identifiable"]}.items():
        say(f"  {name}: present or not, {note}")
    for name, why in report["not_tried"].items():
        say(f"  {name}: not tried, {why}")
    report["base_effects"] = base_effects(final.result.params, report["effects"])
    for e in report["base_effects"]:
        say(f"  {e['name']}: in the base model (aibo learn fits it on this sensor), {fig.short(e['parameters'])} in the "
            "final fit")
    say(f"gap ({GAP_METRIC}): {before.gap:.4f} before, {after.gap:.4f} after; mean NIS {before.nis_mean:.2f} -> "
        f"{after.nis_mean:.2f} (2 expected)")
    say(f"motion gap ({MOTION_GAP_METRIC}, each held-out sighting predicted from the pose k s earlier and the "
        "commands alone; in brackets its excess over the one-step gap): "
        + "; ".join(f"{k} s {motion['motion_gap_before'][k]:.4f} -> {v:.4f} ({motion['motion_excess_before'][k]:.4f} "
                    f"-> {motion['motion_excess_after'][k]:.4f})" for k, v in motion["motion_gap_after"].items()))
    if truth:
        say(ground_truth_text(truth))
    say(f"the base model's residual signatures (the named effects' first, then the strongest; p adjusted for the "
        f"{len(sig_before)} pairs tried; the verdict rests on the candidates' tests above):")
    for s, whose in fig.lead_signatures(sig_before, named_signatures(report)):
        say(f"  {s.residual:24s} vs {s.variable:40s} adjusted p = {s.p_holm:.1g}"
            + (f" (the signature of {whose})" if whose else ""))
    t1 = time.perf_counter()
    report["calibrated_simulation"] = calibrated(found["base"], final.result.params, logs, args, say)
    report["calibrated_replays"] = "tracked" if args.tracked_replicas else "open loop"
    seconds["calibrated check"] = time.perf_counter() - t1
    report["innovation_shape"] = innovation_shape(final.result.params, logs)  # where a NIS disagreement is
    report["unexplained"] = unexplained(report)
    said_where = set()  # the NIS rows share one 'where': said in full once, then referred to
    for u in report["unexplained"]:
        of = "; ".join(f"the signature of {w['effect']}, not named ({w['why_not_named']})" for w in fig.signature_of(u))
        where = u.get("where")
        say(f"  still unlike its simulation: {u['statistic']} ({fig.z_text(u['z'])}): {u['reading']}; "
            + ((f"where: {where}; " if where not in said_where else "where: as above; ") if where else "")
            + (of or f"unexplained ({u['why_not_named']})"))
        said_where.add(where)
    report["untried_effects"] = untried_effects(report["unexplained"], names)
    report["untried_candidates"] = untried_candidates(args.candidates, report["untried_effects"])
    if report["untried_effects"]:
        say(untried_text(report["untried_effects"], fig.try_next(report)))
    report["unexplained"] += none_of_the_above(found, logs)
    for u in (u for u in report["unexplained"] if u["effect"] == NONE_OF_THE_ABOVE):
        say(f"none of the above: {u['describes']} (train +{u['gain_train']:.1f} nats, held-out {u['gain_heldout']:+.1f} "
            f"nats, p = {u['p_value']:.2g}); {u['why_not_named']}; its signature: {u['statistic']}"
            + (f", p = {u['signature']['p_value']:.2g}" if u["signature"] else ""))
    report["warnings"] = [w.replace(TESTS_BIAS, bias_tried(found))  # e.g. a fit that may be a wrong world: said loudly
                          for w in final.result.info.get("warnings", [])]
    report["warnings"] += [f"{e.name}: {e.implausible()}" for e in final.result.params.effects if e.implausible()]
    report["warnings"] += [f"{d['name']}: named by the search, dropped from the diagnosed model: in the final fit on the "
                           f"whole log(s), {d['why']}" for d in found["dropped_in_final"]]
    report["warnings"] += [w for e in report["effects"] for w in e["warnings"]]
    report["warnings"] += motion_warning(report)
    report["warnings"] += sign_warnings(found.get("bearing_sign"))
    report["warnings"] += map_warnings(found.get("map_check", []))
    report["warnings"] += [repair_warning(found["map_repair"])] if found.get("map_repair") else []
    report["warnings"] += outlier_warning(report)
    report["warnings"] += round_limit(report["search_rounds"], report["candidates"])
    for w in report["warnings"]:
        print(f"aibo: warning: the diagnosed model: {w}", file=sys.stderr)
        lines.append(f"warning: {w}")
    report["seconds"] = time.perf_counter() - t0
    report["seconds_by_stage"] = seconds
    say(f"{report['seconds']:.1f} s in all ({', '.join(f'{k} {v:.1f} s' for k, v in seconds.items())})")
    written = write_outputs(out, final.result, report, lines, sig_before, sig_after, before, after)
    print(f"wrote {out}/: {', '.join(written)}")
    return 0


def write_outputs(out: Path, final, report: dict, lines: list[str], sig_before, sig_after, before, after) -> list[str]:
    """Every output, built in a temp folder beside ``out`` that then replaces it whole: an interrupted
    or failed run leaves the earlier diagnosis as it was, never a mix. The names written."""
    with atomic_folder(out) as tmp:
        save_result(final, tmp / "model.json")
        fig.signature_panels(tmp / FIGURES[0], sig_before, sig_after, named_signatures(report))
        fig.gap_bars(tmp / FIGURES[1], before.as_dict(), after.as_dict())
        cal = report["calibrated_simulation"]
        if "before" in cal and cal["before"]["disagree_z"] is not None:  # None: too few replicas ran to compare
            fig.calibrated_bars(tmp / FIGURES[2], cal["before"], cal["after"])
        if report["innovation_shape"].get("nis_by_repeat"):  # None: no landmark seen twice, nothing to split
            fig.nis_quantiles(tmp / FIGURES[3], report["innovation_shape"])
        write_json(tmp / "report.json", report)
        fig.html_page(tmp / "report.html", report, "\n".join(lines), [tmp / f for f in FIGURES])
        written = [f for f in ("report.html", "report.json", "model.json", *FIGURES) if (tmp / f).exists()]
    return written


def bias_tried(found: dict) -> str:
    """What the search found of ``landmark_bias``, for the end of the final fit's warning that the size errors drift
    (``learners.em.support.correlated_size_warnings``, which tells an ``aibo learn`` user to run this command)."""
    if any(d["name"] == "landmark_bias" for d in found.get("dropped_in_final", [])):
        return "landmark_bias was named and dropped from the diagnosed model (its own warning says why)"
    if any(c.name == "landmark_bias" for rnd in found["rounds"] for c in rnd):
        return "landmark_bias was tried and not named (its rows in the candidates table say why)"
    return TESTS_BIAS


def named_signatures(report: dict) -> dict[str, tuple[str, ...]]:
    """Each named effect's residual signatures (``EffectModel.signatures``; () for an effect without one)."""
    return {e["name"]: EFFECT_MODELS[e["name"]].signatures() for e in report["effects"] if e["name"] in EFFECT_MODELS}


def _commands(tr) -> str:
    """A log's commands, as ``--tracked-replicas``' refusal names them."""
    return "discrete actions" if tr.discrete else ", ".join(tr.control_names or ()) or "none"


def calibrated(base, final, logs: list, args, say) -> dict:
    """The measured logs against the calibrated simulators of the ``base`` model and of the ``final`` one (the final
    fit: model.json, the twin a user drives; until 2026-11-28 the search's fit of the training half)
    (``experiments.calibrated``): ``{"before", "after"}`` checks, or ``{"note"}`` why not."""
    from experiments.calibrated import MIN_REPLICAS, predictive_check, simulator_config

    if args.replicas == 0:
        return {"note": "not run (--replicas 0)"}
    try:
        simulator_config(final, logs[0])
    except ValueError as err:
        say(f"calibrated simulator: not available: {err}")
        return {"note": f"not available: {err}"}
    say("")
    steered = " steered along the model's smoothed path (--tracked-replicas)" if args.tracked_replicas else ""
    say(f"the measured log against its calibrated simulator ({args.replicas} replays of the measured commands{steered}):")
    checks = {}
    for when, key, model in (("base model", "before", base), ("with the named effects", "after", final)):
        check = predictive_check(model, logs, args.replicas, args.seed, args.jobs, tracking=args.tracked_replicas)
        checks[key] = check.as_dict()
        worst = check.disagreements()
        if len(check.replicas) < MIN_REPLICAS:
            say(f"  {when}: no comparison: {len(check.replicas)} of {args.replicas} replicas ran "
                f"({len(check.failed)} failed; {MIN_REPLICAS} are needed)")
        else:
            say(f"  {when}: {len(worst)} statistics disagree (|z| > {check.threshold:.2g})"
                + "".join(f"\n    {n:70s} {fig.z_text(z)}" for n, z in worst[:6]))
        for failure in check.failed:
            say(f"    {failure}")
    return checks


def motion_gaps(base, model, logs: list) -> dict:
    """report.json's motion-side scores of the base and the named effects' model (both fitted on the training
    half): ``motion_gap_before`` / ``motion_gap_after`` (horizon in seconds -> MOTION_GAP_METRIC) and
    ``motion_gap_change`` (per horizon: the paired change, its standard error over 30 s blocks, z, n)."""
    mb, ma = motion_score(base, logs), motion_score(model, logs)
    return {"motion_gap_metric": MOTION_GAP_METRIC, "motion_gap_before": mb.gap(), "motion_gap_after": ma.gap(),
            "motion_excess_before": mb.excess(), "motion_excess_after": ma.excess(),
            "motion_gap_change": motion_trade(mb, ma)}


#: ``report.json["against_ground_truth"]``'s models and their keys (``learners.scoring.motion_noise_scores``)
TRUTH_MODELS = ("base", "diagnosed")


def against_ground_truth(base: Model, final: Model, logs: list) -> dict:
    """Where every log carries ground truth (``pose``: a simulated log, or a real one with motion capture), which the
    fit never reads: the motion noise of the base model (the search's, training half) and of the diagnosed one
    (``model.json``) against it over 1 s windows (``learners.scoring.motion_noise_scores``: the travel's error over the
    model's own sd; 1 when right, below 1 when the model's robot wanders more than the real one, above 1 when it errs
    more than it says). {} without truth.
    What a check of the sightings cannot see (docs/results.md, "The twin's motion noise against Vicon")."""
    if not logs or any(tr.pose is None for tr in logs):
        return {}
    rows = {name: motion_noise_scores(m, logs, 1.0) for name, m in zip(TRUTH_MODELS, (base, final))}
    feedback = command_feedback(final, logs)
    return ({"window_s": 1.0, **{name: finite_json({k: r[k] for k in NOISE_KEYS}) for name, r in rows.items()}}
            | ({"command_feedback": feedback} if feedback else {}))


#: open-loop sds below 0 at which ``command_feedback``'s correlation says the commands answer the motion (simulated
#: logs, 5 minutes: the waypoint driver -0.5 and -0.6 sd, a 10 s closed loop -1.9, a 2 s one -6.7; MRCLAM robots 1 and
#: 5 against Vicon -21 and -12: docs/results.md, "A driver that steers on its pose")
ANSWERS_SD = 3.0


def answers_motion(truth: dict) -> str:
    """A clause where the log's ground truth says its commands answer the motion (``command_feedback`` below
    -``ANSWERS_SD`` open-loop sds), else ""."""
    f = truth.get("command_feedback")
    if not f or f["correlation"] > -ANSWERS_SD * f["sd_open_loop"]:
        return ""
    return (f"its commands answer the motion: a frame's turn error correlates with the "
            f"commanded turn rate's change {f['frames_later']} frame later at r = {f['correlation']:+.2f} (0 +- "
            f"{f['sd_open_loop']:.2f} for commands open loop), a controller that steered on the robot's pose, which "
            "replays of the measured commands cannot make (--tracked-replicas steers them with a 10 s loop)")


def ground_truth_text(truth: dict) -> str:
    """One line of ``against_ground_truth``."""
    def row(r: dict) -> str:
        return " / ".join("-" if r[k] is None else f"{r[k]:.2f}" for k in NOISE_KEYS)
    return (f"against the log's ground truth (not read by the fit), the travel's error over {truth['window_s']:g} s "
            f"windows / the model's sd, forward / lateral / heading (1: the model's spread is its errors'; below 1 its "
            f"robot wanders more than the real one; above 1 it errs more than it says, by its means or too little "
            f"noise): base {row(truth['base'])}; diagnosed {row(truth['diagnosed'])}"
            + "".join(f"; {clause}" for clause in [answers_motion(truth)] if clause))


def motion_warning(report: dict) -> list[str]:
    """A warning when the named effects make the held-out sightings predicted open loop worse beyond their noise at
    some horizon (the motion gap's paired change, z > MOTION_WORSE_Z): the model predicts the next sighting better and
    the robot's motion over seconds worse, a trade the user should see. Only the motion gap decides: its excess over
    the one-step gap grows with a tighter sensor model too (a pose error costs more nats where the sensor is sharper),
    and on the MRCLAM half-log fits it grew with the bias states where the diagnosed model's forward speed was better
    against Vicon (docs/results.md, "Models on runs they were not fitted to")."""
    worse = {k: c for k, c in report.get("motion_gap_change", {}).items()
             if np.isfinite(c["z"]) and c["z"] > MOTION_WORSE_Z}
    if not report["effects"] or not worse:
        return []
    names = ", ".join(e["name"] for e in report["effects"])
    at = "; ".join(f"{k} s {c['change']:+.3f} +- {c['se']:.3f}" for k, c in worse.items())
    return [f"the named effects ({names}) trade motion for sensing: the one-step gap changes by "
            f"{report['gap_after'] - report['gap_before']:+.3f} nats per sighting, while the held-out sightings "
            f"predicted open loop get worse ({at} nats per sighting, +- s.e.); for driving a simulator over seconds, "
            "the base model (aibo learn's) may be the better motion model"]


def set_aside(found: dict) -> dict:
    """report.json["outliers"]: the sightings the search's base model gated out as gross errors (``set_aside`` of
    ``sightings``, their ``share``; Mahalanobis^2 above ``gate_mahalanobis2``), which no model of the search, the
    final fit and the scores sees (``learners.discrepancy.search.base_and_outliers``)."""
    n, total = found["outliers"]["set_aside"], found["outliers"]["sightings"]
    return {"set_aside": n, "sightings": total, "share": n / total if total else 0.0, "gate_mahalanobis2": DEFAULT_GATE}


def outlier_warning(report: dict) -> list[str]:
    """A warning when more than ``OUTLIER_SHARE`` of the sightings were set aside before the diagnosis, which fits and
    scores every model without them, ``false_sightings`` too. Under the true Gaussian model about none would be
    (P(chi-square(2) > 50) = 1e-11); the search's base, fitted on half a log, set aside none on 69 of 100 effect-free
    blind 5-minute logs (seeds 6000-6049, ``aibo`` and ``paper-sim``) and at most 0.82% (40 of 4,876); on the
    blind ``aibo`` log of seed 2002 with 2% spurious sightings 101 of 4,991, all of them spurious (105 in all), and
    ``false_sightings`` then gained nothing (2026-11-30; docs/results.md, "Residual signatures on effect-free logs")."""
    o = report["outliers"]
    if o["share"] <= OUTLIER_SHARE:
        return []
    tried = {c["name"] for c in report["candidates"]}
    named = {e["name"] for e in report["effects"]}
    why = ("false_sightings, named, models the spurious sightings the gate let through" if "false_sightings" in named
           else "spurious sightings (false_sightings) would leave them; the search tried it on the sightings kept, "
           "where it had none of these to explain" if "false_sightings" in tried
           else "spurious sightings (false_sightings, not among the candidates) would leave them")
    return [f"{o['set_aside']} of {o['sightings']} sightings ({o['share']:.1%}) were set aside as gross errors before "
            f"the diagnosis (Mahalanobis^2 > {o['gate_mahalanobis2']:g} under the search's base model, which on 100 "
            f"effect-free simulated logs set aside at most 0.8%): no model fitted or scored here sees them; {why}"]


def round_limit(rounds: dict, candidates: list[dict]) -> list[str]:
    """A warning when the search stopped at its limit of rounds (``--rounds``) with candidates still significant in the
    last: they were neither named nor refused, and another round would have tried them again."""
    left = [c for c in candidates if left_by_limit(c, rounds)]
    if not left:
        return []
    n = rounds["max_rounds"]
    return [f"the search stopped at its limit of {n} round{'s' if n != 1 else ''} with "
            + ", ".join(f"{c['name']} (held-out {c['gain_heldout']:+.1f} nats, {decisive_p(c)})" for c in left)
            + f" still significant: neither named nor refused; --rounds {n + 1} tries "
            + ("it" if len(left) == 1 else "them") + " again"]


def off_held(effects: list[dict], batch: Batch) -> list[str]:
    """A warning per named effect whose every 95% interval holds the value that switches it off
    (``effect_sizes.holds_off``; effects whose start is that value, ``EffectModel.STARTS_OFF``, on ``batch``, the
    logs' ``make_batch``)."""
    out = []
    for e in effects:
        cls = EFFECT_MODELS[e["name"]]
        if cls.STARTS_OFF and cls.PARAMS:
            why = holds_off(e["name"], e["intervals"], cls.start(batch).values())
            out += [why] if why else []
    return out


def unexplained(report: dict) -> list[dict]:
    """Every disagreement of the final model's calibrated simulation with the log, with its z and a plain reading
    (``plain_reading``) of what the log does that the twin does not. One that is the residual signature
    (``EffectModel.leaves``) of an effect that was not named names it, with why it was not: where the search
    and the simulator part ways, the user should look; one that no effect's signature matches has ``effect`` None
    (the catalogue holds nothing that makes it). A NIS statistic's row says ``where`` the log's innovations depart
    from the model's Gaussian (``report["innovation_shape"]``: which side of the band, which measurement, which turn
    rates)."""
    after = report["calibrated_simulation"].get("after")
    if not after:
        return []
    named = {e["name"] for e in report["effects"]}
    tried = {c["name"]: c for c in report["candidates"]}  # the last round's try of each
    out = []
    for d in after["disagreements"]:
        row = {"statistic": d["statistic"], "z": d["z"], "reading": plain_reading(d["statistic"], d["z"])}
        answers = answers_motion(report.get("against_ground_truth", {})) if CHANGE_SIGNATURE in d["statistic"] else ""
        where = shape_text(d["statistic"], report.get("innovation_shape", {})) or (
            f"against the log's ground truth {answers}" if answers else "")
        row |= {"where": where} if where else {}
        matches = [name for name, cls in sorted(EFFECT_MODELS.items()) if cls.leaves(d["statistic"])]
        whose = [{"effect": name, "why_not_named": why_unnamed(name, tried.get(name), report)}
                 for name in matches if name not in named]
        if whose:  # one row per statistic: the first effect whose signature it is, the others beside it
            out.append(row | whose[0] | {"other_effects": whose[1:]})
        else:
            why = ("the named effects " + ", ".join(matches) + " do not remove it" if matches
                   else "no effect of the catalogue leaves this signature")
            out.append(row | {"effect": None, "why_not_named": why, "other_effects": []})
    return out


def untried_effects(rows: list[dict], tried: list[str]) -> list[dict]:
    """The catalogue's effects left out of the candidates (``tried``) whose residual signature a disagreement left
    after the named effects is (``rows``: ``report.json["unexplained"]``), each with how many of those statistics
    point at it, most first: ``report.json["untried_effects"]``, what a user can try next."""
    counts: dict[str, int] = {}
    tried_set = set(tried)
    for u in rows:
        for name in {w["effect"] for w in fig.signature_of(u)} - tried_set:
            if name in EFFECT_MODELS:
                counts[name] = counts.get(name, 0) + 1
    return [{"effect": n, "statistics": k} for n, k in sorted(counts.items(), key=lambda nk: (-nk[1], nk[0]))]


def untried_candidates(given: str | None, untried: list[dict]) -> str | None:
    """``report.json["untried_candidates"]``: the ``--candidates`` the user gave (``given``, None: the defaults), names
    stripped of spaces, with the ``untried`` effects added; None when there are none."""
    if not untried:
        return None
    return ",".join(candidate_names(given or DEFAULTS) + [u["effect"] for u in untried])


def untried_text(untried: list[dict], options: str) -> str:
    """The terminal's line on ``untried_effects``, with the ``options`` that try them (``diagnose_report.try_next``)."""
    return ("the disagreements left point at effects that were not among the candidates: "
            + ", ".join(f"{u['effect']} ({u['statistics']} statistic{'s' * (u['statistics'] > 1)})" for u in untried)
            + f"; {options} tries them (compare the motion gap and the check before keeping that model)")


def why_unnamed(name: str, c: dict | None, report: dict) -> str:
    """Why effect ``name``, whose signature a disagreement is, is not in the diagnosed model (``c``: its candidate
    entry in the report, None when it was not tried)."""
    if c is None:
        return not_tried(name)
    return (passed_over(c, report.get("search_rounds", {})) or c["note"] or
            f"training gain {c['gain_train']:.1f} nats, p = {c['p_value']:.2g}; held-out gain {c['gain_heldout']:+.1f} nats")


def passed_over(c: dict, rounds: dict) -> str:
    """Why candidate ``c`` (a ``report.json["candidates"]`` entry, its last try) is not in the diagnosed model although
    the search found it significant or named it ("" when neither: its note or gains say why): named and dropped from
    the final fit (the search then ran again from that round without it, ``search.search_without``); or another
    candidate won its round, perhaps the last the search runs (``rounds``: ``report.json["search_rounds"]``). Not its
    test's note, which annotates a verdict the candidate passed (MRCLAM robot 2: ``distance_dependent_noise``
    significant, held-out +397 nats, in the third and last round, where ``beacon_height_scale`` was named, was
    reported "not named" beside its sandwich note)."""
    dropped = {d["name"]: d for d in rounds.get("dropped_in_final", [])}
    if c["name"] in dropped:
        d = dropped[c["name"]]
        return (f"named in round {d['round']}, then dropped from the diagnosed model: in the final fit, "
                f"{d['why']}; the search ran again from that round without it")
    winners, n = rounds.get("winners", []), rounds.get("max_rounds")
    k = c.get("round", 0) - 1
    winner = winners[k] if 0 <= k < len(winners) else None
    if not c.get("significant") or winner is None or c["name"] == winner:
        return ""
    why = f"{winner} had the larger held-out gain in that round"
    if left_by_limit(c, rounds):
        why += f"; that round was the search's last (--rounds {n}): --rounds {n + 1} tries {c['name']} again"
    return (f"significant in round {k + 1} (training gain {c['gain_train']:.1f} nats, {decisive_p(c)}; held-out "
            f"{c['gain_heldout']:+.1f} nats) but not named: {why}")


def left_by_limit(c: dict, rounds: dict) -> bool:
    """Whether candidate entry ``c`` is a try of the search's last round that the limit of rounds left significant
    (``rounds``: ``report.json["search_rounds"]``)."""
    return c["name"] in rounds.get("left_at_cap", []) and c.get("round") == len(rounds.get("winners", []))


def decisive_p(c: dict) -> str:
    """A candidate entry's p-value of the last test it had to pass, as text: the robust likelihood ratio's where it ran
    (its ``checks``; the plain likelihood ratio's overstates the evidence on real logs by up to 10x in nats), else the
    likelihood ratio's."""
    robust = [v["p"] for v in c.get("checks", []) if v["name"] == RobustLikelihoodRatio.name and v.get("p") is not None]
    return f"robust p = {robust[-1]:.2g}" if robust else f"p = {c['p_value']:.2g}"


def not_tried(name: str) -> str:
    """Why effect ``name`` has no candidate in the report: not asked for, or not a default candidate."""
    if EFFECT_MODELS[name].DEFAULT_CANDIDATE:
        return "not among the candidates"
    return f"not among the candidates: tried only when asked for (--candidates ...,{name})"


#: ``report.json["unexplained"][*]["effect"]`` of a significant probe (``learners.model.probes``)
NONE_OF_THE_ABOVE = "none of the above"


def none_of_the_above(found: dict, logs: list) -> list[dict]:
    """The search's significant probes (``found["probes"]``: a speed that depends on the heading or the position, no
    catalogue effect) as ``report.json["unexplained"]`` entries: what the probe found, its test, and the residual
    signature that shows it (``probe_signature``: the final model's smoothed forward speed relative to its prediction
against the probe's fitted factor)."""
    out = []
    for c in found.get("probes", []):
        if not c.significant:
            continue
        probe = c.model.effect(c.name)
        sig = probe_signature(found["model"], logs, probe)
        out.append({"statistic": f"{sig.residual} vs {sig.variable}" if sig else "", "z": None,
                    "effect": NONE_OF_THE_ABOVE, "probe": c.name, "describes": probe.describe(),
                    "parameters": {"coef": np.asarray(probe.coef).tolist()}, "gain_train": c.gain_train,
                    "gain_heldout": c.gain_heldout, "p_value": c.p_value,
                    "why_not_named": "no effect of the catalogue is this dependence; the named effects do not explain it",
                    "signature": sig.as_dict() if sig is not None else None})
    return out


def negligible_when_final(final: Model, named: list[dict], logs: list) -> list[str]:
    """A warning for each named effect whose value in the final fit on the whole logs is negligible (``negligible``):
    the search named it at a value its training-half fit had, and the final fit took it to nothing (on an effect-free
    `paper-sim` log, seed 3000 of the false-alarm study, ``false_sightings`` was named at a rate of 0.0031, about 6
    spurious sightings of the training half, and ended at 0.0003, 1.1 of the whole log's 3,673)."""
    n = sum(tr.n_sightings for tr in logs)
    return [f"{e['name']}: named, but in the final fit on the whole log(s) {why}: the model hardly holds it"
            for e in named if (why := final.effect(e["name"]).negligible(n))]


def base_effects(final: Model, named: list[dict]) -> list[dict]:
    """The effects the diagnosed model carries that no candidate named: the base model's own (``aibo learn``'s range
    shrink on a range sensor: ``EMOptions.range_shrink``), with their values in the final fit."""
    names = {e["name"] for e in named}
    return [e.to_json() for e in final.effects if e.name not in names]


def _report(found: dict, effects: list[dict], before, after, sig_before) -> dict:
    """report.json's body. ``effects``: the named effects' entries (``learners.discrepancy.final.diagnosed``: the
    parameters of the diagnosed model, model.json, every kept effect refitted on the whole logs, with standard errors
    and 95% intervals; ``parameters_when_named``: the candidate's fit in its round; ``warnings``, added by the
    command: negligible in the final fit, ``effect_sizes.read_with_care``'s, every interval holding the value that
    switches it off); ``base_change``: how far the
    named effects moved the base model (both fits on the training half)."""
    # "named": this try is the one that named the effect, and the diagnosed model holds it (not pruned)
    tried = [dict(c.as_dict(), round=k + 1, named=any(c is n for n in found["named"]))
             for k, rnd in enumerate(found["rounds"]) for c in rnd]
    return {
        "effect": effects[0]["name"] if effects else "none",
        "effects": effects,
        "parameters": effects[0]["parameters"] if effects else {},
        "candidates": tried,
        "gap_metric": GAP_METRIC,
        "gap_before": before.gap,
        "gap_after": after.gap,
        "whiteness_metric": WHITENESS_METRIC,  # consistency_*["whiteness"]
        "consistency_before": before.as_dict(),
        "consistency_after": after.as_dict(),
        "signatures": [s.as_dict() for s in sig_before[:12]],
        "not_tried": found["skipped"],
        # rounds repeated from a better base model found by a candidate's fit (learners.discrepancy.search)
        "base_escapes": found.get("escapes", []),
        # the base fit's wrong world, refitted with spurious sightings ({"off_field_fraction"}; None: it fit the field)
        "base_refit": found.get("base_refit"),
        "outliers": set_aside(found),
        # landmarks whose sightings the map does not explain, judged by the base model (learners.em.map_check)
        "map_check": [d.to_dict() for d in found.get("map_check", [])],
        # pairs of them that may be swapped, tried exchanged (EMOptions.map_repair: as aibo learn): "held" true, the
        # search ran on the exchange; None: none tried
        "map_repair": found.get("map_repair"),
        # a range sensor's bearings checked for the other sign, as aibo learn does (learners.em.bearing_sign.sign_check
        # of the base model); None: they looked right
        "bearing_sign": found.get("bearing_sign"),
        "base_change": base_shift(found["base"], found["model"]) if effects else None,
        # each round's winner, the limit, what it left significant, what the final fit dropped (``passed_over``)
        "search_rounds": {"max_rounds": found["max_rounds"], "winners": found["winners"],
                          "left_at_cap": found["left_at_cap"], "dropped_in_final": found.get("dropped_in_final", [])},
    }
