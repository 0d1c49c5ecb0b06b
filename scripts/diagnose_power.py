"""Error rates of the discrepancy workflow (``aibo diagnose``'s search): false alarms, a confusion matrix, pairs.

    python scripts/diagnose_power.py [--seeds 20] [--presets aibo,paper-sim] [--wall-seeds 0] [--power-seeds 5]
                                     [--minutes 10] [--effects a,b] [--pair-seeds 0] [--pair-minutes M] [--out runs/power]
                                     [--candidates all|defaults|a,b,...]

The published tables (docs/results.md, docs/measured.md "How often aibo diagnose is wrong"), in one command (about 1 h on 2
cores): ``python scripts/diagnose_power.py --presets aibo,paper-sim --seeds 25 --wall-seeds 25 --power-seeds 10
--pair-seeds 10 --minutes 5 --pair-minutes 10``.

Blind simulated logs, every effect of the catalogue a candidate (``--candidates all``, the published tables), or the
candidates ``aibo diagnose`` tries by default (``--candidates defaults``: the study as the command runs; give it its own
``--out``, the finished runs are not told apart by their candidates), or a list:
- effect-free logs, ``--seeds`` per noise preset, and ``--wall-seeds`` per preset whose random walk leaves the
  field by 800 mm (the robot meets the walls: ``wall_contact`` is there and is the one right name). A false alarm
  is a log with any other named effect (family-wise; target: at most 5%), with its exact (Clopper-Pearson) 95%
  upper bound; ``angle_bias`` named anywhere is counted apart (it is not identifiable);
- each effect at three strengths over ``--power-seeds`` seeds (``aibo`` preset): the confusion matrix of the
  effect named first (or none) against the hidden one, and the detection rate (the hidden effect named first).
  ``angle_bias`` is in it with "none" as the right answer (not identifiable: ``AngleBias.equivalent``);
- pairs of effects at once (``--pair-seeds`` seeds each, ``PAIRS``, logs of ``--pair-minutes``): both named, and
  each estimate within the single-effect tolerance (``TOLERANCE``, as ``tests/test_discrepancy.py``);
- on every log, whether the search's "none of the above" check (``learners.model.probes``) reported a dependence
  outside the catalogue.
Writes ``power.json``, ``power.md`` (tables), ``power.png`` (detection rates) and ``confusion.png``; resumable
(finished runs are kept in ``runs.jsonl``; a second process started with ``--first-power-seed N`` writes its own
``runs-from-N.jsonl``, skips the runs any of them holds, and the tables read them all).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aibo_core.atomic import atomic_write, read_jsonl, write_jsonl
from aibo_core.trajectory import blind
from aibo_gym.collect import collect
from learners.discrepancy.search import search
from learners.em.options import EMOptions
from learners.model.effects import EFFECT_MODELS

STRENGTHS = {
    "floor_drift": [{"drift_mm_s": [s, 0.0]} for s in (3.0, 6.0, 12.0)],
    "velocity_fade": [{"fade_per_min": f} for f in (0.005, 0.01, 0.02)],
    "actuation_lag": [{"lag_s": t} for t in (0.05, 0.1, 0.2)],
    "off_center_shrink": [{"k": k} for k in (0.05, 0.1, 0.2)],
    "distance_dependent_noise": [{"exponent": e} for e in (0.25, 0.5, 1.0)],
    "beacon_height_scale": [{"scale": [1 + s, 1 - s, 1 + s / 2, 1 - s / 2]} for s in (0.01, 0.02, 0.04)],
    "landmark_bearing_offset": [{"offset_rad": [s, -s, s / 2, -s / 2]} for s in (0.005, 0.01, 0.02)],  # rad
    "landmark_bias": [{"sigma_rel": s, "tau_s": 8.0} for s in (0.02, 0.05, 0.1)],
    "landmark_bearing_bias": [{"sigma_rad": s, "tau_s": 20.0} for s in (0.01, 0.02, 0.04)],  # aibo's noise: 0.027 rad
    "false_sightings": [{"rate": r} for r in (0.02, 0.05, 0.1)],
    "heavy_tailed_noise": [{"rate": 0.1, "scale": c} for c in (1.5, 2.0, 3.0)],  # MRCLAM's tails: about 0.1 at 2
    "turn_dependent_noise": [{"gain_s": g} for g in (0.75, 1.5, 3.0)],  # s/rad: the AIBO turns at up to 1.6 rad/s
    "turn_heading_noise": [{"gain_s": g} for g in (0.75, 1.5, 3.0)],
    "angle_bias": [{"bias_rad": b} for b in (0.02, 0.05, 0.1)],  # not identifiable: "none" is the right answer
}
#: Effects whose right answer is "none" at any strength (the search reports them not identifiable).
NOT_IDENTIFIABLE = ("angle_bias",)
#: Pairs of effects at once: (name, {effect: parameters}, walls met). "drift + wall": a drift that pushes into the walls.
PAIRS = [
    ("drift + wall", {"floor_drift": {"drift_mm_s": [15.0, -10.0]}}, True),
    ("lag + fade", {"actuation_lag": {"lag_s": 0.2}, "velocity_fade": {"fade_per_min": 0.03}}, False),
    ("heights + distance noise", {"beacon_height_scale": {"scale": [1.08, 0.94, 1.04, 0.95]},
                                  "distance_dependent_noise": {"exponent": 1.0}}, False),
]


def _normalized(scale: list[float]) -> np.ndarray:
    s = np.asarray(scale, float)
    return s / np.exp(np.mean(np.log(s)))


#: The single-effect tolerances of ``tests/test_discrepancy.py`` (``HIDDEN``): estimate, truth -> within tolerance.
TOLERANCE = {
    "floor_drift": lambda e, t: np.allclose(e["drift_mm_s"], t["drift_mm_s"], atol=5.0),
    "velocity_fade": lambda e, t: abs(e["fade_per_min"] - t["fade_per_min"]) < 0.005,
    "actuation_lag": lambda e, t: abs(e["lag_s"] - t["lag_s"]) < 0.11,
    "distance_dependent_noise": lambda e, t: abs(e["exponent"] - t["exponent"]) < 0.25,
    "beacon_height_scale": lambda e, t: np.allclose(e["scale"], _normalized(t["scale"]), atol=0.015),
}


WALL_MARGIN_MM = -800.0  # the random walk's margin to the walls: negative, it leaves the field (tests/test_discrepancy_more)


def one(effect: str | None, params: dict | None, seed: int, minutes: float, preset: str = "aibo",
        walls: bool = False, effects: dict | None = None, candidates: list[str] | None = None) -> dict:
    """One blind log, diagnosed with ``candidates`` (None: every effect of the catalogue): what was named, with what
    values, and how long it took (s). ``effects``: several hidden effects at once ({name: parameters}; ``effect`` is
    then the pair's label)."""
    hidden = effects if effects is not None else ({effect: params} if effect else {})
    config = {"noise": preset, "effects": hidden}
    policy = {"margin_mm": WALL_MARGIN_MM} if walls else None
    tr = blind(collect(config, int(minutes * 60 * 30), seed=seed, policy_params=policy))
    t0 = time.perf_counter()
    found = search([tr], sorted(candidates or EFFECT_MODELS), EMOptions(), jobs=2, progress=lambda s: None)
    named = [c.name for c in found["named"]]
    values = {n: {k: np.asarray(v).tolist() for k, v in found["model"].effect(n).values().items()} for n in named}
    return {"effect": effect or "none", "params": params if effects is None else effects, "seed": seed,
            "preset": preset, "walls": walls, "named": named, "values": values,
            "unexplained": [c.name for c in found["probes"] if c.significant],
            "detected": first_named(named) == right_answer(effect or "none"), "seconds": time.perf_counter() - t0}


def chosen_candidates(arg: str) -> list[str]:
    """``--candidates`` as ``aibo diagnose`` reads it (``aibo.commands.diagnose.candidates``: names, "all" for every
    effect of the catalogue, "defaults" for the effects it tries without the option)."""
    from aibo.commands.diagnose import candidates
    from aibo.errors import CLIError

    try:
        return candidates(arg)
    except CLIError as err:
        raise SystemExit(str(err)) from None


def first_named(named: list[str]) -> str:
    """The effect a run named first, "none" when it named nothing."""
    return named[0] if named else "none"


def right_answer(effect: str) -> str:
    """What a run hiding ``effect`` should name first: the effect itself, "none" for an effect-free log or one that is
    not identifiable."""
    return "none" if effect in NOT_IDENTIFIABLE else effect


def pair_ok(r: dict) -> tuple[bool, bool]:
    """(both named, every estimate within its single-effect tolerance) of a pair run; a pair that meets the walls
    names ``wall_contact`` too."""
    hidden = r["params"]
    named = all(n in r["named"] for n in list(hidden) + (["wall_contact"] if r.get("walls") else []))
    close = named and all(TOLERANCE[n](r["values"][n], p) for n, p in hidden.items() if n in TOLERANCE)
    return named, close


def false_alarm(r: dict) -> bool:
    """An effect-free log with a named effect that is not there (``wall_contact`` is there when the walls are met)."""
    allowed = {"wall_contact"} if r.get("walls") else set()
    return bool(set(r["named"]) - allowed)


def upper95(k: int, n: int) -> float:
    """Exact (Clopper-Pearson) one-sided 95% upper bound on a rate seen k times in n."""
    from scipy import stats

    return 1.0 if k >= n else float(stats.beta.ppf(0.95, k + 1, n - k))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20, help="effect-free logs per noise preset")
    ap.add_argument("--presets", default="aibo", help="noise presets of the effect-free logs (aibo,paper-sim)")
    ap.add_argument("--wall-seeds", type=int, default=0, help="effect-free logs per preset that meet the walls")
    ap.add_argument("--power-seeds", type=int, default=5,
                    help="the confusion matrix's seeds end here: seeds 2000 + [--first-power-seed, --power-seeds)")
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--effects", default=",".join(STRENGTHS))
    ap.add_argument("--first-power-seed", type=int, default=0,
                    help="start the confusion matrix's seeds here (a second process can take the later seeds)")
    ap.add_argument("--pair-seeds", type=int, default=0, help="logs per pair of effects (PAIRS)")
    ap.add_argument("--pair-minutes", type=float, default=None, help="length of the pairs' logs (default: --minutes)")
    ap.add_argument("--out", default="runs/power")
    ap.add_argument("--candidates", default="all",
                    help="as aibo diagnose's: comma-separated effects, 'all' (every effect of the catalogue), "
                         "'defaults' (aibo diagnose's without the option)")
    args = ap.parse_args()
    candidates = chosen_candidates(args.candidates)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # one file per process: two processes rewriting one file would each drop the other's runs
    done_path = out / ("runs.jsonl" if args.first_power_seed == 0 else f"runs-from-{args.first_power_seed}.jsonl")
    done = read_jsonl(done_path)
    key = {(r["effect"], json.dumps(r["params"]), r["seed"], r.get("preset", "aibo"), r.get("walls", False))
           for r in all_runs(out)}
    jobs = []
    # interleaved (seed by seed: each preset without, then with walls), so that a run stopped early covers every
    # group of the false-alarm table
    for s in range(max(args.seeds, args.wall_seeds)):
        for preset in args.presets.split(","):
            jobs += [(None, None, 1000 + s, preset, False)] if s < args.seeds else []
            jobs += [(None, None, 3000 + s, preset, True)] if s < args.wall_seeds else []
    # strength by strength, seed by seed: a run stopped early has every cell of the confusion matrix
    for s in range(args.first_power_seed, args.power_seeds):
        for k in range(3):
            jobs += [(e, STRENGTHS[e][k], 2000 + s, "aibo", False) for e in filter(None, args.effects.split(","))]
    jobs += [(label, hidden, 5000 + s, "aibo", walls) for s in range(args.pair_seeds) for label, hidden, walls in PAIRS]
    for effect, params, seed, preset, walls in jobs:
        if (effect or "none", json.dumps(params), seed, preset, walls) in key:
            continue
        pair = effect is not None and effect not in STRENGTHS
        r = (one(effect, None, seed, args.pair_minutes or args.minutes, preset, walls, effects=params,
                 candidates=candidates) if pair
             else one(effect, params, seed, args.minutes, preset, walls, candidates=candidates))
        done.append(r)
        write_jsonl(done_path, done)
        print(f"{r['effect']:26s} {json.dumps(r['params'])!s:45s} {preset}{' walls' if walls else ''} seed {seed}: "
              f"named {r['named']} ({r['seconds']:.0f} s)", flush=True)
    summarize(all_runs(out), out)


