"""Shared pieces of the compiled kernels: constants, kernel status codes, small 3x3 algebra on
tuples, angle wrapping, Horner's rule and the sensor curve ``_curve`` in either basis, and the Python-side helpers every wrapper uses
(``_f64`` contiguous float64 views, ``_raise`` status-to-exception, ``_scratch`` per-thread buffers).
"""

from __future__ import annotations

import math
import threading

import numpy as np
from numba import njit

from learners.arrays.batch import Batch

_TWO_PI = 2.0 * math.pi
_LOG_2PI = math.log(2.0 * math.pi)

# status codes returned by the kernels
_OK = 0
_BAD_FORWARD = 1
_BAD_BACKWARD = 2
_BAD_GAMMA = 3
_BAD_ACTION = 4
_STAGES = {
    _BAD_FORWARD: "forward filter",
    _BAD_BACKWARD: "backward information filter",
    _BAD_GAMMA: "combination (gamma)",
    _BAD_ACTION: "action statistics",
}


# ----------------------------------------------------------------------------------------------
# small algebra on tuples: a 3x3 matrix is a row-major 9-tuple, a vector a 3-tuple. Tuples
# live in registers (no allocation, no reference counting) and LLVM inlines these calls.
# ----------------------------------------------------------------------------------------------


@njit(cache=True)
def _wrap(a):
    """Wrap an angle to (-pi, pi] (same formula as geometry.wrap)."""
    return a - _TWO_PI * math.ceil((a - math.pi) / _TWO_PI)


@njit(cache=True)
def _horner(coef, d):
    """f(d) = sum_k coef[k] d**k and f'(d), by Horner's rule."""
    n = coef.shape[0]
    f = coef[n - 1]
    for k in range(n - 2, -1, -1):
        f = f * d + coef[k]
    if n < 2:
        return f, 0.0
    g = (n - 1) * coef[n - 1]
    for k in range(n - 2, 0, -1):
        g = g * d + k * coef[k]
    return f, g


@njit(cache=True)
def _curve(basis, coef, d):
    """(f(d), f'(d)) of the sensor curve f(d) = sum_k coef[k] x^k with x = d (basis 0,
    ``lowered.BASIS_POWER``) or x = 1/d (basis 1, ``BASIS_INVERSE``); d in mm. Another basis is
    another branch here."""
    if basis == 0:
        return _horner(coef, d)
    x = 1.0 / d
    f, g = _horner(coef, x)
    return f, -g * x * x  # df/dd = df/dx * dx/dd, dx/dd = -x^2


@njit(cache=True)
def _ld3(a, p):
    return (a[p, 0], a[p, 1], a[p, 2])


@njit(cache=True)
def _st3(a, p, v):
    a[p, 0] = v[0]
    a[p, 1] = v[1]
    a[p, 2] = v[2]


@njit(cache=True)
def _ld33(a, p):
    return (a[p, 0, 0], a[p, 0, 1], a[p, 0, 2], a[p, 1, 0], a[p, 1, 1], a[p, 1, 2], a[p, 2, 0], a[p, 2, 1], a[p, 2, 2])


@njit(cache=True)
def _st33(a, p, M):
    a[p, 0, 0] = M[0]
    a[p, 0, 1] = M[1]
    a[p, 0, 2] = M[2]
    a[p, 1, 0] = M[3]
    a[p, 1, 1] = M[4]
    a[p, 1, 2] = M[5]
    a[p, 2, 0] = M[6]
    a[p, 2, 1] = M[7]
    a[p, 2, 2] = M[8]


@njit(cache=True)
def _mm(A, B):
    """A @ B"""
    return (
        A[0] * B[0] + A[1] * B[3] + A[2] * B[6],
        A[0] * B[1] + A[1] * B[4] + A[2] * B[7],
        A[0] * B[2] + A[1] * B[5] + A[2] * B[8],
        A[3] * B[0] + A[4] * B[3] + A[5] * B[6],
        A[3] * B[1] + A[4] * B[4] + A[5] * B[7],
        A[3] * B[2] + A[4] * B[5] + A[5] * B[8],
        A[6] * B[0] + A[7] * B[3] + A[8] * B[6],
        A[6] * B[1] + A[7] * B[4] + A[8] * B[7],
        A[6] * B[2] + A[7] * B[5] + A[8] * B[8],
    )


@njit(cache=True)
def _mv(A, v):
    """A @ v"""
    return (
        A[0] * v[0] + A[1] * v[1] + A[2] * v[2],
        A[3] * v[0] + A[4] * v[1] + A[5] * v[2],
        A[6] * v[0] + A[7] * v[1] + A[8] * v[2],
    )


@njit(cache=True)
def _add(A, B):
    return (A[0] + B[0], A[1] + B[1], A[2] + B[2], A[3] + B[3], A[4] + B[4], A[5] + B[5],
            A[6] + B[6], A[7] + B[7], A[8] + B[8])  # fmt: skip


