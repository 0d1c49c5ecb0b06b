"""``landmark_bias``: each landmark's size measurement carries a slowly varying relative bias of its own,
the first effect that adds state (learner twin of ``aibo_gym.catalogue.LandmarkBias``; same name and
parameter names, a contract).

    size_j = size_scale_j f(d_j) (1 + b_l(t_j)) + size_offset_j + e,   l = the landmark of sighting j,

b_l a first-order Gauss-Markov process per landmark, independent across landmarks, with stationary
standard deviation ``sigma_rel`` and correlation time ``tau_s`` (s): per frame of dt seconds
b' = phi b + N(0, sigma_rel^2 (1 - phi^2)), phi = exp(-dt / tau_s). Real range sensors show it: on
MRCLAM the range errors of one landmark correlate at 0.92-0.97 between consecutive sightings, while
errors to different landmarks at one instant do not (a measurement-side process, not pose error).

How the model carries it: the biases are states of the smoother beside the pose (``Lowered.extra``),
one per landmark seen recently. At most ``K_MAX`` states at once: a landmark seen again keeps its state,
so across a gap its bias decays towards the prior by itself (passes need no segmentation); a landmark
seen for the first time takes a free state, or the one of the landmark seen least recently, restarted
from N(0, sigma_rel^2) (with K_MAX at least the number of landmarks this is exact; otherwise it drops
the correlation of the evicted landmark's bias across its gap, exp(-gap / tau_s)). The allocation
depends on the sightings only (``slot_schedule``), never on the parameters.

M-step: closed form for sigma_rel given phi from the smoothed first and second moments and the lag-one
cross-moments of the states, then a 1-d maximization over phi (tau_s) of that profile. Only the stretch
of each state from its landmark's first sighting to its last counts: the tail after the last sighting
integrates out exactly. That update crawls along a ridge of the likelihood (the states hold a fraction of its
information about tau_s); ``polish`` maximizes the likelihood itself over (sigma_rel, tau_s), the rest held, after
EM has converged (``EMOptions.polish``: ECME's conditional step; on in ``aibo diagnose``'s final fit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.lowered import ExtraStates, Lowered
from learners.arrays.posterior import Posterior
from learners.model.effects import EffectModel, register_effect
from learners.model.parameters import Param

if TYPE_CHECKING:
    from learners.model.model import Model

K_MAX = 8  # bias states carried at once (least recently seen landmark evicted beyond this)
SIGMA_FLOOR = 1e-4  # sigma_rel is kept above this: at 0 the states would be degenerate (a singular smoother)
TAU_BOUNDS_S = (1e-2, 1e4)  # the M-step's search range for tau_s (s)
#: The largest credible sigma_rel. Measured: 0.037-0.108 on the MRCLAM robots (docs/results.md, "Bias states on the
#: real robots"), 0.24 on robot 3 in a wrong world, and 0.47 on a simulated log with 10% spurious sightings and no
#: bias, whose base fit was in a wrong world (97.5% of its poses off the field): there it was named before them.
MAX_PLAUSIBLE_SIGMA = 0.2
#: The longest credible correlation time (s). A bias process that holds for minutes is a per-landmark constant
#: (``beacon_height_scale``) or a slow error of the pose, not a pass-to-pass bias. Measured: 7.8-34.6 s on the
#: five MRCLAM robots; 5-17 s on 11 simulated 5-minute logs with tau_s 8; 87-208 s where it stood in for
#: per-beacon height factors of 1-4% (9 logs) and 437-575 s where it stood in for unmodelled wall contacts
#: (``paper-sim`` noise, effect-free wall logs of seeds 3000 and 3008: docs/results.md).
MAX_PLAUSIBLE_TAU_S = 60.0
#: The shortest credible correlation time (s). A bias that loses most of its correlation within a second is gone
#: before the robot comes back to the landmark (MRCLAM: consecutive sightings of one landmark 0.3-0.4 s apart at the
#: median, a tenth of them more than 2.2-2.8 s apart): no pass-to-pass bias, but white noise on the sightings that the
#: range noise or ``distance_dependent_noise`` carries. Measured with the range curve freed: 0.19-0.69 s where the
#: real robots' fits took it there (four training halves' search fits; robot 4's whole-log final fit, from 35.6 s when
#: named); 5-17 s on 11 simulated 5-minute logs with tau_s 8 (docs/results.md, "The range curve freed by default").
MIN_PLAUSIBLE_TAU_S = 1.0
POLISH_SIMPLEX = 0.05  # ``polish``'s first simplex: log sigma_rel +5%, log tau_s +10%
POLISH_MAX_EVALS = 200  # ``polish``: forward passes at most (measured: 28-50 per call on 5-minute logs)
WARM_GRID = ((0.01, 0.02, 0.04, 0.08), (1.0, 3.0, 10.0, 30.0))  # warm_start's sigma_rel and tau_s (s)


@dataclass(frozen=True)
class SlotSchedule:
    """Which state carries which sighting's bias (``slot``), which frames restart a state (``reset``), and
    which frames' transitions lie inside a state's tenure between its landmark's first and last sighting
    (``count``: they enter the M-step)."""

    slot: np.ndarray  # (S,) int64, -1: no state (a frame that sees more landmarks than there are states)
    reset: np.ndarray  # (N, K) bool: frame i hands state k to a new landmark (restart at its end pose)
    count: np.ndarray  # (N, K) bool

    @property
    def k(self) -> int:
        return int(self.reset.shape[1])


_RECENT: list[tuple[tuple, SlotSchedule]] = []  # the last few schedules, by the identity of their arrays


def slot_schedule(batch: Batch, k_max: int = K_MAX) -> SlotSchedule:
    """The least-recently-seen allocation of ``min(k_max, landmarks seen)`` states over the used sightings
    (module docstring), log by log. EM lowers its model on one batch twice per iteration: the last few
    schedules are kept, keyed by the identity of the batch's arrays (which are never written)."""
    key = (batch.frame_start, batch.sight_start, batch.sight_landmark, batch.used, k_max)
    for k, sched in _RECENT:
        if all(a is b for a, b in zip(k, key)):
            return sched
    sched = _schedule(batch, k_max)
    _RECENT.insert(0, (key, sched))
    del _RECENT[4:]
    return sched


