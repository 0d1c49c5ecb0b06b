"""Structured 3x3 algebra and the sighting linearization of the compiled E-step (``estep``).

These helpers exploit the shape of the aibo model (F = I + column 2, Q = R Sigma R^T, symmetric
results formed from their upper triangle, H with constant entries) and may fuse a * b + c into one
FMA (``_FMA``), like the E-step kernel that inlines them. A 3x3 matrix is a row-major 9-tuple.
"""

from __future__ import annotations

import math

from numba import njit

from learners.inference.kernels.algebra import _curve, _inv_i_plus, _mm, _mv, _sym
from learners.inference.kernels.fasttrig import _atan2

_FMA = {"contract"}


@njit(cache=True, fastmath=_FMA)
def _symm(a00, a01, a02, a11, a12, a22):
    """The symmetric 3x3 (row-major 9-tuple) with the given upper triangle."""
    return (a00, a01, a02, a01, a11, a12, a02, a12, a22)


@njit(cache=True, fastmath=_FMA)
def _rot_sym(c, s, A):
    """R A R^T for symmetric A, R = [[c, -s, 0], [s, c, 0], [0, 0, 1]] (upper triangle, mirrored)."""
    b0 = c * A[0] - s * A[3]
    b1 = c * A[1] - s * A[4]
    b3 = s * A[0] + c * A[3]
    b4 = s * A[1] + c * A[4]
    return _symm(c * b0 - s * b1, s * b0 + c * b1, c * A[2] - s * A[5], s * b3 + c * b4, s * A[2] + c * A[5], A[8])


@njit(cache=True, fastmath=_FMA)
def _dscale_sym(w, d, A):
    """w D A D for symmetric A and D = diag(d0, d1, d2), d a row of ``cov_sd`` (upper triangle, mirrored): a frame's
    motion covariance. Scaling Sigma_A before the rotation keeps the rotation's FMA contractions those of the unscaled
    kernel; d = (1, 1, 1) gives w A exactly, and w = 1 too A itself (the products by 1 are exact)."""
    d0, d1, d2 = d[0], d[1], d[2]
    return _symm(w * (d0 * d0 * A[0]), w * (d0 * d1 * A[1]), w * (d0 * d2 * A[2]), w * (d1 * d1 * A[4]),
                 w * (d1 * d2 * A[5]), w * (d2 * d2 * A[8]))


@njit(cache=True, fastmath=_FMA)
def _fpft_sym(P, a, b):
    """F P F^T for symmetric P, F = I except F[0,2] = a, F[1,2] = b (upper triangle, mirrored)."""
    r02 = P[2] + a * P[8]
    r12 = P[5] + b * P[8]
    return _symm(P[0] + a * P[6] + a * r02, P[1] + a * P[7] + b * r02, r02,
                 P[4] + b * P[7] + b * r12, r12, P[8])  # fmt: skip


@njit(cache=True, fastmath=_FMA)
def _ftyf_sym(Y, a, b):
    """F^T Y F for symmetric Y, F = I except F[0,2] = a, F[1,2] = b (upper triangle, mirrored)."""
    r20 = Y[6] + a * Y[0] + b * Y[3]
    r21 = Y[7] + a * Y[1] + b * Y[4]
    r22 = Y[8] + a * Y[2] + b * Y[5]
    return _symm(Y[0], Y[1], r20, Y[4], r21, r22 + a * r20 + b * r21)


@njit(cache=True, error_model="numpy", fastmath=_FMA)
def _observe_h(mu, bx, by, basis, coef, sc, so, bo):
    """Predicted sighting at pose mu (mm, mm, rad) of the landmark at (bx, by) mm:
    (size sc f(d) + so, bearing atan2(dy, dx) - theta + bo (not wrapped), H as its 4 non-constant
    entries: row 0 = (e0, e1, 0), row 1 = (t0, t1, -1)). sc = 1, so = bo = 0 give today's numbers
    exactly (the products and sums by 1 and 0 are exact)."""
    dx = bx - mu[0]
    dy = by - mu[1]
    q = dx * dx + dy * dy
    d = math.sqrt(q)
    fd, fp = _curve(basis, coef, d)
    fpd = (sc * fp) / d
    rq = 1.0 / q
    return sc * fd + so, (_atan2(dy, dx) - mu[2]) + bo, -fpd * dx, -fpd * dy, dy * rq, -dx * rq


@njit(cache=True, error_model="numpy", fastmath=_FMA)
def _combine_fast(ma, A, Y, y):
    """gamma from alpha N(ma, A) and beta information (Y, y): M = (I + Y A)^-1,
    mu = ma + A M (y - Y ma), cov = A - A M Y A = A M (symmetrized)."""
    AM = _mm(A, _inv_i_plus(_mm(Y, A)))
    Yma = _mv(Y, ma)
    w = _mv(AM, (y[0] - Yma[0], y[1] - Yma[1], y[2] - Yma[2]))
    return (ma[0] + w[0], ma[1] + w[1], ma[2] + w[2]), _sym(AM)
