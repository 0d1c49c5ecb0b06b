"""Figures and the self-contained HTML page of ``aibo diagnose`` (matplotlib Agg, images embedded)."""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from aibo.figures import save_png  # noqa: E402
from aibo_core.atomic import atomic_write  # noqa: E402


def lead_signatures(signatures: list, named: dict[str, tuple[str, ...]], n: int = 6) -> list[tuple[Any, str]]:
    """The ``n`` signatures a reader sees first, each with the named effect it is the signature of ("" for none):
    the named effects' signatures (``named``: effect -> its ``EffectModel.signatures()``) first, then the rest by
    p-value (``signatures`` sorted so). A drift the verdict does not name never comes before one it does."""
    def whose(s: Any) -> str:
        key = f"{s.residual} vs {s.variable}"
        return next((name for name, sigs in named.items() if any(sig in key for sig in sigs)), "")
    tagged = [(s, whose(s)) for s in signatures]
    return ([t for t in tagged if t[1]] + [t for t in tagged if not t[1]])[:n]


def signature_panels(path: Path, before: list, after: list, named: dict[str, tuple[str, ...]] | None = None,
                     n: int = 6) -> None:
    """The residual signatures of the base model a reader sees first (``lead_signatures``), with the same pairs after
    the refit; each titled with its p-value adjusted for every pair tried (Holm, ``Signature.p_holm``)."""
    top = lead_signatures(before, named or {}, n)
    after_by = {(s.residual, s.variable): s for s in after}
    cols = 3
    rows = (len(top) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
    for ax, (s, name) in zip(axes.ravel(), top):
        ax.errorbar(s.centers, s.means, yerr=s.errors, marker="o", color="tab:red", label="base model")
        a = after_by.get((s.residual, s.variable))
        if a is not None:
            ax.errorbar(a.centers, a.means, yerr=a.errors, marker="s", color="tab:blue", label="with named effects")
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xlabel(s.variable)
        ax.set_ylabel(s.residual)
        # on two lines with a name: one line ran into the next panel's title (e.g. distance_dependent_noise's)
        ax.set_title(f"adjusted p = {s.p_holm:.1g}" + (f"\nthe signature of {name} (named)" if name else ""), fontsize=9)
    for ax in axes.ravel()[len(top):]:
        ax.axis("off")
    if top:
        axes.ravel()[0].legend(fontsize=8)
    fig.suptitle(f"Residual signatures of the base model (mean residual per bin, +- 1 s.e.; p adjusted for the {len(before)}"
                 " pairs tried and for serial correlation). The verdict rests on the candidates' tests", fontsize=10)
    fig.tight_layout()
    save_png(fig, path, dpi=100)


def gap_bars(path: Path, before: dict[str, float], after: dict[str, float]) -> None:
    """Held-out gap and innovation consistency before and after adding the named effects."""
    keys = [("gap", "held-out NLL per sighting (nats)"), ("nis_mean", "mean NIS (2 expected)"),
            ("nis_outside", "share outside chi2 95% band (0.05)"),
            ("whiteness", "size-innovation autocorrelation,\nlag 1, per landmark (0)")]
    fig, axes = plt.subplots(1, len(keys), figsize=(3.2 * len(keys), 3.0))
    for ax, (k, label) in zip(axes, keys):
        ax.bar(["before", "after"], [before[k], after[k]], color=["tab:red", "tab:blue"])
        ax.set_title(label, fontsize=9)
    fig.suptitle("Before and after adding the named effects (held-out half)")
    fig.tight_layout()
    save_png(fig, path, dpi=100)


def nis_quantiles(path: Path, shape: dict[str, Any]) -> None:
    """The NIS's quantiles of the sightings that follow their landmark's last most closely and of the others
    (``report["innovation_shape"]``) against the chi-square(2) quantiles the model expects, log-log: on the diagonal
    where the model's Gaussian holds, below it where the sightings are predicted more closely than its noise says."""
    from scipy import stats

    probs = np.asarray(shape["quantile_probs"])
    expected = stats.chi2.ppf(probs, 2)
    halves = shape["nis_by_repeat"]
    fig, ax = plt.subplots(figsize=(5.6, 4.6))
    ax.plot(expected, expected, color="0.6", lw=1, label="the model's chi-square(2)")
    for name, color, text in (("closer", "tab:red", f"within {shape['repeat_split_s']:.2g} s of the landmark's last"),
                              ("further", "tab:blue", "the others")):
        h = halves[name]
        if h["quantiles"] is not None:
            ax.plot(expected, h["quantiles"], "o-", color=color, ms=4, label=f"{text} ({h['sightings']} sightings)")
    for edge in shape["nis_band"]:  # the check's own band (``score.NIS_BAND``), as the report states it
        ax.axvline(edge, color="0.85", lw=1, ls="--")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("NIS quantile the model expects (chi-square, 2 dof)")
    ax.set_ylabel("NIS quantile on the log")
    ax.set_title("Innovations by the time since the landmark was last seen\n(quantiles 1-99%; dashed: the 95% band)",
                 fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    save_png(fig, path, dpi=100)


def _z_by_statistic(check: dict[str, Any] | None) -> dict[str, float | None]:
    """A calibrated check's z per statistic (``{}`` for no check)."""
    return {r["statistic"]: r["z"] for r in (check or {}).get("statistics", [])}


def calibrated_rows(before: dict[str, Any], after: dict[str, Any] | None, n: int = 12) -> list[dict[str, Any]]:
    """The ``n`` statistics of the calibrated check (``before["statistics"]``' rows) that disagree most with the base
    model's simulator or with the named effects' (the larger |z| of the two: a disagreement the effects brought is
    shown too), most first; a z of None (no spread in the replicas) is left out."""
    z_after = _z_by_statistic(after)

    def worst(r: dict[str, Any]) -> float:
        return max(abs(r["z"]), abs(z_after.get(r["statistic"]) or 0.0))

    return sorted((r for r in before["statistics"] if r["z"] is not None), key=lambda r: -worst(r))[:n]


LEGEND_STRIP_IN = 0.3  # inches under the calibrated check's axes for its legend


def calibrated_bars(path: Path, before: dict[str, Any], after: dict[str, Any] | None, n: int = 12) -> None:
    """The measured log against the calibrated simulator: z of the statistics :func:`calibrated_rows` picks, with the
    base model and with the named effects added."""
    z_after = _z_by_statistic(after)
    rows = calibrated_rows(before, after, n)[::-1]
    fig, ax = plt.subplots(figsize=(10.0, 0.38 * len(rows) + 1.6 + LEGEND_STRIP_IN))
    y = range(len(rows))
    ax.barh([k + 0.2 for k in y], [r["z"] for r in rows], height=0.4, color="tab:red", label="base model")
    if after is not None:
        ax.barh([k - 0.2 for k in y], [z_after.get(r["statistic"]) or 0.0 for r in rows], height=0.4,
                color="tab:blue", label="model.json (with the named effects)")
    limit = before["disagree_z"] or 4.0  # None: too few replicas for a threshold
    ax.axvspan(-limit, limit, color="0.9", zorder=0, label=f"|z| <= {limit:.1f}: like a simulated log")
    ax.set_xscale("symlog", linthresh=limit)
    lo, hi = ax.get_xlim()
    ticks = [t for t in (-1000, -100, -30, -10, 0, 10, 30, 100, 1000) if lo <= t <= hi] + [-round(limit, 1), round(limit, 1)]
    ax.set_xticks(sorted(ticks), [f"{t:g}" for t in sorted(ticks)])
    ax.set_yticks(list(y), [r["statistic"] for r in rows], fontsize=8)
    ax.set_xlabel(f"z = (measured - mean of {before['replicas']} simulated replays) / their sd")
    ax.set_title("The measured log against its calibrated simulator (the measured commands replayed)", fontsize=10)
    # the legend in a strip of its own under the axes: inside them it covered the lowest bars
    fig.legend(*ax.get_legend_handles_labels(), fontsize=8, loc="lower center", ncol=3, frameon=False)
    fig.tight_layout(rect=(0.0, LEGEND_STRIP_IN / fig.get_figheight(), 1.0, 1.0))
    save_png(fig, path, dpi=100)


def z_text(z: float | None) -> str:
    """``z = +3.1``; ``z = +-inf`` for a z that is infinite (None in report.json: the replicas had no
    spread, and the measured value differs from them)."""
    return "z = +-inf (the replicas all agree, the measured value differs)" if z is None or not np.isfinite(z) \
        else f"z = {z:+.1f}"


def grid_note(name: str) -> str:
    """`` (lag_s on a grid of step 0.1)`` for an effect whose parameters are profiled over a grid: the
    estimate is good to that step; "" otherwise."""
    from learners.model.effects import EFFECT_MODELS

    grid = getattr(EFFECT_MODELS.get(name), "GRID", {})
    return "".join(f" ({k} on a grid of step {float(np.min(np.diff(g))):g}: good to that step)"
                   for k, g in grid.items() if len(g) > 1)


def short(params: dict[str, Any]) -> str:
    """Effect parameters with 4 significant digits: ``lag_s 0.2, scale [1.056, 0.9454]``."""
    def num(v: Any) -> str:
        return "[" + ", ".join(num(x) for x in v) + "]" if isinstance(v, (list, tuple)) else f"{v:.4g}"
    return ", ".join(f"{k} {num(v)}" for k, v in params.items())


def interval_text(intervals: dict[str, Any]) -> str:
    """``95%: sigma_rel [0.041, 0.049], tau_s [6.9, 11.2]`` (scalars; ``lag_s [0.1, 0.3] (profile over a grid of step
    0.1)`` for a grid parameter, ``lag_s [0.1, >=0.5] (profile, open above)`` for an open one), ``scale +- [0.0048,
    ...]`` (arrays: each component's half-width, or its ``[low, high]`` where a bound clipped the interval); the
    parameters without an interval are left out; "" when none has one."""
    def num(v: Any) -> str:
        return "[" + ", ".join(num(x) for x in v) + "]" if isinstance(v, (list, tuple)) else f"{v:.3g}"
    parts = [_scalar_interval(k, iv, num) if np.ndim(iv["value"]) == 0 else _array_interval(k, iv, num)
             for k, iv in intervals.items() if iv["interval_95"] is not None]
    return "95%: " + ", ".join(parts) if parts else ""


def _array_interval(name: str, iv: dict[str, Any], num) -> str:
    """``scale +- [0.0048, 0.0044]``: the half-widths of an array's intervals (``interval_95`` is [lows, highs]), one per
    component in the order of the values; ``scale [[0.99, 1.01], [0.97, 1]]`` where one is not centred on its value
    (clipped at a bound, or not a Wald interval)."""
    lo, hi = (np.asarray(b, dtype=float) for b in iv["interval_95"])
    value = np.asarray(iv["value"], dtype=float)
    if iv.get("clipped") or not np.allclose((lo + hi) / 2.0, value, rtol=1e-6, atol=1e-12):
        return f"{name} {num([[float(a), float(b)] for a, b in zip(lo, hi)])}"
    return f"{name} +- {num([float(w) for w in (hi - lo) / 2.0])}"


def _scalar_interval(name: str, iv: dict[str, Any], num) -> str:
    """``lag_s [0.1, 0.3] (profile)``; an open end (the profile never fell 1.92 nats below its best up to it: the
    interval reaches at least that far) as ``<=`` / ``>=`` with ``open below`` / ``open above``."""
    (lo, hi), (open_lo, open_hi) = iv["interval_95"], iv.get("open") or (False, False)
    how = (f"profile in the model's own steps of {iv['grid_step']:.3g}" if "grid_interval_95" in iv and "grid_step" in iv
           else "profile, whole logs" if "grid_interval_95" in iv
           else f"profile over a grid of step {iv['grid_step']:g}" if "grid_step" in iv
           else "profile" if str(iv.get("method", "")).startswith("profile") else None)
    notes = ([how] if how else []) + \
        [f"open {side}" for side, is_open in (("below", open_lo), ("above", open_hi)) if is_open]
    return (f"{name} [{'<=' if open_lo else ''}{num(lo)}, {'>=' if open_hi else ''}{num(hi)}]"
            + (f" ({', '.join(notes)})" if notes else ""))


def shift_text(shift: dict[str, Any]) -> str:
    """How far the named effects moved the base model, one phrase."""
    v, top = shift["velocities_rms"], shift["velocities_max_abs"]
    if shift["velocities_key"].endswith("velocities"):
        what, units = "velocities", (" mm/s", " mm/s", " rad/s")
    else:  # a feature map's weights: per unit of its features
        what, units = "command weights (forward, lateral, turn, per unit of the commands' features)", ("", "", "")
    curve = (" and left the sensor curve as it was"  # e.g. a range sensor's, held at range = distance
             if shift["sensor_curve_max_abs"] == 0.0 else
             f" and the sensor curve by at most {shift['sensor_curve_max_abs']:.3g} {shift['sensor_unit']} over "
             f"{shift['sensor_distances_mm'][0]:.0f}-{shift['sensor_distances_mm'][1]:.0f} mm")
    return (f"adding them moved the {what} by {v[0]:.3g}{units[0]}, {v[1]:.3g}{units[1]}, {v[2]:.3g}{units[2]} RMS over "
            f"the commands (at most {top[0]:.3g}{units[0]}, {top[1]:.3g}{units[1]}, {top[2]:.3g}{units[2]})" + curve)


def restricted_text(record: dict[str, Any] | None) -> str:
    """What ``--restricted-noise`` did to the final fit's motion noise (``report.json["restricted_noise"]``), one
    sentence; "" when it was not asked for."""
    if not record:
        return ""
    sd = record["position_noise_sd_mm"]
    ml, r = sd["maximum_likelihood"], sd["restricted"]
    return (f"Its motion noise is the restricted likelihood's (--restricted-noise): the position noise's sd per frame "
            f"{r[0]:.3g} / {r[1]:.3g} mm (x / y), {record['scale']:.3g} times the maximum likelihood's variance "
            f"({ml[0]:.3g} / {ml[1]:.3g} mm)" + (", at the end of the range searched" if record["bound"] else "")
            + "; held there in the fit and in every fit behind the intervals.")


def restricted_variances_text(record: dict[str, Any] | None) -> str:
    """What the restricted step did to the named effects' variance parameters (``report.json["restricted_variances"]``),
    one sentence; "" when no named effect has any."""
    if not record:
        return ""
    if not record["taken"]:
        return (f"Its bias processes' variance parameters are at the likelihood's maximum: the restricted likelihood's "
                f"step was not taken ({record['why']}).")
    moved = ", ".join(f"{name}'s {p} {v['maximum_likelihood']:.3g} -> {v['restricted']:.3g}"
                      for name, params in record["effects"].items() for p, v in params.items())
    return (f"Its bias processes' variance parameters are moved towards the restricted likelihood's maximum by a Newton "
            f"step from the likelihood's ({record['length']:.2g} of it taken), which the fitted velocities bias low "
            f"({moved}; their intervals moved with them).")


def starts_text(starts: list[dict[str, Any]]) -> str:
    """Which start the final fit on the whole log(s) kept (``report.json["final_fit_starts"]``), one phrase."""
    kept = next((s for s in starts if s["kept"]), None)
    if kept is None:
        return "the final fit's start: not recorded"
    others = [s for s in starts if not s["kept"] and s["loglik"] is not None]
    if kept["loglik"] is None or not others:
        return f"the final fit on the whole log(s) started from {kept['start']}"
    return (f"the final fit on the whole log(s) kept the fit from {kept['start']}, more likely by "
            + ", ".join(f"{kept['loglik'] - s['loglik']:.1f} nats than from {s['start']}" for s in others))


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" style="max-width:100%">'


def signature_of(u: dict[str, Any]) -> list[dict[str, Any]]:
    """The effects not named whose residual signature an ``report.json["unexplained"]`` row is, each with why it was
    not named: the row's ``effect`` first, then its ``other_effects`` (empty when the catalogue has none)."""
    if not u.get("effect"):
        return []
    return [{"effect": u["effect"], "why_not_named": u["why_not_named"]}] + list(u.get("other_effects", []))


def _still_unlike(u: dict[str, Any]) -> str:
    """One paragraph on a disagreement left after the named effects (an ``unexplained`` row)."""
    whose = signature_of(u)
    of = ("; ".join(f"the residual signature of <b>{html.escape(w['effect'])}</b>, which was not named "
                    f"({html.escape(w['why_not_named'])})" for w in whose)
          if whose else f"unexplained ({html.escape(u['why_not_named'])})")
    where = f" Where: {html.escape(u['where'])}." if u.get("where") else ""
    return (f"<p><b>Still unlike its simulation:</b> {html.escape(u['statistic'])} ({z_text(u['z'])}): "
            f"{html.escape(u.get('reading', ''))}; {of}.{where}</p>")


def _calibrated(cal: dict[str, Any] | None, unexplained: list[dict[str, Any]], replays: str = "open loop") -> str:
    """One paragraph: where the measured log is unlike its calibrated simulation, before and after (``replays``:
    ``report.json["calibrated_replays"]``)."""
    if not cal:
        return ""
    if "before" not in cal:
        return f"<p>Calibrated simulator: {html.escape(cal.get('note', 'not run'))}</p>"

    def worst(check: dict[str, Any]) -> str:
        d = check["disagreements"]
        return (", ".join(f"{html.escape(x['statistic'])} ({z_text(x['z'])})" for x in d[:4])
                + (f" and {len(d) - 4} more" if len(d) > 4 else "")) if d else "nothing"
    steered = ", steered along the model's smoothed path" if replays == "tracked" else ""
    return (f"<p>Calibrated simulator ({cal['before']['replicas']} replays of the measured commands{steered}): the measured "
            f"log differs in <b>{len(cal['before']['disagreements'])}</b> statistics from the base model's simulation "
            f"({worst(cal['before'])}), and in <b>{len(cal['after']['disagreements'])}</b> from the simulation of the "
            f"diagnosed model, model.json, with the named effects ({worst(cal['after'])}).</p>"
            + "".join(_still_unlike(u) for u in unexplained if "probe" not in u))


def try_next(report: dict[str, Any]) -> str:
    """The options that try ``report.json["untried_effects"]``: ``--candidates`` (``untried_candidates``) and, where the
    named and the untried effects outnumber the search's rounds (each names at most one), ``--rounds``."""
    rounds = len(report["effects"]) + len(report["untried_effects"])
    limit = report.get("search_rounds", {}).get("max_rounds")
    return f"--candidates {report['untried_candidates']}" + (f" --rounds {rounds}" if limit and rounds > limit else "")


def _untried(report: dict[str, Any]) -> str:
    """One paragraph on ``report.json["untried_effects"]``: the effects left out of the candidates that the
    disagreements left point at, and the options that try them (``try_next``)."""
    untried = report.get("untried_effects", [])
    if not untried:
        return ""
    names = ", ".join(f"<b>{html.escape(u['effect'])}</b> ({u['statistics']})" for u in untried)
    return (f"<p><b>Not tried, and pointed at by the disagreements left</b> (statistics each): {names}. "
            f"<code>{html.escape(try_next(report))}</code> tries them; compare the motion gap and the check before "
            f"keeping that model.</p>")


def _none_of_the_above(unexplained: list[dict[str, Any]]) -> str:
    """One paragraph per significant probe (``report.json["unexplained"]`` entries with a ``"probe"``): a dependence
    that no catalogue effect explains."""
    return "".join(
        f"<p><b>None of the above:</b> {html.escape(u['describes'])} (train +{u['gain_train']:.1f} nats, held-out "
        f"{u['gain_heldout']:+.1f} nats, p = {u['p_value']:.2g}); {html.escape(u['why_not_named'])}. Its signature: "
        f"{html.escape(u['statistic'])}" + (f", p = {u['signature']['p_value']:.2g}" if u.get("signature") else "")
        + ".</p>" for u in unexplained if "probe" in u)


#: beside a named effect whose values the report warns about (``report.json["effects"][i]["warnings"]``)
READ_WITH_CARE = "read with care: a warning below says why its value or interval may be off"


def _verdict(report: dict[str, Any]) -> str:
    """The page's first line: the named effects with their values and intervals, and how far they moved the base."""
    odd = [u for u in report.get("unexplained", []) if "probe" in u]
    if not report["effects"]:
        if odd:
            return ("Verdict: <b>none of the above</b>: no candidate of the catalogue improved the fit significantly, "
                    "but the logs show a dependence that none of them is (below)")
        return ("Verdict: <b>no missing effect found</b>: no candidate improved the fit significantly on both halves "
                "of the log")
    named = []
    for e in report["effects"]:
        interval = interval_text(e.get("intervals", {}))
        step = "" if interval else grid_note(e["name"])  # an interval states the grid's step itself
        care = f"; <i>{READ_WITH_CARE}</i>" if e.get("warnings") else ""
        named.append(f"<b>{html.escape(e['name'])}</b> ({html.escape(short(e['parameters']) + step)}"
                     f"{html.escape('; ' + interval) if interval else ''}{care})")
    shift = f"; {html.escape(shift_text(report['base_change']))}" if report.get("base_change") else ""
    rest = "; and something outside the catalogue (none of the above, below)" if odd else ""
    return "Verdict: the base model misses " + ", ".join(named) + shift + rest


def _motion(report: dict[str, Any]) -> str:
    """The motion gap before and after, per horizon, with the paired change and its standard error."""
    before, after = report.get("motion_gap_before"), report.get("motion_gap_after")
    if not before:
        return ""
    change = report.get("motion_gap_change", {})
    ex_b, ex_a = report.get("motion_excess_before", {}), report.get("motion_excess_after", {})
    rows = "".join(
        f"<tr><td>{html.escape(k)} s</td><td>{before[k]:.4f}</td><td>{after[k]:.4f}</td>"
        f"<td>{change[k]['change']:+.4f} &plusmn; {change[k]['se']:.4f}</td>"
        f"<td>{ex_b[k]:.4f}</td><td>{ex_a[k]:.4f}</td>"
        f"<td>{change[k]['excess_change']:+.4f} &plusmn; {change[k]['excess_se']:.4f}</td><td>{change[k]['n']}</td></tr>"
        for k in after if k in change and k in ex_b and k in ex_a)
    return (f"<p>Motion gap ({html.escape(report['motion_gap_metric'])}): each held-out sighting predicted from the "
            "filtered pose k seconds before it and the commands alone, in nats per sighting; lower is better. The "
            "one-step gap above is mostly the sensor model; the excess (motion gap less the one-step gap of the same "
            "sightings) is what the model loses when its motion has to carry the pose for k seconds (descriptive: it also grows "
            "when the sensor model gets sharper).</p>"
            "<table><tr><th>horizon</th><th>gap before</th><th>gap after</th><th>change (&plusmn; s.e., 30 s blocks)</th>"
            "<th>excess before</th><th>excess after</th><th>change</th>"
            f"<th>sightings</th></tr>{rows}</table>")


def _set_aside(outliers: dict[str, Any] | None) -> str:
    """How many sightings the search set aside as gross errors before any model was fitted (report.json["outliers"])."""
    if not outliers:
        return ""
    n, of = outliers["set_aside"], outliers["sightings"]
    return (f"Sightings set aside as gross errors before the diagnosis (Mahalanobis^2 &gt; "
            f"{outliers['gate_mahalanobis2']:g} under the search's base model): "
            + (f"none of {of}." if n == 0 else f"{n} of {of} ({outliers['share']:.1%}); no fit or score here sees them."))


def _trail(checks: list[dict[str, Any]]) -> str:
    """A candidate's checks in the order they ran: the name, with a cross where a deciding check refused and a
    circle where an annotating one found something to say."""
    def mark(v: dict[str, Any]) -> str:
        if v["passed"]:
            return ""
        return " &#10007;" if v["decides"] else " &#9675;"

    return ", ".join(f"{html.escape(v['name'])}{mark(v)}" for v in checks)


def html_page(path: Path, report: dict[str, Any], text: str, figures: list[Path]) -> None:
    """One self-contained page: the verdict first, then the figures, the candidates and the full text."""
    verdict = _verdict(report)
    gain = report["gap_before"] - report["gap_after"]
    change = f"better by {gain:.4f}" if gain >= 0 else f"worse by {-gain:.4f}"
    rows = "".join(
        f"<tr><td>{c['round']}</td><td>{html.escape(c['name'])}</td><td>{c['gain_train']:.1f}</td>"
        f"<td>{c['gain_heldout']:.1f}</td><td>{c['p_value']:.2g}</td><td>{'yes' if c['significant'] else ''}</td>"
        f"<td>{'<b>named</b>' if c.get('named') else ''}</td>"
        f"<td>{'' if c['identifiable'] else 'no'}</td><td>{_trail(c.get('checks', []))}</td>"
        f"<td>{html.escape(c['note'])}</td></tr>"
        for c in report["candidates"])
    body = f"""<!doctype html><html><head><meta charset="utf-8"><title>aibo diagnose</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}td,th{{padding:2px 8px;border-bottom:1px solid #ddd}}
pre{{background:#f6f6f6;padding:1em;overflow:auto}}</style></head><body>
<h1>Discrepancy report</h1><p>{verdict}</p>
{"".join(f'<p style="color:#b00"><b>Warning:</b> {html.escape(w)}</p>' for w in report.get("warnings", []))}
<p>Gap ({html.escape(report['gap_metric'])}: how unlikely the held-out half of the log is under the model, in nats per
sighting; lower is better): <b>{report['gap_before']:.4f}</b> before, <b>{report['gap_after']:.4f}</b> after
{f"the named effects: {change} nats per sighting" if report["effects"] else "(nothing named: the same model)"}.</p>
<p>The diagnosed model (model.json): {html.escape(starts_text(report.get("final_fit_starts", [])))} (the likelihood of
the whole log(s), ungated). {html.escape(restricted_text(report.get("restricted_noise")))}
{html.escape(restricted_variances_text(report.get("restricted_variances")))}
{_set_aside(report.get("outliers"))}</p>
{_motion(report)}
<p>The residual signatures below show where the base model's residuals drift: sighting innovations against predicted
quantities, motion residuals within each command. Each p-value allows for the residuals' serial correlation and is
adjusted for every pair tried (Holm); the named effects' signatures come first. The verdict rests on the candidates'
likelihood-ratio tests and held-out gains (table below: "named" marks the effects the diagnosed model holds).</p>
{_calibrated(report.get("calibrated_simulation"), report.get("unexplained", []), report.get("calibrated_replays", "open loop"))}
{_untried(report)}
{_none_of_the_above(report.get("unexplained", []))}
{''.join(_img(p) for p in figures if p.exists())}
<h2>Candidates</h2><table><tr><th>round</th><th>effect</th><th>train gain (nats)</th><th>held-out gain (nats)</th>
<th>p</th><th>significant</th><th>named</th><th>identifiable</th><th>checks (in order; &#10007; refused, &#9675; a
note that decides nothing)</th><th>note</th></tr>{rows}</table>
<h2>Full report</h2><pre>{html.escape(text)}</pre></body></html>"""
    atomic_write(path, lambda f: f.write(body.encode()))
