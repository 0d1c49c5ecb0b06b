"""Open-loop predictive densities of sightings: each sighting predicted from the filtered belief K frames
before it and the commands alone (no sighting in between applied). What a model's *motion* is judged by:
a one-step prediction leans on the previous sighting, which the sensor model dominates; over seconds the
motion model has to carry the pose.

For sighting j at the end of frame f, start frame f0 = f - K + 1 (its log's first frame at the earliest):

    belief at the start of frame f0:  N(mu_alpha, cov_alpha)  (the forward filter, every sighting up to then)
    for frames i = f0 .. f:           s <- s + R(theta) disp[i] + offset[i] + w   (the model's motion, moments below)
    density:                          log N(z_j; h(m), H P H^T + R_j),  the bearing innovation wrapped.

The motion's moments are matched exactly for a Gaussian heading (``moments="exact"``, the default), not
linearized: with theta ~ N(mu, v), E[cos theta] = exp(-v/2) cos mu, E[sin theta] = exp(-v/2) sin mu, the
second moments likewise at 2 mu with exp(-2 v), and (Stein's lemma) Cov(x, cos theta) = -Cov(x, theta)
E[sin theta]. Over seconds the heading's variance grows to tenths of a rad^2, and the linearized mean (the
EKF's, ``moments="linear"``) overshoots the expected displacement by 1 - exp(-v/2): on 10-minute simulated
logs it scored a forward speed 5% too low better than the true one at 5 s. The motion noise is rotated at the
mean heading, as in the EKF.

The filtered (forward) belief, not the smoothed one, is the start: a smoothed pose at f0 is informed by the
sightings after f0 (those after f too), and read back through the same motion model it would return part of
the prediction's answer. With extra states (``Lowered.extra``: per-landmark biases) the state is the pose, the
bias that multiplies sighting j's size and the one added to its bearing, whose chains run independently of the pose
(exact marginal).

Pure functions of (lowered model, batch, posterior); units mm, rad, frames.
"""

from __future__ import annotations

import numpy as np

from aibo_core import geometry
from learners.arrays.batch import Batch
from learners.arrays.innovations import Innovations, belief_innovations, joint_belief
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior


def open_loop_start(batch: Batch, idx: np.ndarray, k_frames: int) -> np.ndarray:
    """(len(idx),) start frame f0 = f - k_frames + 1 of each sighting's open-loop prediction, -1 where its
    log began less than ``k_frames`` frames before it (such a sighting has no full-horizon prediction)."""
    if k_frames < 1:
        raise ValueError(f"open-loop horizon {k_frames} frames: need at least 1")
    frame = batch.sight_frame[idx]
    log = np.searchsorted(batch.frame_start, frame, side="right") - 1
    f0 = frame - k_frames + 1
    return np.where(f0 >= batch.frame_start[log], f0, -1)


def _heading_moments(mu: np.ndarray, var: np.ndarray):
    """E[cos], E[sin], Var(cos), Var(sin), Cov(cos, sin) of theta ~ N(mu, var), elementwise."""
    a, b = np.exp(-0.5 * var), np.exp(-2.0 * var)
    ec, es = a * np.cos(mu), a * np.sin(mu)
    c2, s2 = b * np.cos(2.0 * mu), b * np.sin(2.0 * mu)
    return ec, es, 0.5 * (1.0 + c2) - ec * ec, 0.5 * (1.0 - c2) - es * es, 0.5 * s2 - ec * es


def _motion_moments(m: np.ndarray, P: np.ndarray, disp: np.ndarray):
    """Mean (n, 5) and covariance (n, 5, 5) of s + R(theta) disp for s ~ N(m, P) (the module docstring's exact
    moments; the bias states, indices 3 and 4, move with the pose only through their covariance)."""
    ux, uy, ut = disp[:, 0], disp[:, 1], disp[:, 2]
    ec, es, vc, vs, cs = _heading_moments(m[:, 2], P[:, 2, 2])
    a = np.zeros_like(m)  # d E[displacement] / d theta, at the shrunk moments: Cov(s, d) = P[:, 2] a^T
    a[:, 0] = -ux * es - uy * ec
    a[:, 1] = ux * ec - uy * es
    mean = m.copy()
    mean[:, 0] += ec * ux - es * uy
    mean[:, 1] += es * ux + ec * uy
    mean[:, 2] += ut
    pa = P[:, :, 2]  # Cov(state, theta)
    cov = P + pa[:, :, None] * a[:, None, :] + a[:, :, None] * pa[:, None, :]
    cov[:, 0, 0] += ux * ux * vc + uy * uy * vs - 2.0 * ux * uy * cs
    cov[:, 1, 1] += ux * ux * vs + uy * uy * vc + 2.0 * ux * uy * cs
    cov[:, 0, 1] += (ux * ux - uy * uy) * cs + ux * uy * (vc - vs)
    cov[:, 1, 0] = cov[:, 0, 1]
    return mean, cov


