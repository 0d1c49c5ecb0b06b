"""The causes of the biases ``scripts/calibration.py`` measured (docs/results.md, "The named effects' estimates against
the truth"), each from logs of that study's seeds or fresh ones, every number reproducible from its command:

    python scripts/calibration_causes.py tau-alone [--replicates 30]   # the Gauss-Markov MLE alone: is tau_s biased?
    python scripts/calibration_causes.py tau-em                         # EM alone stops on a ridge; the polish
    python scripts/calibration_causes.py shrink                         # off_center_shrink: errors in the bearing
    python scripts/calibration_causes.py rate                           # false_sightings: the final fit's iterations
    python scripts/calibration_causes.py sigma-short                    # landmark_bias: sigma_rel short on 5 minutes
    python scripts/calibration_causes.py share --out runs/calibration   # false_sightings: the rate or the log's share?

- ``tau-alone``: landmark_bias's process b_l (sigma_rel 0.05, tau_s 8 s) drawn anew at the sighting frames of the
  study's `aibo` logs 0, 2, 4 (seeds 8000, 8002, 8004), observed as b + e with each sighting's relative size noise
  (sigma_height / its true size), and (sigma_rel, tau_s) fitted by exact maximum likelihood (a scalar Kalman filter
  per landmark): the estimator with the pose and the sensor curve known.
- ``tau-em``: the study's search on `aibo` logs 0, 2, 4, 6, then from the search's model EM alone on the whole log
  (the final fit's options without its polish), the same with the strict stop rule (patience 50, at most 600
  iterations), and the final fit with its polish.
- ``shrink``: k = 0.8 on `aibo` logs of seeds 9100-9103, with the preset's bearing noise and with sigma_angle 0.002
  rad, against the attenuation that regressing the size's shrink on the observed phi^2 instead of the true one
  predicts (weighted by the true size squared, centered: the curve takes a constant factor); and that attenuation on
  the study's `paper-sim` logs 1, 3, 5.
- ``sigma-short``: landmark_bias's sigma_rel on `aibo` logs of 5 and 15 minutes (seeds of the study's even logs;
  ``--preset paper-sim --seeds 8001,8003,... --minutes 5``: its odd ones), from the final fit at the likelihood's
  maximum, after the restricted likelihood's step (``learners.em.restricted.restricted_step``, what `aibo diagnose`
  states by default) and from the maximum likelihood fit with the 40 commands' velocities held at the truth: is the
  shortfall the velocities' (fitted from the same sightings, they take part of the bias's path, as fixed effects
  take part of a variance component's in maximum likelihood), does it fall with the log's length, and does the step
  remove it?
- ``share``: ``false_sightings``' intervals in a calibration study's rows against each log's own share of spurious
  sightings (the simulator's truth, the log made again from its seed), beside the rate simulated.
- ``rate``: the final fit's iterations (log-likelihood, rate) on the study's logs 0, 4, 6 (`aibo`) and 7
  (`paper-sim`), as diagnose runs it, without its first-iteration gate, and without SQUAREM.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one BLAS thread, as the command (aibo/__init__.py)
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from aibo_core.trajectory import blind  # noqa: E402
from aibo_gym.collect import collect  # noqa: E402

STEPS = 9000
BIAS = {"sigma_rel": 0.05, "tau_s": 8.0}


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _geometry(tr) -> tuple[np.ndarray, np.ndarray]:
    """(true distance mm, true bearing rad in the robot frame) of each sighting (its frame's end pose)."""
    f, lm = tr.sighting_frame, tr.landmarks[tr.sighting_landmark]
    p = tr.pose[f + 1]
    return (np.hypot(lm[:, 0] - p[:, 0], lm[:, 1] - p[:, 1]),
            np.arctan2(lm[:, 1] - p[:, 1], lm[:, 0] - p[:, 0]) - p[:, 2])


def _search(tr, effect: str):
    from learners.discrepancy.search import search
    from learners.em.options import EMOptions

    # as scripts/calibration.py and aibo diagnose, the variances at the likelihood's maximum: the causes below are of
    # the maximum likelihood fit (sigma-short steps it to the restricted likelihood's itself)
    opts = EMOptions(seed=0, lag_search=False, restricted_variances=False)
    return search([blind(tr)], [effect], opts, jobs=1, progress=lambda s: None), opts


def gauss_markov_nll(params: np.ndarray, data: list, dt: float) -> float:
    """Negative log-likelihood of (log sigma_rel, log tau_s) for ``data``: per landmark (frames, y, noise variances)."""
    s, tau = math.exp(params[0]), math.exp(params[1])
    out = 0.0
    for frames, y, r in data:
        phis = np.exp(-np.diff(frames) * dt / tau)
        m, p = 0.0, s * s
        for i in range(len(y)):
            if i:
                ph = phis[i - 1]
                m, p = ph * m, ph * ph * p + s * s * (1 - ph * ph)
            S = p + r[i]
            v = y[i] - m
            out += 0.5 * (math.log(2 * math.pi * S) + v * v / S)
            m, p = m + p / S * v, (1 - p / S) * p
    return out


def tau_alone(replicates: int) -> None:
    from scipy.optimize import minimize

    rng = np.random.default_rng(0)
    fits = []
    for seed in (8000, 8002, 8004):
        tr = collect({"noise": "aibo", "effects": {"landmark_bias": BIAS}}, STEPS, seed=seed)
        truth = tr.meta["truth"]
        d, _ = _geometry(tr)
        rel_var = (truth["sigma_height"] / (truth["sensor"]["height_px_mm"] / d)) ** 2
        phi = math.exp(-tr.dt / BIAS["tau_s"])
        for _ in range(replicates):
            data = []
            for lm in range(len(tr.landmarks)):
                sel = np.flatnonzero(tr.sighting_landmark == lm)
                fr = tr.sighting_frame[sel]
                w = BIAS["sigma_rel"] * math.sqrt(1 - phi * phi) * rng.standard_normal(fr[-1] - fr[0] + 1)
                b = np.empty(len(w))
                b[0] = BIAS["sigma_rel"] * rng.standard_normal()
                for i in range(1, len(b)):
                    b[i] = phi * b[i - 1] + w[i]
                data.append((fr, b[fr - fr[0]] + np.sqrt(rel_var[sel]) * rng.standard_normal(len(sel)), rel_var[sel]))
            res = minimize(gauss_markov_nll, [math.log(BIAS["sigma_rel"]), math.log(BIAS["tau_s"])], args=(data, tr.dt),
                           method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-4})
            fits.append([seed, *np.exp(res.x)])
        f = np.array([x for x in fits if x[0] == seed])
        print(f"seed {seed}: {tr.n_sightings} sightings, median relative noise {np.median(np.sqrt(rel_var)):.3f}; "
              f"sigma_rel {f[:, 1].mean():.4f}, tau_s mean {f[:, 2].mean():.2f} s (sd {f[:, 2].std(ddof=1):.2f})")
    f = np.array(fits)
    print(f"all {len(f)}: tau_s {f[:, 2].mean():.2f} +- {f[:, 2].std(ddof=1) / math.sqrt(len(f)):.2f} s, "
          f"sigma_rel {f[:, 1].mean():.4f} +- {f[:, 1].std(ddof=1) / math.sqrt(len(f)):.4f} (truth 8 s, 0.05)")


