"""What a named effect is worth, beside its name: its parameters with standard errors and 95% intervals, and how far
adding it moved the base model (velocities and sensor curve), in the model file's units.

Intervals are Wald intervals, value +- 1.96 SE, with the robust standard errors of the diagnosed model's fit
(``learners.em.uncertainty``: the larger of the Fisher error, from finite differences of the EKF innovations, and the
sandwich error; the Fisher ones are kept beside them as "se_fisher" and "interval_95_fisher"). Measured: on simulated
logs the coverage of the robust intervals is the Fisher ones' or higher (docs/results.md, "Robust standard errors");
on MRCLAM robots the Fisher errors are 2-5 times smaller than the differences between a robot's two halves. Where the
information does not determine a parameter its standard error is None and so is the interval. A Wald interval assumes
a quadratic log-likelihood: for a parameter near a bound (a rate near 0, a correlation time near its cap) it is only a
guide. Where value +- 1.96 SE crosses the parameter's domain (``clipped``: true) a positive parameter fitted on the
log scale gets the Wald interval of its logarithm (``_wald``; the method says so), any other the interval clipped to
the domain; ``aibo diagnose`` then replaces either by the profile-likelihood interval on the whole logs where the
effect has one scalar parameter (``profile``). A parameter profiled over a grid (``EffectModel.GRID``, a lag) has no
standard error; its interval is the profile-likelihood one, from the search's profile on the training half: the grid
values within chi-square(1, 0.95) / 2 = 1.92 nats of the best, widened to the neighbouring grid values
(``profile_interval``; ``grid_step`` in the entry), so it holds the true profile interval to the grid's step, and is
wider than the whole log's would be (half the sightings). The value is the final fit's, refined between the grid's
values where the effect polishes (``ActuationLag.polish``: the lag maximizing the whole logs' likelihood within a grid
step of the search's, the rest held). Where the logs resolve the parameter finer than its grid (a lag of discrete
commands acts in whole frames), ``aibo diagnose`` then replaces that interval by the whole logs' profile in those
steps (``profile.refine_grid_intervals``; the grid one kept as ``grid_interval_95``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from learners.em.uncertainty import CHI2_1_95, Z95, file_values
from learners.model.effects import EFFECT_MODELS
from learners.model.model import Model


def profile_interval(grid: list[float], lls: list[float]) -> list[float]:
    """The 95% profile-likelihood interval of a grid parameter, to the grid's step: from ``lls`` (nats, the profile
    over ``grid`` in order, possibly stopped early), the grid values within ``CHI2_1_95 / 2`` of the best, widened on
    each side to the neighbouring grid value (the first outside, or the grid's end): the interval's true ends lie
    between a value inside and that one, so the widened interval holds it (a sharp profile at 0.2 on a grid of step
    0.1 is [0.1, 0.3], not [0.2, 0.2])."""
    ll = np.asarray(lls, dtype=float)
    g = np.asarray(grid, dtype=float)
    inside = np.flatnonzero(ll >= ll.max() - CHI2_1_95 / 2.0)
    return [float(g[max(inside.min() - 1, 0)]), float(g[min(inside.max() + 1, len(g) - 1)])]


def grid_step(grid: list[float]) -> float:
    """The step of a parameter's grid (the smallest spacing, to 12 decimals: 0.1, not 0.09999999999999998)."""
    return float(np.round(np.min(np.diff(np.asarray(grid, dtype=float))), 12))


#: a Wald entry's method with the robust errors (``learners.em.uncertainty``: the larger of the Fisher and sandwich)
ROBUST_WALD = "wald, robust (the larger of the Fisher and the sandwich standard error)"


#: the end of a Wald entry's method where its interval is on the log scale (``_wald``)
LOG_SCALE = "; on the log scale, value x exp(+-1.96 SE / value) (the interval in the value's units crossed the domain)"


def _wald(value: np.ndarray, se: Any, param) -> tuple[list, list, bool, bool]:
    """(se, the 95% Wald interval [lo, hi] clipped to the parameter's domain, whether it crossed the domain, whether it
    is on the log scale). A positive parameter fitted on the log scale (``Param.transform`` "log": a noise's sd, a
    correlation time) whose interval value +- 1.96 SE crosses the domain gets the Wald interval of its logarithm
    instead, value x exp(+-1.96 SE / value) (the delta method's SE of log value is SE / value): the scale its fit and
    its information are on, where it cannot reach 0. Clipped, [0.001 s, 143 s] said nothing of a correlation time of 50
    s +- 48 but that it was positive; on the log scale [7.6, 327] (``landmark_bearing_bias`` on 5-minute ``aibo`` logs
    at 0.02 rad / 20 s, 2026-11-30: 25 of 29 tau_s intervals crossed 0; on the log scale 28 of 29 held 20 s). The single
    scalar parameter of an effect is profiled where its interval crossed the domain (``profile.wants_profile``)."""
    se = np.asarray(se, dtype=float)
    wald_lo, wald_hi = value - Z95 * se, value + Z95 * se
    crossed = bool(np.any(wald_lo < param.low) or np.any(wald_hi > param.high))
    log_scale = crossed and param.transform == "log" and bool(np.all(value > 0))
    if log_scale:
        wald_lo, wald_hi = value * np.exp(-Z95 * se / value), value * np.exp(Z95 * se / value)
    lo, hi = np.clip(wald_lo, param.low, param.high), np.clip(wald_hi, param.low, param.high)
    return se.tolist(), [lo.tolist(), hi.tolist()], crossed, log_scale


def _determined(se: Any) -> bool:
    return se is not None and not np.any(np.asarray(se, dtype=object) == None)  # noqa: E711 (None: undetermined)


def effect_intervals(model: Model, name: str, standard_errors: dict[str, Any],
                     profiles: dict[str, list[list[float]]] | None = None,
                     robust_errors: dict[str, Any] | None = None) -> dict[str, dict[str, Any]]:
    """Per parameter of effect ``name`` in ``model``: {"value", "se", "interval_95", "method"} (lists for array
    parameters; se and interval None where the fit's information does not determine it). ``profiles``: a grid
    parameter's profile (``Candidate.profile``), whose interval is then the profile-likelihood one (se None).
    ``robust_errors``: the fit's robust standard errors (``info["robust_standard_errors"]``): where given, a Wald entry's
    "se" and "interval_95" are theirs (method ``ROBUST_WALD``) and the Fisher ones are kept as "se_fisher" and
    "interval_95_fisher"."""
    effect = model.effect(name)
    out = {}
    for pname, value in effect.values().items():
        v = np.asarray(value, dtype=float)
        if profiles and pname in profiles:
            step = grid_step(effect.GRID[pname]) if pname in effect.GRID else grid_step(profiles[pname][0])
            method = f"profile likelihood over a grid of step {step:g}, training half, widened to the neighbouring grid values"
            if not np.any(np.isclose(v, np.asarray(profiles[pname][0], dtype=float))):
                method += "; the value refined between them by the final fit (the whole logs' most likely, the rest held)"
            out[pname] = {"value": v.tolist(), "se": None, "interval_95": profile_interval(*profiles[pname]),
                          "grid_step": step, "method": method}
            continue
        key = f"effects.{name}.{pname}"
        se = standard_errors.get(key)
        if not _determined(se):
            out[pname] = {"value": v.tolist(), "se": None, "interval_95": None, "method": None}
            continue
        se_f, interval_f, clipped, log_scale = _wald(v, se, effect.PARAMS[pname])
        out[pname] = {"value": v.tolist(), "se": se_f, "interval_95": interval_f,
                      "method": "wald" + (LOG_SCALE if log_scale else ""), "clipped": clipped}
        robust = (robust_errors or {}).get(key)
        if _determined(robust):  # the interval stated is the robust one; the Fisher one kept beside it
            se_r, interval_r, clipped, log_scale = _wald(v, robust, effect.PARAMS[pname])
            out[pname] |= {"se": se_r, "interval_95": interval_r, "method": ROBUST_WALD + (LOG_SCALE if log_scale else ""),
                           "clipped": clipped, "se_fisher": se_f, "interval_95_fisher": interval_f}
    return out


def holds_off(name: str, intervals: dict[str, dict[str, Any]], off: dict[str, Any]) -> str:
    """Why named effect ``name`` may not be there ("" when it is): every one of its 95% ``intervals``
    (``effect_intervals``) holds the value ``off`` that switches it off (``EffectModel.STARTS_OFF``), i.e. the final
    fit on the whole logs cannot tell it from none. Measured on MRCLAM robot 5: ``velocity_fade`` named at
    -0.0075/min on the training half ends at 0.0002 +- 0.0024/min."""
    held = []
    for pname, iv in intervals.items():
        if iv["interval_95"] is None:
            return ""
        lo, hi = (np.asarray(b, dtype=float) for b in iv["interval_95"])
        o = np.broadcast_to(np.asarray(off[pname], dtype=float), lo.shape)
        if not np.all((lo <= o) & (o <= hi)):
            return ""
        held.append(f"{pname} {_fmt(off[pname])} in [{_fmt(iv['interval_95'][0])}, {_fmt(iv['interval_95'][1])}]")
    if not held:
        return ""
    return (f"{name}: the final fit's 95% intervals hold the value that switches it off ({'; '.join(held)}): "
            "named on the training half, it is not distinguishable from none on the whole log(s)")


def moved_since_named(name: str, intervals: dict[str, dict[str, Any]], when_named: dict[str, Any],
                      se_when_named: dict[str, Any] | None = None) -> str:
    """Why the final estimate of named effect ``name`` should be read with care ("" when it need not): a parameter's
    value when it was named (the candidate's fit on the training half, ``when_named``) is further from the final fit's
    (whole logs, every kept effect) than their sampling error allows: the two fits disagree, and the reported value is
    the final fit's (``model.json``'s). Allowed: the final fit's 95% interval (``effect_intervals``), and where the
    training half's robust standard error is known (``se_when_named``, ``Candidate.standard_errors``) and the final
    one too, value +- 1.96 sqrt(se_named^2 - se^2) if wider: the standard error of the difference of two nested
    estimates, the whole log's the efficient one (Hausman 1978). With half of the sightings se_named^2 is 2 se^2 and
    the final interval is that allowance; a training half that carries less (a floor drift, learnt from the dead
    reckoning between sightings, of which the held-out blocks take every other) makes it wider: on 37 simulated `aibo`
    logs that named a 12 mm/s drift the final interval alone flagged 18 (docs/results.md, calibration). A grid
    parameter (a lag) was named at a grid value, known to half the grid's step: its interval is widened by that much
    (MRCLAM robot 1: a lag named at 0.2 on the 0.1 s grid, 0.224 [0.217, 0.233] in the final fit, agrees)."""
    grid = EFFECT_MODELS[name].GRID if name in EFFECT_MODELS else {}
    moved = []
    for pname, iv in intervals.items():
        if iv["interval_95"] is None or pname not in when_named:
            continue
        half = grid_step(grid[pname]) / 2.0 if pname in grid else 0.0
        lo, hi = (np.asarray(b, dtype=float) + d for b, d in zip(iv["interval_95"], (-half, half)))
        named_se = (se_when_named or {}).get(pname)
        if named_se is not None and iv.get("se") is not None:
            value, se = np.asarray(iv["value"], dtype=float), np.asarray(iv["se"], dtype=float)
            allow = Z95 * np.sqrt(np.maximum(np.asarray(named_se, dtype=float) ** 2 - se ** 2, 0.0))
            lo, hi = np.fmin(lo, value - allow), np.fmax(hi, value + allow)
        before = np.broadcast_to(np.asarray(when_named[pname], dtype=float), lo.shape)
        if np.any((before < lo) | (before > hi)):
            moved.append(f"{pname} {_fmt(when_named[pname])} when named, {_fmt(iv['value'])} in the final fit "
                         f"(95% [{_fmt(iv['interval_95'][0])}, {_fmt(iv['interval_95'][1])}])")
    if not moved:
        return ""
    return (f"{name}: the final fit on the whole log(s) moved it outside its interval from the value it was named at "
            f"({'; '.join(moved)}): the training-half and whole-log fits disagree; the value reported is the final fit's")


def without_interval(name: str, intervals: dict[str, dict[str, Any]]) -> str:
    """Why named effect ``name``'s value is no measured one ("" when every parameter has its interval): the final fit
    gives a parameter no 95% interval (``effect_intervals``: its information does not determine it). MRCLAM robot 4's
    whole log, the twin's recipe, before ``heavy_tails.MAX_LOG_VAR_STEP``: ``heavy_tailed_noise`` named at its start,
    rate 0.1 and scale 2 (EM kept its start, every step from it less likely), both intervals null, and no word."""
    none = [f"{pname} {_fmt(iv['value'])}" for pname, iv in intervals.items() if iv["interval_95"] is None]
    if not none:
        return ""
    return (f"{name}: no 95% interval for {', '.join(none)}: the final fit's information does not determine it (the "
            "fit may have stopped short of the likelihood's maximum there); the value stated is not a measured one")


def _fmt(v: Any) -> str:
    a = np.asarray(v, dtype=float)
    return f"{float(a):.3g}" if a.ndim == 0 else "[" + ", ".join(f"{x:.3g}" for x in a.ravel()) + "]"


def base_shift(before: Model, after: Model) -> dict[str, Any]:
    """How the base model moved between ``before`` (no effects) and ``after`` (with the named effects): the
    largest change of each velocity component over the commands (file units: mm/s, mm/s, rad/s; for a feature
    map, its weights) and of the sensor curve's mean over its distance range (px or mm)."""
    a, b = file_values(before), file_values(after)
    key = "action_model.velocities" if "action_model.velocities" in a else "action_model.weights"
    diff = (b[key] - a[key]).reshape(-1, 3)
    lo, hi = after.sensor.distance_range_mm
    d = np.linspace(lo, hi, 64)
    dc = np.abs(np.asarray(after.sensor.mean(d)) - np.asarray(before.sensor.mean(d)))
    return {"velocities_max_abs": np.abs(diff).max(axis=0).tolist(),
            "velocities_rms": np.sqrt(np.mean(diff ** 2, axis=0)).tolist(), "velocities_key": key,
            "sensor_curve_max_abs": float(dc.max()), "sensor_unit": after.sensor.unit,
            "sensor_distances_mm": [float(lo), float(hi)]}


def short_of_maximum(effects: list[dict]) -> list[str]:
    """A warning per named effect's parameter for which a fit held at another value beat the diagnosed model by more
    than 1.92 nats (its interval's ``beaten_by_nats``, ``learners.discrepancy.profile``): the value stated is then
    outside its own 95% profile interval, not the likelihood's maximum. (By less, only the interval's note says so:
    of 75 simulated logs that named ``distance_dependent_noise``, a held fit beat the final fit by 0.5-1.8 nats on
    20, the stop rules' slack, and by 2.0-19.5 on 6; scripts/calibration.py, docs/results.md.)"""
    return [f"{e['name']}: {pname} {iv['value']:.3g} is not the likelihood's maximum: a fit with it held elsewhere is "
            f"{iv['beaten_by_nats']:.1f} nats more likely (more than the 95% interval's {CHI2_1_95 / 2.0:.2f}); "
            "the value stated may be off by more than its interval says"
            for e in effects for pname, iv in e["intervals"].items() if iv.get("beaten_by_nats", 0.0) > CHI2_1_95 / 2.0]


def read_with_care(entry: dict[str, Any]) -> list[str]:
    """The warnings ``aibo diagnose`` gives about one named effect's stated values (``entry``: an item of
    ``report.json["effects"]``, ``final.Diagnosed.effects``): a parameter without an interval (``without_interval``),
    moved since it was named (``moved_since_named``), short of the likelihood's maximum (``short_of_maximum``). The
    report's other warnings are about the fit as a whole. ``scripts/calibration.py`` measures the coverage of the
    intervals the report says none of these about apart from the rest."""
    name, intervals = entry["name"], entry["intervals"]
    return [w for w in (without_interval(name, intervals),
                        moved_since_named(name, intervals, entry.get("parameters_when_named", {}),
                                          entry.get("se_when_named"))) if w] \
        + short_of_maximum([entry])