def all_runs(out: Path) -> list[dict]:
    """The runs of every OUT/runs*.jsonl (one file per process that ran)."""
    return [r for path in sorted(out.glob("runs*.jsonl")) for r in read_jsonl(path)]


def false_alarm_lines(none: list[dict]) -> list[str]:
    """The false-alarm table: per noise preset and walls met, the logs with a wrong name."""
    alarms = sum(false_alarm(r) for r in none)
    checked = [r for r in none if "unexplained" in r]  # runs older than the "none of the above" check lack it
    odd = sum(bool(r["unexplained"]) for r in checked)
    lines = [f"False alarms: {alarms} of {len(none)} effect-free logs ({alarms / max(len(none), 1):.1%}; 95% upper "
             f"bound {upper95(alarms, len(none)):.1%}); angle_bias named in {sum('angle_bias' in r['named'] for r in none)}; "
             f"\"none of the above\" reported in {odd} of {len(checked)}.",
             "", "| noise preset | walls met | logs | false alarms | 95% upper bound | named (count) | none of the above |",
             "|---|---|---|---|---|---|---|"]
    for preset, walls in sorted({(r.get("preset", "aibo"), bool(r.get("walls"))) for r in none}):
        rs = [r for r in none if (r.get("preset", "aibo"), bool(r.get("walls"))) == (preset, walls)]
        k = sum(false_alarm(r) for r in rs)
        counts: dict[str, int] = {}
        for r in rs:
            for n in r["named"]:
                counts[n] = counts.get(n, 0) + 1
        lines.append(f"| {preset} | {'yes' if walls else 'no'} | {len(rs)} | {k} ({k / len(rs):.0%}) | "
                     f"{upper95(k, len(rs)):.0%} | {', '.join(f'{n} {c}' for n, c in sorted(counts.items())) or '-'} | "
                     f"{_unexplained_cell(rs)} |")
    return lines


