"""``aibo bench``: speed of the E-step and of whole fits, measured in one run on this machine.

Figures (all also in ``--json``):
- E-step frames/s, compiled (numba) and the NumPy per-step reference, on the same 27,000-frame
  log in the same run, and their ratio;
- M-step time, compiled and NumPy reference, on the same E-step output;
- first-call compile time of the E-step and M-step kernels (a fresh process, empty numba cache);
- a paper-scale fit (27,000 frames, paper start, to convergence): iterations, time per iteration,
  wall time (compile excluded), final log-likelihood;
- scaling at 2,700 / 27,000 / 270,000 / 1,000,000 frames: E-step + M-step time and peak memory,
  each size in its own process so peak memory is that size's alone;
- bias states (``landmark_bias``, 4 states): the augmented E-step and its action statistics, compiled vs the
  NumPy reference on the same log in the same run;
- workflows, wall time as a user meets them: ``aibo learn`` with its defaults (starts, alias search, standard
  errors) on a 15-minute log (``--quick``: 5), in this process and as a command (a fresh process), and
  ``aibo diagnose`` with every candidate and its default replays on a
  10-minute log with a hidden 0.2 s actuation lag (``--quick``: 2 candidates, no replays).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from aibo_core import trajectory
from aibo_core.atomic import atomic_write

SIZES = (2_700, 27_000, 270_000, 1_000_000)
QUICK_SIZES = (2_700, 9_000)
PAPER_FRAMES = 27_000
QUICK_PAPER_FRAMES = 9_000  # --quick: a smoke test of the whole benchmark, not a measurement


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def machine() -> dict:
    return {"python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count(),
            "processor": platform.processor() or "unknown"}


def estep_speed(tr) -> dict:
    """Compiled vs NumPy reference E-step on the same log, after warm-up."""
    from learners.arrays.batch import make_batch
    from learners.inference.kernels import smooth_compiled
    from learners.inference.reference import smooth
    from learners.model.model import start_model

    batch = make_batch([tr])
    params = start_model(batch, tr.dt).lower(batch)
    smooth_compiled(params, batch)  # warm-up (numba compile or cache load)
    t_c = _median_time(lambda: smooth_compiled(params, batch), 7)
    spent = smooth_compiled(params, batch)
    t_reuse = _median_time(lambda: smooth_compiled(params, batch, out=spent), 21)  # as inside the EM loop
    t_np = _median_time(lambda: smooth(params, batch), 1)
    n = batch.n_frames
    return {"frames": n, "compiled_s": t_c, "compiled_reuse_s": t_reuse, "numpy_s": t_np,
            "compiled_frames_per_s": n / t_c, "numpy_frames_per_s": n / t_np, "speedup": t_np / t_c}


def mstep_speed(tr) -> dict:
    """Compiled vs NumPy reference M-step (default options) on the same E-step output."""
    from learners.arrays.batch import make_batch
    from learners.em.estep import e_step
    from learners.em.fit import m_step
    from learners.em.options import EMOptions
    from learners.model.model import start_model

    batch = make_batch([tr])
    params = start_model(batch, tr.dt)
    post = e_step(params, batch, "compiled")
    rng = np.random.default_rng(0)
    fast, ref = EMOptions(), EMOptions(estep="numpy")
    m_step(params, batch, post, rng, fast)  # warm-up
    t_c = _median_time(lambda: m_step(params, batch, post, rng, fast), 21)
    t_np = _median_time(lambda: m_step(params, batch, post, rng, ref), 3)
    return {"frames": batch.n_frames, "compiled_s": t_c, "numpy_s": t_np, "speedup": t_np / t_c}


def compile_time() -> float:
    """Seconds of the first E-step call in a fresh process with an empty numba cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        out = subprocess.run([sys.executable, "-m", "aibo.bench_worker", "compile"], env=env,
                             capture_output=True, text=True, check=True)
    return float(json.loads(out.stdout)["compile_s"])


def paper_fit(tr, opts) -> dict:
    """A full fit from the paper's start to convergence (compiled E-step already warm): EM's wall time and
    iterations (every start's), and apart the standard errors' time."""
    from experiments.loop import fit_em, score

    t0 = time.perf_counter()
    res = fit_em([tr], opts)
    se = res.info.get("uncertainty_seconds", 0.0)
    wall = time.perf_counter() - t0 - se
    err = score(res.params, [tr])
    its = res.info.get("iterations_all_starts", res.iterations)
    return {"options": dict(opts.__dict__), "iterations": its, "best_iteration": res.info["best_iteration"],
            "wall_s": wall, "per_iteration_ms": 1000 * wall / its, "standard_errors_s": se,
            "final_loglik": max(res.loglik), "errors": err}


