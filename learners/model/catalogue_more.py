"""Learner-side twins of the simulator's ``false_sightings`` and ``wall_contact`` (``aibo_gym/catalogue.py``;
same names and parameter names). Both carry per-sighting or per-frame quantities computed in their
M-step from the latest posterior (non-parameter fields, recomputed every M-step, tied to the batch
they were computed on by a key: on another batch they are not applied).

=================  ==============================================  =======================================
name               how the model carries it                        its M-step
=================  ==============================================  =======================================
false_sightings    a mixture: real (the Gaussian) with probability  responsibilities w = P(real | z) at the
                   1 - rate, spurious (uniform over the data's      smoothed path; rate = mean(1 - w); the
                   box of sizes x image positions) with ``rate``;   sensor's sigmas re-weighted by w
                   in the filter a sighting's variances x 1/w
wall_contact       each frame's outward world motion cancelled      each frame's contact probability per
                   (``offset``) times the probability that its      wall from the smoothed end pose's
                   end pose is within ``MARGIN_MM`` of that wall    mean and variance
=================  ==============================================  =======================================

false_sightings, in the filter: the EKF cannot carry a mixture; each sighting's size and bearing
variances are multiplied by 1/w (w floored at ``W_FLOOR``; ``size_var_factor`` and
``bearing_var_factor`` of the lowered arrays), so a spurious sighting pulls the path little. Only
the spurious sightings that survive the outlier gate (Mahalanobis^2 <= 50 at the first iteration)
are left for the mixture to weigh. The likelihood (the E-step's and the
held-out score's) is the mixture's: (1 - rate) N(z; filter's prediction, un-inflated noise) + rate u.
In the held-out score the responsibilities are not applied (they belong to the training batch):
the filter there is the plain Gaussian one, the densities the mixture's (causal, conservative).

wall_contact: the walls are where the log's ``field`` says (clamp walls: the robot's centre stays
on the field). The contacts come from the training half's smoothed path, so in the held-out
score (same frames) they are decided with the training half's sightings of the whole log (past and
future; never the held-out ones). A contact is a probability, not a 0/1 snapshot (a deviation from
a hard wall; the filter's motion stays linear): P(|x_end| > half - ``MARGIN_MM``) per axis under the
smoothed marginal N(mean, var) of the end pose, and the lowered model cancels that share of the
outward motion (the expected cancellation to first order). Measured on the blind 10-minute logs of
``scripts/diagnose_power.py``'s drift + walls pair (drift [15, -10] mm/s pushing into a corner, seeds
5000-5009): with contacts 0/1 by the smoothed mean the drift was named on 5 of 10 logs, within 5 mm/s
on 3; with the probability, on 9 and 9 (docs/results.md). The drift's M-step leaves out every frame a
wall may block (``Lowered.blocked``: a contact probability of ``MIN_PROBABILITY`` or more): only the frames
at least 1/2 likely blocked, the drift came out shrunk by a tenth (within tolerance on 8 of 10). On
seed 5004 the 0/1 rule flagged 3,627 frames, of which 1,158 had their true pose more than 5 mm from a
wall, and missed 462 of the 2,931 against one; the drift's fit stopped 1.2 nats (training) below the
true drift held fixed, and scored -8.3 nats held out where the true drift scored +6.6.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.innovations import Innovations
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.model.effects import ConditionalInformation, EffectModel, register_effect, smoothed_innovations
from learners.model.parameters import Param

if TYPE_CHECKING:
    from learners.model.model import Model

W_FLOOR = 1e-4  # false_sightings: responsibilities floored here (variances x 1e4 at most: no information left)
MAX_RATE = 0.5  # false_sightings: as the simulator's bound
START_RATE = 0.05  # false_sightings: EM cannot leave rate 0 (every w is 1 there)
INNER = 10  # false_sightings: mixture EM iterations (w, rate, sigmas) per M-step at the fixed smoothed path


def _digest(a: np.ndarray) -> str:
    """A digest of an array's bytes that is the same in every process and run (``hash`` of bytes is salted per
    interpreter: a key made in one process would not match in a spawned worker or a later run)."""
    return hashlib.blake2b(np.ascontiguousarray(a).tobytes(), digest_size=16).hexdigest()


def sighting_key(batch: Batch) -> tuple:
    """What ties per-sighting state (a mixture's weights) to the batch it was computed on: the sightings' count and
    digests of their values and landmarks."""
    return (batch.n_sightings, _digest(batch.sight_value), _digest(batch.sight_landmark))


def _frame_key(batch: Batch) -> tuple:
    cmds = batch.actions if batch.actions is not None else batch.controls
    return (batch.n_frames, _digest(batch.frame_start), _digest(cmds))


def _real_probability(v: np.ndarray, hph: np.ndarray, var_size: np.ndarray, var_bearing: np.ndarray, rate: float,
                      log_u: float) -> np.ndarray:
    """(n,) w: each sighting's probability of being real, (1 - rate) N(v; 0, HPH^T + R) / (that + rate u), R the
    diagonal (``var_size``, ``var_bearing``, (n,) each) and ``v`` (n, 2) the innovations at the smoothed path. This
    arithmetic, not ``Innovations.logdens``': EM's path with the mixture is chaotic (SQUAREM's jumps on a likelihood
    its responsibilities reshape), and last-bit differences moved one fit by 10,000 nats."""
    s00, s11, s01 = hph[:, 0, 0] + var_size, hph[:, 1, 1] + var_bearing, hph[:, 0, 1]
    det = s00 * s11 - s01 ** 2
    m2 = (s11 * v[:, 0] ** 2 - 2 * s01 * v[:, 0] * v[:, 1] + s00 * v[:, 1] ** 2) / det
    a = math.log1p(-rate) - 0.5 * (m2 + np.log(det)) - math.log(2.0 * math.pi)
    b = math.log(rate) + log_u
    return np.exp(a - np.logaddexp(a, b))


def spurious_log_density(batch: Batch) -> float:
    """log u: a spurious sighting's density, uniform over the box of the used sightings' sizes and
    positions in the image (bearing - head pan; the whole circle without a head pan)."""
    z = batch.sight_value[batch.used]
    size_span = float(np.ptp(z[:, 0])) if len(z) > 1 else 1.0
    if batch.head_pan is not None and len(z) > 1:
        angle_span = float(np.ptp(batch.image_angle[batch.used]))
    else:
        angle_span = 2.0 * math.pi
    return -math.log(max(size_span, 1e-9) * max(angle_span, 1e-9))


class WeighedSightings:
    """What a noise mixture's effect does in the filter (the EKF carries one Gaussian): each sighting's size and bearing
    variances divided by a weight ``w`` its M-step computed at the smoothed path (fields ``w``, (S,), and ``key``, the
    batch it belongs to; floored at ``W_FLOOR``); a sighting's OWN density (``predictive``) without them."""

    def lower(self, lo: Lowered, batch: Batch) -> None:
        if self.weighs(batch):
            inv = 1.0 / np.maximum(self.w, W_FLOOR)
            lo.size_var_factor = lo.size_var_factor * inv
            lo.bearing_var_factor = lo.bearing_var_factor * inv

    def predictive(self):
        return replace(self, w=None, key=None)

    def weighed(self, model, batch: Batch, post: Posterior):
        """This effect with its weights ``w`` computed on ``batch`` at ``post``'s smoothed path, its parameters held
        (``learners.em.estep.weighed_on``)."""
        raise NotImplementedError

    def weighs(self, batch: Batch) -> bool:
        """Whether this effect's weights are ``batch``'s (else the filter takes its sightings at full weight)."""
        return self.w is not None and self.key == sighting_key(batch)


@register_effect
@dataclass(frozen=True)
class FalseSightings(WeighedSightings, EffectModel):
    """A fraction ``rate`` of the sightings are spurious (module docstring). Residual signature: none
    (outliers anywhere in the image: heavy tails of the size and bearing residuals)."""

    rate: float
    w: np.ndarray | None = field(default=None, compare=False, repr=False)  # (S,) P(real | z) of the keyed batch
    key: tuple | None = field(default=None, compare=False, repr=False)
    log_u: float | None = None  # log density of a spurious sighting (set by ``start`` or the first M-step)

    name: ClassVar[str] = "false_sightings"
    PARAMS: ClassVar[dict[str, Param]] = {"rate": Param("fraction of sightings", "log", low=0.0, high=0.5, shape=())}
    EXAMPLE: ClassVar[dict[str, Any]] = {"rate": 0.05}
    STARTS_OFF: ClassVar[bool] = False  # EM starts from a few spurious sightings (START_RATE)
    DENSITY_ORDER: ClassVar[int] = 1  # wraps the real sightings' density, whatever its shape

    @classmethod
    def start(cls, batch: Batch) -> "FalseSightings":
        return cls(START_RATE, log_u=spurious_log_density(batch))

    MIN_SPURIOUS: ClassVar[float] = 5.0  # fewer expected spurious sightings than this: outliers, not an effect

    def negligible(self, n_sightings: int) -> str:
        expected = self.rate * n_sightings
        if expected >= self.MIN_SPURIOUS:
            return ""
        return (f"negligible: the rate {self.rate:.2g} means {expected:.1f} spurious sightings in {n_sightings} "
                f"(fewer than {self.MIN_SPURIOUS:g}): a few outliers, not an effect")

    def _rate(self) -> float:
        return float(min(max(self.rate, W_FLOOR), MAX_RATE))

    def predictive_logdens(self, base_logdens: np.ndarray, innov: Innovations, batch: Batch,
                           idx: np.ndarray) -> np.ndarray:
        """log((1 - rate) N + rate u), N the real sightings' density ``base_logdens``."""
        r = self._rate()
        log_u = self.log_u if self.log_u is not None else spurious_log_density(batch)
        return np.logaddexp(math.log1p(-r) + base_logdens, math.log(r) + log_u)

    def _at_path(self, model: "Model", batch: Batch, post: Posterior) -> tuple[Lowered, float, np.ndarray, Innovations]:
        """(the model without this effect, lowered; log u; the applied sightings; their innovations at the smoothed
        path): what the M-step and the rate's information both read."""
        lo0 = model.without_effect(self.name).lower(batch)
        log_u = self.log_u if self.log_u is not None else spurious_log_density(batch)
        idx, inn = smoothed_innovations(lo0, batch, post)
        return lo0, log_u, idx, inn

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """Responsibilities at the smoothed path: w = (1 - rate) N(z; h(mu), H Sigma H^T + R) / (that + rate u)
        (R without this effect's inflation), rate = mean(1 - w); sigma_size^2 = sum w (r^2 + H Sigma H^T) / vf /
        sum w and sigma_bearing^2 likewise (first order; the sensor M-step's sigmas are not the mixture's),
        iterated ``INNER`` times at the fixed path."""
        lo0, log_u, idx, inn = self._at_path(model, batch, post)
        v, hph = inn.v, inn.hph
        e2 = v ** 2 + np.diagonal(hph, axis1=1, axis2=2)  # expected squared residuals (size, bearing)
        vf, bvf = lo0.size_var_factor[idx], lo0.bearing_var_factor[idx]
        var_s, var_b = lo0.sigma_size**2, lo0.sigma_bearing**2
        r = self._rate()
        for _ in range(INNER):  # the mixture's EM at the fixed path (the path-only part converges slowly)
            w = _real_probability(v, hph, var_s * vf, var_b * bvf, r, log_u)
            r = float(np.clip(np.mean(1.0 - w), W_FLOOR, MAX_RATE))
            ws = float(w.sum())
            var_s = float(np.sum(w * e2[:, 0] / vf) / ws)
            var_b = float(np.sum(w * e2[:, 1] / bvf) / ws)
        rate = r
        w_all = np.ones(batch.n_sightings)
        w_all[idx] = w
        sensor = replace(model.sensor, sigma_size=math.sqrt(var_s), sigma_bearing=math.sqrt(var_b))
        new = replace(self, rate=rate, w=w_all, key=sighting_key(batch), log_u=log_u)
        return model.with_effect(new).with_(sensor=sensor)

    def _weights_at_path(self, model: "Model", batch: Batch, post: Posterior) -> tuple[np.ndarray, np.ndarray, float]:
        """(the applied sightings, their probabilities of being real at the smoothed path, log u), the rate and the
        sensor's sigmas held."""
        lo0, log_u, idx, inn = self._at_path(model, batch, post)
        w = _real_probability(inn.v, inn.hph, lo0.sigma_size ** 2 * lo0.size_var_factor[idx],
                              lo0.sigma_bearing ** 2 * lo0.bearing_var_factor[idx], self._rate(), log_u)
        return idx, w, log_u

    def weighed(self, model: "Model", batch: Batch, post: Posterior) -> "FalseSightings":
        """This effect with its weights computed on ``batch`` at ``post``'s smoothed path, the rate held
        (``learners.em.estep.weighed_on``)."""
        idx, w, log_u = self._weights_at_path(model, batch, post)
        w_all = np.ones(batch.n_sightings)
        w_all[idx] = w
        return replace(self, w=w_all, key=sighting_key(batch), log_u=log_u)

    def conditional_information(self, model: "Model", batch: Batch, post: Posterior) -> ConditionalInformation | None:
        """The rate's information in the likelihood its M-step maximizes: the mixture of each sighting's density at
        the smoothed path (the path and the sensor's sigmas held) and the spurious one. With w_i a sighting's
        probability of being real, its score is (1 - w_i) / r - w_i / (1 - r) and the observed information the sum
        of their squares (the second derivative of log((1 - r) N_i + r u) is minus the score squared). It holds
        the rate's sampling error at the path, not the path's own (``EffectModel.conditional_information``)."""
        idx, w, _ = self._weights_at_path(model, batch, post)
        r = self._rate()
        scores = ((1.0 - w) / r - w / (1.0 - r))[:, None]
        info = float(np.sum(scores ** 2))
        if not (math.isfinite(info) and info > 0):
            return None
        order = np.argsort(idx, kind="stable")
        return ConditionalInformation(("rate",), np.array([[1.0 / info]]), scores[order], np.asarray(idx)[order])

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "parameters": {"rate": float(self.rate)}}