def _unexplained_cell(rs: list[dict]) -> str:
    """How many of the runs ``rs`` reported "none of the above", and which probes (count)."""
    checked = [r for r in rs if "unexplained" in r]
    if not checked:
        return "not checked"
    counts: dict[str, int] = {}
    for r in checked:
        for n in r["unexplained"]:
            counts[n] = counts.get(n, 0) + 1
    k = sum(bool(r["unexplained"]) for r in checked)
    return f"{k} of {len(checked)}" + (f" ({', '.join(f'{n} {c}' for n, c in sorted(counts.items()))})" if k else "")


@dataclass
class Confusion:
    """Hidden effect (one row per effect and strength) against the effect named first (columns: every name named
    first in these runs or hidden in them, "none" last)."""

    rows: list[str]  # "effect strength"
    cols: list[str]
    counts: np.ndarray  # (rows, cols) runs
    runs: np.ndarray  # (rows,)
    right: np.ndarray  # (rows,) the column of each row's right answer (``right_answer``)

    def detected(self) -> np.ndarray:
        """(rows,) the share of runs that named the right answer first."""
        return self.counts[np.arange(len(self.rows)), self.right] / np.maximum(self.runs, 1)


def confusion(done: list[dict]) -> Confusion:
    power = [r for r in done if r["effect"] in STRENGTHS]
    cols = sorted(set(STRENGTHS) | {first_named(r["named"]) for r in power} - {"none"}) + ["none"]
    rows, counts, runs, right = [], [], [], []
    for e in sorted(STRENGTHS):
        for k, p in enumerate(STRENGTHS[e]):
            rs = [r for r in power if r["effect"] == e and r["params"] == p]
            if not rs:
                continue
            rows.append(f"{e} {['weak', 'medium', 'strong'][k]}")
            c = np.zeros(len(cols), int)
            for r in rs:
                c[cols.index(first_named(r["named"]))] += 1
            counts.append(c)
            runs.append(len(rs))
            right.append(cols.index(right_answer(e)))
    return Confusion(rows, cols, np.array(counts, int).reshape(len(rows), len(cols)), np.array(runs, int),
                     np.array(right, int))