def tau_em() -> None:
    """The table of docs/results.md's first calibration cause: from the search's model, EM alone on the whole log (the
    final fit's options without the polish: the search's stop rule), EM alone with the strict stop rule (patience 50,
    at most 600 iterations) and the final fit with the polish (``EMOptions.polish``, the final fit's default)."""
    from learners.discrepancy.final import final_options
    from learners.discrepancy.fitting import train_loglik
    from learners.em.learner import EMLearner

    print("| log (seed) | warm start | named (training half) | EM alone: iterations, sigma_rel, tau_s | "
          "patience 50: iterations, sigma_rel, tau_s | gain (nats) | with the polish: sigma_rel, tau_s |\n"
          "|---|---|---|---|---|---|---|")
    for seed in (8000, 8002, 8004, 8006):
        found, opts = _search(collect({"noise": "aibo", "effects": {"landmark_bias": BIAS}}, STEPS, seed=seed),
                              "landmark_bias")
        c, logs, fopts = found["named"][0], found["logs"], replace(final_options(opts), uncertainty=False)
        alone, strict, polished = (EMLearner(o, check_field=False).fit(logs, init=found["model"]) for o in (
            replace(fopts, polish=False), replace(fopts, polish=False, patience=50, max_iter=600), fopts))
        w, e, s, p = (c.start.effect("landmark_bias"), *(f.params.effect("landmark_bias")
                                                         for f in (alone, strict, polished)))
        print(f"| {seed - 8000} ({seed}) | {w.sigma_rel:.2f}, {w.tau_s:.0f} s | {c.parameters['sigma_rel']:.4f}, "
              f"{c.parameters['tau_s']:.1f} s | {len(alone.history)}, {e.sigma_rel:.4f}, {e.tau_s:.2f} s | "
              f"{len(strict.history)}, {s.sigma_rel:.4f}, {s.tau_s:.2f} s | "
              f"{train_loglik(strict.params, logs) - train_loglik(alone.params, logs):+.1f} | "
              f"{p.sigma_rel:.4f}, {p.tau_s:.2f} s |", flush=True)


