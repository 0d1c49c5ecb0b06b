"""The final fit ``aibo diagnose`` makes of the searched model and the named effects' intervals
(``learners.discrepancy.final.diagnosed``)."""

from __future__ import annotations

import pytest


def test_diagnosed_is_the_final_fit_of_the_searched_model_with_each_named_effects_intervals():
    """``learners.discrepancy.final.diagnosed`` (what ``aibo diagnose`` and the calibration study call): the final fit
    warm-started from ``found["model"]`` on ``found["logs"]`` with the search's stop rule; a named effect's parameters
    are the final fit's, its Wald intervals come from that fit's standard errors, a grid parameter's from the search's
    profile, and ``parameters_when_named`` from the candidate."""
    from learners.arrays.batch import make_batch
    from learners.discrepancy.candidate import Candidate
    from learners.discrepancy.effect_sizes import Z95
    from learners.discrepancy.final import FINAL_FIT_STAGE, diagnosed, final_options
    from learners.discrepancy.fitting import SEARCH_PATIENCE
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions
    from learners.model.catalogue import ActuationLag, VelocityFade
    from tests._logs import sim_log

    tr = sim_log(3000)
    opts = EMOptions(seed=0, lag_search=False)
    fopts = final_options(opts)
    assert (fopts.starts, fopts.alias_search, fopts.patience, fopts.min_improvement) == (1, False, SEARCH_PATIENCE, 0.1)
    base = EMLearner(EMOptions(max_iter=15, lag_search=False)).fit([tr]).params
    batch = make_batch([tr])
    model = base.with_effect(VelocityFade.start(batch)).with_effect(ActuationLag.start(batch))
    profile = [[0.0, 0.1, 0.2, 0.3], [-9.0, 0.0, -1.0, -30.0]]  # the grid's training log-likelihoods
    named = [Candidate("velocity_fade", {"fade_per_min": 0.004}, 5.0, 1.0, 1, 0.001, model=model),
             Candidate("actuation_lag", {"lag_s": 0.1}, 9.0, 2.0, 1, 1e-5, model=model, profile={"lag_s": profile})]
    out = diagnosed({"model": model, "logs": [tr], "named": named}, opts)
    assert [e["name"] for e in out.effects] == ["velocity_fade", "actuation_lag"]
    assert list(out.seconds) == [FINAL_FIT_STAGE] and out.profiled == []
    fade, lag = out.effects
    se = out.result.info["standard_errors"]["effects.velocity_fade.fade_per_min"]
    value = float(out.result.params.effect("velocity_fade").fade_per_min)
    iv = fade["intervals"]["fade_per_min"]
    assert fade["parameters"] == {"fade_per_min": value} and iv["value"] == value and iv["se"] == pytest.approx(se)
    assert iv["method"] == "wald" and iv["interval_95"] == pytest.approx([value - Z95 * se, value + Z95 * se])
    assert fade["parameters_when_named"] == {"fade_per_min": 0.004}
    assert lag["intervals"]["lag_s"]["interval_95"] == [0.0, 0.3]  # within 1.92 nats: 0.1 and 0.2, widened by a step
    assert lag["parameters_when_named"] == {"lag_s": 0.1}