def _schedule(batch: Batch, k_max: int) -> SlotSchedule:
    used = np.flatnonzero(batch.used)
    K = min(k_max, len(np.unique(batch.sight_landmark[used])))
    slot = np.full(batch.n_sightings, -1, dtype=np.int64)
    reset = np.zeros((batch.n_frames, K), dtype=bool)
    count = np.zeros((batch.n_frames, K), dtype=bool)
    if K == 0:
        return SlotSchedule(slot, reset, count)
    frames = batch.sight_frame
    log_of = batch.sight_log
    for log in range(batch.n_logs):
        owner = [-1] * K  # landmark in each state
        last = [-1] * K  # frame of its last sighting
        start = [-1] * K  # frame at which its tenure began
        state_of: dict[int, int] = {}
        for j in used[log_of[used] == log]:
            i, lm = int(frames[j]), int(batch.sight_landmark[j])
            k = state_of.get(lm, -1)
            if k < 0:
                free = [s for s in range(K) if owner[s] < 0]
                old = [s for s in range(K) if owner[s] >= 0 and last[s] < i]
                k = free[0] if free else (min(old, key=lambda s: last[s]) if old else -1)
                if k < 0:
                    continue  # more landmarks in this frame than states
                if owner[k] >= 0:
                    count[start[k] + 1:last[k] + 1, k] = True
                    del state_of[owner[k]]
                owner[k], start[k] = lm, i
                state_of[lm] = k
                reset[i, k] = True
            slot[j] = k
            last[k] = i
        for k in range(K):
            if owner[k] >= 0:
                count[start[k] + 1:last[k] + 1, k] = True
    return SlotSchedule(slot, reset, count)