def scaling(log_path: Path, sizes) -> list[dict]:
    rows = []
    for n in sizes:
        out = subprocess.run([sys.executable, "-m", "aibo.bench_worker", "scale", str(log_path), str(n)],
                             capture_output=True, text=True)
        if out.returncode != 0:
            rows.append({"frames": n, "error": out.stderr.strip().splitlines()[-1:]})
            continue
        row = json.loads(out.stdout)
        rows.append(row)
        print(f"  {n:>9,d} frames: E-step {1000 * row['estep_s']:8.1f} ms, M-step {1000 * row['mstep_s']:8.1f} ms "
              f"(again: {1000 * row['estep_reuse_s']:.1f} + {1000 * row['mstep_again_s']:.1f} ms), "
              f"peak {row['peak_mb']:.1f} MB ({row['bytes_per_frame']:.0f} B/frame), process max RSS {row['max_rss_mb']:.0f} MB",
              flush=True)
    return rows


def bias_states_speed(frames: int) -> dict:
    """The augmented E-step (pose + 4 bias states) and its action statistics on a simulated log with a landmark
    bias, compiled vs the NumPy reference, in the same run (the E-step's reference once: it is slow)."""
    from experiments.loop import simulate
    from learners.arrays.batch import make_batch
    from learners.em.estep import e_step
    from learners.inference.augmented import displacement_statistics, smooth_augmented
    from learners.inference.kernels.augmented_stats import displacement_statistics_compiled
    from learners.model.landmark_bias import LandmarkBias
    from learners.model.model import start_model

    tr = simulate({"noise": "aibo", "effects": {"landmark_bias": {"sigma_rel": 0.05, "tau_s": 8.0}}}, frames, 3)
    batch = make_batch([tr])
    model = start_model(batch, tr.dt).with_effect(LandmarkBias(0.05, 8.0))
    lo = model.lower(batch)
    post = e_step(model, batch, "compiled", lo=lo)  # warm-up (compile or cache load)
    displacement_statistics_compiled(lo, batch, post, True)
    t_e = _median_time(lambda: e_step(model, batch, "compiled", lo=lo), 7)
    t_e_np = _median_time(lambda: smooth_augmented(lo, batch), 1)
    t_d = _median_time(lambda: displacement_statistics_compiled(lo, batch, post, True), 7)
    t_d_np = _median_time(lambda: displacement_statistics(lo, batch, post, True), 3)
    return {"frames": batch.n_frames, "states": lo.extra.k, "estep_compiled_s": t_e, "estep_numpy_s": t_e_np,
            "estep_speedup": t_e_np / t_e, "action_stats_compiled_s": t_d, "action_stats_numpy_s": t_d_np,
            "action_stats_speedup": t_d_np / t_d}


@contextlib.contextmanager
def _silenced():
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        yield


