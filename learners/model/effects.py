"""Effects: model components for real-world effects the base model lacks (the learner's twins of
the simulator's ``aibo_gym.effects``, registered under the same names).

An effect is a ``Component`` (walk-through: ``docs/adding-an-effect.md``) that
- ``lower(lo, batch)``: writes itself into the lowered arrays (``learners.arrays.lowered``),
  e.g. a per-sighting size scale, by replacing them (the neutral ones are shared, read-only); no
  kernel changes;
- ``maximize(model, batch, post)``: its conditional M-step (ECM: the other parameters held at
  their newest values), returning the new Model (it may also re-normalize another component);
- ``start(batch)``: its neutral value sized for the data (the effect switched off);
- ``predictive()`` and ``predictive_logdens(base, innov, batch, idx)``: a mixture's density of a sighting
  (default: the Gaussian), used by the E-step's likelihood and the held-out score.

It also carries what the discrepancy search and the tests need: ``SIGNATURE`` (the residual signature
that shows it missing), ``PROBE`` and ``REMEDY`` (identifiability) and ``EXAMPLE`` (a parameter set).
Register one with ``@register_effect``; ``EFFECT_MODELS`` maps names to classes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import numpy as np

from aibo_core.geometry import wrap
from learners.arrays.batch import Batch
from learners.arrays.innovations import Innovations, belief_innovations, joint_belief
from learners.arrays.lowered import Lowered, sighting_model
from learners.arrays.posterior import Posterior
from learners.model.parameters import Component, Param, as_numbers

if TYPE_CHECKING:
    from learners.model.model import Model


@dataclass(frozen=True)
class ConditionalInformation:
    """An effect's own likelihood of the sightings with the forward filter held, about its maximum
    (``EffectModel.conditional_information``): the inverse observed information over k coordinates (the effect's
    parameters ``names`` first, then nuisances estimated with them), and each applied sighting's score (its log density's
    gradient over the same coordinates) in the order of ``rows`` (batch sighting indices, in time order)."""

    names: tuple[str, ...]  # the effect's parameters, the first len(names) coordinates (scalars)
    cov: np.ndarray  # (k, k) inverse of the observed information (nats^-1, the coordinates' units squared)
    scores: np.ndarray  # (n, k) d log density / d coordinate of each sighting of ``rows``
    rows: np.ndarray  # (n,) the sightings (indices into the batch), in time order


class EffectModel(Component):
    """Base of the effect components (module docstring). Every hook is optional."""

    name: ClassVar[str] = ""
    #: the residual signature (part of a ``learners.discrepancy.signatures`` "residual vs variable" name)
    #: that shows when the effect is missing; "" when none (a constant offset, outliers)
    SIGNATURE: ClassVar[str] = ""
    #: other statistics of the calibrated check that show it missing, beside ``SIGNATURE`` (parts of their names): a
    #: delay shows against the time since a command changed and, signed, against how much the command changed
    ALSO_SIGNATURES: ClassVar[tuple[str, ...]] = ()
    #: Parameters estimated by profile likelihood over a grid (outside EM), e.g. a lag: name -> grid.
    GRID: ClassVar[dict[str, tuple[float, ...]]] = {}
    #: What the effect needs from the logs besides commands and sightings (``"head_pan"``, ``"field"``).
    NEEDS: ClassVar[tuple[str, ...]] = ()
    #: A plausible strength (in the parameters' units) for the identifiability probe of
    #: ``learners.discrepancy.search``: a candidate that is not significant is refitted with its estimate
    #: moved by this step and frozen; {} (no probe) for an effect without a meaningful step.
    PROBE: ClassVar[dict[str, Any]] = {}
    #: What would make the effect identifiable when the data cannot tell it from the base model ("":
    #: the report says its profile likelihood is flat).
    REMEDY: ClassVar[str] = ""
    #: A realistic parameter set (every key of ``PARAMS``; array parameters of a 4-beacon field), valid
    #: for ``cls.start(batch).with_values(**EXAMPLE)`` and for the simulator twin: the tests use it.
    EXAMPLE: ClassVar[dict[str, Any]] = {}
    #: Effects lower (``Model.lower``) in this order, the order they were added within one value: a constraint on
    #: the motion (``wall_contact``: 1) after every effect that moves the robot (a floor drift).
    LOWER_ORDER: ClassVar[int] = 0
    #: Whether ``start`` switches the effect off (its values the neutral ones: a rate 0, a scale 1); False where EM
    #: needs a weak effect to start from (a bias of 1%, a few spurious sightings).
    STARTS_OFF: ClassVar[bool] = True
    #: The order ``predictive_logdens`` hooks run in (``learners.em.predictive.model_logdens``): 0 a hook that reshapes
    #: the Gaussian (a scale mixture of the noise), 1 a mixture with a non-Gaussian component that wraps it (spurious
    #: sightings: (1 - rate) x whatever the real sightings' density is + rate x uniform).
    DENSITY_ORDER: ClassVar[int] = 0
    #: Whether ``aibo diagnose`` tries the effect by default (False: only when ``--candidates`` names it, for an
    #: effect whose evidence on real logs is not yet good enough to be named without being asked for).
    DEFAULT_CANDIDATE: ClassVar[bool] = True
    #: Nuisances the effect can stand in for (classes with ``around(post, batch)``, ``n_frames()``, ``given()``; e.g.
    #: ``WallSlowdown``): the search tests a significant candidate again given each (``checks.GivenNuisance``).
    CONFOUNDERS: ClassVar[tuple[type, ...]] = ()
    #: The parameters of a covariance, not of the path's mean (a bias process's sd and correlation time): ``aibo
    #: diagnose``'s final fit moves them to the restricted likelihood's maximum by one Newton step
    #: (``learners.em.restricted.restricted_step``), as mixed models estimate variance components beside fitted means.
    VARIANCE_PARAMS: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def signatures(cls) -> tuple[str, ...]:
        """Every residual signature of the effect: ``SIGNATURE`` and ``ALSO_SIGNATURES`` (none: ())."""
        return tuple(s for s in (cls.SIGNATURE, *cls.ALSO_SIGNATURES) if s)

    @classmethod
    def leaves(cls, statistic: str) -> bool:
        """Whether ``statistic`` (a calibrated check's statistic or a "residual vs variable" signature name) is one
        of the effect's residual signatures: what a model without the effect gets wrong."""
        return any(s in statistic for s in cls.signatures())

    def negligible(self, n_sightings: int) -> str:
        """Why the fitted effect is too small to name ("" when it is not), on data of ``n_sightings``
        sightings: a significant likelihood gain that rests on a handful of data points is an outlier
        set aside, not an effect. Default: never negligible."""
        return ""

    def implausible(self) -> str:
        """Why the fitted values are not physically credible for this effect ("" when they are): a
        significant gain at such values means the effect stands in for something else (a wrong world,
        outliers), so it is not named. Default: always credible."""
        return ""

    def ridge_possible(self) -> bool:
        """Whether a fit that ended at implausible values (:meth:`implausible`) may have climbed a ridge before the
        base model adapted to the effect, so that the search's staged refit (``learners.discrepancy.search.staged``:
        the rest first with the effect frozen at its warm start, then everything) may end elsewhere. False where the
        implausible values are the model's own limit, which EM returns to from any start. Default: True."""
        return True

    def dof(self) -> int:
        """Free numbers the effect adds (for the likelihood-ratio test): grid parameters count one each.
        A normalization declared by a parameter's transform (``Param.constraints``: a ``"logcontrast"``
        group) is subtracted, as it is from the packed vector."""
        return sum(1 if name in self.GRID else np.size(v) - self.PARAMS[name].constraints
                   for name, v in self.values().items())

    def equivalent(self, model: "Model") -> "Model | None":
        """A model WITHOUT this effect that predicts every sighting exactly as ``model`` (which holds it)
        does, when the effect is a reparameterization of the base model (a structural non-identifiability);
        None when there is none (default). The discrepancy search scores it: a significant gain that the
        equivalent model matches is EM's slow convergence along that direction, not the effect."""
        return None

    def undetermined(self, batch: Batch) -> list[str]:
        """The entries (``"scale[3]"``) no applied sighting of ``batch`` can depend on, so that EM keeps them at
        their start (``learners.em.support.check_support`` lists them, like a command never executed); default:
        none."""
        return []

    def warm_start(self, model: "Model", batch: Batch, loglik: Callable[["Model"], float]) -> "EffectModel":
        """A start for EM given the rest of the model (``model`` holds this effect); default: itself.
        An effect whose parameters EM moves slowly from ``start`` picks a better one here; ``loglik`` gives a
        model's log-likelihood (nats) on ``batch`` (one forward pass: ``learners.em.estep.forward_loglik``; the
        model's components never run inference themselves)."""
        return self

    def polish(self, model: "Model", batch: Batch, loglik: Callable[["Model"], float]) -> "EffectModel":
        """This effect's parameters maximizing ``loglik`` (the likelihood itself, one forward pass per call) with the
        rest of ``model`` held: a conditional maximization step on the observed-data likelihood (ECME, Liu & Rubin
        1994), which EM's loop takes once it has converged when ``EMOptions.polish`` is on (``learners.em.fit``);
        default: itself. For an effect whose M-step, a maximum of the expected complete-data likelihood, moves its
        parameters slowly along a ridge of the likelihood (``landmark_bias``: docs/results.md, calibration)."""
        return self

    def grid_resolution(self, pname: str, batch: Batch) -> float | None:
        """The step below which grid parameter ``pname`` does not change the model on ``batch`` (a lag of discrete
        commands acts in whole frames: the frame, s), so that its profile at that step is the exact one; None where
        it acts continuously (its interval is then the search's grid one, with the grid's step). Default: None."""
        return None

    def commands(self, commands: np.ndarray, batch: Batch) -> np.ndarray:
        """The commands in force per frame (e.g. delayed by a lag); default: as logged."""
        return commands

    def disp_scale(self, batch: Batch) -> np.ndarray | None:
        """Factor on each frame's mean displacement, or None: (N,) one per frame for all three components
        (e.g. a fading battery), or (N, 3) per component (forward, lateral, turn; e.g. a turn scale)."""
        return None

    def lower(self, lo: Lowered, batch: Batch) -> None:
        """Write the effect into the lowered arrays (replacing them); default: nothing."""

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """The conditional M-step (ECM); default: nothing (grid parameters are profiled outside EM).

        ``mu_star`` (N, 3): the action statistics of this M-step (posterior mean robot-frame displacement
        of each frame net of the previous world offset, the prior's pull included: ``learners.inference``)."""
        return model

    def conditional_information(self, model: "Model", batch: Batch, post: Posterior) -> "ConditionalInformation | None":
        """Where the Fisher information of the EKF's innovations (``learners.em.uncertainty``) cannot see this effect's
        parameters (a mixture's rate and width change each sighting's density, not the filter): the observed
        information of the effect's own likelihood given ``post`` (the forward filter held) and each sighting's score,
        from which the caller makes the standard errors and their robust (sandwich) form. None by default (the
        filter's information is the one)."""
        return None

    def predictive(self) -> "EffectModel":
        """The effect as it enters a sighting's OWN predictive density (default: itself). An effect whose
        ``lower`` uses the sightings themselves (responsibilities) returns itself without that part."""
        return self

    def predictive_logdens(self, base_logdens: np.ndarray, innov: Innovations, batch: Batch,
                           idx: np.ndarray) -> np.ndarray:
        """The model's log density of sightings ``idx`` given their log densities so far ``base_logdens`` (the
        Gaussian predictive one, or an earlier effect's hook's) and their innovations ``innov`` (the prediction's
        share of the covariance and the sensor's own noise apart: ``learners.arrays.innovations``); default:
        ``base_logdens`` itself. A mixture overrides it (spurious sightings, a scale mixture of the noise); the
        E-step's likelihood and the scores then use it. Hooks run in ``DENSITY_ORDER``."""
        return base_logdens

    @classmethod
    def start(cls, batch: Batch) -> "EffectModel":
        """The effect switched off, sized for ``batch``; default: every (scalar) parameter 0 and no
        other field set. Effects with array parameters or extra state override it."""
        return cls(**{name: 0.0 for name in cls.PARAMS})

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "parameters": {k: v.tolist() for k, v in self.values().items()}}


