"""Probes: effects OUTSIDE the catalogue, for the discrepancy search's "none of the above" check.

A probe is a generic alternative, not a named effect: the walking speed (forward and lateral displacement; the
turn is left alone) multiplied by a factor linear in covariates of the robot's state,

    factor_i = 1 + sum_k coef_k phi_k(state_i),

the covariates read off a smoothed path (``around``: the model being checked) and then held fixed, as
``WallSlowdown``'s near-wall frames are. When a probe gains significantly over the search's final model, the logs
show a dependence that no named effect (and, once the search has tried them all, no catalogue effect) explains:
the report says "none of the above" with the probe's residual signature, instead of forcing a catalogue name on
it. Probes are never candidates and never named (they are not in ``EFFECT_MODELS``).

=================  ==============================  ========================================================
probe              covariates phi_k                what it stands for
=================  ==============================  ========================================================
speed_vs_heading   cos(theta), sin(theta)          a sloped floor, wind, a pulling cable: faster one way
speed_vs_position  (x - mean x) / 1 m,             a patch of carpet, an uneven floor: the speed changes
                   (y - mean y) / 1 m              across the field
=================  ==============================  ========================================================

A world-frame drift (``floor_drift``) adds the same velocity whatever the command; these scale the command's own
motion, so they are not the drift in another form (a drift is still partly absorbed by ``speed_vs_heading``:
that is why the check runs after the search, once the catalogue had its turn).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.posterior import Posterior
from learners.model.catalogue_more import WallSlowdown, _frame_key
from learners.model.effects import EffectModel
from learners.model.parameters import Param

if TYPE_CHECKING:
    from learners.model.model import Model

#: The factor never goes below this (a speed cannot reverse).
MIN_FACTOR = 0.05


@dataclass(frozen=True)
class SpeedProbe(EffectModel):
    """Base of the probes (module docstring): a speed factor 1 + basis @ coef on the forward and lateral
    displacement of every frame; ``basis`` (N, K) is fixed by ``around`` for one batch's frames."""

    coef: np.ndarray  # (K,) dimensionless per unit covariate
    basis: np.ndarray | None = field(default=None, compare=False, repr=False)  # (N, K) covariates per frame
    key: tuple | None = field(default=None, compare=False, repr=False)

    PARAMS: ClassVar[dict[str, Param]] = {"coef": Param("per unit covariate", "scaled", 0.05, low=-5.0, high=5.0,
                                                        shape=(2,))}
    #: one line: what the factor depends on, with ``{terms}`` for the fitted factor
    DESCRIBES: ClassVar[str] = ""
    #: the covariates' names, in ``coef``'s order
    TERMS: ClassVar[tuple[str, ...]] = ()
    #: a robot pushing a wall moves slower towards it, in those headings and at those places (docs/results.md, "Given
    #: the walls")
    CONFOUNDERS: ClassVar[tuple[type, ...]] = (WallSlowdown,)

    @classmethod
    def covariates(cls, post: Posterior, batch: Batch) -> np.ndarray:
        """(N, K) covariates of each frame, read off the smoothed path ``post``."""
        raise NotImplementedError

    @classmethod
    def start(cls, batch: Batch) -> "SpeedProbe":
        return cls(np.zeros(2))

    @classmethod
    def around(cls, post: Posterior, batch: Batch) -> "SpeedProbe":
        """The neutral probe with its covariates read off the smoothed path ``post`` of ``batch``."""
        basis = cls.covariates(post, batch)
        return cls(np.zeros(basis.shape[1]), basis=basis, key=_frame_key(batch))

    def _factor(self, batch: Batch) -> np.ndarray | None:
        if self.basis is None or self.key != _frame_key(batch) or not np.any(self.coef):
            return None
        return np.maximum(1.0 + self.basis @ self.coef, MIN_FACTOR)

    def disp_scale(self, batch: Batch) -> np.ndarray | None:
        f = self._factor(batch)
        return None if f is None else np.stack([f, f, np.ones_like(f)], axis=1)

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """Generalized least squares given the rest of the model: mu*_i - p_i ~ (phi_i . coef) q_i, with p_i the
        displacement without this factor and q_i = (p_x, p_y, 0) its part the factor scales; with
        W_i = Sigma_i^-1 (``Lowered.frame_cov``), a_i = q_i' W_i q_i and b_i = q_i' W_i (mu*_i - p_i):
        coef = (sum a_i phi_i phi_i')^-1 sum b_i phi_i."""
        if self.basis is None or self.key != _frame_key(batch):
            return model
        lo = model.lower(batch)
        f = self._factor(batch)
        p = lo.disp if f is None else lo.disp / np.stack([f, f, np.ones_like(f)], axis=1)
        q = p * np.array([1.0, 1.0, 0.0])
        qw = lo.information(q)  # W_i q_i
        a = np.einsum("ij,ij->i", qw, q)
        b = np.einsum("ij,ij->i", qw, mu_star - p)
        lhs = np.einsum("i,ik,il->kl", a, self.basis, self.basis)
        if np.linalg.cond(lhs) > 1e12:
            return model
        coef = np.clip(np.linalg.solve(lhs, self.basis.T @ b), -5.0, 5.0)
        return model.with_effect(replace(self, coef=coef))

    def describe(self) -> str:
        """The fitted factor in words."""
        return self.DESCRIBES.format(terms=" ".join(f"{c:+.3f} {n}" for c, n in zip(self.coef, self.TERMS)))

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "parameters": {"coef": np.asarray(self.coef).tolist()}}


@dataclass(frozen=True)
class SpeedVsHeading(SpeedProbe):
    """Speed x (1 + c0 cos theta + c1 sin theta), theta the world heading at the frame's start (rad)."""

    name: ClassVar[str] = "speed_vs_heading"
    DESCRIBES: ClassVar[str] = "the walking speed depends on the world heading: x (1 {terms})"
    TERMS: ClassVar[tuple[str, ...]] = ("cos(heading)", "sin(heading)")

    @classmethod
    def covariates(cls, post: Posterior, batch: Batch) -> np.ndarray:
        th = post.mu_gamma[batch.frame_to_pose, 2]
        return np.stack([np.cos(th), np.sin(th)], axis=1)


@dataclass(frozen=True)
class SpeedVsPosition(SpeedProbe):
    """Speed x (1 + c0 (x - mean x) + c1 (y - mean y)), positions at the frame's start in m about the path's mean."""

    name: ClassVar[str] = "speed_vs_position"
    DESCRIBES: ClassVar[str] = "the walking speed changes across the field: x (1 {terms})"
    TERMS: ClassVar[tuple[str, ...]] = ("x/m", "y/m")

    @classmethod
    def covariates(cls, post: Posterior, batch: Batch) -> np.ndarray:
        xy = post.mu_gamma[batch.frame_to_pose, :2] / 1000.0
        return xy - xy.mean(axis=0)


#: The probes the search's final check fits (name -> class); never candidates, never named.
PROBES: dict[str, type[SpeedProbe]] = {c.name: c for c in (SpeedVsHeading, SpeedVsPosition)}
