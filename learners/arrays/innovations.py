"""Sightings' innovations under a Gaussian prediction of the pose: what a sighting's predictive density is made of.

A sighting z = (size, bearing) predicted from a pose belief N(m, P) has the innovation v = z - h(m) (size in px or
mm, bearing in rad, wrapped) and the covariance S = H P H^T + R: the predicted pose's share H P H^T and the sensor's
own noise R (diagonal: the size and bearing variances, each sighting's variance factors applied). Kept apart, they
let an effect that changes the sensor's noise alone (a scale mixture: ``heavy_tailed_noise``) evaluate the density
with R scaled and the pose's share held; ``logdens()`` is the Gaussian predictive log density itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from aibo_core import geometry

if TYPE_CHECKING:
    from learners.arrays.batch import Batch
    from learners.arrays.lowered import Lowered
    from learners.arrays.posterior import Posterior

LOG_2PI = float(np.log(2.0 * np.pi))
BELIEF_DIM = 5  # a sighting's belief: the pose (x mm, y mm, theta rad), its size bias b and its bearing bias c (rad)


@dataclass(frozen=True)
class Innovations:
    """n sightings' innovations (module docstring)."""

    v: np.ndarray  # (n, 2) z - h(m): size (px or mm), bearing (rad, wrapped)
    hph: np.ndarray  # (n, 2, 2) H P H^T (the predicted pose's share), as computed (its off-diagonal entries may differ
    # in the last bit: kept so, the density's arithmetic is the filter's own, and EM's path with a mixture, which rounding
    # can move, the same as before this container)
    r: np.ndarray  # (n, 2) the sensor's own size and bearing variances (R's diagonal)

    def logdens(self, noise_factor: float | np.ndarray = 1.0) -> np.ndarray:
        """(n,) log N(v; 0, H P H^T + noise_factor R), ``noise_factor`` a number or one per sighting."""
        s00 = self.hph[:, 0, 0] + noise_factor * self.r[:, 0]
        s11 = self.hph[:, 1, 1] + noise_factor * self.r[:, 1]
        s01 = self.hph[:, 0, 1]
        v0, v1 = self.v[:, 0], self.v[:, 1]
        det = s00 * s11 - s01 * self.hph[:, 1, 0]
        m2 = (s11 * v0 * v0 - 2.0 * s01 * v0 * v1 + s00 * v1 * v1) / det
        return -0.5 * (m2 + np.log(det) + 2.0 * LOG_2PI)


def joint_belief(lo: "Lowered", post: "Posterior", idx: np.ndarray, pose: np.ndarray,
                 smoothed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Mean (n, 5) and covariance (n, 5, 5) of (x, y, theta, b, c) at poses ``pose`` for sightings ``idx``: the
    filtered (``smoothed`` False: alpha) or smoothed (gamma) pose and, with extra states (``lo.extra``), the size bias b
    of sighting j's slot and the bearing bias c (rad) of its bearing slot (each 0 with variance 0 where it has none, or
    without extra states)."""
    if lo.extra is None or post.extra is None:
        return _pose_only(post.mu_gamma[pose] if smoothed else post.mu_alpha[pose],
                          post.cov_gamma[pose] if smoothed else post.cov_alpha[pose])
    ex = post.extra
    return _with_slot(lo, idx, *((ex.smoothed_mean[pose], ex.smoothed_cov[pose]) if smoothed else
                                 (ex.filtered_mean[pose], ex.filtered_cov[pose])))


def frame_prediction(lo: "Lowered", batch: "Batch", post: "Posterior", idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (n, 5) and covariance (n, 5, 5) of (x, y, theta, b, c) as the forward filter predicted them for the frame of
    each sighting ``idx``, before any of the frame's sightings: the filtered belief at the frame's start moved by its
    motion (with extra states, the augmented filter's own prediction). A sighting after others in its frame (rare)
    gets the frame's prediction, not the one updated by those (``learners.inference.predictive`` applies them)."""
    frame = batch.sight_frame[idx]
    if lo.extra is not None and post.extra is not None:
        return _with_slot(lo, idx, post.extra.predicted_mean[frame], post.extra.predicted_cov[frame])
    return _pose_only(*pose_prediction(lo, batch, post, frame))