def attenuation(tr) -> float:
    """The factor by which regressing the size's shrink on the observed phi^2 (phi = bearing - head pan) instead of the
    true one shrinks k: cov(phi_obs^2, phi_true^2) / var(phi_obs^2), weighted by the true size squared, centered."""
    d, bearing = _geometry(tr)
    pan = tr.head_pan[tr.sighting_frame]
    true2, obs2 = _wrap(bearing - pan) ** 2, _wrap(tr.sighting_value[:, 1] - pan) ** 2
    w = d ** -2.0

    def c(x):
        return x - np.average(x, weights=w)

    return float(np.average(c(obs2) * c(true2), weights=w) / np.average(c(obs2) ** 2, weights=w))


def shrink() -> None:
    from learners.discrepancy.final import diagnosed

    k = 0.8
    for sigma_angle in (None, 0.002):
        for seed in (9100, 9101, 9102, 9103):
            cfg = {"noise": "aibo", "effects": {"off_center_shrink": {"k": k}}}
            if sigma_angle is not None:
                cfg["sigma_angle"] = sigma_angle
            tr = collect(cfg, STEPS, seed=seed)
            found, opts = _search(tr, "off_center_shrink")
            iv = diagnosed(found, opts).effects[0]["intervals"]["k"]
            print(f"aibo, sigma_angle {sigma_angle or 'of the preset'}, seed {seed}: k {iv['value']:.4f} "
                  f"[{iv['interval_95'][0]:.4f}, {iv['interval_95'][1]:.4f}] (se {iv['se']:.4f}); k / truth "
                  f"{iv['value'] / k:.3f}; predicted attenuation {attenuation(tr):.3f}", flush=True)
    for seed in (8001, 8003, 8005):
        tr = collect({"noise": "paper-sim", "effects": {"off_center_shrink": {"k": 0.1}}}, STEPS, seed=seed)
        print(f"paper-sim, seed {seed}: predicted attenuation {attenuation(tr):.3f}")


def rate() -> None:
    from learners.discrepancy.final import final_options
    from learners.discrepancy.fitting import train_loglik
    from learners.em.learner import EMLearner

    for seed, preset in ((8000, "aibo"), (8004, "aibo"), (8006, "aibo"), (8007, "paper-sim")):
        tr = collect({"noise": preset, "effects": {"false_sightings": {"rate": 0.08}}}, STEPS, seed=seed)
        found, opts = _search(tr, "false_sightings")
        c = found["named"][0]
        print(f"{preset} log {seed - 8000} (seed {seed}): {len(tr.meta['truth']['spurious_sightings'])} spurious of "
              f"{tr.n_sightings} sightings; named at rate {c.parameters['rate']:.4f}")
        fo = final_options(opts)
        for label, o in (("as diagnose", fo), ("no gate", replace(fo, gate=None)), ("no SQUAREM", replace(fo, accel="none"))):
            res = EMLearner(replace(o, uncertainty=False), check_field=False).fit(found["logs"], init=found["model"])
            hist = [(h.iteration, h.loglik, float(h.params.effect("false_sightings").rate)) for h in res.history]
            best = max(hist, key=lambda h: h[1])
            drops = [b[1] - a[1] for a, b in zip(hist, hist[1:])]
            print(f"  {label}: {res.pruned_observations} pruned, rate {res.params.effect('false_sightings').rate:.4f} "
                  f"(the best of {len(hist)} iterations, at iteration {best[0]}); the largest drop of the "
                  f"log-likelihood between iterations {min(drops):.0f} nats; ungated log-likelihood "
                  f"{train_loglik(res.params, found['logs']):.1f}; (iteration, rate) "
                  + ", ".join(f"({i}, {r:.3f})" for i, _, r in hist[:8]) + ", ...", flush=True)


def _held_velocities_fit(found, opts, final, true_weights: np.ndarray):
    """EM with the final fit's options from the diagnosed model ``final`` with the action weights held at
    ``true_weights`` (mm, mm, rad per frame): the table's M-step (``table_means_compiled``, the path of discrete
    commands) returns them instead of the regression; the rest (the motion noise, the curve, the bias) is fitted."""
    import learners.inference.kernels as kernels
    from learners.discrepancy.final import final_options
    from learners.em.learner import EMLearner

    calls, regress = [], kernels.table_means_compiled

    def held(commands, mu_star, weights):
        calls.append(1)
        return true_weights.copy()

    kernels.table_means_compiled = held
    try:
        start = final.with_(action=final.action.with_values(weights=true_weights.copy()))
        res = EMLearner(replace(final_options(opts), uncertainty=False), check_field=False).fit(found["logs"], init=start)
    finally:
        kernels.table_means_compiled = regress
    if not calls:
        raise RuntimeError("the action M-step did not take the table's path: the velocities were not held")
    return res