EFFECT_MODELS: dict[str, type[EffectModel]] = {}


def register_effect(cls: type[EffectModel]) -> type[EffectModel]:
    """Class decorator: make ``cls`` available under ``cls.name``."""
    if not cls.name:
        raise ValueError(f"effect class {cls.__name__} has no name")
    EFFECT_MODELS[cls.name] = cls
    return cls


def effect_from_json(doc: Any, source: str) -> EffectModel:
    """An effect from its model-file entry ``{"name": ..., "parameters": {...}}``: every parameter a
    number (or list) in its declared shape and domain (``Param.domain_error``); ValueError naming the
    file and the field otherwise."""
    if not isinstance(doc, dict) or doc.get("name") not in EFFECT_MODELS:
        valid = ", ".join(sorted(EFFECT_MODELS))
        raise ValueError(f"{source}: field 'effects': unknown effect {doc!r:.80} (valid choices: {valid})")
    cls = EFFECT_MODELS[doc["name"]]
    params = doc.get("parameters")
    if not isinstance(params, dict) or set(params) != set(cls.PARAMS):
        raise ValueError(f"{source}: field 'effects.{cls.name}.parameters': expected keys {sorted(cls.PARAMS)}")
    values = {}
    for key, value in params.items():
        where = f"{source}: field 'effects.{cls.name}.parameters.{key}'"
        try:
            arr = as_numbers(value)
        except ValueError as err:
            raise ValueError(f"{where}: {err}") from None
        problem = cls.PARAMS[key].domain_error(arr)
        if problem:
            raise ValueError(f"{where}: {problem}")
        values[key] = float(arr) if arr.shape == () else arr
    return cls(**values)


