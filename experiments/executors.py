"""Running many :class:`~experiments.run.RunSpec` s: serial, a local process pool, or Ray.

``run_all(specs, out_dir, backend="pool", jobs=None, address=None)`` skips the specs whose record
is already in ``out_dir`` (an interrupted sweep resumes; nothing finished is lost or redone), runs
the rest, and after each completed run rewrites ``out_dir/results.jsonl`` atomically (one record
per line, in the order of ``specs``). A run is deterministic in its spec, so every backend gives
the same records (``timing`` aside) at the same BLAS thread count (the workers' is 1; a serial run
with more threads differs in the last bits of the information matrix's eigenvalues).

* ``serial``: in this process;
* ``pool``: ``concurrent.futures.ProcessPoolExecutor`` (spawned workers, ``OMP_NUM_THREADS=1``
  and the other BLAS thread counts set to 1 unless already set: on few cores the workers are the
  parallelism);
* ``ray``: ``ray.util.multiprocessing.Pool`` on a local Ray instance or the cluster at
  ``address`` (the optional extra ``ray``, imported only here); workers get the same thread
  settings and this checkout on ``PYTHONPATH`` through the runtime environment.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Iterable

from aibo_core.atomic import read_jsonl, write_jsonl
from experiments.run import RunSpec, load_record, run_json

BACKENDS = ("serial", "pool", "ray")
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


def worker_env() -> dict[str, str]:
    """Environment variables for worker processes: one BLAS/OpenMP thread each and no M-step second thread
    (``learners.em.second_thread``), unless set: the workers are the parallelism."""
    return {**{k: os.environ.get(k, "1") for k in THREAD_VARS}, "AIBO_SECOND_THREAD": os.environ.get("AIBO_SECOND_THREAD", "0")}


def write_results(out_dir: Path, records: list[dict[str, Any]]) -> None:
    write_jsonl(out_dir / "results.jsonl", records, sort_keys=True)


def read_results(out_dir: str | Path) -> list[dict[str, Any]]:
    return read_jsonl(Path(out_dir) / "results.jsonl")


def _pool_map(todo: list[dict], out: str, jobs: int) -> Iterable[dict]:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, wait

    from aibo_core.workers import process_pool

    os.environ.update(worker_env())  # spawned workers inherit it
    with process_pool(jobs, mp.get_context("spawn")) as ex:
        pending = {ex.submit(run_json, s, out) for s in todo}
        try:
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in done:
                    yield f.result()
        except BaseException:
            for f in pending:
                f.cancel()
            raise


def _ray_map(todo: list[dict], out: str, jobs: int | None, address: str | None) -> Iterable[dict]:
    try:
        import ray
        from ray.util.multiprocessing import Pool
    except ImportError:
        raise ValueError("--backend ray needs Ray (pip install -e '.[ray]')") from None
    root = str(Path(__file__).resolve().parents[1])
    env = {**worker_env(), "PYTHONPATH": os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])])}
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, runtime_env={"env_vars": env}, include_dashboard=False,
                 logging_level="ERROR", log_to_driver=False, **({} if address else {"num_cpus": jobs}))
    pool = Pool(processes=jobs)
    try:
        yield from pool.imap_unordered(_ray_task, [(s, out) for s in todo])
        pool.close()
        pool.join()
    except BaseException:
        pool.terminate()
        raise
    finally:
        if started:
            ray.shutdown()


def _ray_task(args):
    return run_json(*args)


def run_all(specs: list[RunSpec], out_dir: str | Path, backend: str = "pool", jobs: int | None = None,
            address: str | None = None, on_record: Callable[[dict, int, int], None] | None = None) -> list[dict]:
    """Run every spec not yet done in ``out_dir``; the records of all specs, in order of ``specs``."""
    if backend not in BACKENDS:
        raise ValueError(f"backend {backend!r} (valid choices: {', '.join(BACKENDS)})")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    specs = [s.normalized() for s in specs]
    ids = [s.run_id for s in specs]
    if len(set(ids)) != len(ids):
        raise ValueError("the sweep has the same run twice (identical specs)")
    found: dict[str, dict] = {}
    for s in specs:
        rec = load_record(out, s)
        if rec is not None:
            found[s.run_id] = rec
    todo = [s.to_json() for s in specs if s.run_id not in found]
    jobs = max(1, min(jobs or os.cpu_count() or 1, len(todo) or 1))

    def ordered() -> list[dict]:
        return [found[i] for i in ids if i in found]

    if not todo:
        write_results(out, ordered())
        return ordered()
    # results.jsonl is rewritten only once a run of this sweep completes: a sweep refused or failing
    # before then leaves an earlier sweep's results as they were
    if backend == "serial":
        stream: Iterable[dict] = (run_json(s, str(out)) for s in todo)
    elif backend == "pool":
        stream = _pool_map(todo, str(out), jobs)
    else:
        stream = _ray_map(todo, str(out), jobs, address)
    for rec in stream:
        found[rec["id"]] = rec
        write_results(out, ordered())
        if on_record is not None:
            on_record(rec, len(found), len(specs))
    return ordered()
