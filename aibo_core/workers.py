"""Worker processes that never outlive their parent.

A ``ProcessPoolExecutor`` worker waits on a pipe whose other end its siblings also hold, so when the
parent is killed (kill -9, the OOM killer) the workers wait forever, each holding its memory.
``process_pool`` gives every worker a watchdog thread (``exit_with_parent``) that ends the worker
within ``POLL_S`` seconds once its parent is gone. A thread rather than Linux's PR_SET_PDEATHSIG:
that signal fires when the *thread* that started the worker ends, which need not be the parent.
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable

#: Seconds between two checks of a worker's parent.
POLL_S = 0.5


def exit_with_parent(parent_pid: int) -> None:
    """Pool initializer: end this process (exit status 1) as soon as ``parent_pid`` is no longer its parent."""
    if os.getppid() != parent_pid:
        os._exit(1)  # the parent died before this worker started
    threading.Thread(target=_watch, args=(parent_pid,), name="exit-with-parent", daemon=True).start()


def _watch(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(POLL_S)
    os._exit(1)


def process_pool(jobs: int, mp_context: Any = None) -> ProcessPoolExecutor:
    """A ``ProcessPoolExecutor`` of ``jobs`` workers that exit when this process dies."""
    return ProcessPoolExecutor(max_workers=jobs, mp_context=mp_context, initializer=exit_with_parent,
                               initargs=(os.getpid(),))


def pool_map(pool: ProcessPoolExecutor | None, fn: Callable[[Any], Any], args: list[Any]) -> list[Any]:
    """``fn`` over ``args``, in the worker pool when there is one, else in this process; results in order."""
    return list(pool.map(fn, args)) if pool is not None else [fn(a) for a in args]