def pose_prediction(lo: "Lowered", batch: "Batch", post: "Posterior", frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (n, 3) and covariance (n, 3, 3) of the pose at the end of each of ``frame``, as the forward filter predicts
    it before the frame's sightings: the filtered belief at the frame's start (mu_alpha, cov_alpha) moved by the frame's
    mean displacement (EKF linearization), its world offset, and its motion noise."""
    p = batch.frame_to_pose[frame]
    g, F, R3 = geometry.motion(post.mu_alpha[p], lo.disp[frame])
    P = F @ post.cov_alpha[p] @ np.swapaxes(F, 1, 2) + lo.cov_scale[frame, None, None] * (
        R3 @ lo.shaped_cov(frame) @ np.swapaxes(R3, 1, 2))
    return g + lo.offset[frame], P


def _pose_only(mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 5-state belief of pose beliefs (n, 3), (n, 3, 3): no biases (0, variance 0)."""
    m = np.zeros((len(mean), BELIEF_DIM))
    P = np.zeros((len(mean), BELIEF_DIM, BELIEF_DIM))
    m[:, :3], P[:, :3, :3] = mean, cov
    return m, P


def _with_slot(lo: "Lowered", idx: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 5-state beliefs (pose, the size bias of sighting j's slot, the bearing bias of its bearing slot) out of beliefs
    on the whole augmented state (n, 3 + K), (n, 3 + K, 3 + K); a sighting without a state of a kind gets 0 with
    variance 0 there."""
    n = len(idx)
    slots = np.stack([lo.extra.slot[idx], lo.extra.bearing_slot[idx]], axis=1)  # (n, 2)
    has = slots >= 0
    cols = np.concatenate([np.r_[0, 1, 2][None, :].repeat(n, 0), np.where(has, 3 + slots, 0)], axis=1)
    m = mean[np.arange(n)[:, None], cols]
    P = cov[np.arange(n)[:, None, None], cols[:, :, None], cols[:, None, :]]
    for e in range(2):
        m[~has[:, e], 3 + e] = 0.0
        P[~has[:, e], 3 + e, :] = 0.0
        P[~has[:, e], :, 3 + e] = 0.0
    return m, P


def belief_innovations(lo: "Lowered", batch: "Batch", idx: np.ndarray, m: np.ndarray, P: np.ndarray) -> Innovations:
    """The innovations of sightings ``idx`` from the 5-state beliefs (pose, size bias b, bearing bias c) N(m, P) of
    ``joint_belief``: size = scale f(d) (1 + b) + offset, bearing = atan2(dy, dx) - theta + bearing offset + c; R from
    ``lo``."""
    xy = batch.sight_xy[idx]
    dx, dy = xy[:, 0] - m[:, 0], xy[:, 1] - m[:, 1]
    q = dx * dx + dy * dy
    d = np.sqrt(q)
    f, fp = lo.curve(d)
    sc, b = lo.size_scale[idx], m[:, 3]
    H = np.zeros((len(idx), 2, BELIEF_DIM))
    H[:, 0, 0] = -sc * fp * (1.0 + b) * dx / d
    H[:, 0, 1] = -sc * fp * (1.0 + b) * dy / d
    H[:, 0, 3] = sc * f
    H[:, 1, 0] = dy / q
    H[:, 1, 1] = -dx / q
    H[:, 1, 2] = -1.0
    H[:, 1, 4] = 1.0
    S = H @ P @ np.swapaxes(H, 1, 2)
    r = np.stack([lo.sigma_size ** 2 * lo.size_var_factor[idx], lo.sigma_bearing ** 2 * lo.bearing_var_factor[idx]],
                 axis=1)
    v0 = batch.sight_value[idx, 0] - (sc * f * (1.0 + b) + lo.size_offset[idx])
    v1 = geometry.wrap(batch.sight_value[idx, 1] - (np.arctan2(dy, dx) - m[:, 2] + lo.bearing_offset[idx] + m[:, 4]))
    return Innovations(np.stack([v0, v1], axis=1), S, r)
