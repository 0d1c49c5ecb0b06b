"""EM that falls: each EM step whose likelihood falls is booked, and a fall from the returned model is warned of.

With an exact E-step EM never falls; this one linearizes (and a mixture weighs sightings at the smoothed path), so
it can. What is booked is checked against the likelihood trace itself; the warning against known traces.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from aibo_core.trajectory import blind
from aibo_gym.collect import collect
from learners.em import fit as em_fit
from learners.em.fit import EMState, initial_state, run, setback_from_best
from learners.em.learner import SETBACK_WARN_NATS, EMLearner, setback_record, setback_warnings
from learners.em.options import EMOptions
from learners.model.model import paper_start
from tests._logs import sim_log


def _state(loglik: list[float], setbacks: list[list[float]]) -> EMState:
    best = int(np.argmax(loglik))
    return EMState(iteration=len(loglik), params=None, best=None, best_loglik=max(loglik), best_iteration=best,
                   loglik=loglik, used=np.ones(1, bool), pruned=0, rng_state={}, setbacks=setbacks)


def test_a_fall_far_below_the_best_is_a_way_from_a_poor_start_not_a_fall_from_the_best():
    # iterations 1-6 (1-based): a fall of 300 at 3, far below the best (-100 at 4); then 3 from the best at 5 and 1
    # more at 6, a step from 3 nats below the best
    ll = [-900.0, -400.0, -700.0, -100.0, -103.0, -104.0]
    st = _state(ll, [[2, -400.0, -700.0], [4, -100.0, -103.0], [5, -103.0, -104.0]])
    assert setback_from_best(st) == (3.0, 5)
    assert setback_from_best(st, within=0.0) == (3.0, 5)
    assert setback_from_best(st, within=400.0) == (300.0, 3)
    assert setback_from_best(_state(ll[:4], [[2, -400.0, -700.0]])) == (0.0, 0)
    rec = setback_record(st)
    assert rec == {"nats": 300.0, "iteration": 3, "from_best_nats": 3.0, "from_best_iteration": 5, "iterations": 6}
    assert 3.0 > SETBACK_WARN_NATS and "fell by 3.00 nats" in setback_warnings(rec)[0]
    assert setback_warnings({**rec, "from_best_nats": SETBACK_WARN_NATS}) == []
    assert setback_record(_state([-3.0, -2.0], [])) is None and setback_warnings(None) == []


@pytest.mark.parametrize("accel", ["none", "squarem"])
def test_every_em_step_that_falls_is_booked_and_no_other(monkeypatch, accel):
    """A stand-in E-step with a scripted likelihood and an M-step that keeps the model: SQUAREM then never jumps
    (its three iterates are one point), so both loops take plain EM steps and book exactly the falls."""
    script = iter([-50.0, -20.0, -25.0, -10.0, -10.5, -13.0, -9.0, -9.4] + [-9.4] * 40)
    monkeypatch.setattr(em_fit, "e_step", lambda *a, **k: SimpleNamespace(loglik=next(script)))
    monkeypatch.setattr(em_fit, "maximize", lambda params, *a, **k: params)
    tr = sim_log(300, seed=4)
    start = paper_start([tr])
    from learners.arrays.batch import make_batch

    opts = EMOptions(accel=accel, gate=None, patience=5, min_improvement=0.1, polish=False, max_iter=20)
    st = run(make_batch([tr]), initial_state(start, make_batch([tr]), opts), opts)
    assert st.setbacks == [[2, -20.0, -25.0], [4, -10.0, -10.5], [5, -10.5, -13.0], [7, -9.0, -9.4]]
    # the best is -9.0 (iteration 7); steps taken from within 1 nat of it: -10 -> -10.5 (at 5) and -9 -> -9.4 (at 8)
    assert setback_from_best(st) == (0.5, 5)


def test_a_real_fit_books_the_falls_its_trace_shows():
    """An effect-free 5-minute ``aibo`` log whose fit falls 994 nats at its 6th iteration, far below its best, and
    ends well: booked, consistent with the trace, and not warned of."""
    tr = blind(collect({"noise": "aibo", "effects": {}}, 9000, seed=1004))
    learner = EMLearner(EMOptions(seed=0))
    res = learner.fit([tr])
    rec = res.info["setback"]
    assert rec["nats"] > 900 and rec["iteration"] < 10 and rec["from_best_nats"] == 0.0, rec
    assert not [w for w in res.info["warnings"] if "fell by" in w]
    ll, k = res.loglik, rec["iteration"] - 1
    assert any(abs(ref - ll[k] - rec["nats"]) < 1e-9 for ref in ll[:k])  # a fall from a likelihood in the trace


@pytest.mark.parametrize("stop_at", [17, 20])
def test_a_resumed_fit_books_the_falls_an_unbroken_one_does(tmp_path, stop_at):
    """The log above falls at its 6th iteration, while its starts are screened (15 iterations): interrupted after
    that and resumed from the checkpoint, the fit books what the unbroken fit books."""
    tr = blind(collect({"noise": "aibo", "effects": {}}, 9000, seed=1004))
    opts = EMOptions(seed=0, max_iter=30)
    full = EMLearner(opts).fit([tr])
    ckpt = tmp_path / "m.checkpoint.npz"

    def stop(rec):
        if rec.iteration == stop_at:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        EMLearner(opts, checkpoint_path=ckpt, checkpoint_every=1).fit([tr], progress=stop)
    resumed = EMLearner(opts, checkpoint_path=ckpt, checkpoint_every=1).fit([tr])
    assert 15 <= resumed.info["resumed_from"] < stop_at
    assert resumed.info["setback"] == full.info["setback"] and full.info["setback"]["nats"] > 900
