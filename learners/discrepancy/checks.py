"""The discrepancy search's rules, each a declared check: when it applies, whether it decides or only annotates, and
its verdict (``learners.discrepancy.candidate.Verdict``: name, passed, gains, p, note).

A candidate is significant when every deciding check that ran passed. The checks run in the order of
:data:`CANDIDATE_CHECKS` (a probe's: :data:`PROBE_CHECKS`); each says in :meth:`Check.applies` whether it runs given
the verdicts so far (most deciding checks only test a candidate still significant: the order is the procedure).
The evidence behind each rule, the log it was measured on, is in docs/results.md#the-searchs-checks, under the
check's name, linked from its docstring. A new rule is one class here, its place in a list, and its test.

=======================  ========  ====================================================================================
check                    decides?  applies to
=======================  ========  ====================================================================================
likelihood ratio         yes       every candidate: 2 gain ~ chi2(dof) against the refitted null, AND a held-out gain
given a nuisance         yes       a significant candidate whose effect class declares ``CONFOUNDERS`` (wall contact)
reparameterisation       yes       a significant candidate whose class knows an equivalent model without it
given its own base       yes       a significant candidate: the base refitted from its fit, without it
plausibility             yes       a significant candidate: negligible (a handful of data) or implausible values
robust likelihood ratio  yes       a significant candidate with estimated parameters: 2 gain / c ~ chi2(dof), c the
                                   Fisher information's overstatement of the data's (sandwich against Fisher)
flat grid profile        yes       a candidate profiled over a grid: the profile never leaves ``FLAT_NATS``
frozen probe             no        a candidate not significant, with a ``PROBE`` step and no grid (last round only)
motion side              no        the candidate named: open-loop held-out gaps 1, 2 and 5 s after against before
=======================  ========  ====================================================================================
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from learners.em.uncertainty import OVERSTATEMENT_BLOCK_S
from learners.model.effects import EFFECT_MODELS

from .candidate import Candidate, Verdict
from .fitting import FLAT_NATS, SearchContext, held, with_values
from .score import MOTION_WORSE_Z, motion_score, motion_trade


class Check:
    """A rule of the search (module docstring). Subclasses set ``name`` and ``decides`` and implement ``applies`` and
    ``run``."""

    name: ClassVar[str] = ""
    decides: ClassVar[bool] = True

    def applies(self, ctx: SearchContext, c: Candidate) -> bool:
        """Whether this check runs on ``c`` given its verdicts so far (default: while ``c`` is significant)."""
        return c.significant

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        raise NotImplementedError

    def verdict(self, passed: bool, **kw) -> Verdict:
        return Verdict(self.name, bool(passed), self.decides, **kw)


def run_checks(checks: tuple[Check, ...], ctx: SearchContext, c: Candidate) -> Candidate:
    """``c`` with the verdicts of the ``checks`` that apply, in order (each sees the verdicts before it)."""
    for check in checks:
        if check.applies(ctx, c):
            c.checks.append(check.run(ctx, c))
    return c


class LikelihoodRatio(Check):
    """The test against the refitted null (``fitting.lr_test``; evidence: docs/results.md#the-searchs-checks).

    The null is not the current model as it stands but the current model refitted from itself as the candidate is (the
    candidate's fit with its parameters frozen at their neutral start: the same start and EM budget); for a candidate
    profiled over a grid that holds its neutral value, that grid point's fit. Its numbers are the candidate's
    ``gain_train``, ``gain_heldout``, ``p_value``."""

    name = "likelihood ratio"

    def applies(self, ctx: SearchContext, c: Candidate) -> bool:
        return True

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        p, ok = ctx.test(c.gain_train, c.gain_heldout, c.dof)
        return self.verdict(ok, gains={"train": c.gain_train, "heldout": c.gain_heldout}, p=p)


def tested(name: str, model, ll: float, ctx: SearchContext, null: tuple[float, float] | None = None) -> Candidate:
    """The candidate of ``model`` (holding effect ``name``, training log-likelihood ``ll``) with its likelihood-ratio
    verdict against ``null`` (training, held-out log-likelihoods; default the round's)."""
    null_ll, null_heldout = null if null is not None else (ctx.null_ll, ctx.null_heldout)
    effect = model.effect(name)
    c = Candidate(name, effect.values(), max(ll - null_ll, 0.0), ctx.heldout(model) - null_heldout, effect.dof(),
                  float("nan"), model=model, loglik=ll, null=null)
    v = LikelihoodRatio().run(ctx, c)
    c.p_value = v.p
    c.checks.append(v)
    return c


class GivenNuisance(Check):
    """The test repeated given each confounder the effect's class declares (``EffectModel.CONFOUNDERS``, e.g. a free
    speed factor near the walls for a fade of the speed): null = current + nuisance, alternative = the candidate's
    start + nuisance, both fitted alike; passes when that test passes (evidence: docs/results.md#the-searchs-checks).
    The nuisance is never named; where it covers no frame the check does not apply."""

    name = "given a nuisance"

    def applies(self, ctx: SearchContext, c: Candidate) -> bool:
        return c.significant and bool(_class_of(c.name).CONFOUNDERS)

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        verdict = self.verdict(True)  # no confounder covers a frame of these logs
        for confounder in _class_of(c.name).CONFOUNDERS:
            nuisance = confounder.around(ctx.posterior, ctx.batch)
            if not nuisance.n_frames():
                continue
            null = ctx.fit(ctx.current.with_effect(nuisance))
            alt = ctx.fit(c.start.with_effect(nuisance))
            gain = max(ctx.loglik(alt) - ctx.loglik(null), 0.0)
            held_gain = ctx.heldout(alt) - ctx.heldout(null)
            p, ok = ctx.test(gain, held_gain, c.dof)
            verdict = self.verdict(ok, gains={"train": gain, "heldout": held_gain}, p=p,
                                   note=(f"given {null.effect(confounder.name).given()}: train +{gain:.1f} nats, "
                                         f"held-out {held_gain:+.1f} nats, p = {p:.2g}"
                                         + ("" if ok else ": not significant")))
            if not ok:
                break
        return verdict


class Reparameterisation(Check):
    """Not identifiable when the class's equivalent model WITHOUT the effect (``EffectModel.equivalent``: a bearing
    offset is a start heading and velocities turned by it) scores within ``FLAT_NATS`` of the candidate's fit: the
    gain is EM's slow convergence along the reparameterisation; that model becomes the candidate's better base
    (evidence: docs/results.md#the-searchs-checks)."""

    name = "reparameterisation"

    def applies(self, ctx: SearchContext, c: Candidate) -> bool:
        return c.significant and c.model.effect(c.name).equivalent(c.model) is not None

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        eq = c.model.effect(c.name).equivalent(c.model)
        ll_eq = ctx.loglik(eq)
        if c.loglik - ll_eq >= FLAT_NATS:
            return self.verdict(True, gains={"train": c.loglik - ll_eq})
        note = ("not identifiable from these data: the model without it explains the sightings as well "
                f"({ll_eq - c.loglik:+.1f} nats); " + (_class_of(c.name).REMEDY or "a reparameterization of the base model"))
        return self.verdict(False, gains={"train": c.loglik - ll_eq}, note=note, identifiable=False, escape=(eq, ll_eq))


class GivenItsOwnBase(Check):
    """The test repeated against the base model refitted from the candidate's own fit (the effect removed, everything
    else where the fit left it); a gain the base keeps without the effect was EM leaving a poor optimum of the base
    parameters while the effect was in. The training half's test only: two base fits of equal training likelihood can
    differ by tens of nats held out. The refitted base is the verdict's ``escape``: the search repeats the round from
    it when it beats the round's null (evidence: docs/results.md#the-searchs-checks)."""

    name = "given its own base"

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        escape = ctx.fit(c.model.without_effect(c.name))
        ll_esc = ctx.loglik(escape)
        gain = max(c.loglik - ll_esc, 0.0)
        p, ok = ctx.test(gain, np.inf, c.dof)
        note = "" if ok else (f"the base model refitted from its fit without it keeps the gain (train +{gain:.1f} nats "
                              f"over it, p = {p:.2g}): the base model was at a poorer optimum")
        return self.verdict(ok, gains={"train": gain}, p=p, note=note, escape=(escape, ll_esc))


class Plausibility(Check):
    """Not named when the fitted effect rests on a handful of data (``EffectModel.negligible``) or its values are not
    physically credible (``EffectModel.implausible``: a landmark "bias" of 30% stands in for something else)
    (evidence: docs/results.md#the-searchs-checks)."""

    name = "plausibility"

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        effect = c.model.effect(c.name)
        why = effect.negligible(sum(tr.n_sightings for tr in ctx.logs)) or effect.implausible()
        return self.verdict(not why, note=why)


class RobustLikelihoodRatio(Check):
    """The likelihood-ratio test again with the training gain divided by c, the factor by which the Fisher information
    overstates what the training halves carry about the effect's parameters (``SearchContext.overstatement``: the
    sandwich I^-1 J I^-1 against I^-1 on the candidate's fit, scores summed over 30 s blocks, c >= 1). When the model
    is not the data's (real logs: errors correlated over seconds, noise not Gaussian) 2 gain is not chi-square(dof)
    but a sum of chi-square(1)s weighted by that ratio's eigenvalues (Kent 1982); dividing by their mean is Satorra &
    Bentler's (1994) scaling. 1.0-4.4 on simulated logs; on the MRCLAM robots' half logs the effects' c are 1.8-17,
    and effects named on the strength of a few tens of nats do not hold on the other half of the log (evidence:
    docs/results.md#the-searchs-checks). Applies to a significant candidate with estimated parameters: a grid's
    (a lag) are profiled, not estimated (``flat grid profile``)."""

    name = "robust likelihood ratio"

    def applies(self, ctx: SearchContext, c: Candidate) -> bool:
        return c.significant and c.model is not None and c.dof > 0 and not _class_of(c.name).GRID

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        factor, errors = ctx.overstatement(c.model, c.name)
        gain = c.gain_train / factor
        p, ok = ctx.test(gain, c.gain_heldout, c.dof)
        note = (f"the Fisher information overstates the data's by x{factor:.2f} (sandwich, {OVERSTATEMENT_BLOCK_S:g} s "
                f"blocks): train +{c.gain_train:.1f} nats count as +{gain:.1f}, p = {p:.2g}" + ("" if ok else ": not significant"))
        return self.verdict(ok, gains={"train": gain}, p=p, note=note, overstatement=factor, standard_errors=errors)


class FlatGridProfile(Check):
    """A candidate profiled over a grid (``EffectModel.GRID``, e.g. a lag) whose profile spans less than ``FLAT_NATS``:
    the data cannot tell its values apart, not identifiable (the grid's profile is its identifiability check)."""

    name = "flat grid profile"

    def applies(self, ctx: SearchContext, c: Candidate) -> bool:
        return bool(_class_of(c.name).GRID) and bool(c.profile)

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        (_, lls), = c.profile.values()
        span = max(lls) - min(lls)
        return self.verdict(span >= FLAT_NATS, gains={"span": span},
                            **({} if span >= FLAT_NATS else {"note": _not_identifiable(c.name), "identifiable": False}))


class FrozenProbe(Check):
    """A candidate that is not significant, refitted with its estimate moved by its class's ``PROBE`` (a plausible
    strength) and frozen: within ``FLAT_NATS`` of its free fit, the profile is flat and the data cannot tell the effect
    from the base model: reported not identifiable, with the class's ``REMEDY``. It changes no decision (only a
    candidate already not significant is probed), so the search runs it on its last round only (evidence:
    docs/results.md#the-searchs-checks)."""

    name = "frozen probe"
    decides = False

    def applies(self, ctx: SearchContext, c: Candidate) -> bool:
        cls = _class_of(c.name)
        return not c.significant and c.identifiable and c.model is not None and bool(cls.PROBE) and not cls.GRID

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        effect = c.model.effect(c.name)
        shifted = {k: np.asarray(v) + np.asarray(effect.values()[k]) for k, v in _class_of(c.name).PROBE.items()}
        fitted = ctx.fit(c.model.with_effect(with_values(effect, shifted)), held(ctx.opts, c.name))
        drop = c.loglik - ctx.loglik(fitted)
        flat = drop < FLAT_NATS
        return self.verdict(not flat, gains={"train": -drop},
                            **({"note": _not_identifiable(c.name), "identifiable": False} if flat else {}))


class MotionSide(Check):
    """The named candidate's open-loop held-out gaps (``learners.discrepancy.score.motion_score``: each held-out
    sighting predicted from the filtered pose 1, 2 and 5 s earlier and the commands alone) against the current model's:
    an effect that improves the sensing while the motion gets worse beyond its noise is kept with this note, not
    silently (``aibo diagnose`` also compares the final models; evidence: docs/results.md#the-searchs-checks).
    Annotates only: the motion gap's excess over the one-step gap grew on every MRCLAM robot where the diagnosed model
    was the better one against Vicon."""

    name = "motion side"
    decides = False

    def applies(self, ctx: SearchContext, c: Candidate) -> bool:
        return c.model is not None and ctx.current is not None

    def run(self, ctx: SearchContext, c: Candidate) -> Verdict:
        trade = motion_trade(motion_score(ctx.current, ctx.logs), motion_score(c.model, ctx.logs))
        worse = {h: d for h, d in trade.items() if np.isfinite(d["z"]) and d["z"] > MOTION_WORSE_Z}
        note = ("" if not worse else "the motion gets worse while the sensing improves: open-loop gap "
                + ", ".join(f"{h} s {d['change']:+.3f} nats (z {d['z']:+.1f})" for h, d in worse.items()))
        return self.verdict(not worse, gains={f"motion_{h}s": -d["change"] for h, d in trade.items()}, note=note)


def _class_of(name: str):
    from learners.model.probes import PROBES

    return EFFECT_MODELS[name] if name in EFFECT_MODELS else PROBES[name]


def _not_identifiable(name: str) -> str:
    return "not identifiable from these data: " + (_class_of(name).REMEDY or "its profile likelihood is flat")


#: a catalogue candidate's checks, in order (the likelihood-ratio test runs with its fit: ``tested``)
CANDIDATE_CHECKS: tuple[Check, ...] = (GivenNuisance(), Reparameterisation(), GivenItsOwnBase(), Plausibility(),
                                       RobustLikelihoodRatio(), FlatGridProfile())
#: a "none of the above" probe's checks, in order
PROBE_CHECKS: tuple[Check, ...] = (GivenNuisance(), GivenItsOwnBase(), RobustLikelihoodRatio())
#: run on the last round's candidates only (they change no decision)
LAST_ROUND_CHECKS: tuple[Check, ...] = (FrozenProbe(),)