@register_effect
@dataclass(frozen=True)
class WallContact(EffectModel):
    """The walls stop the robot where the model lets it pass (module docstring). No parameters: its
    dof is 0 (``learners.discrepancy.search`` names it on its held-out gain). Residual signature: the
    motion residuals against the distance to the walls."""

    #: (N, 2) per axis: the outward sign of the wall nearest the end pose times the contact probability (0: none)
    contact: np.ndarray | None = field(default=None, compare=False, repr=False)
    heading: np.ndarray | None = field(default=None, compare=False, repr=False)  # (N,) smoothed heading at the frame's start
    key: tuple | None = field(default=None, compare=False, repr=False)

    name: ClassVar[str] = "wall_contact"
    SIGNATURE: ClassVar[str] = "vs distance to walls"
    PARAMS: ClassVar[dict[str, Param]] = {}
    NEEDS: ClassVar[tuple[str, ...]] = ("field",)
    MARGIN_MM: ClassVar[float] = 60.0  # an end pose this close to a wall (or beyond it) is against it
    SD_FLOOR_MM: ClassVar[float] = 10.0  # the smallest standard deviation of an end coordinate the probability uses
    MIN_PROBABILITY: ClassVar[float] = 0.01  # smaller contact probabilities are 0 (the contact frames stay few)
    #: lowered after every other effect: a wall stops whatever moves the robot outwards, a floor drift too. Before
    #: (in the order named), a drift named after the walls pushed through them in the model; on the blind 10-minute
    #: log of seed 5000 (drift [15, -10] mm/s, walls met) the drift then came out 0.0 and was not named.
    LOWER_ORDER: ClassVar[int] = 1

    @classmethod
    def start(cls, batch: Batch) -> "WallContact":
        return cls()

    def n_contacts(self) -> int:
        return 0 if self.contact is None else int(np.any(self.contact != 0, axis=1).sum())

    def lower(self, lo: Lowered, batch: Batch) -> None:
        """Contact frames: the outward world-frame component of R(theta) disp + offset (per wall touched)
        times the contact probability cancelled through ``offset``; those frames are ``blocked``."""
        if self.contact is None or self.key != _frame_key(batch):
            return
        rows = np.flatnonzero(np.any(self.contact != 0, axis=1))
        if len(rows) == 0:
            return
        c, s = np.cos(self.heading[rows]), np.sin(self.heading[rows])
        d = lo.disp[rows]
        move = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], axis=1) + lo.offset[rows, :2]
        sign = self.contact[rows]
        cancel = np.where(move * sign > 0, -np.abs(sign) * move, 0.0)
        offset = np.array(lo.offset, copy=True)
        offset[rows, :2] += cancel
        lo.offset = offset
        blocked = np.zeros(len(lo.disp), bool) if lo.blocked is None else np.array(lo.blocked, copy=True)
        blocked[rows] |= np.any(cancel != 0.0, axis=1)
        lo.blocked = blocked

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """The contacts (:func:`contact_probability` of each frame's smoothed end pose, signed by that wall's
        outward normal per axis) and the frames' start headings, from the smoothed path."""
        if batch.field is None:
            return model
        p = batch.frame_to_pose
        end, cov = post.mu_gamma[p + 1], post.cov_gamma[p + 1]
        prob = contact_probability(end[:, :2], np.diagonal(cov, axis1=1, axis2=2)[:, :2], np.asarray(batch.field, float),
                                   self.MARGIN_MM, self.SD_FLOOR_MM)
        contact = np.sign(end[:, :2]) * np.where(prob < self.MIN_PROBABILITY, 0.0, prob)
        return model.with_effect(replace(self, contact=contact, heading=post.mu_gamma[p, 2].copy(),
                                         key=_frame_key(batch)))

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "parameters": {}}


