"""The sightings the search sets aside as outliers (``learners.discrepancy.search.base_and_outliers``): judged by a base
model that may have stopped in a poorer world, they are judged again by ``aibo learn``'s model of the whole log."""

from __future__ import annotations

import numpy as np

from aibo_core.trajectory import blind
from aibo_gym.collect import collect
from learners.discrepancy.search import base_and_outliers, base_fits, outliers
from learners.em.options import EMOptions


def test_a_base_fit_in_a_poorer_world_does_not_set_good_sightings_aside():
    """An effect-free 5-minute ``aibo`` log (seed 6045): the base fit from the paper's start on the training half gates
    out 1,245 of its 4,776 sightings; ``aibo learn``'s model of the whole log none. The search's base is then the fit
    from that model: nothing set aside, and more likely on the sightings neither gates out (by 706 nats)."""
    tr = blind(collect({"noise": "aibo", "effects": {}}, 9000, seed=6045))
    opts = EMOptions().comparable()
    first, _ = base_fits([tr], opts)
    assert outliers(first, [tr]).sum() > 1000
    said: list[str] = []
    base, refit, (kept,), n = base_and_outliers([tr], opts, progress=said.append)
    assert n == 0 and kept.n_sightings == tr.n_sightings and refit is None
    assert [e.name for e in base.effects] == [e.name for e in first.effects]  # learn's structure is not taken
    assert len(said) == 1 and said[0].startswith("  the base fit gated out 1245 sightings") and "kept" in said[0]


def test_a_base_that_gates_out_few_is_kept_as_it_is():
    """Where the base fit gates out at most 1% (here none), nothing else is fitted: the base and the logs are
    ``base_fits``' own, and nothing is said."""
    tr = blind(collect({"noise": "aibo", "effects": {}}, 9000, seed=6000))
    opts = EMOptions().comparable()
    first, _ = base_fits([tr], opts)
    said: list[str] = []
    base, _, (kept,), n = base_and_outliers([tr], opts, progress=said.append)
    assert said == [] and n == int(outliers(first, [tr]).sum()) <= 0.01 * tr.n_sightings
    np.testing.assert_array_equal(np.asarray(base.action.weights), np.asarray(first.action.weights))
