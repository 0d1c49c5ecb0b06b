"""Action M-step statistics (paper section III-A; docs/em-math.md "Action M-step"), vectorized.

For frame i (start pose p, end pose p+1) the joint f_alpha,delta over (s_p, s_{p+1}) is
alpha_p (mean mu_alpha,p, cov P_alpha,p) times delta_i (information Y_delta, y_delta),
block-diagonal (eq. (6)). The robot-frame displacement NET OF the world offset,
d(s_p, s_{p+1}) = R(-theta_p)(s_{p+1} - s_p - offset_i) (heading: theta_{p+1} - theta_p - offset_i[2]),
is d_0(s_p, s'') of s'' = s_{p+1} - offset_i, whose delta factor is (Y_delta, y_delta - Y_delta offset_i).
It is linearized at the SMOOTHED means (named choice: mu_delta may not exist):
d ~ L1 s_p + L2 s'' + m. Its belief under f_alpha,delta, in information form:

    Y' = L2^-T Y_delta L2^-1, y' = L2^-T y''         (L2 = R3(-theta) is a rotation: L2^-1 = L2^T)
    P1 = L1 P_alpha,p L1^T, m1 = L1 mu_alpha,p + m
    Y_d = (I + Y' P1)^-1 Y', y_d = (I + Y' P1)^-1 (y' + Y' m1)

multiplied by the frame's prior N(disp_i, Sigma_i) (footnote 3, with the prior per frame; Sigma_i = cov_scale_i
D_i Sigma_A D_i: ``Lowered.frame_cov``):

    C*_i = (Sigma_i^-1 + Y_d)^-1, mu*_i = disp_i + C*_i (y_d - Y_d disp_i).

Units: displacements per frame (mm, mm, rad) in the frame of the start pose. The per-frame formula is
``learners.arrays.displacement.pose_displacement_beliefs`` (an effect on the motion's noise reads it frame by frame).
"""

from __future__ import annotations

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.displacement import pose_displacement_beliefs
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior


def action_statistics(lo: Lowered, batch: Batch, post: Posterior, need_cov: bool):
    """Per-frame posterior mean of the displacement (net of the offset) times the frame's prior.

    Returns ``mu_star`` (N, 3) (mm, mm, rad per frame) and, if ``need_cov``, ``C_sum`` (3, 3) =
    sum_i D_i^-1 C*_i D_i^-1 / cov_scale_i (``Lowered.whitened``; else None).
    """
    mu_star, C_star = pose_displacement_beliefs(lo, batch, post)
    C_sum = lo.whitened(C_star).sum(axis=0) if need_cov else None
    return mu_star, C_sum


def residual_cov(mu_star: np.ndarray, pred: np.ndarray, cov_scale: np.ndarray,
                 cov_sd: np.ndarray | None = None) -> np.ndarray:
    """sum_i D_i^-1 r_i r_i^T D_i^-1 / cov_scale_i, r_i = mu*_i - pred_i, D_i = diag(cov_sd[i]) (None: ones), (3, 3)
    (mm^2, mm rad, rad^2 per frame^2)."""
    r = np.asarray(mu_star, dtype=float) - np.asarray(pred, dtype=float)
    if cov_sd is not None:
        r = r / np.asarray(cov_sd, dtype=float)
    return (r / np.asarray(cov_scale, dtype=float)[:, None]).T @ r