def cubature_distances(batch: Batch, post: Posterior) -> tuple[np.ndarray, np.ndarray]:
    """(sighting indices (n,), distances (n, 6) mm) of the used sightings at the 6 cubature points of
    the smoothed pose beliefs (mu +- sqrt(3) L e_j, L = chol(Sigma_gamma)), as the sensor M-step."""
    idx = np.flatnonzero(batch.used)
    pose = batch.sight_pose[idx]
    L = np.linalg.cholesky(post.cov_gamma[pose])
    s3L = np.sqrt(3.0) * np.swapaxes(L, 1, 2)
    mu = post.mu_gamma[pose]
    pts = np.concatenate([mu[:, None, :] + s3L, mu[:, None, :] - s3L], axis=1)
    d = np.hypot(batch.sight_xy[idx, None, 0] - pts[..., 0], batch.sight_xy[idx, None, 1] - pts[..., 1])
    return idx, d


def smoothed_innovations(lo: Lowered, batch: Batch, post: Posterior) -> tuple[np.ndarray, Innovations]:
    """(indices (n,), innovations) of the used sightings at the smoothed path: v = z - h(mu_gamma) (with a size bias
    state, its smoothed value), the smoothed belief's share H Sigma_gamma H^T and ``lo``'s noise R: what a noise
    mixture's M-step weighs (responsibilities at the path, first order in its uncertainty)."""
    idx = np.flatnonzero(batch.used)
    pose = batch.sight_pose[idx]
    if lo.extra is None or post.extra is None:  # the pose alone (as the sensor M-step: the same arithmetic)
        h, H, rd = sighting_model(lo, post.mu_gamma[pose], batch.sight_xy[idx], idx)
        v = batch.sight_value[idx] - h
        v[:, 1] = wrap(v[:, 1])
        return idx, Innovations(v, H @ post.cov_gamma[pose] @ np.swapaxes(H, 1, 2), rd)
    return idx, belief_innovations(lo, batch, idx, *joint_belief(lo, post, idx, pose, smoothed=True))


