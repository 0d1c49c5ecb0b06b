"""Issue 18: ``velocity_fade`` named on effect-free 5-minute logs (``scripts/diagnose_power.py``). Two causes, each
with the log it was measured on (``learners/discrepancy/search.py``, module docstring):

- the null of the test was the current model as it stood, while each candidate is refitted from it: EM's own slack
  (5.4 nats on seed 1012) was credited to the candidate;
- on a log whose robot spends more of its later minutes pressing a wall (seed 3008), a fade of the speed stands in
  for the walls: the fade is now tested again given a free speed factor near the walls (``WallSlowdown``).
"""

from __future__ import annotations

import numpy as np
import pytest

from aibo_core.trajectory import blind
from aibo_gym.collect import collect
from learners.arrays.batch import make_batch
from learners.discrepancy.search import search
from learners.em.estep import e_step
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.model.effects import EFFECT_MODELS
from tests._logs import sim_log

FIVE_MINUTES = 9000  # frames
# jobs=2 as ``scripts/diagnose_power.py``: candidates fitted in worker processes. On seed 1012 the fade's fit came out
# differently in-process (jobs=1: 0.0 nats over the old null) and alone in the pool (the old test did not name it) than
# among every candidate in the pool (5.7 nats): a dependence on what ran before in the process, not understood yet


def test_wall_slowdown_is_neutral_at_one_and_scales_only_the_near_frames():
    from learners.model.catalogue_more import WallSlowdown  # here: the other tests also run on the code before it

    tr = sim_log(3000)
    model = EMLearner(EMOptions(max_iter=5, starts=1, alias_search=False, lag_search=False)).fit([tr]).params
    batch = make_batch([tr])
    nuisance = WallSlowdown.around(e_step(model, batch, "compiled"), batch)
    assert nuisance.n_frames() > 0
    assert model.with_effect(nuisance).effective_commands(batch)[1] is None  # factor 1: no scale at all
    slowed = WallSlowdown(0.8, near=nuisance.near, key=nuisance.key)
    scale = model.with_effect(slowed).effective_commands(batch)[1]
    assert np.allclose(scale[nuisance.near], 0.8) and np.allclose(scale[~nuisance.near], 1.0)
    assert slowed.disp_scale(make_batch([sim_log(3001)])) is None  # another log's frames: not applied


@pytest.mark.slow
def test_null_is_refitted_as_the_candidates_are():
    """Seed 1012 (aibo noise, effect-free, every candidate, as ``scripts/diagnose_power.py``): the current model
    refitted from itself gained 5.4 nats (EM's slack); over the unrefitted model ``velocity_fade`` gained 5.7 nats
    (p = 0.0007) and was named. Over the refitted null it gains 0.3 nats."""
    tr = blind(collect({"noise": "aibo"}, FIVE_MINUTES, seed=1012))
    found = search([tr], sorted(EFFECT_MODELS), EMOptions(), jobs=2, progress=lambda s: None)
    assert "velocity_fade" not in [c.name for c in found["named"]]
    fade = next(c for c in found["rounds"][0] if c.name == "velocity_fade")
    assert fade.gain_train < 2.0, fade


@pytest.mark.slow
def test_velocity_fade_is_not_named_for_a_robot_pressing_the_walls():
    """Seed 3008 (aibo noise, effect-free, the random walk leaves the field by 800 mm: blocked frames per minute 35,
    130, 367, 392, 272): a fade of 0.029/min gained 8.2 nats (p = 5e-5) over a converged null and was named; given
    the free speed factor near the walls it gains about 2 nats and is not."""
    tr = blind(collect({"noise": "aibo"}, FIVE_MINUTES, seed=3008, policy_params={"margin_mm": -800.0}))
    found = search([tr], ["velocity_fade"], EMOptions(), jobs=2, progress=lambda s: None)
    fade = found["rounds"][0][0]
    assert fade.p_value < 0.01  # without the walls' nuisance it would pass
    assert "given a free speed factor" in fade.note and not fade.significant, fade
    assert [c.name for c in found["named"]] == []


@pytest.mark.slow
def test_velocity_fade_is_still_named_when_the_speed_fades():
    """Power kept: a fade of 0.01/min on a 10-minute log (seed 2000) is named, given the walls' nuisance too."""
    tr = blind(collect({"noise": "aibo", "effects": {"velocity_fade": {"fade_per_min": 0.01}}}, 2 * FIVE_MINUTES, seed=2000))
    found = search([tr], ["velocity_fade"], EMOptions(), jobs=2, progress=lambda s: None)
    assert [c.name for c in found["named"]] == ["velocity_fade"], found["rounds"][0][0]
    assert abs(found["named"][0].parameters["fade_per_min"] - 0.01) < 0.005
