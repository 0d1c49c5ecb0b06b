"""The discrepancy search's fits and likelihoods, and the context one round of it shares.

Every fit of the search is EM warm-started from a model of the search (one start, no alias search, no lag search, no
standard errors), compared with another fit by the E-step's log-likelihood on the same sightings
(:func:`train_loglik`), never by the fit's own gated one. :class:`SearchContext` carries what the fits and tests of a
round share, so that a check (``learners.discrepancy.checks``) is a function of (context, candidate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
from scipy import stats

from aibo_core.trajectory import Trajectory
from learners.arrays.batch import Batch, make_batch
from learners.arrays.posterior import Posterior
from learners.base import LearnResult
from learners.em.estep import e_step
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.model.effects import EffectModel
from learners.model.model import Model

from .score import score

ALPHA = 0.01  # false-alarm level of one round of the search (all candidates together)
FLAT_NATS = 2.0  # a frozen probe within this many nats of the free fit: a flat profile
ZERO_DOF_NATS = 3.0  # a zero-parameter effect must gain this much, on the training AND the held-out half
#: The stop rule of the search's warm-started fits (the base's polish, every candidate, every refit): no new best
#: likelihood (by ``EMOptions.min_improvement``) for this many iterations. ``aibo learn``'s 50 (the paper's) made every
#: warm-started fit at least 51 iterations, most of them spent after convergence (measured on MRCLAM robot 1 with
#: bias states: 51-59 iterations at 190 ms each for candidates that had converged at once).
SEARCH_PATIENCE = 15
HELD_MAX_ITER = 150  # EM iterations of a fit with one effect held (a grid or profile point, the frozen probe)


def fit(logs: list[Trajectory], init: Model | None, opts: EMOptions, action_model: str | None = None,
        initial: tuple | None = None) -> Model:
    """EM on ``logs`` from ``init`` (the paper's start when None; one start when warm-started). The alias search
    (``learners.em.alias``) runs in the base fit from the paper's start only: a warm-started refit that switched a
    command to its alias would credit the jump in likelihood to the effect tried."""
    return _learner(opts, init).fit(logs, init=init, action_model=action_model, initial=initial).params


def _learner(opts: EMOptions, init: Model | None) -> EMLearner:
    """The learner of :func:`fit`."""
    # no lag search: the search profiles actuation_lag itself, as a candidate (named, tested like the others); no
    # standard errors: only the parameters are kept (the report's intervals are the final fit's, on the whole logs)
    opts = replace(opts, lag_search=False, uncertainty=False)
    # a warm start is one start: screening stretched copies of a converged model's curve (the paper's-start rescue,
    # ``learners.em.starts``) only spends 60 iterations per fit before start 0 wins as it would alone
    return EMLearner(opts if init is None else replace(opts, alias_search=False, starts=1), check_field=False)


def fit_from_paper_start(logs: list[Trajectory], opts: EMOptions, action_model: str | None = None,
                         initial: tuple | None = None) -> tuple[Model, LearnResult | None]:
    """(EM from the paper's start on ``logs``, as :func:`fit`; its refit with spurious sightings where it ended in a
    wrong world and the refit found the field, else None: ``EMLearner.fit_in_field``). The search keeps the first fit
    as its base and gives the refit to ``false_sightings`` as a second start (docs/results.md, "Spurious sightings:
    the search's second start")."""
    first, refit = _learner(opts, None).fit_in_field(logs, action_model, initial)
    return first.params, refit


def learned(logs: list[Trajectory], opts: EMOptions, action_model: str | None = None) -> Model:
    """``aibo learn``'s model of ``logs`` (EM from the paper's start with the options ``opts``, no standard errors; a
    wrong world refitted with spurious sightings as learn refits it, ``EMLearner.fit_in_field``): the final fit's second
    start (``final.final_starts``), and the judge of the outliers where the search's base fit gates many
    (``search.base_and_outliers``)."""
    first, refit = EMLearner(replace(opts, uncertainty=False), check_field=False).fit_in_field(logs, action_model)
    return (first if refit is None else refit).params


def train_loglik(model: Model, train: list[Trajectory]) -> float:
    """``model``'s log-likelihood (nats) of the sightings of ``train`` (the E-step's, ungated)."""
    return float(e_step(model, make_batch(train), "compiled").loglik)


def held(opts: EMOptions, name: str) -> EMOptions:
    """``opts`` for a fit with effect ``name`` held at the values it starts from (a grid or profile point, the frozen
    probe): at most HELD_MAX_ITER iterations."""
    return replace(opts, frozen=opts.frozen + (name,), max_iter=min(opts.max_iter, HELD_MAX_ITER))


def with_values(effect: EffectModel, values: dict[str, Any]) -> EffectModel:
    """``effect`` with ``values`` (scalars as floats, arrays as float arrays)."""
    return effect.with_values(**{k: (float(v) if np.ndim(v) == 0 else np.asarray(v, float)) for k, v in values.items()})


def lr_test(gain: float, held_gain: float, dof: int, n_tests: int) -> tuple[float, bool]:
    """(p, significant) of an effect that gains ``gain`` nats on the training half and ``held_gain`` on the held-out
    half with ``dof`` parameters, one of ``n_tests`` tests: p of the likelihood-ratio test 2 gain ~ chi-square(dof),
    significant below ALPHA / n_tests (Bonferroni) with a held-out gain > 0. With no parameter (dof 0: nothing is
    estimated, e.g. ``wall_contact``'s contacts read off the smoothed path) there is no such test: significant when
    both gains exceed ``ZERO_DOF_NATS`` (p then for reference only, as if of one dof)."""
    p = float(stats.chi2.sf(2.0 * gain, max(dof, 1)))
    if dof == 0:
        return p, gain > ZERO_DOF_NATS and held_gain > ZERO_DOF_NATS
    return p, p < ALPHA / max(n_tests, 1) and held_gain > 0


@dataclass(frozen=True)
class SearchContext:
    """What the fits and tests of one round of the search share (it replaces their long argument lists)."""

    train: list[Trajectory]  # the training halves, outliers set aside: every fit's data
    logs: list[Trajectory]  # the whole logs, outliers set aside: every held-out score's
    opts: EMOptions  # the warm-started fits' options
    current: Model | None = None  # the model this round extends
    null_ll: float = math.nan  # the null's training log-likelihood (nats): ``current`` refitted as the candidates are
    null_heldout: float = math.nan  # the null's held-out log-likelihood (nats)
    n_tests: int = 1  # the tests sharing the level ALPHA this round

    def fit(self, init: Model, opts: EMOptions | None = None) -> Model:
        """EM on the training halves from ``init`` (:func:`fit`), with this round's options unless ``opts``."""
        return fit(self.train, init, self.opts if opts is None else opts)

    @cached_property
    def batch(self) -> Batch:
        """The training halves as one batch (made once per context and process)."""
        return make_batch(self.train)

    @cached_property
    def posterior(self) -> Posterior:
        """``current``'s E-step on the training halves (its smoothed path: the probes' and nuisances' covariates)."""
        return e_step(self.current, self.batch, "compiled")

    def loglik(self, model: Model) -> float:
        """``model``'s training log-likelihood (nats; :func:`train_loglik`)."""
        return float(e_step(model, self.batch, "compiled").loglik)

    def heldout(self, model: Model) -> float:
        """``model``'s held-out log-likelihood (nats; ``learners.discrepancy.score``)."""
        return score(model, self.logs).heldout_loglik

    def overstatement(self, model: Model, name: str) -> tuple[float, dict[str, list | float]]:
        """(How many times the Fisher information of ``model`` on the training halves overstates what they carry about
        effect ``name``'s parameters, ``learners.em.uncertainty.information_overstatement`` over blocks of
        ``OVERSTATEMENT_BLOCK_S``; those parameters' robust standard errors there, by parameter name, in the model
        file's units), from one ``parameter_uncertainty`` with the coordinates the fit held, held."""
        from learners.em.accel import Packer
        from learners.em.learner import fit_options
        from learners.em.uncertainty import OVERSTATEMENT_BLOCK_S, information_overstatement, parameter_uncertainty

        fixed = Packer(fit_options(self.opts, self.batch, model)[0]).fixed
        unc = parameter_uncertainty(model, self.batch, fixed)
        prefix = f"effects.{name}."
        errors = {k[len(prefix):]: np.asarray(v, dtype=float).tolist()
                  for k, v in (unc.robust_standard_errors or unc.standard_errors).items()
                  if k.startswith(prefix) and v is not None and np.all(np.isfinite(np.asarray(v, dtype=float)))}
        return information_overstatement(unc, prefix, OVERSTATEMENT_BLOCK_S), errors

    def test(self, gain: float, held_gain: float, dof: int) -> tuple[float, bool]:
        """:func:`lr_test` as one of this round's ``n_tests``."""
        return lr_test(gain, held_gain, dof, self.n_tests)