def geometric_mean_one(num: np.ndarray, den: np.ndarray, log_product: float) -> np.ndarray:
    """Factors s (B,) maximizing -sum_b (den_b s_b^2 - 2 num_b s_b) (a weighted least squares of sizes on the curve
    per landmark: den_b = sum f^2, num_b = sum f z, both > 0) subject to sum_b log s_b = ``log_product``. Lagrange:
    den_b s_b^2 - num_b s_b + lam = 0, so s_b(lam) = (num_b + sqrt(num_b^2 - 4 den_b lam)) / (2 den_b), the larger
    root (the maximum); sum log s_b falls with lam, whose root is bracketed in (-inf, min num_b^2 / (4 den_b)] and
    found by Brent's method (lam = 0 gives the unconstrained s_b = num_b / den_b)."""
    def factors(lam: float) -> np.ndarray:
        return (num + np.sqrt(np.maximum(num * num - 4.0 * den * lam, 0.0))) / (2.0 * den)

    def excess(lam: float) -> float:
        return float(np.sum(np.log(factors(lam)))) - log_product

    hi = float(np.min(num * num / (4.0 * den)))
    if excess(hi) >= 0.0:  # even the smallest factors are too large (a common shrink of ~2x): the nearest point
        return factors(hi)
    low = -abs(hi) - 1.0
    while excess(low) < 0.0:
        low *= 2.0
    from scipy.optimize import brentq  # here, not at import (SciPy's load costs every command)

    return factors(brentq(excess, low, hi, xtol=1e-15 * max(1.0, abs(hi)), rtol=4 * np.finfo(float).eps))


