"""Learner-side twins of the effect catalogue (simulator twins: ``aibo_gym/catalogue.py``, same names
and parameter names, a contract). Each lowers itself into the inference arrays and has a conditional
M-step (ECM) or, for a lag, a grid searched by profile likelihood outside EM.

=========================  ===========================================  ======================================
name                       how the model carries it                     its M-step
=========================  ===========================================  ======================================
floor_drift                world-frame offset per frame                 generalized least squares of the
                                                                        smoothed world-frame residual motion
velocity_fade              factor (1 - fade t) on every displacement    closed form given the action model
actuation_lag              the commands delayed by lag (s)              profile likelihood over ``GRID``
response_time              the commands low-passed (time constant s)    1-d minimization of the motion
                                                                        residuals given the action model
angle_bias                 offset of every predicted bearing            mean wrapped bearing residual
landmark_bearing_offset    offset of the bearing, one per landmark,     mean wrapped bearing residual per
                           summing to 0                                 landmark, given the sum (weighted)
off_center_shrink          size x (1 - k phi^2), phi = bearing - pan    closed form given the curve
distance_dependent_noise   size variance x (d / 2500 mm)^(2 exponent)   1-d maximization over the exponent
=========================  ===========================================  ======================================

(``beacon_height_scale`` lives in ``effects.py`` as the worked example.) The M-steps use the
smoothed means where a cubature expectation would change little (first order).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import numpy as np

from aibo_core.geometry import rot, wrap
from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.model.catalogue_more import WallSlowdown
from learners.model.effects import EffectModel, register_effect
from learners.model.image_angle import phi2_posterior
from learners.model.parameters import Param

if TYPE_CHECKING:
    from learners.model.model import Model

REFERENCE_DISTANCE_MM = 2500.0  # distance_dependent_noise: the factor is 1 at this distance (as the simulator)
#: The timing effects' signed signature: the turn and the forward motion on the frames where the model's command
#: changes, against how much it changed (``learners.discrepancy.signatures.CHANGE_OF``'s variables)
CHANGE_SIGNATURE = "vs change of the commanded"


def _cubature_distances(batch: Batch, post: Posterior, idx: np.ndarray) -> np.ndarray:
    """(len(idx), 6) the distance (mm) from each sighting's smoothed pose to its landmark at the 2n = 6 cubature points
    mu +- sqrt(3) L e_j (L L^T the smoothed covariance), weight 1/6 each: the points the sensor M-step takes its
    expectations over (``learners.inference.sensor_stats.sensor_points``, method "cubature")."""
    pose = batch.sight_pose[idx]
    s3L = np.sqrt(3.0) * np.swapaxes(np.linalg.cholesky(post.cov_gamma[pose]), 1, 2)  # row j = sqrt(3) L e_j
    mu = post.mu_gamma[pose][:, None, :]
    pts = np.concatenate([mu + s3L, mu - s3L], axis=1)  # (n, 6, 3)
    return np.hypot(batch.sight_xy[idx, None, 0] - pts[..., 0], batch.sight_xy[idx, None, 1] - pts[..., 1])


def _sight_geometry(model: "Model", batch: Batch, post: Posterior):
    """Used sightings: (indices, distance (mm), predicted bearing without offsets (rad)) at smoothed means."""
    idx = np.flatnonzero(batch.used)
    pose = post.mu_gamma[batch.sight_pose[idx]]
    dx, dy = (batch.sight_xy[idx] - pose[:, :2]).T
    return idx, np.hypot(dx, dy), wrap(np.arctan2(dy, dx) - pose[:, 2])


@register_effect
@dataclass(frozen=True)
class FloorDrift(EffectModel):
    """A constant world-frame drift (sloped or grained floor). Residual signature: world heading."""

    drift_mm_s: np.ndarray  # (2,) mm/s in the world frame

    name: ClassVar[str] = "floor_drift"
    SIGNATURE: ClassVar[str] = "motion (sigma) vs world heading"
    PARAMS: ClassVar[dict[str, Param]] = {"drift_mm_s": Param("mm/s, world frame", "scaled", (10.0, 10.0), low=-1e4,
                                                                      high=1e4, shape=(2,))}
    PROBE: ClassVar[dict[str, Any]] = {"drift_mm_s": np.array([20.0, 0.0])}
    #: the power study's medium strength (scripts/diagnose_power.py; the calibration takes its strong 12 mm/s, which a
    #: 5-minute log names more often); the calibrated check sees it on a 10-minute log (tests/test_check_sees_effects.py)
    EXAMPLE: ClassVar[dict[str, Any]] = {"drift_mm_s": np.array([6.0, 0.0])}

    @classmethod
    def start(cls, batch: Batch) -> "FloorDrift":
        return cls(np.zeros(2))

    def lower(self, lo: Lowered, batch: Batch) -> None:
        lo.offset = lo.offset + np.array([self.drift_mm_s[0] * batch.dt, self.drift_mm_s[1] * batch.dt, 0.0])

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """drift dt = (sum Q_i^-1)^-1 sum Q_i^-1 e_i, with e_i = R(theta_i) (mu*_i - u_i) + o_i the world-frame
        motion the new action model u_i leaves unexplained (mu*_i net of the previous offset o_i, so the
        prior's pull keeps frames without sightings near zero: EM-consistent), Q_i = R Sigma_xy R^T. Frames a wall
        blocks (``Lowered.blocked``, ``wall_contact``) are left out: there the drift moves the robot along the wall
        at most, and the cancelled offset says nothing of it."""
        p = batch.frame_to_pose
        lo = model.lower(batch)
        th = post.mu_gamma[p, 2]
        c, s = np.cos(th), np.sin(th)
        r = mu_star[:, :2] - lo.disp[:, :2]
        e = np.stack([c * r[:, 0] - s * r[:, 1], s * r[:, 0] + c * r[:, 1]], axis=1) + lo.offset[:, :2]
        Wr = np.linalg.inv(np.asarray(model.action.cov)[:2, :2])  # robot-frame information
        R = np.stack([np.stack([c, -s], 1), np.stack([s, c], 1)], 1)  # (N, 2, 2)
        d = np.asarray(lo.cov_sd, dtype=float)[:, :2]  # each frame's factors on the xy standard deviations
        W = R @ (Wr[None] / (d[:, :, None] * d[:, None, :])) @ np.swapaxes(R, 1, 2) / lo.cov_scale[:, None, None]
        if lo.blocked is not None:
            W = W * ~lo.blocked[:, None, None]
        drift = np.linalg.solve(W.sum(axis=0), np.einsum("nij,nj->i", W, e)) / batch.dt
        return model.with_effect(FloorDrift(drift))


@register_effect
@dataclass(frozen=True)
class VelocityFade(EffectModel):
    """Every walking velocity shrinks linearly with elapsed time (battery): factor 1 - fade t (t in
    minutes since the log's start). Residual signature: elapsed time."""

    fade_per_min: float  # fraction of the velocity lost per minute

    name: ClassVar[str] = "velocity_fade"
    SIGNATURE: ClassVar[str] = "motion (sigma) vs elapsed time"
    PARAMS: ClassVar[dict[str, Param]] = {"fade_per_min": Param("1/min", "scaled", 0.01, low=-1.0, high=1.0, shape=())}
    PROBE: ClassVar[dict[str, Any]] = {"fade_per_min": 0.03}
    EXAMPLE: ClassVar[dict[str, Any]] = {"fade_per_min": 0.02}
    #: a robot that spends more of its later minutes pressing a wall moves slower later (docs/results.md, "Given the
    #: walls")
    CONFOUNDERS: ClassVar[tuple[type, ...]] = (WallSlowdown,)

    def disp_scale(self, batch: Batch) -> np.ndarray:
        return np.maximum(0.0, 1.0 - self.fade_per_min * batch.frame_time / 60.0)

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """Given the action model: mu*_i ~ (1 - f t_i) p_i (p_i the undamped displacement), so
        f = sum t p' Sigma^-1 (p - mu*) / sum t^2 p' Sigma^-1 p."""
        lo = model.lower(batch)
        disp, mu = lo.disp, mu_star
        scale = self.disp_scale(batch)
        keep = scale > 0
        p = disp[keep] / scale[keep, None]
        t = batch.frame_time[keep] / 60.0
        Wi = np.linalg.inv(np.asarray(model.action.cov))
        pw = p @ Wi
        num = np.sum(t * np.einsum("ij,ij->i", pw, p - mu[keep]))
        den = np.sum(t * t * np.einsum("ij,ij->i", pw, p))
        return model.with_effect(VelocityFade(float(num / den)) if den > 0 else self)


@register_effect
@dataclass(frozen=True)
class ActuationLag(EffectModel):
    """A new command takes effect only after ``lag_s`` (s). Discrete commands (indices) move by whole frames: the
    command in force at frame t is the one logged at t - ceil(lag_s / dt). Continuous commands are the held command
    signal delayed by lag_s and averaged over the frame: with lag_s = (n + a) dt, 0 <= a < 1, the command of frame t
    is (1 - a) c[t - n] + a c[t - n - 1] (the same as a shift of n frames when a = 0), so the lag is a continuous
    parameter below the frame period. Before a log's first command, its first command. Residual signature: time
    since the last command change. Estimated by profile likelihood over ``GRID`` (``aibo diagnose``) and, for
    continuous commands, refined between the grid's values by ``aibo learn`` (``learners.em.lag``)."""

    lag_s: float  # s

    name: ClassVar[str] = "actuation_lag"
    SIGNATURE: ClassVar[str] = "vs time since command change"
    ALSO_SIGNATURES: ClassVar[tuple[str, ...]] = (CHANGE_SIGNATURE,)
    PARAMS: ClassVar[dict[str, Param]] = {"lag_s": Param("s", "scaled", 0.1, trainable=False, low=0.0, high=60.0,
                                                                 shape=())}
    GRID: ClassVar[dict[str, tuple[float, ...]]] = {"lag_s": (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)}
    EXAMPLE: ClassVar[dict[str, Any]] = {"lag_s": 0.2}  # no PROBE: the grid's profile shows a flat likelihood

    def polish(self, model: "Model", batch: Batch, loglik: Callable[["Model"], float]) -> "ActuationLag":
        """The lag maximizing the likelihood within one grid step either side of this one, the rest of ``model`` held
        (``EffectModel.polish``): the search places it on ``GRID`` (0.1 s apart), the final fit refines it below.
        Continuous commands: Brent's method on the continuous lag, to 1 ms. Discrete commands move by whole frames:
        each frame's lag in the range, the most likely kept."""
        step = float(np.min(np.diff(self.GRID["lag_s"])))
        low, high = max(self.lag_s - step, 0.0), self.lag_s + step

        @functools.cache  # the best and the start are compared again after the search: no second forward pass
        def ll(lag_s: float) -> float:
            return loglik(model.with_effect(ActuationLag(float(lag_s))))

        if batch.controls is None:  # discrete: the frame lags in [low, high] (ceil(lag / dt) frames each)
            lags = [k * batch.dt for k in range(math.ceil(low / batch.dt - 1e-9), math.floor(high / batch.dt + 1e-9) + 1)]
            best = max(lags, key=ll)
        else:
            from scipy.optimize import minimize_scalar  # here, not at import (SciPy's load costs every command)

            best = float(minimize_scalar(lambda x: -ll(x), bounds=(low, high), method="bounded",
                                         options={"xatol": 1e-3}).x)
        return ActuationLag(float(best)) if ll(best) > ll(self.lag_s) else self

    def grid_resolution(self, pname: str, batch: Batch) -> float | None:
        """Discrete commands: the frame (every lag in ((n - 1) dt, n dt] is the same model as n dt); continuous: None."""
        return batch.dt if batch.controls is None else None

    def commands(self, commands: np.ndarray, batch: Batch) -> np.ndarray:
        frames = self.lag_s / batch.dt
        if np.asarray(commands).ndim == 1:  # discrete: whole frames
            return _shifted(commands, math.ceil(frames - 1e-9), batch)
        n = math.floor(frames + 1e-9)
        a = frames - n if frames - n > 1e-9 else 0.0
        out = _shifted(commands, n, batch)
        return out if a == 0.0 else (1.0 - a) * out + a * _shifted(commands, n + 1, batch)


#: response_time's M-step: the coarse values its 1-d search starts from (s); Brent's method refines the best
RESPONSE_GRID = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0)


def low_passed(c: np.ndarray, tau_s: float, dt: float) -> np.ndarray:
    """``c`` (commands sampled every ``dt`` s along axis 0) through a first-order lag of time constant ``tau_s``:
    y[t] = y[t - 1] + a (c[t] - y[t - 1]), a = 1 - exp(-dt / tau_s), the state starting at c[0] (``ResponseTime``;
    ``scripts/mrclam_turn_response.py`` against Vicon)."""
    from scipy.signal import lfilter  # here, not at import (SciPy's load costs every command)

    c = np.asarray(c, dtype=float)
    a = 1.0 - math.exp(-dt / tau_s)
    return lfilter([a], [1.0, a - 1.0], c, axis=0, zi=((1.0 - a) * c[:1]))[0]


@register_effect
@dataclass(frozen=True)
class ResponseTime(EffectModel):
    """The robot follows its continuous commands through a first-order lag of time constant ``tau_s`` (s): a step in
    the command is reached as 1 - exp(-t / tau_s), as a drive whose speed controller cannot change the speed at once.
    The command in force is the logged one low-passed, y[t] = y[t - 1] + a (c[t] - y[t - 1]), a = 1 - exp(-dt /
    tau_s), starting at each log's first command (after ``actuation_lag``'s delay when both act: the two commute).
    Discrete commands (indices) cannot be averaged: the effect needs continuous ones (``NEEDS``). Residual signature:
    time since the last command change, as a lag's; a lag moves the robot the old command's way for a moment, a
    response time part of the way, fading; signed, the turn against the change of the commanded turn rate
    (``signatures.CHANGE_OF``). EM's lag search fits a delay that stands in for it to within a few nats on 5 minutes
    (``tests/test_response_time.py``). Not a default candidate (``DEFAULT_CANDIDATE``; ``aibo diagnose
    --candidates`` names it): on MRCLAM robots 1, 2, 3 and 5 it is named with the lag (tau 0.10-0.23 s, the lag 0.23-0.26
    -> 0.16-0.18 s), the held-out and motion gaps better, the turn rate against Vicon 1-11% closer, but the forward
    speed 3-19% further and the calibrated check's disagreements not fewer (docs/results.md, "A first-order response
    of the commands"). Its intervals cover 89% on simulated closed-loop logs, 100% open loop (the same place)."""

    tau_s: float  # s

    name: ClassVar[str] = "response_time"
    SIGNATURE: ClassVar[str] = "vs time since command change"
    ALSO_SIGNATURES: ClassVar[tuple[str, ...]] = (CHANGE_SIGNATURE,)
    NEEDS: ClassVar[tuple[str, ...]] = ("controls",)
    PARAMS: ClassVar[dict[str, Param]] = {"tau_s": Param("s", "scaled", 0.1, low=0.0, high=RESPONSE_GRID[-1], shape=())}
    PROBE: ClassVar[dict[str, Any]] = {"tau_s": 0.2}
    EXAMPLE: ClassVar[dict[str, Any]] = {"tau_s": 0.15}
    DEFAULT_CANDIDATE: ClassVar[bool] = False  # the evidence on real robots is mixed (class docstring)

    def commands(self, commands: np.ndarray, batch: Batch) -> np.ndarray:
        c = np.asarray(commands)
        if self.tau_s <= 0.0 or c.ndim == 1:  # off, or indices (never fitted: NEEDS controls)
            return commands
        out = np.array(c, dtype=float, copy=True)
        for i, j in zip(batch.frame_start[:-1], batch.frame_start[1:]):
            if j > i:  # each log's own: the state starts at its first command
                out[i:j] = low_passed(c[i:j], self.tau_s, batch.dt)
        return out

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """Given the action model: the tau_s minimizing sum_i (mu*_i - d_i(tau))' Sigma_i^-1 (mu*_i - d_i(tau)),
        d_i the frame's mean displacement with the commands low-passed (and every other effect's transform and
        scale), Sigma_i the frame's motion covariance: the expected complete-data likelihood's only term in tau_s. Over
        ``RESPONSE_GRID``, then Brent's method between the best value's neighbours."""
        from scipy.optimize import minimize_scalar  # here, not at import

        Wi = np.linalg.inv(np.asarray(model.action.cov))
        lo = model.lower(batch)
        w = 1.0 / lo.cov_scale

        def cost(tau: float) -> float:
            commands, scale = model.with_effect(ResponseTime(float(tau))).effective_commands(batch)
            d = model.action.displacements(commands)
            r = lo.whiten(mu_star - (d if scale is None else d * scale))
            return float(np.sum(w * np.einsum("ij,jk,ik->i", r, Wi, r)))

        grid = RESPONSE_GRID
        costs = [cost(t) for t in grid]
        k = int(np.argmin(costs))
        left, right = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        found = minimize_scalar(cost, bounds=(left, right), method="bounded", options={"xatol": 1e-4})
        best = float(found.x) if found.fun < costs[k] else float(grid[k])
        return model.with_effect(ResponseTime(best))


def _shifted(commands: np.ndarray, n: int, batch: Batch) -> np.ndarray:
    """``commands`` (N, ...) delayed by n frames within each log of ``batch`` (a log's first command before it)."""
    if n <= 0:
        return commands
    out = np.array(commands, copy=True)
    for a, b in zip(batch.frame_start[:-1], batch.frame_start[1:]):
        if b - a > n:
            out[a + n:b] = commands[a:b - n]
            out[a:a + n] = commands[a]
    return out


@register_effect
@dataclass(frozen=True)
class AngleBias(EffectModel):
    """A constant offset in the observed bearing (a camera mounted askew). With a free action model and
    an unknown start heading it is NOT identifiable: a heading offset of b with every velocity rotated
    by b explains the data exactly. Residual signature: none."""

    bias_rad: float

    name: ClassVar[str] = "angle_bias"
    PARAMS: ClassVar[dict[str, Param]] = {"bias_rad": Param("rad", "scaled", 0.01, low=-math.pi, high=math.pi, shape=())}
    PROBE: ClassVar[dict[str, Any]] = {"bias_rad": 0.1}
    REMEDY: ClassVar[str] = (
        "a constant bearing offset b is explained exactly by a heading offset of b and every velocity rotated by b; "
        "a start heading or velocities known and held fixed would make it identifiable (EM re-estimates every log's "
        "start pose and the velocities)")
    EXAMPLE: ClassVar[dict[str, Any]] = {"bias_rad": 0.03}

    def lower(self, lo: Lowered, batch: Batch) -> None:
        lo.bearing_offset = lo.bearing_offset + self.bias_rad

    def equivalent(self, model: "Model") -> "Model | None":
        """The same predictions without the offset: z = bearing(world) - theta + b is bearing(world) - theta'
        with theta' = theta - b, and R(theta) d = R(theta') R(b) d, so every log's start heading moves by -b and
        every robot-frame displacement weight (and Sigma_A's x-y block) turns by R(b). None when the action model
        holds the rotated weights at 0 (a unicycle has no lateral motion: there the offset is identifiable)."""
        b = float(self.bias_rad)
        turn = np.eye(3)
        turn[:2, :2] = rot(b)
        action = model.action
        weights = np.asarray(action.weights, float) @ turn.T
        if np.any(np.abs(weights[action.zero_cells()]) > 1e-12 * max(1.0, float(np.abs(weights).max()))):
            return None
        cov = turn @ np.asarray(action.cov, float) @ turn.T
        init = tuple(replace(i, mean=np.asarray(i.mean, float) - np.array([0.0, 0.0, b])) for i in model.init)
        return model.without_effect(self.name).with_(action=action.with_values(weights=weights, cov=0.5 * (cov + cov.T)),
                                                     init=init)

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        lo = model.lower(batch)
        idx, _, bearing = _sight_geometry(model, batch, post)
        other = lo.bearing_offset[idx] - self.bias_rad
        bias = float(np.mean(wrap(batch.sight_value[idx, 1] - bearing - other)))
        return model.with_effect(AngleBias(bias))


@register_effect
@dataclass(frozen=True)
class LandmarkBearingOffset(EffectModel):
    """Each landmark is seen at a bearing offset of its own (rad): measured bearing = true bearing +
    ``offset_rad[b]`` for landmark b (a marker's visible centre off its surveyed position, a barcode read
    off-centre). Residual signature: the bearing residuals depend on the landmark's identity.

    The offsets are contrasts: held to sum 0 and packed (SQUAREM, standard errors) as their B - 1 Helmert
    contrasts (transform ``"contrast"``). Their common part is a constant bearing offset, ``angle_bias``'s,
    which a start heading offset and rotated velocities explain (exactly for a free action model): it is the
    heading's, not this effect's."""

    offset_rad: np.ndarray  # (B,) rad, summing to 0

    name: ClassVar[str] = "landmark_bearing_offset"
    #: Tried only when asked for: on MRCLAM robots 1 and 4 it was named and cleared "bearing vs landmark", but its
    #: offsets correlate +0.32-0.37 with Vicon's (a south-north contrast trades with the heading), robot 1's pose got
    #: worse (221 vs 177 mm) and two other statistics disagreed more (docs/results.md, "Per-landmark bearing offsets")
    DEFAULT_CANDIDATE: ClassVar[bool] = False
    SIGNATURE: ClassVar[str] = "bearing (sigma) vs landmark"
    PARAMS: ClassVar[dict[str, Param]] = {  # summing to 0: B - 1 free numbers
        "offset_rad": Param("rad per landmark", "contrast", 0.01, low=-math.pi, high=math.pi, shape=(-1,))}
    EXAMPLE: ClassVar[dict[str, Any]] = {"offset_rad": np.array([0.01, -0.01, 0.005, -0.005])}
    #: Below this (rad) on every landmark the offsets are too small to matter (0.06 degrees: a tenth of one
    #: pixel's bearing on a camera of 60 degrees over 100 pixels).
    NEGLIGIBLE_RAD: ClassVar[float] = 0.001
    #: Above this (rad) on any landmark the "offset" is not a marker's: 0.1 rad is 250 mm at 2.5 m, a map error.
    IMPLAUSIBLE_RAD: ClassVar[float] = 0.1

    @classmethod
    def start(cls, batch: Batch) -> "LandmarkBearingOffset":
        return cls(np.zeros(len(batch.landmarks)))

    def lower(self, lo: Lowered, batch: Batch) -> None:
        if np.any(self.offset_rad):
            lo.bearing_offset = lo.bearing_offset + self.offset_rad[batch.sight_landmark]

    def undetermined(self, batch: Batch) -> list[str]:
        """The offsets of the landmarks never sighted (among the applied sightings)."""
        seen = np.bincount(batch.sight_landmark[batch.used], minlength=len(self.offset_rad)) > 0
        return [f"offset_rad[{b}]" for b in np.flatnonzero(~seen)]

    def negligible(self, n_sightings: int) -> str:
        big = float(np.max(np.abs(self.offset_rad), initial=0.0))
        return (f"negligible: the largest offset is {1e3 * big:.2f} mrad, below {1e3 * self.NEGLIGIBLE_RAD:g} mrad"
                if big < self.NEGLIGIBLE_RAD else "")

    def implausible(self) -> str:
        big = float(np.max(np.abs(self.offset_rad), initial=0.0))
        return (f"an offset of {1e3 * big:.0f} mrad is above {1e3 * self.IMPLAUSIBLE_RAD:g} mrad: a wrong landmark "
                "position, not a marker's offset" if big > self.IMPLAUSIBLE_RAD else "")

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """Closed form at the smoothed means: per landmark b, the mean wrapped bearing residual r[b] without this
        effect over its W[b] (the sum of the weights 1 / bearing_var_factor of its sightings), then the sum-0
        constraint: offset[b] = r[b] - lam / W[b], lam = (sum r - sum of the old offsets) / sum 1 / W, the maximum of
        sum_b W[b] (offset[b] - r[b])^2 given the sum (ECM: the exact conditional maximum, so EM's fixed point is a
        stationary point of the likelihood). A common part of the residuals is left to the heading when it can take it
        up (then lam is 0). A landmark never sighted keeps its offset (its start, 0), and the sighted ones keep the
        sum they had, so the group stays at sum 0."""
        lo = model.lower(batch)
        idx, _, bearing = _sight_geometry(model, batch, post)
        lm = batch.sight_landmark[idx]
        r = wrap(batch.sight_value[idx, 1] - bearing - (lo.bearing_offset[idx] - self.offset_rad[lm]))
        w = 1.0 / lo.bearing_var_factor[idx]
        B = len(self.offset_rad)
        den = np.bincount(lm, weights=w, minlength=B)
        seen = den > 0
        if not seen.any():
            return model
        W = den[seen]
        mean = np.bincount(lm, weights=w * r, minlength=B)[seen] / W
        offset = np.array(self.offset_rad, dtype=float)
        lam = (np.sum(mean) - np.sum(offset[seen])) / np.sum(1.0 / W)
        offset[seen] = mean - lam / W
        return model.with_effect(LandmarkBearingOffset(offset))


def implied_distance(lo: Lowered, batch: Batch) -> np.ndarray:
    """(S,) the distance (mm) at which the lowered curve predicts each measured size (the curve
    inverted on a grid over 100 mm .. 20 m, where it is monotone; clipped at the ends)."""
    grid = np.geomspace(100.0, 20000.0, 400)
    f = lo.curve(grid)[0]
    size = (batch.sight_value[:, 0] - lo.size_offset) / lo.size_scale
    order = np.argsort(f)
    return np.interp(size, f[order], grid[order])


def _size_fit(model: "Model", batch: Batch, post: Posterior, skip: EffectModel):
    """Used sightings: (indices, distance, prediction without ``skip``'s size scale, observed size less offsets,
    weights 1 / variance factor)."""
    lo = model.lower(batch)
    idx, d, _ = _sight_geometry(model, batch, post)
    mine = np.ones(len(idx)) if not isinstance(skip, OffCenterShrink) else skip.factor(batch, lo.sigma_bearing)[idx]
    f = model.sensor.mean(d) * lo.size_scale[idx] / mine
    return idx, d, f, batch.sight_value[idx, 0] - lo.size_offset[idx], 1.0 / lo.size_var_factor[idx]


@register_effect
@dataclass(frozen=True)
class OffCenterShrink(EffectModel):
    """The size measurement shrinks away from the image centre: size x (1 - k phi^2), phi the sighting's position in
    the image (rad: bearing - head pan, ``Batch.image_angle``; phi^2 taken as its expectation given the observed
    bearing, ``expected_phi2``, which undoes the attenuation the bearing's noise brings). On a
    camera's landmark heights: lens falloff. On a range computed from a landmark's apparent size (MRCLAM's): the depth
    along the camera's axis, d cos(phi) ~ d (1 - phi^2 / 2), not the distance d; ``aibo learn`` therefore fits it on
    every range sensor (``EMOptions.range_shrink``). A camera fixed to the body (no head pan) has phi = the bearing.
    Residual signature: position in the image."""

    k: float

    name: ClassVar[str] = "off_center_shrink"
    SIGNATURE: ClassVar[str] = "size (sigma) vs position in the image"
    PARAMS: ClassVar[dict[str, Param]] = {"k": Param("1/rad^2", "scaled", 0.05, low=-10.0, high=10.0, shape=())}
    PROBE: ClassVar[dict[str, Any]] = {"k": 0.3}
    EXAMPLE: ClassVar[dict[str, Any]] = {"k": 0.2}

    def factor(self, batch: Batch, sigma_bearing: float) -> np.ndarray:
        """(S,) 1 - k E[phi^2 | the observed phi] (``expected_phi2``; ``sigma_bearing``: the sensor's, rad)."""
        return 1.0 - self.k * expected_phi2(batch, sigma_bearing)

    def lower(self, lo: Lowered, batch: Batch) -> None:
        lo.size_scale = lo.size_scale * self.factor(batch, lo.sigma_bearing)

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """z = f (1 - k g), g = E[phi^2 | observed], is linear in k: k = sum w f g (f - z) / sum w f^2 g^2."""
        idx, _, f, z, w = _size_fit(model, batch, post, self)
        g = expected_phi2(batch, model.sensor.sigma_bearing)[idx]
        den = np.sum(w * f * f * g * g)
        return model.with_effect(OffCenterShrink(float(np.sum(w * f * g * (f - z)) / den))) if den > 0 else model


def expected_phi2(batch: Batch, sigma_bearing: float) -> np.ndarray:
    """(S,) E[phi^2 | phi_obs]: the true position in the image squared, expected given the observed one, phi_obs =
    phi + e, e ~ N(0, s2 = sigma_bearing^2) (rad^2). Regression calibration (Carroll et al. 2006, ch. 4) with the prior
    of phi deconvolved from the used sightings' angles (``learners.model.image_angle``: a field of view's sharp edge
    stays sharp). The size's shrink regressed on phi_obs^2 itself is attenuated by the bearing's noise (k 4.5% low on
    ``aibo`` logs, 2.5-6 standard errors low at k 0.45 on wheeled ones); a Gaussian prior of phi undid half of that and
    put the sightings past the image's edge further out than the edge (docs/results.md, calibration, "off_center_shrink").
    On a bearing much sharper than the spread of phi (MRCLAM: 3-6 mrad against 0.3 rad) g is phi_obs^2 to within
    s2. Where the noise is a large part of the spread (lam = v / (v + s2) below ``MIN_LAMBDA``, v = var(phi_obs) - s2:
    ``paper-sim``'s 0.5 rad, lam about 0.2) g's dependence on sigma_bearing let the size's fit move the bearing noise
    (a false alarm at k 0.25 on an effect-free ``paper-sim`` log, +9.4 nats, where phi_obs^2 gives +0.3): g is then
    phi_obs^2 itself. s is the noise an EM fit holds (``Batch.angle_noise``: its start model's), else
    ``sigma_bearing``."""
    phi = batch.image_angle
    if not len(phi):
        return phi ** 2
    noise = float(sigma_bearing if batch.angle_noise is None else batch.angle_noise)
    used = phi[batch.used] if batch.used.any() else phi
    v = max(float(np.var(used)) - noise ** 2, 0.0)
    lam = v / (v + noise ** 2) if v + noise ** 2 > 0 else 1.0
    if lam < MIN_LAMBDA:
        return phi ** 2
    return _phi2_posterior_of(phi.tobytes(), used.tobytes(), noise)


@functools.lru_cache(maxsize=8)
def _phi2_posterior_of(angles: bytes, used: bytes, sigma_bearing: float) -> np.ndarray:
    """``phi2_posterior``'s E[phi^2 | phi_obs] of float64 angle arrays given as bytes: remembered, since a fit lowers its
    model several times per iteration at one ``sigma_bearing`` (the array returned is read-only)."""
    out = phi2_posterior(np.frombuffer(angles), np.frombuffer(used), sigma_bearing)
    out.setflags(write=False)
    return out


#: ``expected_phi2``: the regression calibration's lam (the true phi's share of the observed one's variance) below
#: which phi_obs^2 is taken as it is (``aibo``, wheeled, MRCLAM: 0.99-1; ``paper-sim``: about 0.2; the paper's start,
#: 0.2 rad, on wheeled and MRCLAM logs: 0.6-0.7, a bearing noise not yet learned; was 0.5 with the Gaussian prior)
MIN_LAMBDA = 0.9


@register_effect
@dataclass(frozen=True)
class DistanceDependentNoise(EffectModel):
    """Size noise grows with distance: sigma_size x (d / 2500 mm)^exponent, exponent >= 0. The distance of each
    sighting is read off its measured size through the current sensor curve (so the factor needs no
    path and is the same for any data). Residual signature: the size residuals' spread depends on
    distance."""

    exponent: float

    name: ClassVar[str] = "distance_dependent_noise"
    SIGNATURE: ClassVar[str] = "|size| (sigma) vs distance"
    PARAMS: ClassVar[dict[str, Param]] = {"exponent": Param("", "scaled", 0.1, low=0.0, high=10.0, shape=())}
    PROBE: ClassVar[dict[str, Any]] = {"exponent": 1.0}
    EXAMPLE: ClassVar[dict[str, Any]] = {"exponent": 0.5}

    def factor(self, lo: Lowered, batch: Batch) -> np.ndarray:
        """(S,) variance factor (d / 2500 mm)^(2 exponent), d the distance whose predicted size is measured."""
        return (implied_distance(lo, batch) / REFERENCE_DISTANCE_MM) ** (2.0 * self.exponent)

    def lower(self, lo: Lowered, batch: Batch) -> None:
        if self.exponent != 0.0:
            lo.size_var_factor = lo.size_var_factor * self.factor(lo, batch)

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """The exponent (and sigma_size) maximizing the expected Gaussian log-likelihood of the size residuals: each
        squared residual's expectation under the smoothed pose (the mean over its cubature points, as the sensor
        M-step takes sigma_size's), not its value at the smoothed mean, which leaves out the pose's own spread
        (largest near a landmark, where the size changes fastest with the distance) and made this step disagree
        with the sensor M-step's sigma_size (docs/results.md, "Calibration": the exponent's calibration before and
        after)."""
        lo = model.lower(batch)
        idx = np.flatnonzero(batch.used)
        d = _cubature_distances(batch, post, idx)  # (n, 6)
        pred = model.sensor.mean(d.ravel()).reshape(d.shape) * lo.size_scale[idx, None]
        r2 = np.mean((batch.sight_value[idx, 0, None] - lo.size_offset[idx, None] - pred) ** 2, axis=1)
        other = lo.size_var_factor[idx] / self.factor(lo, batch)[idx]
        logd = np.log(implied_distance(lo, batch)[idx] / REFERENCE_DISTANCE_MM)

        def profile(e: float) -> tuple[float, float]:
            v = other * np.exp(2.0 * e * logd)
            s2 = float(np.mean(r2 / v))
            return -0.5 * float(np.sum(np.log(s2 * v))) - 0.5 * len(r2), s2

        # exponent >= 0: the catalogue's effect is noise that GROWS with distance. A negative exponent
        # would explain outliers among the large (near) sizes, which false_sightings describes: free,
        # it came out -0.44 on a log with 10% spurious sightings and was named before them.
        grid = np.linspace(0.0, 3.0, 61)
        e = float(grid[int(np.argmax([profile(g)[0] for g in grid]))])
        fine = np.linspace(max(e - 0.05, 0.0), e + 0.05, 21)
        e = float(fine[int(np.argmax([profile(g)[0] for g in fine]))])
        sensor = replace(model.sensor, sigma_size=math.sqrt(profile(e)[1]))
        return model.with_effect(replace(self, exponent=e)).with_(sensor=sensor)