def sigma_short(seeds: list[int], preset: str = "aibo", lengths: tuple[int, ...] = (5, 15)) -> None:
    from learners.discrepancy.final import final_options, plausible_diagnosis
    from learners.em.restricted import restricted_step

    print("| seed | minutes | sigma_rel, tau_s: final fit (maximum likelihood) | restricted (``restricted_step``, the share "
          "of the Newton step taken) | velocities held at the truth | motion sd x, y (mm/frame; truth 3): final / held "
          "|\n|---|---|---|---|---|---|")
    for minutes in lengths:
        for seed in seeds:
            tr = collect({"noise": preset, "effects": {"landmark_bias": BIAS}}, minutes * 1800, seed=seed)
            found, opts = _search(blind(tr), "landmark_bias")
            if not found["named"]:
                print(f"| {seed} | {minutes} | not named | | | |")
                continue
            found, diagnosis = plausible_diagnosis(found, opts, progress=lambda s: None)  # as diagnose: both starts
            final = diagnosis.result.params
            stepped, record = restricted_step(final, found["logs"], final_options(opts))
            held = _held_velocities_fit(found, opts, final, np.asarray(tr.meta["truth"]["velocities"]) * tr.dt).params
            e, r, h = (m.effect("landmark_bias") for m in (final, stepped, held))
            sd = [np.sqrt(np.diag(m.action.cov))[:2] for m in (final, held)]
            print(f"| {seed} | {minutes} | {e.sigma_rel:.4f}, {e.tau_s:.1f} s | {r.sigma_rel:.4f}, {r.tau_s:.1f} s "
                  f"({record['length']:.2f}) | {h.sigma_rel:.4f}, {h.tau_s:.1f} s | {sd[0][0]:.2f}, {sd[0][1]:.2f} / "
                  f"{sd[1][0]:.2f}, {sd[1][1]:.2f} |")


def share(out: str) -> None:
    """``false_sightings``' intervals in the calibration rows of ``out`` against each log's own share of spurious
    sightings (the simulator's ``meta["truth"]["spurious_sightings"]``, the log made again from its seed)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from calibration import STRENGTH, all_rows, estimates

    rows = [r for r in all_rows(Path(out)) if r["effect"] == "false_sightings" and estimates(r) is not None]
    for preset in sorted({r["preset"] for r in rows}):
        diffs, ses, held_share, held_rate = [], [], 0, 0
        for r in (r for r in rows if r["preset"] == preset):
            tr = collect({"noise": preset, "effects": {"false_sightings": r["params"]}},
                         int(round(r["minutes"] * 60 * 30)), seed=r["seed"])
            own = len(tr.meta["truth"]["spurious_sightings"]) / tr.n_sightings
            iv = estimates(r)["rate"]
            lo, hi = iv["interval_95"]
            diffs.append(iv["value"] - own)
            ses.append(iv["se"])
            held_share += lo <= own <= hi
            held_rate += lo <= STRENGTH["false_sightings"]["rate"] <= hi
        n = len(diffs)
        print(f"{preset}: {n} logs named it; the interval holds the rate on {held_rate}, the log's own share on "
              f"{held_share}; estimate - share {np.mean(diffs):+.4f} (sd {np.std(diffs, ddof=1):.4f}, its mean's "
              f"+-{np.std(diffs, ddof=1) / np.sqrt(n):.4f}), mean SE {np.mean(ses):.4f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["tau-alone", "tau-em", "shrink", "rate", "sigma-short", "share"])
    ap.add_argument("--out", default="runs/calibration", help="share: the calibration study's folder")
    ap.add_argument("--replicates", type=int, default=30, help="tau-alone: draws of the process per log")
    ap.add_argument("--seeds", default="8000,8002,8004,8006,8008,8010,8012,8014,8016,8018",
                    help="sigma-short: the seeds (the calibration study's even logs are `aibo`, its odd ones `paper-sim`)")
    ap.add_argument("--preset", default="aibo", choices=["aibo", "paper-sim"], help="sigma-short: the noise preset")
    ap.add_argument("--minutes", default="5,15", help="sigma-short: the log lengths (minutes, comma-separated)")
    args = ap.parse_args()
    sys.stdout.reconfigure(line_buffering=True)
    {"tau-alone": lambda: tau_alone(args.replicates), "tau-em": tau_em, "shrink": shrink, "rate": rate,
     "sigma-short": lambda: sigma_short([int(s) for s in args.seeds.split(",")], args.preset,
                                         tuple(int(m) for m in args.minutes.split(","))),
     "share": lambda: share(args.out)}[args.what]()


if __name__ == "__main__":
    main()
