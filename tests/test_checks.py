"""The search's declared checks (``learners.discrepancy.checks``) on stand-ins with known answers: what each check
decides, when it applies, and what a candidate's flags and note are, read off its verdicts."""

from __future__ import annotations

import numpy as np
import pytest

from learners.discrepancy import checks
from learners.discrepancy.candidate import Candidate, Verdict
from learners.discrepancy.fitting import FLAT_NATS
from learners.model.effects import EFFECT_MODELS
from learners.model.probes import PROBES
from tests._search_stand_ins import StandInContext as _Context
from tests._search_stand_ins import StandInEffect as _Effect
from tests._search_stand_ins import StandInModel as _Model


def _candidate(name="velocity_fade", loglik=-1000.0, effect=None, **kw) -> Candidate:
    model = _Model((effect or _Effect(name),))
    c = Candidate(name, {}, kw.pop("gain_train", 20.0), kw.pop("gain_heldout", 5.0), 1, 1e-10, model=model,
                  loglik=loglik, **kw)
    c.checks.append(Verdict("likelihood ratio", True))
    return c


def test_a_candidate_is_significant_when_every_deciding_verdict_passed():
    c = Candidate("x", {}, 1.0, 1.0, 1, 0.5)
    assert not c.significant  # no deciding check ran
    c.checks.append(Verdict("likelihood ratio", True))
    assert c.significant and c.identifiable and c.note == ""
    c.checks.append(Verdict("an annotation", False, decides=False, note="informs"))
    assert c.significant and c.note == "informs"  # an annotation does not decide
    c.checks.append(Verdict("plausibility", False, note="30% is no bias"))
    assert not c.significant and c.note == "30% is no bias"


def test_the_note_is_the_last_word_and_the_escape_the_last_base_fitted():
    a, b = _Model(()), _Model((_Effect("y"),))
    c = Candidate("x", {}, 1.0, 1.0, 1, 0.5, checks=[
        Verdict("given a nuisance", True, note="given walls: train +9 nats"),
        Verdict("reparameterisation", True, escape=(a, -10.0)),
        Verdict("given its own base", False, note="the base keeps the gain", escape=(b, -5.0))])
    assert c.note == "the base keeps the gain" and c.escape is b and c.escape_ll == -5.0
    assert Candidate("x", {}, 1.0, 1.0, 1, 0.5).escape_ll == -np.inf


def test_given_its_own_base_refuses_a_gain_the_base_keeps_without_the_effect():
    """The candidate's fit is 20 nats above the null, but the base refitted from it (the effect removed) is only 0.5
    below the candidate: the gain was the base leaving a poor optimum."""
    c = _candidate()
    v = checks.GivenItsOwnBase().run(_Context({frozenset({"velocity_fade"}): -1000.0, frozenset(): -1000.5}), c)
    assert not v.passed and v.decides and v.gains["train"] == pytest.approx(0.5)
    assert "keeps the gain" in v.note and v.escape[1] == -1000.5
    v = checks.GivenItsOwnBase().run(_Context({frozenset({"velocity_fade"}): -1000.0, frozenset(): -1030.0}), c)
    assert v.passed and v.note == "" and v.p < 1e-10


def test_plausibility_refuses_a_negligible_or_implausible_fit():
    ctx = _Context({})
    assert checks.Plausibility().run(ctx, _candidate()).passed
    for effect in (_Effect("velocity_fade", why_negligible="3 sightings"),
                   _Effect("velocity_fade", why_implausible="30% is no bias")):
        v = checks.Plausibility().run(ctx, _candidate(effect=effect))
        assert not v.passed and v.note in ("3 sightings", "30% is no bias")