def contact_probability(mean: np.ndarray, var: np.ndarray, field_mm: np.ndarray, margin_mm: float,
                        sd_floor_mm: float) -> np.ndarray:
    """(N, 2) per axis: the probability that a coordinate distributed N(``mean``, ``var``) (mm, mm^2; (N, 2)) is
    within ``margin_mm`` of the field's wall on its side or beyond it, |x| > field / 2 - margin (taken on the side of
    the mean), the standard deviation floored at ``sd_floor_mm``."""
    from scipy.special import ndtr  # here, not at import: SciPy costs every command ~0.7 s to load

    sd = np.sqrt(np.maximum(var, sd_floor_mm ** 2))
    return ndtr((np.abs(mean) - (field_mm / 2.0 - margin_mm)) / sd)


@dataclass(frozen=True)
class WallSlowdown(EffectModel):
    """A NUISANCE, not a catalogue effect (not registered: never a candidate, never named): one free factor on
    the mean displacement of the frames whose smoothed end pose (of the model it was made from) is within
    ``NEAR_MM`` of a wall or beyond it, i.e. the frames where the robot may be pressing a wall. The search
    tests a time-signature candidate (``velocity_fade``, whose ``CONFOUNDERS`` name it) GIVEN it
    (``learners.discrepancy.checks.GivenNuisance``): a fade of
    the speed over the log is what more time spent pushing a wall later in the log looks like.

    ``NEAR_MM`` is wide on purpose: on the effect-free wall log of seed 3008 (``aibo`` noise, 5 min) the
    base fit's smoothed path at the truly blocked frames was 415 mm beyond to 476 mm inside the wall (10-90%
    quantiles; the base model knows no walls), so the 60 mm of ``wall_contact`` catches only part of them."""

    factor: float = 1.0  # on the near-wall frames' displacements (1: neutral)
    near: np.ndarray | None = field(default=None, compare=False, repr=False)  # (N,) bool
    key: tuple | None = field(default=None, compare=False, repr=False)

    name: ClassVar[str] = "wall_slowdown"
    PARAMS: ClassVar[dict[str, Param]] = {"factor": Param("", "scaled", 0.1, low=0.0, high=2.0, shape=())}
    NEEDS: ClassVar[tuple[str, ...]] = ("field",)
    NEAR_MM: ClassVar[float] = 500.0

    @classmethod
    def start(cls, batch: Batch) -> "WallSlowdown":
        return cls(1.0)

    @classmethod
    def around(cls, post: Posterior, batch: Batch) -> "WallSlowdown":
        """The neutral nuisance on the frames near a wall by the smoothed path ``post`` (none without a field)."""
        if batch.field is None:
            return cls(1.0)
        half = np.asarray(batch.field, float) / 2.0
        end = post.mu_gamma[batch.frame_to_pose + 1]
        near = np.any(half[None, :] - np.abs(end[:, :2]) < cls.NEAR_MM, axis=1)
        return cls(1.0, near=near, key=_frame_key(batch))

    def n_frames(self) -> int:
        """The frames it acts on (near a wall)."""
        return 0 if self.near is None else int(self.near.sum())

    def given(self) -> str:
        """What a test given it holds, for the report (``checks.GivenNuisance``)."""
        return f"a free speed factor on the {self.n_frames()} frames near a wall (x{self.factor:.2f})"

    def disp_scale(self, batch: Batch) -> np.ndarray | None:
        if self.near is None or self.key != _frame_key(batch) or self.factor == 1.0:
            return None
        return np.where(self.near, self.factor, 1.0)

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """As ``velocity_fade``'s: mu*_i ~ f p_i on the near frames (p_i the displacement without this factor),
        f = sum p' W mu* / sum p' W p (W = Sigma_i^-1: ``Lowered.frame_cov``), clipped to the domain."""
        if self.near is None or self.key != _frame_key(batch) or not self.near.any():
            return model
        lo = model.lower(batch)
        scale = self.disp_scale(batch)
        rows = np.flatnonzero(self.near)
        p = lo.disp[rows] / (1.0 if scale is None else scale[rows, None])
        pw = lo.information(p, rows)
        den = float(np.sum(pw * p))
        if den <= 0:
            return model
        f = float(np.clip(np.sum(pw * mu_star[rows]) / den, 0.0, 2.0))
        return model.with_effect(replace(self, factor=f))