@register_effect
@dataclass(frozen=True)
class LandmarkBias(EffectModel):
    """A per-landmark relative size bias, a first-order Gauss-Markov process (module docstring).
    Residual signature: the size residuals of one landmark correlated over seconds."""

    sigma_rel: float  # stationary standard deviation of b (a fraction of the size)
    tau_s: float  # correlation time (s)

    name: ClassVar[str] = "landmark_bias"
    #: the calibrated check's statistic that reads it (a bias that persists over a landmark's consecutive sightings)
    SIGNATURE: ClassVar[str] = "size-innovation autocorrelation"
    PARAMS: ClassVar[dict[str, Param]] = {
        "sigma_rel": Param("fraction of the size", "log", low=0.0, high=0.5, shape=()),  # as the simulator's bounds
        "tau_s": Param("s", "log", low=1e-3, high=1e6, shape=()),
    }
    #: the strength every study of the project uses (the power study's medium, the calibration's, issue 34's tau of 8 s)
    EXAMPLE: ClassVar[dict[str, Any]] = {"sigma_rel": 0.05, "tau_s": 8.0}
    VARIANCE_PARAMS: ClassVar[tuple[str, ...]] = ("sigma_rel", "tau_s")  # the states' covariance (REML's step)

    STARTS_OFF: ClassVar[bool] = False  # at sigma_rel 0 EM could not move it (``start``)

    @classmethod
    def start(cls, batch: Batch) -> "LandmarkBias":
        """A weak bias to start EM from (at sigma_rel = 0 EM could not move it: its moments would be 0)."""
        return cls(0.01, 5.0)

    def warm_start(self, model: "Model", batch: Batch, loglik: Callable[["Model"], float]) -> "LandmarkBias":
        """The most likely point of ``WARM_GRID`` (``loglik``: forward passes, the rest of ``model`` fixed): EM
        moves (sigma_rel, tau_s) slowly (the states carry most of the information about them), and from a
        weak start it crawls along a ridge of long correlation times (measured: from 0.01 / 5 s it
        was at 0.025 / 44 s after 80 iterations, 70 nats below the optimum near the truth)."""
        return max((LandmarkBias(s, t) for s in WARM_GRID[0] for t in WARM_GRID[1]),
                   key=lambda e: loglik(model.with_effect(e)))

    def polish(self, model: "Model", batch: Batch, loglik: Callable[["Model"], float]) -> "LandmarkBias":
        """(sigma_rel, tau_s) maximizing the likelihood itself, the rest of ``model`` held (ECME's conditional step;
        ``EffectModel.polish``): Nelder-Mead over their logarithms from the current values, to 0.01 nat. Why: EM's
        M-step maximizes the expected log density of the states, whose information about tau_s is a fraction of the
        likelihood's, and the fit stops on a ridge with tau_s still falling (5-minute logs at tau_s 8 s: 11.8 s
        at EM's stop, 9.3 s after 370 more iterations; docs/results.md, calibration)."""
        return polish_ar1(self, model, loglik, sigma_name="sigma_rel")

    def implausible(self) -> str:
        """A 'bias' above ``MAX_PLAUSIBLE_SIGMA`` is not one: the base model's sizes are off by more than a
        landmark's apparent size drifts, and the states stand in for a wrong world or outliers; nor is one that
        holds longer than ``MAX_PLAUSIBLE_TAU_S`` or decorrelates faster than ``MIN_PLAUSIBLE_TAU_S``."""
        if self.sigma_rel > MAX_PLAUSIBLE_SIGMA:
            return (f"sigma_rel {self.sigma_rel:.2f} is no bias (above {MAX_PLAUSIBLE_SIGMA}): the bias states stand in "
                    "for something larger (a wrong world of the base model, or outliers: see the other candidates)")
        if self.tau_s > MAX_PLAUSIBLE_TAU_S:
            return (f"tau_s {self.tau_s:.0f} s is no pass-to-pass bias (above {MAX_PLAUSIBLE_TAU_S:.0f} s): the states "
                    "stand in for a per-landmark constant (beacon_height_scale) or a slow error of the pose (e.g. "
                    "unmodelled walls)")
        if self.tau_s < MIN_PLAUSIBLE_TAU_S:
            return (f"tau_s {self.tau_s:.2f} s is no pass-to-pass bias (below {MIN_PLAUSIBLE_TAU_S:.0f} s): it is gone "
                    "before the landmark is seen again, white noise on the sightings (the range noise, "
                    "distance_dependent_noise)")
        return ""

    def ridge_possible(self) -> bool:
        """A correlation time below ``MIN_PLAUSIBLE_TAU_S`` is the model's white-noise limit (the states take the
        sightings' own noise), not a ridge: the staged refit returned there on every log it was tried on (9 of 9
        effect-free 5-minute logs, seeds 7000-7011, tau_s 0.27-0.75 s after it, 0-0.9 nats gained), at the cost of
        two more fits (docs/results.md, "Staged fits"). A correlation time above ``MAX_PLAUSIBLE_TAU_S`` may be a
        ridge (seed 2001's 150 s, which the staged refit rescues). Below 1 s no refit is made whatever else is
        implausible (a sigma_rel above ``MAX_PLAUSIBLE_SIGMA`` there is white noise too)."""
        return self.tau_s >= MIN_PLAUSIBLE_TAU_S

    def lower(self, lo: Lowered, batch: Batch) -> None:
        if self.sigma_rel <= 0.0:
            return
        lower_ar1(lo, batch, self.sigma_rel, self.tau_s, kind="size")

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """sigma_rel, tau_s maximizing the expected log density of the states (module docstring)."""
        fitted = maximize_ar1(batch, post, kind="size") if self.sigma_rel > 0.0 else None  # none: no states
        return model if fitted is None else model.with_effect(LandmarkBias(*fitted))