@njit(cache=True)
def _sym(A):
    """(A + A^T) / 2"""
    s01 = 0.5 * (A[1] + A[3])
    s02 = 0.5 * (A[2] + A[6])
    s12 = 0.5 * (A[5] + A[7])
    return (A[0], s01, s02, s01, A[4], s12, s02, s12, A[8])


@njit(cache=True)
def _inv(A):
    """(A^-1, det A) for a general 3x3 A, by cofactors (det 0 gives non-finite entries)."""
    c00 = A[4] * A[8] - A[5] * A[7]
    c01 = A[5] * A[6] - A[3] * A[8]
    c02 = A[3] * A[7] - A[4] * A[6]
    det = A[0] * c00 + A[1] * c01 + A[2] * c02
    r = 1.0 / det
    return (
        c00 * r,
        (A[2] * A[7] - A[1] * A[8]) * r,
        (A[1] * A[5] - A[2] * A[4]) * r,
        c01 * r,
        (A[0] * A[8] - A[2] * A[6]) * r,
        (A[2] * A[3] - A[0] * A[5]) * r,
        c02 * r,
        (A[1] * A[6] - A[0] * A[7]) * r,
        (A[0] * A[4] - A[1] * A[3]) * r,
    ), det


@njit(cache=True)
def _inv_i_plus(X):
    """(I + X)^-1"""
    return _inv((1.0 + X[0], X[1], X[2], X[3], 1.0 + X[4], X[5], X[6], X[7], 1.0 + X[8]))[0]


@njit(cache=True)
def _fin3(v):
    return math.isfinite(v[0] + v[1] + v[2])


@njit(cache=True)
def _fin33(A):
    return math.isfinite(A[0] + A[1] + A[2] + A[3] + A[4] + A[5] + A[6] + A[7] + A[8])


@njit(cache=True)
def _fpft(P, a, b):
    """F P F^T for F = I except F[0,2] = a, F[1,2] = b (the motion Jacobian)."""
    # rows: r0 += a r2, r1 += b r2
    r00 = P[0] + a * P[6]
    r01 = P[1] + a * P[7]
    r02 = P[2] + a * P[8]
    r10 = P[3] + b * P[6]
    r11 = P[4] + b * P[7]
    r12 = P[5] + b * P[8]
    # columns: c0 += a c2, c1 += b c2
    return (
        r00 + a * r02, r01 + b * r02, r02,
        r10 + a * r12, r11 + b * r12, r12,
        P[6] + a * P[8], P[7] + b * P[8], P[8],
    )  # fmt: skip


# zero 3x3 matrix / 3-vector as tuples (initial values of accumulations)
_ZERO33 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
_ZERO3 = (0.0, 0.0, 0.0)


# ----------------------------------------------------------------------------------------------
# Python-side helpers shared by the wrappers
# ----------------------------------------------------------------------------------------------


def _f64(a, shape=None) -> np.ndarray:
    out = np.ascontiguousarray(a, dtype=np.float64)
    if shape is not None and out.shape != shape:
        raise ValueError(f"expected shape {shape}, got {out.shape}")
    return out


def _raise(status: int, k: int, j: int, batch: Batch) -> None:
    if status == _OK:
        return
    stage = _STAGES.get(status, f"status {status}")
    if k < 0:
        raise FloatingPointError(f"non-finite or singular value in the {stage}")
    frame = int(batch.frame_start[k]) + j
    raise FloatingPointError(f"non-finite value in the E-step {stage}: log {k}, frame {j} (batch frame {frame})")


_SCRATCH = threading.local()


def _scratch(name: str, shape) -> np.ndarray:
    """A per-thread reusable float64 work array of ``shape`` (contents undefined). The M-step runs
    every EM iteration with the same sizes; fresh 0.2-0.7 MB temporaries cost more in first-touch
    page faults than the kernels that fill them. Never returned to a caller."""
    store = getattr(_SCRATCH, "arrays", None)
    if store is None:
        store = _SCRATCH.arrays = {}
    size = math.prod(shape) if isinstance(shape, tuple) else int(shape)
    buf = store.get(name)
    if buf is None or buf.size < size:
        buf = store[name] = np.empty(max(size, 1))
    return buf[:size].reshape(shape)


def release_scratch() -> int:
    """Drop this thread's ``_scratch`` arrays (they are made again on the next call that needs them); returns
    the bytes released. After EM they are ~171 bytes per frame (1,000,000 frames, 3 iterations: 171 MiB of
    M-step and E-step work arrays) that the standard errors do not use."""
    store = getattr(_SCRATCH, "arrays", None) or {}
    size = sum(buf.nbytes for buf in store.values())
    store.clear()
    return size
