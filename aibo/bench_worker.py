"""Measurements that ``aibo bench`` runs in a fresh process (compile time, per-size peak memory).

    python -m aibo.bench_worker compile
    python -m aibo.bench_worker scale LOG.npz N_FRAMES

Prints one JSON object on stdout.
"""

from __future__ import annotations

import json
import resource
import sys
import time

import numpy as np


def _peak_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB


def compile_cmd() -> dict:
    from learners.em.data import Batch
    from learners.em.params import paper_start

    n = 100
    batch = Batch(np.zeros(n, np.int64), np.full((n, 2), np.nan), np.full((n, 2), np.nan), np.zeros(n, bool),
                  np.array([0, n]), 1 / 30)
    t0 = time.perf_counter()
    from learners.em.kernels import action_statistics_compiled, smooth_compiled

    post = smooth_compiled(paper_start(1 / 30), batch)
    action_statistics_compiled(paper_start(1 / 30), batch, post)
    return {"compile_s": time.perf_counter() - t0}


def scale_cmd(path: str, n: int) -> dict:
    from aibo_gym import trajectory
    from learners.em.data import make_batch
    from learners.em.fit import EMOptions, e_step, m_step
    from learners.em.params import paper_start

    tr = trajectory.load(path)
    if n > tr.n_frames:
        raise SystemExit(f"{path} has only {tr.n_frames} frames")
    tr = trajectory.Trajectory(tr.dt, tr.actions[:n], tr.obs[:n], tr.beacon[:n], tr.head_pan[:n], tr.beacons,
                               tr.field, tr.attempted)
    batch = make_batch([tr])
    params = paper_start(tr.dt)
    e_step(params, make_batch([trajectory.Trajectory(tr.dt, tr.actions[:50], tr.obs[:50], tr.beacon[:50],
                                                     tr.head_pan[:50], tr.beacons, tr.field, tr.attempted)]),
           "compiled")  # load kernels before the baseline
    base = _peak_bytes()
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    post = e_step(params, batch, "compiled")
    t1 = time.perf_counter()
    m_step(params, batch, post, rng, EMOptions())
    t2 = time.perf_counter()
    peak = _peak_bytes() - base
    return {"frames": n, "estep_s": t1 - t0, "mstep_s": t2 - t1, "peak_mb": peak / 2**20, "bytes_per_frame": peak / n}


def main() -> None:
    cmd = sys.argv[1]
    out = compile_cmd() if cmd == "compile" else scale_cmd(sys.argv[2], int(sys.argv[3]))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