def test_a_flat_grid_profile_is_not_identifiable_and_a_peaked_one_is():
    ctx = _Context({})
    flat = _candidate("actuation_lag", profile={"lag_s": [[0.0, 0.1, 0.2], [-100.0, -99.0, -100.0 + FLAT_NATS / 2]]})
    peaked = _candidate("actuation_lag", profile={"lag_s": [[0.0, 0.1, 0.2], [-100.0, -60.0, -90.0]]})
    check = checks.FlatGridProfile()
    assert check.applies(ctx, flat) and not check.applies(ctx, _candidate())  # velocity_fade has no grid
    v = check.run(ctx, flat)
    assert not v.passed and not v.identifiable and "not identifiable" in v.note
    assert check.run(ctx, peaked).passed


def test_checks_that_need_a_significant_candidate_do_not_run_after_a_refusal():
    """The order is the procedure: once a deciding check refused, the later deciding checks do not apply."""
    c = _candidate(effect=_Effect("velocity_fade", why_implausible="no"))
    ran = checks.run_checks((checks.Plausibility(), checks.GivenItsOwnBase()), _Context({}), c)
    assert [v.name for v in ran.checks] == ["likelihood ratio", "plausibility"] and not ran.significant


def test_the_frozen_probe_annotates_only_candidates_that_are_not_significant():
    probe = checks.FrozenProbe()
    assert not probe.decides
    c = _candidate()
    assert not probe.applies(_Context({}), c)  # significant
    c.checks.append(Verdict("plausibility", False, note="no"))
    assert probe.applies(_Context({}), c)
    assert not probe.applies(_Context({}), _candidate("actuation_lag"))  # a grid's profile is its check


def test_confounders_are_declared_on_the_effect_classes():
    """Every declared confounder is a nuisance the check can use; the effects and probes that stand in for a wall
    declare it (the search names no effect itself)."""
    from learners.model.catalogue_more import WallSlowdown

    classes = list(EFFECT_MODELS.values()) + list(PROBES.values())
    for cls in classes:
        for nuisance in cls.CONFOUNDERS:
            assert all(hasattr(nuisance, a) for a in ("around", "n_frames", "given", "name")), (cls, nuisance)
    assert WallSlowdown in EFFECT_MODELS["velocity_fade"].CONFOUNDERS
    assert all(WallSlowdown in cls.CONFOUNDERS for cls in PROBES.values())
    assert checks.GivenNuisance().applies(None, _candidate())
    assert not checks.GivenNuisance().applies(None, _candidate("landmark_bias"))


def test_a_candidate_row_carries_its_whole_trail():
    c = _candidate()
    c.checks.append(Verdict("given its own base", False, gains={"train": 0.5}, p=0.3, note="keeps the gain"))
    row = c.as_dict()
    assert row["significant"] is False and row["note"] == "keeps the gain"
    assert [v["name"] for v in row["checks"]] == ["likelihood ratio", "given its own base"]
    assert row["checks"][1] == {"name": "given its own base", "passed": False, "decides": True,
                                "gains": {"train": 0.5}, "p": 0.3, "note": "keeps the gain"}


def test_the_robust_likelihood_ratio_divides_the_gain_by_the_informations_overstatement():
    """20 nats of one parameter (p 2.6e-10) hold when the information is the data's (c = 1) and when it overstates
    them 2x (10 nats, p 7.7e-6 < 0.01); at 8x the gain counts as 2.5 nats (p 0.025 > 0.01): not significant, and the
    note says by how much. A grid's candidate (a lag: profiled, not estimated) is not tested."""
    check = checks.RobustLikelihoodRatio()
    c = _candidate(gain_train=20.0)
    assert check.applies(_Context({}), c) and not check.applies(_Context({}), _candidate("actuation_lag"))
    for factor, passed in ((1.0, True), (2.0, True), (8.0, False)):
        v = check.run(_Context({}, factor=factor), c)
        assert v.passed is passed and v.decides and v.gains["train"] == pytest.approx(20.0 / factor)
        assert f"x{factor:.2f}" in v.note and ("not significant" in v.note) is (not passed)
        assert v.overstatement == factor and v.as_dict()["overstatement"] == factor  # the backward check reuses it
    assert check.run(_Context({}, factor=8.0), c).p == pytest.approx(0.0253, abs=2e-4)