# --------------------------------------------------------------------------- per-landmark AR(1) states, either kind
# The helpers below serve both per-landmark bias processes (this module's sizes, ``landmark_bearing_bias``'s
# bearings): the same allocation of states (``slot_schedule``), the same AR(1) chain and M-step. Their states sit in
# ``Lowered.extra`` in a fixed order, size states first (``LandmarkBearingBias.LOWER_ORDER`` lowers it after this
# one), so an effect finds its columns from its kind alone.


def lower_ar1(lo: Lowered, batch: Batch, sigma: float, tau_s: float, kind: str) -> None:
    """Append one AR(1) state per allocated landmark (stationary sd ``sigma``, correlation time ``tau_s`` s) to
    ``lo.extra``, read by the sightings' sizes (``kind`` "size": a relative bias) or bearings ("bearing": rad)."""
    if sigma <= 0.0:
        return
    sched = slot_schedule(batch)
    if sched.k == 0:
        return
    phi, q = ar1_step(sigma, tau_s, batch.dt)
    var = sigma ** 2
    slots = {"slot": sched.slot} if kind == "size" else {"bearing_slot": sched.slot}
    lo.extra = ExtraStates.append(lo.extra, np.where(sched.reset, 0.0, phi), np.where(sched.reset, var, q),
                                  np.full((batch.n_logs, sched.k), var), **slots)


def ar1_step(sigma: float, tau_s: float, dt: float) -> tuple[float, float]:
    """(phi, q) of one step of ``dt`` s of a first-order Gauss-Markov process of stationary sd ``sigma`` and correlation
    time ``tau_s`` (s): b' = phi b + N(0, q), phi = exp(-dt / tau_s), q = sigma^2 (1 - phi^2)."""
    phi = math.exp(-dt / tau_s)
    return phi, sigma ** 2 * (1.0 - phi * phi)