@register_effect
@dataclass(frozen=True)
class BeaconHeightScale(EffectModel):
    """Beacons differ in physical height: the size of landmark b is ``scale[b] * f(d)``.

    ``scale`` (one factor per landmark) is normalized to geometric mean 1: a common factor is
    the sensor curve's. It is packed (SQUAREM, standard errors) as the B - 1 contrasts of its
    logs (transform ``"logcontrast"``), so the common factor is the curve's alone. Residual signature
    without it: size residuals depend on the landmark's identity.
    """

    scale: np.ndarray  # (B,) dimensionless

    name: ClassVar[str] = "beacon_height_scale"
    SIGNATURE: ClassVar[str] = "size (sigma) vs landmark"
    PARAMS: ClassVar[dict[str, Param]] = {  # normalized to geometric mean 1: B - 1 free numbers
        "scale": Param("factor per landmark", "logcontrast", low=1e-6, high=1e3, shape=(-1,))}
    EXAMPLE: ClassVar[dict[str, Any]] = {"scale": np.array([1.02, 0.98, 1.01, 0.99])}

    @classmethod
    def start(cls, batch: Batch) -> "BeaconHeightScale":
        return cls(np.ones(len(batch.landmarks)))

    def lower(self, lo: Lowered, batch: Batch) -> None:
        lo.size_scale = lo.size_scale * self.scale[batch.sight_landmark]

    def undetermined(self, batch: Batch) -> list[str]:
        """The factors of the landmarks never sighted (among the applied sightings)."""
        seen = np.bincount(batch.sight_landmark[batch.used], minlength=len(self.scale)) > 0
        return [f"scale[{b}]" for b in np.flatnonzero(~seen)]

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """The conditional maximum given the curve (ECM), the factors held at geometric mean 1: per landmark the
        weighted least squares of the sizes on f(d) (cubature points, weights 1 / size_var_factor; sums num_b =
        sum f z, den_b = sum f^2) under sum log scale = 0 (``geometric_mean_one``). The common level is the curve's,
        fitted in its own step: this one never moves the curve. (It used to move the unconstrained factors' common
        factor into the curve's coefficients, which broke a curve held at range = distance (``EMOptions.range_curve``):
        on MRCLAM robot 4's first half the held range curve drifted to 1.069 x distance, the forward speed trading
        with it.) A landmark never sighted keeps its factor (its start, 1: the data say nothing of it) and the sighted
        ones keep the product they had (``learners.em.uncertainty`` reports it as undetermined)."""
        lo = model.lower(batch)
        idx, d = cubature_distances(batch, post)
        f = model.sensor.mean(d) * (lo.size_scale[idx] / self.scale[batch.sight_landmark[idx]])[:, None]
        z = (batch.sight_value[idx, 0] - lo.size_offset[idx])[:, None]
        w = 1.0 / lo.size_var_factor[idx][:, None]
        B = len(self.scale)
        lm = batch.sight_landmark[idx]
        num = np.bincount(lm, weights=(w * f * z).sum(axis=1), minlength=B)
        den = np.bincount(lm, weights=(w * f * f).sum(axis=1), minlength=B)
        seen = den > 0
        if not seen.any() or np.any(num[seen] <= 0):
            return model
        scale = self.scale.copy()
        scale[seen] = geometric_mean_one(num[seen], den[seen], float(np.sum(np.log(self.scale[seen]))))
        return model.with_effect(BeaconHeightScale(scale))