def _propagate(lo: Lowered, idx: np.ndarray, f0: np.ndarray, k_frames: int, m: np.ndarray, P: np.ndarray,
               moments: str = "exact"):
    """Run the beliefs (m, P) of ``joint_belief`` through frames f0 .. f0 + k_frames - 1, open loop."""
    if moments not in ("exact", "linear"):
        raise ValueError(f"moments {moments!r}: 'exact' or 'linear'")
    n, dim = len(idx), m.shape[1]
    slots = (np.stack([lo.extra.slot[idx], lo.extra.bearing_slot[idx]], axis=1) if lo.extra is not None
             else np.full((n, 2), -1))
    has = slots >= 0
    s = np.maximum(slots, 0)
    F4 = np.repeat(np.eye(dim)[None], n, axis=0)  # the pose's Jacobian; the biases scaled by phi below
    Q4 = np.zeros((n, dim, dim))
    for step in range(k_frames):
        fr = f0 + step
        g, F, R3 = geometry.motion(m[:, :3], lo.disp[fr])
        Q4[:, :3, :3] = lo.cov_scale[fr, None, None] * (R3 @ lo.shaped_cov(fr) @ np.swapaxes(R3, 1, 2))
        if moments == "exact":
            m, P = _motion_moments(m, P, lo.disp[fr])
        else:
            m[:, :3] = g
            F4[:, :3, :3] = F
            P = F4 @ P @ np.swapaxes(F4, 1, 2)
        m[:, :3] += lo.offset[fr]
        if lo.extra is not None:
            for e in range(2):  # the size bias (3), the bearing bias (4)
                phi = np.where(has[:, e], lo.extra.phi[fr, s[:, e]], 0.0)
                Q4[:, 3 + e, 3 + e] = np.where(has[:, e], lo.extra.q[fr, s[:, e]], 0.0)
                m[:, 3 + e] *= phi
                P[:, 3 + e, :] *= phi[:, None]
                P[:, :, 3 + e] *= phi[:, None]
        P = P + Q4
        P = 0.5 * (P + np.swapaxes(P, 1, 2))
    return m, P


def open_loop_logdens(lo: Lowered, batch: Batch, post: Posterior, idx: np.ndarray, k_frames: int,
                      lo_own: Lowered | None = None, moments: str = "exact") -> np.ndarray:
    """(len(idx),) log N(z_j; h(m), H P H^T + R_j) of sightings ``idx`` predicted ``k_frames`` frames open loop
    (module docstring); NaN where the log began too recently (``open_loop_start``). Arguments: ``open_loop_innovations``."""
    ok, innov = open_loop_innovations(lo, batch, post, idx, k_frames, lo_own, moments)
    out = np.full(len(ok), np.nan)
    out[ok] = innov.logdens()
    return out


def open_loop_innovations(lo: Lowered, batch: Batch, post: Posterior, idx: np.ndarray, k_frames: int,
                          lo_own: Lowered | None = None, moments: str = "exact") -> tuple[np.ndarray, Innovations]:
    """(ok (len(idx),) bool, the innovations of sightings ``idx[ok]``) predicted ``k_frames`` frames open loop (module
    docstring); not ok where the log began too recently (``open_loop_start``). ``lo_own``: the arrays whose noise R
    the sighting's own density uses (default ``lo``; see ``learners.em.predictive.predictive_innovations``);
    ``moments``: "exact" (a Gaussian heading's, the default) or "linear" (the EKF's prediction)."""
    lo_own = lo if lo_own is None else lo_own
    idx = np.asarray(idx, dtype=np.int64)
    f0 = open_loop_start(batch, idx, k_frames)
    ok = f0 >= 0
    if not ok.any():
        return ok, Innovations(np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros((0, 2)))
    j, f0 = idx[ok], f0[ok]
    m, P = _propagate(lo, j, f0, k_frames, *joint_belief(lo, post, j, batch.frame_to_pose[f0], smoothed=False), moments)
    return ok, belief_innovations(lo_own, batch, j, m, P)