def _columns(batch: Batch, post: Posterior, kind: str) -> slice:
    """The columns of ``post.extra``'s states that carry ``kind``'s biases (size states first, then bearing ones)."""
    k = slot_schedule(batch).k
    return slice(0, k) if kind == "size" else slice(post.extra.cross.shape[1] - k, None)


def maximize_ar1(batch: Batch, post: Posterior, kind: str) -> tuple[float, float] | None:
    """(sigma, tau_s) maximizing the expected log density of ``kind``'s states (closed form for sigma given phi,
    then a 1-d maximization over tau_s of that profile; module docstring); None without states."""
    if post.extra is None:
        return None
    sched = slot_schedule(batch)
    ex, cols = post.extra, _columns(batch, post, kind)
    p = batch.frame_to_pose
    mean, var = ex.mean[:, cols], ex.var[:, cols]
    m0, m1 = mean[p], mean[p + 1]
    e00, e11, e01 = m0 * m0 + var[p], m1 * m1 + var[p + 1], m0 * m1 + ex.cross[:, cols]
    c, r = sched.count, sched.reset
    n_tr, n_init = int(c.sum()), int(r.sum())
    if n_init == 0:
        return None
    s00, s01, s11, s_init = float(e00[c].sum()), float(e01[c].sum()), float(e11[c].sum()), float(e11[r].sum())
    n = n_tr + n_init

    def sigma2(phi: float) -> float:
        return (s_init + (s11 - 2.0 * phi * s01 + phi * phi * s00) / (1.0 - phi * phi)) / n

    def negative_profile(log_tau: float) -> float:
        phi = math.exp(-batch.dt / math.exp(log_tau))
        return 0.5 * (n * math.log(sigma2(phi)) + n_tr * math.log(1.0 - phi * phi))

    from scipy.optimize import minimize_scalar  # here, not at import (SciPy's load costs every command)

    best = minimize_scalar(negative_profile, bounds=tuple(math.log(t) for t in TAU_BOUNDS_S), method="bounded",
                           options={"xatol": 1e-4})
    tau = float(math.exp(best.x))
    return max(math.sqrt(sigma2(math.exp(-batch.dt / tau))), SIGMA_FLOOR), tau


def polish_ar1(effect: EffectModel, model: "Model", loglik: Callable[["Model"], float], sigma_name: str) -> EffectModel:
    """``effect`` (an AR(1) bias: ``sigma_name`` and ``tau_s``) at the (sigma, tau_s) maximizing the likelihood itself,
    the rest of ``model`` held: Nelder-Mead over their logarithms from the current values, to 0.01 nat
    (``LandmarkBias.polish``)."""
    from scipy.optimize import minimize  # here, not at import (SciPy's load costs every command)

    lo_s, lo_t = math.log(SIGMA_FLOOR), math.log(TAU_BOUNDS_S[0])
    hi_s, hi_t = math.log(effect.PARAMS[sigma_name].high), math.log(TAU_BOUNDS_S[1])
    sigma = getattr(effect, sigma_name)

    def at(x: np.ndarray) -> EffectModel:
        return type(effect)(math.exp(min(max(x[0], lo_s), hi_s)), math.exp(min(max(x[1], lo_t), hi_t)))

    def negative(x: np.ndarray) -> float:
        return -loglik(model.with_effect(at(x)))

    x0 = np.array([math.log(max(sigma, SIGMA_FLOOR)), math.log(effect.tau_s)])
    simplex = [x0, x0 + POLISH_SIMPLEX * np.array([1.0, 0.0]), x0 + POLISH_SIMPLEX * np.array([0.0, 2.0])]
    best = minimize(negative, x0, method="Nelder-Mead",
                    options={"initial_simplex": simplex, "xatol": 1e-3, "fatol": 0.01, "maxfev": POLISH_MAX_EVALS})
    return at(best.x) if best.fun < negative(x0) else effect
