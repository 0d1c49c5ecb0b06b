"""Time the EM M-step (learners.em.fit.m_step) on one 27,000-frame paper-sim log: the fused compiled
path (``estep="compiled"``: kernels.action_update_compiled / sensor_update_compiled) against the
previous compiled path (update_action_model with action_statistics_compiled, update_sensor_model
with sensor_points_fast) and the NumPy reference (``estep="numpy"``).

    python scripts/bench_mstep.py [--frames 27000] [--repeat 30] [--ref-repeat 3] [--em-iters 3]

The posterior is that of the compiled E-step after ``--em-iters`` reference EM iterations from the
paper's start (so the models are not degenerate). Prints the best-of-N time of each path for both
sensor methods and learn_motion_noise on/off, the E-step time for scale, and the largest relative
difference of the new path's parameters from the reference.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from aibo_gym.collect import collect
from learners.em.action_mstep import update_action_model
from learners.em.data import make_batch
from learners.em.fit import EMOptions, m_step
from learners.em.kernels import action_statistics_compiled, sensor_points_fast, smooth_compiled
from learners.em.params import InitialState, Params, paper_start
from learners.em.sensor_mstep import update_sensor_model


def old_compiled_m_step(params, batch, post, rng, opts):
    """The compiled M-step as it was before the fused kernels (for timing only)."""
    action = update_action_model(params, batch, post, learn_noise=opts.learn_motion_noise,
                                 statistics=action_statistics_compiled)  # fmt: skip
    sensor = update_sensor_model(params, batch, post, rng, method=opts.sensor_method, n_samples=opts.n_samples,
                                 degree=opts.degree, points=sensor_points_fast)  # fmt: skip
    init = tuple(InitialState(post.mu_gamma[p].copy(), post.cov_gamma[p].copy()) for p in batch.pose_start[:-1])
    return Params(action, sensor, init)


def _best_of(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _max_rel(a: Params, b: Params) -> float:
    pairs = [(a.action.disp, b.action.disp), (a.action.cov, b.action.cov), (a.sensor.coef, b.sensor.coef),
             (a.sensor.sigma_height, b.sensor.sigma_height), (a.sensor.sigma_angle, b.sensor.sigma_angle),
             (a.sensor.distance_range_mm, b.sensor.distance_range_mm)]  # fmt: skip
    out = 0.0
    for x, y in pairs:
        x, y = np.asarray(x, float), np.asarray(y, float)
        scale = np.maximum(np.abs(y), 1e-12 * max(1.0, float(np.abs(y).max())))
        out = max(out, float(np.max(np.abs(x - y) / scale)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=27000)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--ref-repeat", type=int, default=3)
    ap.add_argument("--em-iters", type=int, default=3)
    args = ap.parse_args()

    tr = collect({"noise": "paper-sim"}, steps=args.frames, seed=1)
    batch = make_batch([tr])
    params = paper_start(tr.dt)
    post = smooth_compiled(params, batch)
    for it in range(args.em_iters):
        params = m_step(params, batch, post, np.random.default_rng(it),
                        EMOptions(estep="numpy", sensor_method="cubature", learn_motion_noise=True))  # fmt: skip
        post = smooth_compiled(params, batch)
    print(f"log: {batch.n_frames} frames, {int(batch.used.sum())} used sightings")
    t = time.perf_counter()
    m_step(params, batch, post, np.random.default_rng(0), EMOptions())
    print(f"first compiled m_step (compile or cache load): {(time.perf_counter() - t) * 1e3:.0f} ms")
    t_e = _best_of(lambda: smooth_compiled(params, batch), args.repeat)
    print(f"E-step smooth_compiled: {t_e * 1e3:.2f} ms (best of {args.repeat})")
    print(f"{'method':9s} {'learn':5s} {'new':>9s} {'old':>9s} {'numpy':>9s} {'old/new':>8s}  max rel diff new vs numpy")
    for method in ("cubature", "sample"):
        for learn in (True, False):
            opts = EMOptions(sensor_method=method, learn_motion_noise=learn)
            ref_opts = replace(opts, estep="numpy")
            rng = np.random.default_rng(0)
            old_compiled_m_step(params, batch, post, rng, opts)
            t_new = _best_of(lambda: m_step(params, batch, post, rng, opts), args.repeat)
            t_old = _best_of(lambda: old_compiled_m_step(params, batch, post, rng, opts), args.repeat)
            t_ref = _best_of(lambda: m_step(params, batch, post, rng, ref_opts), args.ref_repeat)
            diff = _max_rel(m_step(params, batch, post, np.random.default_rng(1), opts),
                            m_step(params, batch, post, np.random.default_rng(1), ref_opts))  # fmt: skip
            print(f"{method:9s} {str(learn):5s} {t_new * 1e3:7.2f}ms {t_old * 1e3:7.2f}ms {t_ref * 1e3:7.2f}ms "
                  f"{t_old / t_new:7.1f}x  {diff:.1e}")  # fmt: skip


if __name__ == "__main__":
    main()
