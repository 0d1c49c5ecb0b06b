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
    """Seconds to import and run the compiled E-step and M-step once (numba compiles them)."""
    from aibo_core.actions import attempted_velocities
    from aibo_core.trajectory import Trajectory
    from learners.arrays.batch import make_batch
    from learners.model.model import start_model

    n = 100
    tr = Trajectory(1 / 30, np.array([[1350.0, 1950.0]]), np.arange(n), np.zeros(n, np.int64),
                    np.tile([20.0, 0.5], (n, 1)), actions=np.zeros(n, np.int64), attempted=attempted_velocities())
    batch = make_batch([tr])
    t0 = time.perf_counter()
    from learners.em.estep import e_step
    from learners.em.fit import m_step
    from learners.em.options import EMOptions

    params = start_model(batch, tr.dt)
    for method in ("cubature", "sample"):
        m_step(params, batch, e_step(params, batch, "compiled"), np.random.default_rng(0),
               EMOptions(sensor_method=method))
    return {"compile_s": time.perf_counter() - t0}


def scale_cmd(path: str, n: int) -> dict:
    """Time one E-step and one M-step on the first ``n`` frames; peak memory of the batch, the
    posterior and the M-step (NumPy allocations, traced with tracemalloc; the kernels allocate
    nothing large themselves)."""
    import tracemalloc

    from aibo_core import trajectory
    from learners.arrays.batch import make_batch
    from learners.em.estep import e_step
    from learners.em.fit import m_step
    from learners.em.options import EMOptions
    from learners.model.model import start_model

    full = trajectory.load(path)
    if n > full.n_frames:
        raise SystemExit(f"{path} has only {full.n_frames} frames")
    tr, small = trajectory.head(full, n), make_batch([trajectory.head(full, min(n, 500))])
    del full
    params, opts, rng = start_model(small, tr.dt), EMOptions(), np.random.default_rng(0)
    m_step(params, small, e_step(params, small, "compiled"), rng, opts)  # load the kernels first
    tracemalloc.start()
    batch = make_batch([tr])
    t0 = time.perf_counter()
    post = e_step(params, batch, "compiled")
    t1 = time.perf_counter()
    m_step(params, batch, post, rng, opts)
    t2 = time.perf_counter()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    t3 = time.perf_counter()
    e_step(params, batch, "compiled", reuse=post)  # steady state inside EM: memory already paged in
    t4 = time.perf_counter()
    m_step(params, batch, post, rng, opts)
    t5 = time.perf_counter()
    return {"frames": n, "estep_s": t1 - t0, "mstep_s": t2 - t1, "estep_reuse_s": t4 - t3, "mstep_again_s": t5 - t4,
            "peak_mb": peak / 2**20, "bytes_per_frame": peak / n, "max_rss_mb": _peak_bytes() / 2**20}


def main() -> None:
    cmd = sys.argv[1]
    out = compile_cmd() if cmd == "compile" else scale_cmd(sys.argv[2], int(sys.argv[3]))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
