"""The model "lowered" to per-frame and per-sighting arrays: everything inference sees.

Model components (``learners.model``) write these arrays in NumPy; the E-step (reference and
compiled) and the M-step statistics read only these, so a new effect or a continuous command never
touches a kernel. Units: displacements per frame (mm, mm, rad); sizes in the log's unit (px or mm).

Motion of frame i (pose s -> s'):   s' = s + R(theta) disp[i] + offset[i] + w,
                                    w ~ N(0, R(theta) Sigma_i R(theta)^T),
                                    Sigma_i = cov_scale[i] D_i cov D_i, D_i = diag(cov_sd[i])
(``Lowered.frame_cov``: one factor on the whole covariance, and one per component on its standard deviations:
forward, lateral, heading).
Sighting j (of the end pose s'):    size    = size_scale[j] f(d) + size_offset[j] + e1,
                                    bearing = wrap(atan2(dy, dx) - theta + bearing_offset[j]) + e2,
    e1 ~ N(0, sigma_size^2 size_var_factor[j]), e2 ~ N(0, sigma_bearing^2 bearing_var_factor[j]), d the distance (mm) to
    the landmark, f(d) = sum_k coef[k] x^k with x = d (``basis == BASIS_POWER``) or x = 1/d
    (``basis == BASIS_INVERSE``).

Extra states (``ExtraStates``, None for the base model): K scalar states b beside the pose, x = (s, b),
each a linear-Gaussian AR(1) chain, b_k' = phi[i, k] b_k + N(0, q[i, k]) in frame i; a sighting with
slot[j] = k measures size = size_scale[j] f(d) (1 + b_k) + size_offset[j] + e1 (per-landmark size biases), and one
with bearing_slot[j] = k' measures bearing = ... + bearing_offset[j] + b_k' + e2 (per-landmark bearing biases, rad).
A sighting reads at most one state of each kind; effects that add states append their columns
(``ExtraStates.append``).
Inference then runs on the augmented state (``learners.inference.augmented`` and its compiled twin).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aibo_core import geometry

BASIS_POWER = 0  # f(d) = sum_k coef[k] d^k   (the paper's cubic: degree 3)
BASIS_INVERSE = 1  # f(d) = sum_k coef[k] d^-k  (pinhole-like: c0 + c1/d + c2/d^2)


@dataclass
class ExtraStates:
    """K extra scalar states beside the pose (module docstring). A frame with phi = 0 and q = v restarts
    a state from N(0, v) (a slot handed to another landmark)."""

    slot: np.ndarray  # (S,) int64: the state whose (1 + b) multiplies sighting j's size; -1: none
    phi: np.ndarray  # (N, K) per-frame transition factor
    q: np.ndarray  # (N, K) per-frame process noise variance
    init_var: np.ndarray  # (L, K) variance of each state at each log's first pose (mean 0)
    bearing_slot: np.ndarray | None = None  # (S,) int64: the state added to sighting j's bearing (rad); -1: none

    def __post_init__(self) -> None:
        if self.bearing_slot is None:
            self.bearing_slot = np.full(len(self.slot), -1, dtype=np.int64)

    @property
    def k(self) -> int:
        return int(self.phi.shape[1])

    @staticmethod
    def append(extra: "ExtraStates | None", phi: np.ndarray, q: np.ndarray, init_var: np.ndarray,
               slot: np.ndarray | None = None, bearing_slot: np.ndarray | None = None) -> "ExtraStates":
        """``extra`` (None: no states yet) with K' more states (``phi``, ``q`` (N, K'), ``init_var`` (L, K')) after
        its own; ``slot`` / ``bearing_slot`` (S,) index the new states (-1: none) and must not give a sighting a second
        state of a kind it already reads."""
        n_s = len(slot if slot is not None else bearing_slot)
        none = np.full(n_s, -1, dtype=np.int64)
        if extra is None:
            return ExtraStates(none if slot is None else slot, phi, q, init_var,
                               none if bearing_slot is None else bearing_slot)
        k0 = extra.k
        joined = []
        for old, new, kind in ((extra.slot, slot, "size"), (extra.bearing_slot, bearing_slot, "bearing")):
            if new is None:
                joined.append(old)
                continue
            if np.any((old >= 0) & (new >= 0)):
                raise ValueError(f"extra states: a sighting would read two {kind} states")
            joined.append(np.where(new >= 0, new + k0, old))
        return ExtraStates(joined[0], np.concatenate([extra.phi, phi], axis=1), np.concatenate([extra.q, q], axis=1),
                           np.concatenate([extra.init_var, init_var], axis=1), joined[1])


@dataclass
class Lowered:
    """Per-frame (N rows), per-sighting (S rows) and per-log (L rows) arrays of one model on one Batch."""

    disp: np.ndarray  # (N, 3) robot-frame mean displacement (mm, mm, rad per frame)
    offset: np.ndarray  # (N, 3) world-frame offset added after the rotation (mm, mm, rad per frame)
    cov: np.ndarray  # (3, 3) motion covariance Sigma_A (robot frame, per frame)
    cov_scale: np.ndarray  # (N,) per-frame scale of cov
    basis: int  # BASIS_POWER or BASIS_INVERSE
    coef: np.ndarray  # (m,) sensor curve coefficients in that basis
    sigma_size: float  # size noise std (px or mm) at size_var_factor 1
    sigma_bearing: float  # bearing noise std (rad)
    size_scale: np.ndarray  # (S,) multiplies f(d)
    size_offset: np.ndarray  # (S,) added to the size (px or mm)
    size_var_factor: np.ndarray  # (S,) multiplies sigma_size^2
    bearing_offset: np.ndarray  # (S,) added to the predicted bearing (rad)
    init_mean: np.ndarray  # (L, 3) first pose mean per log (mm, mm, rad)
    init_cov: np.ndarray  # (L, 3, 3)
    bearing_var_factor: np.ndarray | None = None  # (S,) multiplies sigma_bearing^2 (None: ones, filled in)
    extra: ExtraStates | None = None  # extra states beside the pose (None: the pose alone)
    #: (N,) bool: frames whose motion a wall may cancel in part (``wall_contact``: any contact probability), None:
    #: none. Their displacement
    #: does not depend on what moves the robot outwards, so an M-step that estimates such a motion leaves them out.
    blocked: np.ndarray | None = None
    #: (N, 3) per-frame factors on the motion noise's standard deviations (forward, lateral, heading; module
    #: docstring), None: ones, filled in
    cov_sd: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.bearing_var_factor is None:
            self.bearing_var_factor = _constant((len(self.size_var_factor),), 1.0)
        if self.cov_sd is None:
            self.cov_sd = _constant((len(self.disp), 3), 1.0)

    def shaped_cov(self, frames=None) -> np.ndarray:
        """(n, 3, 3) D_i cov D_i of ``frames`` (an index array or a slice; default every frame): each frame's motion
        covariance in the robot frame before its ``cov_scale`` (mm^2, mm^2, rad^2; module docstring). Unit factors
        give ``cov`` exactly."""
        d = _of_frames(self.cov_sd, frames)
        return d[:, :, None] * np.asarray(self.cov, dtype=float)[None] * d[:, None, :]

    def frame_cov(self, frames=None) -> np.ndarray:
        """(n, 3, 3) Sigma_i = cov_scale[i] D_i cov D_i of ``frames`` (default every frame): each frame's motion
        covariance in the robot frame (mm^2, mm^2, rad^2; module docstring)."""
        c = _of_frames(self.cov_scale, frames)
        return c[:, None, None] * self.shaped_cov(frames)

    def whiten(self, v: np.ndarray, frames=None) -> np.ndarray:
        """(n, 3) D_i^-1 v_i of per-frame robot-frame vectors ``v`` (n, 3) of ``frames`` (default every frame): a
        displacement residual in the units of cov's standard deviations, before cov_scale."""
        return v / _of_frames(self.cov_sd, frames)

    def information(self, v: np.ndarray, frames=None) -> np.ndarray:
        """(n, 3) Sigma_i^-1 v_i of per-frame robot-frame vectors ``v`` (n, 3) of ``frames`` (default every frame):
        each frame's motion information applied to ``v`` (1/mm, 1/mm, 1/rad for a displacement in mm, mm, rad)."""
        c = _of_frames(self.cov_scale, frames)
        return self.whiten(self.whiten(v, frames) @ np.linalg.inv(np.asarray(self.cov)), frames) / c[:, None]

    def unshaped(self, m: np.ndarray, frames=None) -> np.ndarray:
        """(n, 3, 3) D_i^-1 m_i D_i^-1 of per-frame second moments ``m`` (n, 3, 3) of ``frames`` (default every frame):
        the per-component factors taken out, ``cov_scale`` left in (``shaped_cov``'s inverse). Unit factors give m
        exactly."""
        d = _of_frames(self.cov_sd, frames)
        return m / (d[:, :, None] * d[:, None, :])

    def whitened(self, m: np.ndarray, frames=None) -> np.ndarray:
        """(n, 3, 3) D_i^-1 m_i D_i^-1 / cov_scale[i] of per-frame second moments ``m`` (n, 3, 3) of ``frames``
        (default every frame): in the units of cov, what the M-step of Sigma_A averages. Unit factors give m /
        cov_scale exactly."""
        return self.unshaped(m, frames) / _of_frames(self.cov_scale, frames)[:, None, None]

    @staticmethod
    def plain(disp: np.ndarray, cov: np.ndarray, basis: int, coef: np.ndarray, sigma_size: float,
              sigma_bearing: float, init_mean: np.ndarray, init_cov: np.ndarray, n_sightings: int) -> "Lowered":
        """The arrays with no effect: zero offsets, unit scales. These neutral arrays are shared and
        READ-ONLY (made once per size: EM lowers its model twice per iteration); an effect replaces
        an array (``lo.size_scale = lo.size_scale * s``), never writes into it."""
        n = len(disp)
        return Lowered(
            disp=np.ascontiguousarray(disp, dtype=float), offset=_constant((n, 3), 0.0),
            cov=np.asarray(cov, dtype=float), cov_scale=_constant((n,), 1.0), basis=int(basis),
            coef=np.asarray(coef, dtype=float), sigma_size=float(sigma_size), sigma_bearing=float(sigma_bearing),
            size_scale=_constant((n_sightings,), 1.0), size_offset=_constant((n_sightings,), 0.0),
            size_var_factor=_constant((n_sightings,), 1.0), bearing_offset=_constant((n_sightings,), 0.0),
            bearing_var_factor=_constant((n_sightings,), 1.0),
            init_mean=np.asarray(init_mean, dtype=float).reshape(-1, 3),
            init_cov=np.asarray(init_cov, dtype=float).reshape(-1, 3, 3),
        )

    def curve(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(f(d), f'(d)) for distances d (mm): the size curve and its derivative."""
        return curve(self.basis, self.coef, d)


def _of_frames(values, frames) -> np.ndarray:
    """The rows of per-frame ``values`` (``cov_sd``, ``cov_scale``) that an index argument of ``Lowered``'s per-frame
    helpers selects, as floats: every frame for None."""
    return np.asarray(values, dtype=float)[slice(None) if frames is None else frames]


_CONSTANTS: dict[tuple, np.ndarray] = {}


def _constant(shape: tuple[int, ...], value: float) -> np.ndarray:
    """A shared read-only array of ``shape`` filled with ``value`` (the last few sizes are kept)."""
    key = (shape, value)
    arr = _CONSTANTS.get(key)
    if arr is None:
        if len(_CONSTANTS) > 16:
            _CONSTANTS.clear()
        arr = _CONSTANTS[key] = np.full(shape, value)
        arr.flags.writeable = False
    return arr


def curve(basis: int, coef: np.ndarray, d) -> tuple[np.ndarray, np.ndarray]:
    """(f(d), f'(d)) of the sensor curve ``sum_k coef[k] x^k``, x = d or 1/d (see the module docstring)."""
    d = np.asarray(d, dtype=float)
    P = np.polynomial.polynomial
    coef = np.asarray(coef, dtype=float)
    if basis == BASIS_POWER:
        return P.polyval(d, coef), P.polyval(d, P.polyder(coef))
    if basis == BASIS_INVERSE:
        x = 1.0 / d
        return P.polyval(x, coef), -P.polyval(x, P.polyder(coef)) * x * x
    raise ValueError(f"unknown sensor basis {basis}")


def sighting_model(lo: Lowered, mean, xy, idx):
    """The lowered observation function of sightings ``idx`` (S' indices) at poses ``mean`` (S', 3).

    h = (size_scale f(d) + size_offset, wrap(atan2(dy, dx) - theta + bearing_offset)) and its
    Jacobian H (S', 2, 3): row 0 = size_scale f'(d) (-dx/d, -dy/d, 0), row 1 = (dy/q, -dx/q, -1),
    with (dx, dy) = landmark - (x, y) in mm, q = dx^2 + dy^2, d = sqrt(q). Returns (h, H, R_diag)
    with R_diag (S', 2) = (sigma_size^2 size_var_factor, sigma_bearing^2 bearing_var_factor).
    """
    mean = np.asarray(mean, dtype=float)
    dx = xy[:, 0] - mean[:, 0]
    dy = xy[:, 1] - mean[:, 1]
    q = dx * dx + dy * dy
    d = np.sqrt(q)
    f, fp = lo.curve(d)
    sc = lo.size_scale[idx]
    h = np.empty((len(idx), 2))
    h[:, 0] = sc * f + lo.size_offset[idx]
    h[:, 1] = geometry.wrap(np.arctan2(dy, dx) - mean[:, 2] + lo.bearing_offset[idx])
    H = np.zeros((len(idx), 2, 3))
    H[:, 0, 0] = -sc * fp * dx / d
    H[:, 0, 1] = -sc * fp * dy / d
    H[:, 1, 0] = dy / q
    H[:, 1, 1] = -dx / q
    H[:, 1, 2] = -1.0
    rd = np.empty((len(idx), 2))
    rd[:, 0] = lo.sigma_size**2 * lo.size_var_factor[idx]
    rd[:, 1] = lo.sigma_bearing**2 * lo.bearing_var_factor[idx]
    return h, H, rd


def fit_polynomial(x, h, w, degree: int = 3, scale=None) -> np.ndarray:
    """Weighted least-squares polynomial f minimizing sum w (scale f(x) - h)^2 (scale 1 if None).

    Well-conditioned: the fit is done in a Chebyshev basis of the scaled variable
    u = (2x - (lo + hi)) / (hi - lo) in [-1, 1] (normal equations of a (degree+1)-square Gram
    matrix, whose condition number stays small in that basis), then converted to ascending powers
    of x. Returns ``degree + 1`` coefficients.
    """
    x = np.asarray(x, dtype=float)
    h = np.asarray(h, dtype=float)
    w = np.asarray(w, dtype=float)
    if len(x) < degree + 1:
        raise ValueError(f"need at least {degree + 1} points to fit a degree-{degree} polynomial, got {len(x)}")
    if not (np.isfinite(x).all() and np.isfinite(h).all() and np.isfinite(w).all()):
        raise FloatingPointError("fit_polynomial: non-finite input")
    lo, hi = float(x.min()), float(x.max())
    if hi <= lo:
        raise ValueError(f"need at least two distinct distances to fit a polynomial, got all {lo}")
    V = np.polynomial.chebyshev.chebvander((2.0 * x - (lo + hi)) / (hi - lo), degree)
    if scale is not None:
        V = V * np.asarray(scale, dtype=float)[:, None]
    Vw = V * w[:, None]
    cheb = np.linalg.solve(Vw.T @ V, Vw.T @ h)
    coef = np.polynomial.Chebyshev(cheb, domain=[lo, hi]).convert(kind=np.polynomial.Polynomial).coef
    out = np.zeros(degree + 1)
    out[: len(coef)] = coef
    return out
