"""The M-step's second thread (learners/em/second_thread.py): the sensor-curve update runs beside the action
statistics and gives the same numbers, bit for bit; a forked child does not wait on its parent's thread."""

from __future__ import annotations

import multiprocessing as mp
import threading

import numpy as np
import pytest

from learners.arrays.batch import make_batch
from learners.em import second_thread
from learners.em.estep import e_step
from learners.em.learner import EMLearner
from learners.em.mstep import maximize
from learners.em.options import EMOptions
from learners.em.uncertainty import file_values
from tests._logs import sim_log


@pytest.fixture(scope="module")
def problem():
    """A 6,000-frame simulated log, the paper's start and its first (compiled) E-step."""
    log = sim_log()
    batch = make_batch([log])
    model = EMLearner().start_params([log], None, batch)
    return model, batch, e_step(model, batch, "compiled")


@pytest.fixture
def second(request):
    """The second thread on (param True) or off for one test, restored after it."""
    previous = second_thread.set_enabled(request.param)
    yield request.param
    second_thread.set_enabled(previous)


def _m_step(problem, method: str, seed: int = 5):
    model, batch, post = problem
    rng = np.random.default_rng(seed)
    new = maximize(model, batch, post, rng, EMOptions(sensor_method=method, n_samples=2))
    return file_values(new), rng.bit_generator.state


@pytest.mark.parametrize("method", ["cubature", "sample"])
def test_the_second_thread_gives_the_same_model_bit_for_bit(problem, method):
    previous = second_thread.set_enabled(True)
    try:
        threaded, state_threaded = _m_step(problem, method)
        second_thread.set_enabled(False)
        inline, state_inline = _m_step(problem, method)
    finally:
        second_thread.set_enabled(previous)
    assert threaded.keys() == inline.keys()
    for key in inline:
        np.testing.assert_array_equal(threaded[key], inline[key], err_msg=key)
    assert state_threaded == state_inline  # the sampled points drew the same numbers from the generator


@pytest.mark.parametrize("second", [True, False], indirect=True)
def test_the_sensor_update_runs_on_the_second_thread_only_when_it_is_on(problem, second, monkeypatch):
    from learners.inference import kernels

    ran_on = []
    update = kernels.sensor_update_compiled

    def recording(*args, **kwargs):
        ran_on.append(threading.current_thread().name)
        return update(*args, **kwargs)

    monkeypatch.setattr(kernels, "sensor_update_compiled", recording)
    _m_step(problem, "cubature")
    assert len(ran_on) == 1
    assert ran_on[0].startswith("aibo-second") == second


def _child_m_step(problem, queue) -> None:
    values, _ = _m_step(problem, "cubature")
    queue.put(float(values["sensor_model.sigma_height"]))


def test_a_forked_child_runs_its_own_second_thread(problem):
    """The parent's thread does not exist in a forked child (a diagnose pool worker waited on it forever)."""
    previous = second_thread.set_enabled(True)
    try:
        values, _ = _m_step(problem, "cubature")  # the parent's thread exists now
        ctx = mp.get_context("fork")
        queue = ctx.Queue()
        child = ctx.Process(target=_child_m_step, args=(problem, queue))
        child.start()
        child.join(timeout=120)
        if child.is_alive():
            child.kill()
            pytest.fail("the forked child's M-step waited on its parent's thread")
        assert child.exitcode == 0
        assert queue.get(timeout=5) == float(values["sensor_model.sigma_height"])
    finally:
        second_thread.set_enabled(previous)


def test_the_second_threads_work_arrays_are_released(problem):
    previous = second_thread.set_enabled(True)
    try:
        _m_step(problem, "cubature")
        assert second_thread.release_scratch() > 0  # the sensor update's points, made on that thread
        assert second_thread.release_scratch() == 0
    finally:
        second_thread.set_enabled(previous)


@pytest.mark.parametrize("value, expected", [("0", False), ("1", True)])
def test_the_environment_turns_it_off_in_processes_that_share_the_cores(value, expected):
    import os
    import subprocess
    import sys
    from pathlib import Path

    if second_thread._usable_cores() < 2:
        pytest.skip("one usable core: the second thread is always off")
    env = {**os.environ, second_thread.ENV_VAR: value, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    out = subprocess.run([sys.executable, "-c", "from learners.em import second_thread; print(second_thread.enabled())"],
                         env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(expected)


def test_sweep_workers_run_without_it():
    from experiments.executors import worker_env

    assert worker_env()[second_thread.ENV_VAR] == "0"
