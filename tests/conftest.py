"""Every test process (pytest-xdist's workers too) runs with one BLAS thread, as the ``aibo`` command does
(``aibo/__init__.py``): imported here, before any test module imports NumPy."""

import os

import aibo  # noqa: F401

if os.environ.get("PYTEST_XDIST_WORKER"):  # two worker processes share the two cores: no M-step second thread in
    # them (``learners.em.second_thread``; tests/test_second_thread.py turns it on where it is tested)
    os.environ.setdefault("AIBO_SECOND_THREAD", "0")  # (and the commands the tests start)
    from learners.em import second_thread

    second_thread.set_enabled(False)
