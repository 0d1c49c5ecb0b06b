"""``aibo experiment policies``: which exploration policy makes EM learn best for a fixed robot time.

For each policy, each log length and each seed: one run (:mod:`experiments.run`). Seed ``s``
uses the robot ``robot_seed = robot_seed_base + s`` (unless the config fixes it), the same robot
for every policy and length, and never robot 0 (the default, on which policies were tuned and
agents trained). ``random-balanced`` runs on its onboard EKF (``localizer="ekf"``) unless
``policy_params`` says otherwise, so every policy steers with onboard information only.

Outputs in the sweep folder: ``results.jsonl`` (one record per run, see ``RECORD_KEYS``),
``summary.json`` (per policy and length: mean, std, min, max over seeds), ``errors_vs_minutes.png``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from aibo_core.atomic import atomic_write, write_json
from experiments.run import RunSpec

#: The contract of results.jsonl: every record has at least these keys.
RECORD_KEYS = ("policy", "minutes", "seed", "vx_rel", "vy_rel", "vth_rel", "sensor_rms_px", "log", "model")
METRICS = ("vx_rel", "vy_rel", "vth_rel", "vel_rel_mean", "sensor_rms_px", "heldout_loglik", "iterations",
           "seen_share", "commands_used", "sigma_height_rel", "sigma_angle_rel", "info_min_eigenvalue",
           "info_condition_number")
BASELINE = "random-balanced"


def policy_specs(names: list[str], params: dict[str, dict] | None = None) -> list[dict]:
    """Specs of the policies named (names or ``sb3:PATH``); ``params``: label -> parameters."""
    from aibo_gym.policies import policy_label, validate_policy

    params = params or {}
    out = []
    for name in names:
        spec = validate_policy(name)
        label = policy_label(spec)
        extra = params.get(label, params.get(name, {}))
        if not isinstance(extra, dict):
            raise ValueError(f"the parameters of policy {label!r} must be a JSON object {{param: value}}, "
                             f"got {extra!r}")
        extra = dict(extra)
        if spec["name"] == "random-balanced":
            extra.setdefault("localizer", "ekf")
        out.append(validate_policy({"name": spec["name"], "params": {**spec["params"], **extra}}))
    return out


def check_params(spec: dict[str, Any], field: Sequence[float]) -> None:
    """ValueError (one line naming the policy and the parameter) for a validated policy spec (``validate_policy``)
    whose numbers no run could use on a ``field`` (length, width mm): ``hold_s`` not positive (the rule the policies
    apply when built, ``HoldPolicy.set_hold``, checked here before any run starts) or ``margin_mm`` outside [0, half
    the field's shorter side) (no predicted path would be safe)."""
    name, params = spec["name"], spec["params"]
    hold = params.get("hold_s")
    if hold is not None and not hold > 0:
        raise ValueError(f"policy '{name}': hold_s must be positive seconds, got {hold:g}")
    margin = params.get("margin_mm")
    half = min(float(v) for v in field) / 2
    if margin is not None and not 0 <= margin < half:
        raise ValueError(f"policy '{name}': margin_mm must be >= 0 and below half the field's shorter side "
                         f"({half:g} mm), got {margin:g}")


def build_specs(policies: list[dict], minutes: list[float], seeds: list[int], config: dict[str, Any] | None = None,
                robot_seed_base: int = 100, learner: dict[str, Any] | None = None,
                holdout_minutes: float = 5.0) -> list[RunSpec]:
    specs = []
    for s in seeds:
        env = dict(config or {})
        env.setdefault("robot_seed", robot_seed_base + s)
        for m in minutes:
            for p in policies:
                specs.append(RunSpec(p, m, s, env, dict(learner or {}), holdout_minutes))
    return specs


def summarize(records: list[dict]) -> dict[str, Any]:
    """Per policy and length: n, and mean/std/min/max over seeds of each metric; the comparison
    with the baseline (``random-balanced``) at its longest length."""
    rows: dict[str, dict[str, Any]] = {}
    for r in records:
        rows.setdefault(r["policy"], {}).setdefault(f"{r['minutes']:g}", []).append(r)
    out: dict[str, Any] = {"policies": {}}
    for pol, by_len in rows.items():
        out["policies"][pol] = {}
        for m, rs in sorted(by_len.items(), key=lambda kv: float(kv[0])):
            cell: dict[str, Any] = {"n": len(rs), "seeds": sorted(r["seed"] for r in rs)}
            for k in METRICS:
                v = np.array([r[k] for r in rs if r.get(k) is not None], float)
                if len(v):
                    cell[k] = {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
                               "median": float(np.median(v)), "min": float(v.min()), "max": float(v.max())}
            out["policies"][pol][m] = cell
    out["comparison"] = compare(out["policies"])
    return out


def _curve(cells: dict[str, Any], key: str) -> tuple[np.ndarray, np.ndarray]:
    ms = sorted(cells, key=float)
    return np.array([float(m) for m in ms]), np.array([cells[m][key]["mean"] for m in ms])


def minutes_to_reach(cells: dict[str, Any], target: float, key: str = "vel_rel_mean") -> float | None:
    """Minutes of data at which the mean error curve (linear between lengths) first reaches ``target``;
    None if it never does within the lengths run; the shortest length if it is already below."""
    ms, err = _curve(cells, key)
    if err[0] <= target:
        return float(ms[0])
    for i in range(1, len(ms)):
        if err[i] <= target:
            f = (err[i - 1] - target) / (err[i - 1] - err[i])
            return float(ms[i - 1] + f * (ms[i] - ms[i - 1]))
    return None


def compare(policies: dict[str, Any]) -> dict[str, Any]:
    if BASELINE not in policies:
        return {}
    base = policies[BASELINE]
    longest = max(base, key=float)
    out = {"baseline": BASELINE, "minutes": float(longest)}
    for pol, cells in policies.items():
        c: dict[str, Any] = {}
        if longest in cells:
            for k in ("vx_rel", "vy_rel", "vth_rel", "vel_rel_mean", "sensor_rms_px"):
                c[f"{k}_change"] = cells[longest][k]["mean"] / base[longest][k]["mean"] - 1
        c["minutes_to_baseline_accuracy"] = minutes_to_reach(cells, base[longest]["vel_rel_mean"]["mean"])
        out[pol] = c
    ranked = sorted((p for p in policies if longest in policies[p]),
                    key=lambda p: policies[p][longest]["vel_rel_mean"]["mean"])
    out["best"] = ranked[0] if ranked else None
    return out


def table(summary: dict[str, Any]) -> str:
    """A Markdown table: mean +- std over seeds per policy and length."""
    head = ("| policy | min | runs | vx | vy | vtheta | mean vel | sensor px | held-out loglik/sighting | iterations | "
            "frames seen | commands |")
    lines = [head, "|" + "---|" * 12]
    for pol, cells in summary["policies"].items():
        for m, c in cells.items():
            def pct(k):
                return f"{100 * c[k]['mean']:.2f} ± {100 * c[k]['std']:.2f}%"
            held = c.get("heldout_loglik")
            lines.append(f"| {pol} | {m} | {c['n']} | {pct('vx_rel')} | {pct('vy_rel')} | {pct('vth_rel')} | "
                         f"{pct('vel_rel_mean')} | {c['sensor_rms_px']['mean']:.3f} ± {c['sensor_rms_px']['std']:.3f} | "
                         + (f"{held['mean']:.3f} ± {held['std']:.3f}" if held else "-")
                         + f" | {c['iterations']['mean']:.0f} | {100 * c['seen_share']['mean']:.0f}% | "
                         f"{c['commands_used']['mean']:.1f} |")
    return "\n".join(lines)


def verdict(summary: dict[str, Any]) -> list[str]:
    comp = summary.get("comparison") or {}
    if not comp:
        return []
    m = comp["minutes"]
    lines = [f"against {comp['baseline']} at {m:g} min (mean of vx, vy, vtheta relative errors):"]
    for pol, c in comp.items():
        if not isinstance(c, dict) or pol == comp["baseline"]:
            continue
        reach = c["minutes_to_baseline_accuracy"]
        when = "never within the lengths run" if reach is None else f"at {reach:.1f} min"
        lines.append(f"  {pol:24s} {100 * c.get('vel_rel_mean_change', math.nan):+6.1f}% velocity error at {m:g} min "
                     f"(vx {100 * c.get('vx_rel_change', math.nan):+.1f}%, vy {100 * c.get('vy_rel_change', math.nan):+.1f}%, "
                     f"vtheta {100 * c.get('vth_rel_change', math.nan):+.1f}%); reaches the baseline's {m:g}-min accuracy {when}")
    lines.append(f"best at {m:g} min: {comp['best']}")
    return lines


def plot(summary: dict[str, Any], path: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("vx_rel", "vx error / range", 100, True), ("vy_rel", "vy error / range", 100, True),
              ("vth_rel", "vtheta error / range", 100, True), ("sensor_rms_px", "sensor RMS (px)", 1, True),
              ("heldout_loglik", "held-out loglik per sighting", 1, False),
              ("seen_share", "frames with a sighting", 100, False)]
    fig, axes = plt.subplots(2, 3, figsize=(13, 7))
    for ax, (key, title, scale, log) in zip(axes.ravel(), panels):
        for pol, cells in summary["policies"].items():
            ms = sorted((m for m in cells if key in cells[m]), key=float)
            if not ms:
                continue
            x = np.array([float(m) for m in ms])
            y = np.array([cells[m][key]["median"] for m in ms]) * scale
            lo = y - np.array([cells[m][key]["min"] for m in ms]) * scale
            hi = np.array([cells[m][key]["max"] for m in ms]) * scale - y
            ax.errorbar(x, y, yerr=[lo, hi], marker="o", capsize=3, label=pol, alpha=0.85)
        ax.set_title(title + (" (%)" if scale == 100 else ""))
        if log:
            ax.set_yscale("log")
        ax.set_xlabel("minutes of data")
        ax.grid(alpha=0.3, which="both")
    axes[0, 0].legend(fontsize=8)
    n = max((c["n"] for cells in summary["policies"].values() for c in cells.values()), default=0)
    fig.suptitle(f"EM accuracy vs robot time per exploration policy (median, bars min to max, over {n} seeds)")
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=90))
    plt.close(fig)


def write_summary(out_dir: str | Path, records: list[dict]) -> dict[str, Any]:
    summary = summarize(records)
    write_json(Path(out_dir) / "summary.json", summary)  # NaN -> null: always valid JSON
    return summary
