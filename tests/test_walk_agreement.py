"""A command table's fit in a world turned or mirrored against the robot's (``learners.em.support.walk_agreement``,
``walk_warnings``): the learned walk velocities stop following the attempted ones."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from aibo_core.trajectory import blind
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.em.support import MAX_WALK_TURN_RAD, walk_agreement, walk_warnings
from tests._logs import sim_log

WARNING = "the learned walk velocities do not follow the commands' attempted ones"


def _with_velocities(model, velocities):
    """``model`` with its command table's velocities (A, 3) set (as weights: displacements per frame)."""
    return model.with_(action=replace(model.action, weights=np.asarray(velocities) * model.action.dt))


def test_known_answers():
    """Velocities that are the attempted ones turned by 30 degrees and halved: R^2 1 and the turn; the attempted ones
    with their vx and vy exchanged (a mirror): R^2 far below 1."""
    tr = blind(sim_log(steps=600, seed=1, noise="aibo"))
    fit = EMLearner(EMOptions(max_iter=2, uncertainty=False, alias_search=False, lag_search=False)).fit([tr]).params
    att = np.asarray(tr.attempted, float)
    turned = att.copy()
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    turned[:, 0], turned[:, 1] = 0.5 * (c * att[:, 0] - s * att[:, 1]), 0.5 * (s * att[:, 0] + c * att[:, 1])
    r2, turn = walk_agreement(_with_velocities(fit, turned), [tr])
    assert r2 > 1 - 1e-12 and np.isclose(turn, np.radians(30.0))
    assert WARNING in walk_warnings(_with_velocities(fit, turned), [tr])[0]  # 30 degrees: beyond the 20
    assert np.radians(30.0) > MAX_WALK_TURN_RAD
    assert walk_warnings(_with_velocities(fit, att * 0.8), [tr]) == []
    mirrored = att[:, [1, 0, 2]]
    assert walk_agreement(_with_velocities(fit, mirrored), [tr])[0] < 0.5


def test_a_swapped_map_is_warned_of_and_the_right_map_is_not():
    """The `aibo` preset, 1,500 frames, seed 2, blind: with beacons 0 and 1 exchanged in the map the fit ends in a
    world where the bearings fit (the walk turned by about 155 degrees), and says so; with the right map it does not."""
    tr = blind(sim_log(steps=1500, seed=2, noise="aibo"))
    right = EMLearner(EMOptions()).fit([tr])
    assert not any(WARNING in w for w in right.info.warnings)
    landmarks = tr.landmarks.copy()
    landmarks[[0, 1]] = landmarks[[1, 0]]
    swapped = EMLearner(EMOptions()).fit([replace(tr, landmarks=landmarks)])
    assert any(WARNING in w for w in swapped.info.warnings), swapped.info.warnings