def _command_seconds(argv: list[str]) -> float:
    """Wall time (s) of ``python -m aibo.cli ARGV`` in a fresh process: imports, the kernels' cache load and all."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "aibo.cli", *argv], check=True, capture_output=True)
    return time.perf_counter() - t0


def workflows(quick: bool) -> dict:
    """Wall time of ``aibo learn`` and ``aibo diagnose`` run as a user runs them (in this process, compiled
    kernels warm), with what they found; ``aibo learn`` also as a command (a fresh process: what its start-up
    costs, the imports and the compiled kernels' cache load)."""
    from aibo.cli import main
    from aibo_core.trajectory import blind
    from experiments.loop import simulate

    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        log, lag_log = Path(tmp) / "learn.npz", Path(tmp) / "diagnose.npz"
        minutes = 5 if quick else 15
        trajectory.save(simulate({"noise": "paper-sim"}, minutes * 1800, 1), log)
        t0 = time.perf_counter()
        with _silenced():  # their own reports and progress: the bench prints its figures
            main(["learn", str(log), "--out", str(Path(tmp) / "m.json")])
        out["learn"] = {"minutes": minutes, "wall_s": time.perf_counter() - t0,
                        "command_wall_s": _command_seconds(["learn", str(log), "--out", str(Path(tmp) / "c.json")])}
        minutes = 10  # as the tests of the search (tests/test_discrepancy.py): a 0.2 s lag, seed 11
        cfg = {"noise": "aibo", "effects": {"actuation_lag": {"lag_s": 0.2}}}
        trajectory.save(blind(simulate(cfg, minutes * 1800, 11)), lag_log)
        extra = ["--candidates", "actuation_lag,floor_drift", "--replicas", "0"] if quick else []
        t0 = time.perf_counter()
        with _silenced():
            main(["diagnose", str(lag_log), "--out", str(Path(tmp) / "d"), *extra])
        report = json.loads((Path(tmp) / "d" / "report.json").read_text())
        slowest = max(report["candidates"], key=lambda c: c["seconds"], default=None)
        out["diagnose"] = {"minutes": minutes, "hidden": "actuation_lag 0.2 s", "wall_s": time.perf_counter() - t0,
                           "named": [e["name"] for e in report["effects"]], "quick": quick,
                           "seconds_by_stage": report["seconds_by_stage"],
                           "slowest_candidate": None if slowest is None else
                           {"name": slowest["name"], "round": slowest["round"], "seconds": slowest["seconds"]}}
    return out


def run(args) -> int:
    from aibo.paths import check_files, declared_inputs
    from experiments.loop import simulate

    check_files(declared_inputs(args), [("--json", args.json)] if args.json else [])

    sizes = QUICK_SIZES if args.quick else SIZES
    paper_frames = QUICK_PAPER_FRAMES if args.quick else PAPER_FRAMES
    report: dict = {"machine": machine(), "quick": bool(args.quick)}
    print(f"machine: {report['machine']}")
    print(f"simulating {max(sizes):,d} frames for the benchmark logs ...", flush=True)
    t0 = time.perf_counter()
    big = simulate({"noise": "paper-sim", "max_steps": max(sizes)}, max(sizes), 7)
    report["collect_frames_per_s"] = big.n_frames / (time.perf_counter() - t0)
    paper = simulate({"noise": "paper-sim"}, paper_frames, 1)

    print(f"E-step, compiled vs NumPy reference ({paper_frames:,d} frames) ...", flush=True)
    report["estep"] = estep_speed(paper)
    e = report["estep"]
    print(f"  compiled {1000 * e['compiled_s']:.1f} ms ({e['compiled_frames_per_s']:,.0f} frames/s; "
          f"{1000 * e['compiled_reuse_s']:.1f} ms reusing its buffers as EM does), "
          f"NumPy {1000 * e['numpy_s']:.0f} ms ({e['numpy_frames_per_s']:,.0f} frames/s): {e['speedup']:.0f}x")
    report["mstep"] = m = mstep_speed(paper)
    print(f"M-step (default options): compiled {1000 * m['compiled_s']:.1f} ms, NumPy {1000 * m['numpy_s']:.0f} ms: "
          f"{m['speedup']:.0f}x")
    report["compile_s"] = compile_time()
    print(f"  first-call compile time {report['compile_s']:.1f} s")

    print(f"fits ({paper_frames:,d} frames, paper start, to convergence) ...", flush=True)
    from learners.em.options import EMOptions

    variants = {"default": EMOptions()} if args.quick else {
        "default": EMOptions(),
        "paper_recipe": EMOptions.paper(),
        "default_without_squarem": EMOptions(accel="none"),
        "learned_noise_sampled_plain": EMOptions.paper(learn_motion_noise=True),
    }
    report["fits"] = {}
    for name, opts in variants.items():
        fit = paper_fit(paper, opts)
        report["fits"][name] = fit
        print(f"  {name:14s} {fit['iterations']:5d} iterations, {fit['per_iteration_ms']:.1f} ms/iteration, "
              f"{fit['wall_s']:.2f} s, loglik {fit['final_loglik']:.1f}, vx/vy {fit['errors']['vx_rel']:.2%}/"
              f"{fit['errors']['vy_rel']:.2%}", flush=True)

    print("bias states (landmark_bias, 4 states), compiled vs NumPy reference ...", flush=True)
    report["bias_states"] = b = bias_states_speed(paper_frames)
    print(f"  E-step {1000 * b['estep_compiled_s']:.1f} ms vs {1000 * b['estep_numpy_s']:.0f} ms "
          f"({b['estep_speedup']:.0f}x); action statistics {1000 * b['action_stats_compiled_s']:.1f} ms vs "
          f"{1000 * b['action_stats_numpy_s']:.0f} ms ({b['action_stats_speedup']:.1f}x)", flush=True)
    print("workflows (as a user runs them) ...", flush=True)
    report["workflows"] = w = workflows(args.quick)
    print(f"  aibo learn, {w['learn']['minutes']}-minute log, defaults: {w['learn']['wall_s']:.1f} s in process, "
          f"{w['learn']['command_wall_s']:.1f} s as a command ({w['learn']['command_wall_s'] / w['learn']['wall_s']:.1f}x: "
          f"imports and the kernels' cache load); aibo diagnose, "
          f"{w['diagnose']['minutes']}-minute log: {w['diagnose']['wall_s']:.1f} s (named: "
          f"{', '.join(w['diagnose']['named']) or 'none'})", flush=True)
    d = w["diagnose"]
    stages = ", ".join(f"{k} {v:.1f} s" for k, v in d["seconds_by_stage"].items())
    slowest = d["slowest_candidate"]
    print(f"    its stages: {stages}" + (f"; the slowest candidate {slowest['name']} (round {slowest['round']}) "
                                         f"{slowest['seconds']:.1f} s" if slowest else ""), flush=True)

    print("scaling (each size in its own process) ...", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.npz"
        trajectory.save(big, path)
        report["scaling"] = scaling(path, sizes)
    if args.json:
        text = json.dumps(report, indent=1)
        atomic_write(args.json, lambda f: f.write(text.encode()))
        print(f"wrote {args.json}")
    return 0
