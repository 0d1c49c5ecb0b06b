"""Geometry of the aibo model: angle wrapping, rotations, the motion and observation
functions with their Jacobians, and the relative displacement used by the action M-step.

All functions are pure and accept either one pose (shape ``(3,)``) or a stack of poses
(shape ``(..., 3)``); Jacobians then carry the same leading axes (``(..., r, c)``).

Units: x, y in mm; theta in rad (kept UNWRAPPED in poses, see docs/em-math.md); beacon
positions in mm; distances in mm; beacon heights in px; bearings in rad (wrapped).
"""

from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * np.pi


def wrap(a):
    """Wrap angles (rad) to (-pi, pi].

    Values already inside (-pi, pi] are returned unchanged (bit for bit); -pi maps to +pi.
    """
    a = np.asarray(a, dtype=float)
    return a - TWO_PI * np.ceil((a - np.pi) / TWO_PI)


def rot(theta):
    """2x2 counterclockwise rotation R(theta) (theta in rad); shape ``(..., 2, 2)``."""
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    out = np.empty(theta.shape + (2, 2))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    return out


def motion(mean, disp):
    """Motion function g(s) = s + R(theta) u and its linearization.

    Parameters
    ----------
    mean : (..., 3) pose (x mm, y mm, theta rad) at the start of the frame.
    disp : (..., 3) robot-frame displacement u = (dx mm, dy mm, dtheta rad) per frame.

    Returns
    -------
    g : (..., 3) predicted pose (mm, mm, rad; heading not wrapped).
    F : (..., 3, 3) Jacobian dg/ds: identity except F[0,2] = -sin(th) ux - cos(th) uy,
        F[1,2] = cos(th) ux - sin(th) uy.
    R3 : (..., 3, 3) rotation R(theta) on (x, y); the motion noise is Q = R3 Sigma_A R3^T.
    """
    mean = np.asarray(mean, dtype=float)
    disp = np.asarray(disp, dtype=float)
    if mean.shape == (3,) and disp.shape == (3,):  # one pose: same numbers, less overhead
        x, y, th = mean.tolist()
        ux, uy, ut = disp.tolist()
        c, s = math.cos(th), math.sin(th)
        g = np.array([x + c * ux - s * uy, y + s * ux + c * uy, th + ut])
        F = np.array([[1.0, 0.0, -s * ux - c * uy], [0.0, 1.0, c * ux - s * uy], [0.0, 0.0, 1.0]])
        R3 = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return g, F, R3
    th = mean[..., 2]
    c, s = np.cos(th), np.sin(th)
    ux, uy, ut = disp[..., 0], disp[..., 1], disp[..., 2]
    shape = np.broadcast_shapes(mean.shape, disp.shape)
    g = np.empty(shape)
    g[..., 0] = mean[..., 0] + c * ux - s * uy
    g[..., 1] = mean[..., 1] + s * ux + c * uy
    g[..., 2] = th + ut
    F = np.zeros(shape[:-1] + (3, 3))
    F[..., 0, 0] = 1.0
    F[..., 1, 1] = 1.0
    F[..., 2, 2] = 1.0
    F[..., 0, 2] = -s * ux - c * uy
    F[..., 1, 2] = c * ux - s * uy
    R3 = np.zeros(shape[:-1] + (3, 3))
    R3[..., 0, 0] = c
    R3[..., 0, 1] = -s
    R3[..., 1, 0] = s
    R3[..., 1, 1] = c
    R3[..., 2, 2] = 1.0
    return g, F, R3


def observe(mean, beacon_xy, sensor):
    """Observation function h(s) = (f(dist), bearing) and its Jacobian.

    Parameters
    ----------
    mean : (..., 3) pose (x mm, y mm, theta rad).
    beacon_xy : (..., 2) position (mm) of the beacon seen.
    sensor : SensorModel (``coef``: f in ascending powers of d in mm, px).

    Returns
    -------
    h : (..., 2) (f(d) px, wrap(atan2(by - y, bx - x) - theta) rad).
    H : (..., 2, 3) Jacobian: row 0 = f'(d) (-dx/d, -dy/d, 0); row 1 = (dy/q, -dx/q, -1),
        with dx = bx - x, dy = by - y, q = dx^2 + dy^2, d = sqrt(q).
    dist : (...,) distance d (mm) from the robot to the beacon.
    """
    mean = np.asarray(mean, dtype=float)
    b = np.asarray(beacon_xy, dtype=float)
    dx = b[..., 0] - mean[..., 0]
    dy = b[..., 1] - mean[..., 1]
    q = dx * dx + dy * dy
    d = np.sqrt(q)
    f = sensor.height(d)
    fp = sensor.dheight(d)
    shape = np.broadcast_shapes(mean.shape[:-1], b.shape[:-1])
    h = np.empty(shape + (2,))
    h[..., 0] = f
    h[..., 1] = wrap(np.arctan2(dy, dx) - mean[..., 2])
    H = np.zeros(shape + (2, 3))
    H[..., 0, 0] = -fp * dx / d
    H[..., 0, 1] = -fp * dy / d
    H[..., 1, 0] = dy / q
    H[..., 1, 1] = -dx / q
    H[..., 1, 2] = -1.0
    return h, H, d


def rel_disp(s0, s1):
    """Relative displacement d(s0, s1) = R(-theta0)(s1 - s0) (mm, mm, rad), in the frame of s0.

    The heading component is theta1 - theta0, not wrapped (poses are unwrapped).
    """
    s0 = np.asarray(s0, dtype=float)
    s1 = np.asarray(s1, dtype=float)
    th = s0[..., 2]
    c, s = np.cos(th), np.sin(th)
    dx = s1[..., 0] - s0[..., 0]
    dy = s1[..., 1] - s0[..., 1]
    out = np.empty(np.broadcast_shapes(s0.shape, s1.shape))
    out[..., 0] = c * dx + s * dy
    out[..., 1] = -s * dx + c * dy
    out[..., 2] = s1[..., 2] - s0[..., 2]
    return out


def rel_disp_jac(s0, s1):
    """First-order expansion of d at the point (s0, s1): d(a, b) ~ L1 a + L2 b + m.

    Returns
    -------
    L1 : (..., 3, 3) dd/ds0 = [-R(-theta0) | dd/dtheta0], i.e. -R3(-theta0) with column 2
         replaced by (-sin dx + cos dy, -cos dx - sin dy, -1).
    L2 : (..., 3, 3) dd/ds1 = R3(-theta0).
    m : (..., 3) offset d(s0, s1) - L1 s0 - L2 s1 (mm, mm, rad).
    """
    s0 = np.asarray(s0, dtype=float)
    s1 = np.asarray(s1, dtype=float)
    shape = np.broadcast_shapes(s0.shape, s1.shape)
    th = s0[..., 2]
    c, s = np.cos(th), np.sin(th)
    dx = s1[..., 0] - s0[..., 0]
    dy = s1[..., 1] - s0[..., 1]
    L2 = np.zeros(shape[:-1] + (3, 3))
    L2[..., 0, 0] = c
    L2[..., 0, 1] = s
    L2[..., 1, 0] = -s
    L2[..., 1, 1] = c
    L2[..., 2, 2] = 1.0
    L1 = -L2
    L1[..., 0, 2] = -s * dx + c * dy
    L1[..., 1, 2] = -c * dx - s * dy
    L1[..., 2, 2] = -1.0
    d = rel_disp(s0, s1)
    m = d - np.einsum("...ij,...j->...i", L1, s0) - np.einsum("...ij,...j->...i", L2, s1)
    return L1, L2, m