def confusion_lines(conf: Confusion) -> list[str]:
    if not conf.rows:
        return []
    lines = ["", "Confusion matrix (`aibo` preset): the effect named first against the hidden one, runs per cell; "
             "detected = the hidden effect named first (for `angle_bias`, none: it is not identifiable).", "",
             "| hidden effect, strength | " + " | ".join(c.replace("_", " ") for c in conf.cols) + " | detected | runs |",
             "|---|" + "---|" * (len(conf.cols) + 2)]
    for label, c, n, right, rate in zip(conf.rows, conf.counts, conf.runs, conf.right, conf.detected()):
        cells = [f"**{v}**" if j == right else (str(v) if v else ".") for j, v in enumerate(c)]
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {rate:.0%} | {n} |")
    return lines


def pair_lines(done: list[dict]) -> list[str]:
    labels = [label for label, _, _ in PAIRS]
    pairs = [r for r in done if r["effect"] in labels]
    if not pairs:
        return []
    lines = ["", "| pair | logs | both named | both within the single-effect tolerance | also named |",
             "|---|---|---|---|---|"]
    for label, hidden, walls in PAIRS:
        rs = [r for r in pairs if r["effect"] == label]
        ok = [pair_ok(r) for r in rs]
        extra: dict[str, int] = {}
        for r in rs:
            for n in set(r["named"]) - set(hidden) - ({"wall_contact"} if walls else set()):
                extra[n] = extra.get(n, 0) + 1
        lines.append(f"| {label} | {len(rs)} | {sum(a for a, _ in ok)} | {sum(b for _, b in ok)} | "
                     f"{', '.join(f'{n} {c}' for n, c in sorted(extra.items())) or '-'} |")
    return lines


