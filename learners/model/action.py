"""The action model: mean robot-frame displacement per frame = features(command) x weights.

Feature maps (``feature_map``, defined in :mod:`aibo_core.features` and shared with the simulator; the
model file records the name and, for continuous commands, the log's ``control_names`` and units):

=============  =====================  ========================================================
name           command                features (F)
=============  =====================  ========================================================
``table``      discrete index a       one-hot of a (F = number of commands): the paper's table
                                      of 40 velocities; weights[a] = displacement of command a
``diff_drive`` (v mm/s, omega rad/s)  [v, omega, v |omega|, |omega|, 1]: linear gains and
                                      cross-coupling, forward speed lost while turning either
                                      way (v |omega|), a turn-size-dependent drift (|omega|)
                                      and a constant offset
``unicycle``   (v mm/s, omega rad/s)  the ``diff_drive`` features with the lateral (dy) column of
                                      the weights held at exactly 0: a wheeled robot cannot move
                                      sideways; and the forward (dx) column's omega, |omega| and
                                      constant rows held at 0 (``ZERO_CELLS``: no forward motion
                                      from turning in place, which EM used to trade heading for
                                      speed, nor without a command), and the turn (dtheta)
                                      column's constant (no turn without a command). Sigma_A
                                      keeps its dy variance (slip, and the path curving within
                                      one frame)
``linear``     any k numbers          [c_1, ..., c_k, 1]
=============  =====================  ========================================================

``weights`` (F, 3) are per-frame displacements (mm, mm, rad) per unit feature; velocities are
displacements / dt (mm/s, mm/s, rad/s; x forward, y left, CCW positive). ``cov`` (3, 3) is the
per-frame displacement covariance Sigma_A (mm^2, rad^2), shared by all frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from aibo_core.features import FEATURE_MAPS, ZERO_CELLS, ZERO_OUTPUTS  # noqa: F401  (re-exported: their historical home)
from learners.model.parameters import Component, Param

#: The paper's fixed per-frame motion noise: 10 mm, 10 mm, 0.1 rad standard deviations (footnote 2).
PAPER_MOTION_STD = (10.0, 10.0, 0.1)


def per_component(scale: np.ndarray) -> np.ndarray:
    """A displacement factor as (N, 3) (forward, lateral, turn): an (N,) factor repeated on the three."""
    scale = np.asarray(scale, dtype=float)
    return np.broadcast_to(np.reshape(scale, (len(scale), -1)), (len(scale), 3))


@dataclass(frozen=True)
class ActionModel(Component):
    """features(command) x weights, with a shared per-frame noise covariance (module docstring)."""

    weights: np.ndarray  # (F, 3) per-frame displacement per unit feature (mm, mm, rad)
    cov: np.ndarray  # (3, 3) Sigma_A (mm^2, rad^2 per frame)
    dt: float  # s per frame
    feature_map: str = "table"
    control_names: tuple[str, ...] = ()

    PARAMS: ClassVar[dict[str, Param]] = {
        "weights": Param("mm, mm, rad per frame per unit feature", "scaled", PAPER_MOTION_STD),
        "cov": Param("mm^2, rad^2 per frame", "logchol", order=1),
    }

    @property
    def discrete(self) -> bool:
        return self.feature_map == "table"

    @property
    def disp(self) -> np.ndarray:
        """(A, 3) displacement per frame of each discrete command (table models only)."""
        if not self.discrete:
            raise ValueError(f"a '{self.feature_map}' action model has no table of displacements")
        return self.weights

    @property
    def velocities(self) -> np.ndarray:
        """(A, 3) velocity of each discrete command: vx mm/s, vy mm/s, vtheta rad/s (table models)."""
        return self.disp / self.dt

    def features(self, commands: np.ndarray) -> np.ndarray:
        """(N, F) features of continuous commands (N, k)."""
        fn, n_features = FEATURE_MAPS[self.feature_map]
        c = np.asarray(commands, dtype=float)
        if c.ndim != 2 or n_features(c.shape[1]) != len(self.weights):
            raise ValueError(f"feature map '{self.feature_map}' with {len(self.weights)} features cannot take "
                             f"commands of shape {c.shape}")
        return fn(c)

    def displacements(self, commands: np.ndarray) -> np.ndarray:
        """(N, 3) mean per-frame displacement (mm, mm, rad) for discrete indices (N,) or continuous (N, k)."""
        if self.discrete:
            idx = np.asarray(commands)
            if idx.ndim != 1 or idx.dtype.kind not in "iu":
                raise ValueError(f"a table action model takes command indices of shape (N,), got {idx.shape}")
            if idx.size and (idx.min() < 0 or idx.max() >= len(self.weights)):
                raise ValueError(f"command index outside 0..{len(self.weights) - 1}")
            # np.take, not weights[idx]: the same rows, ~6x faster on 27,000 frames (35 vs 234 us; every E-step)
            return np.take(self.weights, idx, axis=0)
        return self.features(commands) @ self.weights

    def velocity(self, commands) -> np.ndarray:
        """(N, 3) velocities [forward mm/s, lateral mm/s, turn rad/s] for discrete command indices (N,)
        or continuous commands (N, k) in the units the log declared (public API); (3,) for one
        command (an index, or k controls), as ``SensorModel.mean`` takes one distance."""
        c = np.asarray(commands)
        one = c.ndim == (0 if self.discrete else 1)
        v = self.displacements(c[None] if one else c) / self.dt
        return v[0] if one else v

    def regress(self, commands: np.ndarray, mu_star: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
        """New weights: least squares of the per-frame displacement estimates ``mu_star`` (N, 3) on the
        features (times ``scale`` when an effect scales the motion: (N,) per frame, or (N, 3) per frame and
        component). ``table``: the mean over the frames of each command (commands never executed keep
        their weights); otherwise ordinary least squares over all frames (equal weights: one shared noise
        covariance), each component on its own scaled features."""
        s3 = None if scale is None else per_component(scale)
        if s3 is not None and self.discrete:  # per command and component: sum s mu / sum s^2 (diagonal)
            n_act = len(self.weights)
            out = np.array(self.weights, dtype=float)
            for k in range(3):
                den = np.bincount(commands, weights=s3[:, k] * s3[:, k], minlength=n_act)
                num = np.bincount(commands, weights=s3[:, k] * mu_star[:, k], minlength=n_act)
                seen = den > 0
                out[seen, k] = num[seen] / den[seen]
            return out
        if self.discrete:
            n_act = len(self.weights)
            counts = np.bincount(commands, minlength=n_act).astype(float)
            # one pass: element (i, k) goes to bin 3 a_i + k; each bin still sums in frame order
            sums = np.bincount((3 * commands[:, None] + np.arange(3)).ravel(), weights=np.ravel(mu_star),
                               minlength=3 * n_act).reshape(n_act, 3)
            out = np.array(self.weights, dtype=float)
            seen = counts > 0
            out[seen] = sums[seen] / counts[seen, None]
            return out
        phi = self.features(commands)
        if s3 is not None and not np.all(s3 == s3[:, :1]):  # a factor per component: a design matrix each
            cols = [phi * s3[:, k, None] for k in range(3)]
            w = np.stack([np.linalg.lstsq(c.T @ c, c.T @ mu_star[:, k], rcond=None)[0]
                          for k, c in enumerate(cols)], axis=1)
            return self.constrained(cols, mu_star, w)
        if s3 is not None:
            phi = phi * s3[:, :1]
        w = np.linalg.lstsq(phi.T @ phi, phi.T @ mu_star, rcond=None)[0]  # normal equations: F x F
        return self.constrained([phi] * 3, mu_star, w)

    def constrained(self, designs: list[np.ndarray], targets: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """The constrained least-squares solution from the unconstrained one, ``weights`` (F, 3): the output
        columns the feature map holds at 0 (``ZERO_OUTPUTS``) set to 0, and each column that holds some features
        at 0 (``ZERO_CELLS``) refitted on its other features (``designs[k]``: column k's (N, F) design, ``targets``
        (N, 3)). Every column has its own least squares, so the others do not depend on these."""
        zero, cells = ZERO_OUTPUTS.get(self.feature_map, ()), ZERO_CELLS.get(self.feature_map, {})
        if not zero and not cells:
            return weights
        out = np.array(weights, dtype=float)
        out[:, list(zero)] = 0.0
        for k, rows in cells.items():
            keep = [f for f in range(out.shape[0]) if f not in rows]
            d = designs[k][:, keep]
            out[:, k] = 0.0
            out[keep, k] = np.linalg.lstsq(d.T @ d, d.T @ targets[:, k], rcond=None)[0]
        return out

    def zero_cells(self) -> np.ndarray:
        """(F, 3) bool: the weights the feature map holds at exactly 0 (the ``ZERO_OUTPUTS`` columns and the
        ``ZERO_CELLS``; none for ``table``, ``diff_drive``, ``linear``)."""
        mask = np.zeros(np.shape(self.weights), dtype=bool)
        mask[:, list(ZERO_OUTPUTS.get(self.feature_map, ()))] = True
        for k, rows in ZERO_CELLS.get(self.feature_map, {}).items():
            mask[list(rows), k] = True
        return mask

    def held(self, name: str) -> np.ndarray:
        """``Component.held``: the weights the feature map holds at 0 (``zero_cells``; packed row by row)."""
        return self.zero_cells().ravel() if name == "weights" else super().held(name)

    def determined(self, commands: np.ndarray) -> np.ndarray:
        """(F,) bool: which weights the commands of a log determine (table: the commands executed;
        features: all, when the feature matrix has full column rank)."""
        if self.discrete:
            return np.bincount(commands, minlength=len(self.weights)) > 0
        phi = self.features(commands)
        return np.full(len(self.weights), np.linalg.matrix_rank(phi) == phi.shape[1])

    @staticmethod
    def zeros(n_features: int, dt: float, feature_map: str = "table", control_names: tuple[str, ...] = (),
              std=PAPER_MOTION_STD) -> "ActionModel":
        """All displacements zero (the paper's start), noise ``std`` (mm, mm, rad per frame)."""
        return ActionModel(np.zeros((n_features, 3)), np.diag(np.square(np.asarray(std, float))), float(dt),
                           feature_map, tuple(control_names))
