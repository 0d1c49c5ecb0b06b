"""Time the compiled E-step (learners.em.kernels.smooth_compiled) against the NumPy reference
(learners.em.smoother.smooth) on one synthetic 27,000-frame log (15 min at 30 Hz).

    python scripts/bench_estep.py [--frames 27000] [--repeat 20] [--ref-repeat 1] [--no-ref]

Prints the first-call time of the compiled kernels (numba compile, or a load from numba's
on-disk cache when it is warm), then frames/s of each implementation after warm-up and the ratio.
The synthetic log is simulated here (no env package): 40 actions held 5 s each, steered to stay
on a 5.4 m x 3.6 m field, a sighting of a random beacon in ~60% of frames.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from learners.em.data import Batch
from learners.em.params import N_ACTIONS, ActionModel, InitialState, Params, SensorModel

DT = 1.0 / 30.0
BEACONS = np.array([[-2900.0, -2000.0], [0.0, -2000.0], [2900.0, -2000.0],
                    [-2900.0, 2000.0], [0.0, 2000.0], [2900.0, 2000.0]])  # fmt: skip


def _wrap(a):
    return a - 2 * np.pi * np.ceil((a - np.pi) / (2 * np.pi))


def simulate(n: int, seed: int = 0) -> tuple[Params, Batch]:
    rng = np.random.default_rng(seed)
    disp = np.column_stack([rng.uniform(-12, 22, N_ACTIONS), rng.uniform(-8, 8, N_ACTIONS),
                            rng.uniform(-0.1, 0.1, N_ACTIONS)])  # fmt: skip
    seg = 150
    pose = np.zeros(3)
    actions = np.empty(n, np.int64)
    obs = np.full((n, 2), np.nan)
    bxy = np.full((n, 2), np.nan)
    a = 0
    for i in range(n):
        if i % seg == 0:
            # among 8 random actions, the one whose 1 s rollout ends nearest the centre
            best = np.inf
            for c in rng.integers(0, N_ACTIONS, 8):
                p = pose.copy()
                for _ in range(30):
                    th = p[2]
                    p = p + [math.cos(th) * disp[c, 0] - math.sin(th) * disp[c, 1],
                             math.sin(th) * disp[c, 0] + math.cos(th) * disp[c, 1], disp[c, 2]]  # fmt: skip
                dd = abs(p[0]) / 2200 + abs(p[1]) / 1400
                if dd < best:
                    best, a = dd, int(c)
        actions[i] = a
        u = disp[a] + rng.normal(0, [3.0, 3.0, 0.01])
        th = pose[2]
        pose = pose + [math.cos(th) * u[0] - math.sin(th) * u[1], math.sin(th) * u[0] + math.cos(th) * u[1], u[2]]
        if abs(pose[0]) > 2500 or abs(pose[1]) > 1700:  # keep inside (a wall)
            pose[:2] = np.clip(pose[:2], [-2500, -1700], [2500, 1700])
        if rng.random() < 0.6:
            b = int(rng.integers(0, len(BEACONS)))
            dx, dy = BEACONS[b] - pose[:2]
            d = math.hypot(dx, dy)
            bxy[i] = BEACONS[b]
            obs[i] = [57000.0 / d + rng.normal(0, 0.8), _wrap(math.atan2(dy, dx) - pose[2] + rng.normal(0, 0.03))]
    dgrid = np.linspace(900, 5500, 200)
    coef = np.polynomial.polynomial.polyfit(dgrid, 57000.0 / dgrid, 3)
    params = Params(
        ActionModel(disp, np.diag([10.0**2, 10.0**2, 0.1**2]), DT),
        SensorModel(coef, 1.0, 0.04),
        (InitialState(np.zeros(3), np.diag([100.0**2, 100.0**2, 0.1**2])),),
    )
    batch = Batch(actions, obs, bxy, ~np.isnan(obs).any(axis=1), np.array([0, n], np.int64), DT)
    return params, batch


def _best_of(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=27000)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--ref-repeat", type=int, default=1)
    ap.add_argument("--no-ref", action="store_true", help="skip the NumPy reference")
    args = ap.parse_args()

    params, batch = simulate(args.frames)
    n = batch.n_frames
    print(f"synthetic log: {n} frames, {int(batch.used.sum())} sightings")

    t = time.perf_counter()
    from learners.em.kernels import action_statistics_compiled, smooth_compiled

    t_import = time.perf_counter() - t
    t = time.perf_counter()
    post = smooth_compiled(params, batch)
    t_first = time.perf_counter() - t
    t = time.perf_counter()
    action_statistics_compiled(params, batch, post)
    t_first_act = time.perf_counter() - t
    print(f"first call (compile or cache load): smooth_compiled {t_first * 1e3:.0f} ms, "
          f"action_statistics_compiled {t_first_act * 1e3:.0f} ms (import {t_import * 1e3:.0f} ms)")  # fmt: skip

    t_c = _best_of(lambda: smooth_compiled(params, batch), args.repeat)
    t_a = _best_of(lambda: action_statistics_compiled(params, batch, post), args.repeat)
    print(f"compiled  smooth: {t_c * 1e3:8.2f} ms  {n / t_c:12,.0f} frames/s  (best of {args.repeat})")
    print(f"compiled  action_statistics: {t_a * 1e3:8.2f} ms  {n / t_a:12,.0f} frames/s")
    if args.no_ref:
        return
    from learners.em.smoother import smooth

    t_r = _best_of(lambda: smooth(params, batch), args.ref_repeat)
    print(f"reference smooth: {t_r * 1e3:8.2f} ms  {n / t_r:12,.0f} frames/s  (best of {args.ref_repeat})")
    print(f"ratio reference / compiled: {t_r / t_c:,.0f}x")
    try:
        from learners.em.action_mstep import action_statistics
    except ImportError:
        return
    t_ra = _best_of(lambda: action_statistics(params, batch, post), args.ref_repeat)
    print(f"reference action_statistics: {t_ra * 1e3:8.2f} ms  ratio {t_ra / t_a:,.0f}x")


if __name__ == "__main__":
    main()
