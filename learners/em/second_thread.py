"""A second thread for work that overlaps the main one (the M-step's sensor-curve update beside its action
statistics, ``mstep.maximize``).

The compiled kernels release the GIL (``nogil=True``), so on two cores the two halves of an M-step take
the longer of the two instead of their sum: one EM iteration at 27,000 frames 6.9-7.2 -> 5.7-6.1 ms
(scripts in docs/results.md). The numbers do not change: each half runs its own serial code.

- ``submit(fn, ...)`` returns a ``Future``, or None when the second thread is off (run ``fn`` in line);
- it is off on a single usable core, with ``AIBO_SECOND_THREAD=0`` in the environment (a sweep's pool workers
  and pytest-xdist's get it: every core already runs a process of its own), and after ``set_enabled(False)``;
- a forked child forgets its parent's thread (it does not exist there) and starts its own on first use;
- ``release_scratch()`` drops the thread's work arrays, as ``kernels.release_scratch`` does the caller's.
"""

from __future__ import annotations

import os
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable


def _usable_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


#: set to "0" in processes that already share the cores with others (a sweep's pool workers, pytest-xdist's)
ENV_VAR = "AIBO_SECOND_THREAD"
_ENABLED = _usable_cores() > 1 and os.environ.get(ENV_VAR, "1") != "0"
_EXECUTOR: ThreadPoolExecutor | None = None


def enabled() -> bool:
    return _ENABLED


def set_enabled(flag: bool) -> bool:
    """Turn the second thread on or off; returns the previous setting."""
    global _ENABLED
    previous, _ENABLED = _ENABLED, bool(flag)
    return previous


def submit(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Future | None:
    """``fn(*args, **kwargs)`` started on the second thread, or None when it is off."""
    global _EXECUTOR
    if not _ENABLED:
        return None
    if _EXECUTOR is None:
        _EXECUTOR = ThreadPoolExecutor(max_workers=1, thread_name_prefix="aibo-second")
    return _EXECUTOR.submit(fn, *args, **kwargs)


def release_scratch() -> int:
    """Drop the second thread's ``_scratch`` work arrays; returns the bytes released (0 without a thread)."""
    if _EXECUTOR is None:
        return 0
    from learners.inference.kernels import release_scratch as release

    return _EXECUTOR.submit(release).result()


def _forget() -> None:
    """After a fork: the parent's thread does not exist in the child, and a task submitted to it would wait
    forever (a diagnose pool worker did)."""
    global _EXECUTOR
    _EXECUTOR = None


os.register_at_fork(after_in_child=_forget)