def summarize(done: list[dict], out: Path) -> None:
    none = [r for r in done if r["effect"] == "none"]
    alarms = sum(false_alarm(r) for r in none)
    fa = alarms / len(none) if none else float("nan")
    conf = confusion(done)
    lines = false_alarm_lines(none) if none else []
    lines += confusion_lines(conf) + pair_lines(done)
    power: dict[str, list[float]] = {}
    for label, rate in zip(conf.rows, conf.detected()):
        power.setdefault(label.rsplit(" ", 1)[0], []).append(float(rate))
    text = "\n".join(lines) + "\n"
    atomic_write(out / "power.md", lambda f: f.write(text.encode()))
    summary = json.dumps({"false_alarm_rate": fa, "false_alarm_upper95": upper95(alarms, len(none)) if none else None,
                          "n_none": len(none), "power": power,
                          "confusion": {"rows": conf.rows, "columns": conf.cols, "counts": conf.counts.tolist(),
                                        "runs": conf.runs.tolist()},
                          "pairs": {label: [pair_ok(r) for r in done if r["effect"] == label] for label, _, _ in PAIRS}},
                         indent=1)
    atomic_write(out / "power.json", lambda f: f.write(summary.encode()))
    figures(power, fa, conf, out)
    print(text)


def figures(power: dict, fa: float, conf: Confusion, out: Path) -> None:
    """power.png (detection rate against strength) and confusion.png (the confusion matrix as fractions)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for e, rates in power.items():
        ax.plot([1, 2, 3][: len(rates)], rates, marker="o", label=e + (" (right: none)" if e in NOT_IDENTIFIABLE else ""))
    ax.axhline(fa, color="k", ls=":", label=f"false alarms ({fa:.0%})")
    ax.set_xticks([1, 2, 3], ["weak", "medium", "strong"])
    ax.set_ylabel("detection rate")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(fontsize=7)
    ax.set_title("aibo diagnose: detection power against strength")
    fig.tight_layout()
    fig.savefig(out / "power.png", dpi=110)
    plt.close(fig)
    if not conf.rows:
        return
    rows, cols, counts, runs = conf.rows, conf.cols, conf.counts, conf.runs
    frac = counts / runs[:, None]
    fig, ax = plt.subplots(figsize=(1.2 + 0.55 * len(cols), 1.0 + 0.3 * len(rows)))
    ax.imshow(frac, cmap="Blues", vmin=0, vmax=1, aspect="auto")
    for i, j in zip(*np.nonzero(counts)):
        ax.text(j, i, str(counts[i, j]), ha="center", va="center", fontsize=7, color="w" if frac[i, j] > 0.6 else "k")
    ax.set_xticks(range(len(cols)), [c.replace("_", " ") for c in cols], rotation=40, ha="right", fontsize=7)
    ax.set_yticks(range(len(rows)), [f"{r} ({n})" for r, n in zip(rows, runs)], fontsize=7)
    ax.set_xlabel("named first")
    ax.set_title("aibo diagnose: hidden effect (runs) against the effect named first", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "confusion.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
