"""Residual signatures: the residuals of a fit against the variables a missing effect shows up in. Each
(residual, variable) pair gets binned means (bins of equal counts; landmarks as categories) and a p-value of "the
same mean in every bin" that holds for serially correlated residuals (``equal_means``).

Sightings: the residual is the one-step innovation (the forward filter's prediction error, measured minus predicted,
over its predicted standard deviation) and the variables are predicted quantities (the filtered pose at the start of
the sighting's frame, moved by the frame's motion; the predicted bearing): under the model the innovation is
independent of everything the filter knew before the sighting, so no variable shares its noise. A variable computed
from the measurement itself (the measured bearing's position in the image) or from the smoothed pose (which has seen
the sighting) regresses the residual on its own noise: binned by the measured position in the image, the bearing
residual rose across the image on every effect-free simulated log (p = 0 on ``paper-sim``, 3e-13 on ``aibo``).
The bearing is not binned by the position in the image: which landmark is sighted depends on where it truly is in
the image (only inside the field of view; the one nearest the centre when several are), a selection the filter does
not model. Binned by the predicted position, the bearing innovations point inward near the image's edges on
effect-free logs (``paper-sim``: +0.24 and -0.20 sigma in the edge bins, p < 1e-8 on 14 of 20 logs of 5 minutes
even with the sightings predicted within 3 prior standard deviations of the edge left out: the prediction's error
is wider than the filter's prior). The size is binned by it (whether a landmark is seen does not depend on its
size's noise).

Motion: the smoothed robot-frame displacement minus the model's, in motion-noise standard deviations, each command's
mean removed (``motion_residuals``), against the elapsed time, the time since the command changed, the smoothed
heading and distance to the walls. Neighbouring frames' residuals are correlated; ``equal_means`` accounts for it.

The motion residuals' world heading is the smoothed heading ``HEADING_LEAD_S`` (1 s) before the frame, carried to it
by the model's turns (``carried_heading``), and binned in equal sectors of the circle from -pi (``CIRCULAR``), not at its
quantiles. The smoothed heading at the frame holds the recent motion noise, which the smoothed residuals share (the
smoother spreads each correction over neighbouring frames); where a robot steers it holds each heading for seconds,
quantile edges fall inside those peaks and split their frames by that shared noise: on effect-free wheeled logs of the
waypoint driver "turn vs world heading" came out at p down to 2e-6 and the calibrated check disagreed on 5 of 10
(the evidence: docs/results.md, "The calibrated check on effect-free logs").

A bearing offset of one landmark's own (``landmark_bearing_offset``) hides from "bearing vs landmark": while the robot
keeps sighting the same landmark, the filter turns its heading to that landmark's offset, so only the first sighting
after one of another landmark shows it; "bearing vs landmark, at a change of landmark" keeps those sightings only
(offsets of 10 / -10 / 5 / -5 mrad, 5-minute ``aibo`` logs of seeds 4-7: p = 1e-6, 2e-3, 1e-6, 5e-6 against 0.14,
0.01, 0.27, 0.19 over all sightings; effect-free seeds 4-6: 0.23, 0.11, 0.52).

The residuals' magnitudes against the time since the command changed are signatures too: a delayed command (a lag)
moves the robot the old command's way for a moment, in a direction that depends on the change, so the signed means
cancel over the changes and only the magnitudes rise (0.2 s lag, 5-minute ``aibo`` log: "|bearing| vs time since
command change" p = 3e-11, "|turn|" 5e-7, while no signed signature reached 0.05).

Signed, the motion residuals show a timing error where the change of the command is the variable: on the frames where
the model's commanded turn rate (speed) changes, the turn (forward motion) against how much it changed
(``CHANGE_OF``, ``command_change``). A robot that follows later than the model says turns less than it at a change to
the left and more at one to the right, so the residual falls with the change. A 0.15 s first-order response
(``response_time``) under a model without any timing effect, 5-minute wheeled log of seed 4: "turn vs change of the
commanded turn rate" p = 2e-12 (the magnitudes' against the time since the change: none below 0.05); with the lag
search's delay in the model (a delay stands in for such a response), 0.028 (seed 5: 0.4); effect-free: 0.13 and 0.31
(seeds 4, 5). On 100 effect-free logs (seeds 6000-6049 of both presets) each is below 0.05 on 7 or 8 and below 0.001
on none. Kept on the frame of each change and the next as well, they were below 0.05 on 20 of 100 each: the two
frames' residuals are correlated and the reference took them for independent.

The bearing's magnitudes against the commanded turn rate (``TURN_RATE``) show a motion noise that grows with the
turn: the bearing's innovation carries the heading's uncertainty (MRCLAM robots under ``aibo learn``'s model: the
bearing innovations' RMS 0.59-0.82 at the lowest quartile of the last 2 s's |omega|, 1.30-1.47 at the highest, robots
1, 3 and 5). The smoothed turn's magnitudes against it are not a signature: on effect-free ``paper-sim`` logs (0.5 rad
bearings) they were at p < 0.001 on 3 of 30 and p < 0.05 on 11 (the bearing's on 0 and 7; ``aibo``: 0 and 1), seeds
6000-6029, 2026-11-28.

Many pairs are tried: ``Signature.p_holm`` is each p-value adjusted for all of them (Holm), the one to read before
calling a drift real. The candidate search decides; the signatures show where the residuals drift.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from aibo_core import geometry
from aibo_core.geometry import rel_disp, wrap
from aibo_core.trajectory import Trajectory
from learners.arrays.batch import Batch, make_batch
from learners.arrays.posterior import Posterior
from learners.em.estep import e_step
from learners.em.options import DEFAULT_GATE
from learners.inference.kernels.estep import innovations_compiled
from learners.model.model import Model

from .equal_means import bin_means, wald_p

if TYPE_CHECKING:
    from learners.model.probes import SpeedProbe

N_BINS = 8
#: Circular variables (rad), binned in ``N_BINS`` equal sectors from -pi, not at their quantiles (module docstring).
CIRCULAR = ("world heading (rad)",)
#: The motion residuals' world heading: the smoothed heading this long (s) before the frame, carried to the frame by
#: the model's own turns (module docstring), so that it holds none of the noise the frame's smoothed residual shares.
HEADING_LEAD_S = 1.0
#: The variable of the magnitudes' signature of a motion noise that grows with the turn (``turn_dependent_noise``): the
#: turn rate the model commands in the frame, |disp[i, 2]| / dt (rad/s), known before the frame.
TURN_RATE = "commanded turn rate (rad/s)"
#: The variables of the signed timing signatures (module docstring): how much the model's commanded motion changed into
#: the frame, on the frames where it changed (elsewhere NaN: left out).
CHANGE_OF = {"forward motion": "change of the commanded speed (mm/s)",
             "turn": "change of the commanded turn rate (rad/s)"}


@dataclass
class Signature:
    residual: str  # e.g. "size (sigma)", "bearing (sigma)", "|size| (sigma)", "forward motion (sigma)"
    variable: str  # e.g. "distance (mm)"
    centers: list[float]  # bin centres (or landmark index)
    means: list[float]  # mean residual per bin (sigma units)
    errors: list[float]  # standard error per bin (serial correlation allowed for, ``equal_means.bin_means``)
    p_value: float  # "the same mean in every bin" (``equal_means``), serial correlation accounted for
    p_holm: float = 1.0  # p_value adjusted for every signature of the same call (Holm); set by ``signatures``

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _binned(name: str, variable: str, r: np.ndarray, x: np.ndarray, categorical: bool = False) -> Signature | None:
    """The signature of residual ``r`` against variable ``x`` (both in time order); a variable of ``CIRCULAR`` in
    equal sectors."""
    ok = np.isfinite(r) & np.isfinite(x)
    r, x = r[ok], x[ok]
    if len(r) < 4 * N_BINS:
        return None
    if categorical:
        centers, idx = np.unique(x, return_inverse=True)
    elif variable in CIRCULAR:
        width = 2.0 * np.pi / N_BINS
        idx = np.floor((wrap(x) + np.pi) / width).astype(int) % N_BINS
        centers = -np.pi + width * (np.arange(N_BINS) + 0.5)
    else:
        edges = np.unique(np.quantile(x, np.linspace(0, 1, N_BINS + 1)))
        if len(edges) < 3:
            return None
        idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
        centers = np.array([np.mean(x[idx == k]) if np.any(idx == k) else np.nan for k in range(len(edges) - 1)])
    count = np.bincount(idx, minlength=len(centers))
    keep = count > 1
    if keep.sum() < 2:
        return None
    inside = keep[idx]  # bins with fewer than 2 residuals are left out, the others renumbered 0, 1, ...
    r, idx = r[inside], (np.cumsum(keep) - 1)[idx[inside]]
    means, cov, nu = bin_means(r, idx, int(keep.sum()))
    p = wald_p(means, cov, nu)
    return Signature(name, variable, [float(c) for c in centers[keep]], means.tolist(),
                     np.sqrt(np.maximum(np.diag(cov), 0.0)).tolist(), p if np.isfinite(p) else 1.0)


def holm(p: np.ndarray) -> np.ndarray:
    """Holm's step-down adjustment of the p-values ``p`` (family-wise error over all of them)."""
    p = np.asarray(p, dtype=float)
    order = np.argsort(p)
    adjusted = np.minimum(np.maximum.accumulate((len(p) - np.arange(len(p))) * p[order]), 1.0)
    out = np.empty_like(p)
    out[order] = adjusted
    return out


def sighting_residuals(model: Model, batch: Batch, post: Posterior) -> dict[str, np.ndarray]:
    """Per used sighting: the normalized one-step innovations of size and bearing, and the variables, all predicted
    before the sighting (module docstring): distance (mm) and world heading (rad) from the filtered pose at the start
    of the frame moved by the frame's motion, the predicted bearing's position in the image (rad, with a head pan)
    (``post``: the E-step on ``batch``, whose ``mu_alpha`` is that filter's)."""
    lo = model.lower(batch)
    _, innov = innovations_compiled(lo, batch)
    frame = batch.sight_frame
    p = batch.frame_to_pose[frame]
    pose, _, _ = geometry.motion(post.mu_alpha[p], lo.disp[frame])
    pose = pose + lo.offset[frame]
    dx, dy = (batch.sight_xy - pose[:, :2]).T
    out = {
        "size": innov[:, 0] / np.sqrt(innov[:, 2]),
        "bearing": innov[:, 1] / np.sqrt(innov[:, 4]),
        "distance (mm)": np.hypot(dx, dy),
        "elapsed time (min)": batch.frame_time[frame] / 60.0,
        "time since command change (s)": (frame - batch.command_start[frame]) * batch.dt,
        "landmark": batch.sight_landmark.astype(float),
        "world heading (rad)": wrap(pose[:, 2]),
        TURN_RATE: np.abs(lo.disp[frame, 2]) / batch.dt,
    }
    used = batch.used & np.isfinite(innov[:, 0])
    if batch.head_pan is not None:
        out["position in the image, predicted (rad)"] = wrap(batch.sight_value[:, 1] - innov[:, 1] - batch.head_pan[frame])
    return {k: v[used] for k, v in out.items()}


def motion_residuals(model: Model, batch: Batch, post: Posterior, field: np.ndarray | None) -> dict[str, np.ndarray]:
    """Per frame: smoothed robot-frame displacement minus the model's, in motion-noise std, and variables. With
    discrete commands each command's mean residual is removed: a command's velocity is a free parameter of the model,
    and its estimation error (fitted on the training half) is no signature; what a variable explains within the
    commands is. Measured on effect-free logs, 5 minutes: "lateral motion vs elapsed time" p 5e-05 -> 1,
    "forward motion vs elapsed time" 4e-11 -> 0.8 (the commands' mix changes along a log)."""
    lo = model.lower(batch)
    p = batch.frame_to_pose
    s0, s1 = post.mu_gamma[p], post.mu_gamma[p + 1]
    r = lo.whiten(rel_disp(s0, s1 - lo.offset) - lo.disp) / np.sqrt(np.diag(lo.cov)[None, :] * lo.cov_scale[:, None])
    if batch.actions is not None:
        count = np.maximum(np.bincount(batch.actions), 1)
        r = r - np.stack([np.bincount(batch.actions, weights=r[:, k]) / count for k in range(3)], axis=1)[batch.actions]
    out = {
        "forward motion": r[:, 0], "lateral motion": r[:, 1], "turn": r[:, 2],
        "elapsed time (min)": batch.frame_time / 60.0,
        "time since command change (s)": (np.arange(batch.n_frames) - batch.command_start) * batch.dt,
        "world heading (rad)": carried_heading(s0[:, 2], lo.disp[:, 2], batch),
    }
    change = command_change(lo.disp, batch) / batch.dt
    out[CHANGE_OF["forward motion"]], out[CHANGE_OF["turn"]] = change[:, 0], change[:, 2]
    if field is not None:
        half = np.asarray(field, float) / 2
        out["distance to walls (mm)"] = np.min(np.stack([half[0] - np.abs(s1[:, 0]), half[1] - np.abs(s1[:, 1])]), axis=0)
    return out


def carried_heading(theta: np.ndarray, turn: np.ndarray, batch: Batch) -> np.ndarray:
    """(N,) each frame's world heading (rad, wrapped) as ``HEADING_LEAD_S`` earlier, carried forward by the commanded
    turns since: ``theta`` (N,) the smoothed (unwrapped) heading at each frame's start, ``turn`` (N,) the model's turn
    per frame (rad); at a log's first frames, from its first. The smoothed heading itself integrates the recent motion
    noise, which the frame's smoothed residual shares (module docstring)."""
    i = np.arange(batch.n_frames)
    j = np.maximum(i - int(round(HEADING_LEAD_S / batch.dt)), batch.log_first_frame)
    turned = np.r_[0.0, np.cumsum(turn)]
    return wrap(theta[j] + turned[i] - turned[j])


def command_change(disp: np.ndarray, batch: Batch) -> np.ndarray:
    """(N, 3) how far the model's displacement ``disp`` (mm, mm, rad per frame) moved from the frame before, per
    component on the frames where it moved; NaN where it did not and on each log's first frame. The model's own
    displacement, not the logged command: a model with a delay changes its motion where it says the robot does (a
    delay of a fraction of a frame over two frames, a response time on every frame after a change)."""
    out = np.full(disp.shape, np.nan)
    step = np.diff(disp, axis=0)
    moved = np.abs(step) > 1e-9 * np.maximum(np.abs(disp).max(axis=0), 1e-12)
    out[1:][moved] = step[moved]
    out[batch.frame_start[:-1][np.diff(batch.frame_start) > 0]] = np.nan
    return out


def changes_of_landmark(landmark: np.ndarray) -> np.ndarray:
    """(S,) bool: the sightings (in time order) of another landmark than the sighting before (the first one too)."""
    return np.r_[True, landmark[1:] != landmark[:-1]] if len(landmark) else np.zeros(0, bool)


def signatures(model: Model, logs: list[Trajectory]) -> list[Signature]:
    """Every (residual, variable) signature of ``model`` on ``logs``, most significant first."""
    batch = make_batch(logs)
    post = e_step(model, batch, "compiled", DEFAULT_GATE)
    batch = batch.with_used(batch.used & ~(post.mahal2 > DEFAULT_GATE))
    found: list[Signature] = []
    s = sighting_residuals(model, batch, post)
    for res in ("size", "bearing"):
        for var in [k for k in s if k not in ("size", "bearing", TURN_RATE)]:
            if not (res == "bearing" and var.startswith("position in the image")):  # a selection (module docstring)
                found.append(_binned(f"{res} (sigma)", var, s[res], s[var], categorical=var == "landmark"))
    switch = changes_of_landmark(s["landmark"])
    found.append(_binned("bearing (sigma)", "landmark, at a change of landmark", s["bearing"][switch],
                         s["landmark"][switch], categorical=True))
    found.append(_binned("|size| (sigma)", "distance (mm)", np.abs(s["size"]), s["distance (mm)"]))
    since = "time since command change (s)"
    found += [_binned(f"|{res}| (sigma)", since, np.abs(s[res]), s[since]) for res in ("size", "bearing")]
    found.append(_binned("|bearing| (sigma)", TURN_RATE, np.abs(s["bearing"]), s[TURN_RATE]))
    m = motion_residuals(model, batch, post, logs[0].field)
    for res in ("forward motion", "lateral motion", "turn"):
        for var in [k for k in m if k not in ("forward motion", "lateral motion", "turn", *CHANGE_OF.values())]:
            found.append(_binned(f"{res} (sigma)", var, m[res], m[var]))
        found.append(_binned(f"|{res}| (sigma)", since, np.abs(m[res]), m[since]))
    found += [_binned(f"{res} (sigma)", var, m[res], m[var]) for res, var in CHANGE_OF.items()]
    found = [f for f in found if f is not None]
    for f, q in zip(found, holm(np.array([f.p_value for f in found]))):
        f.p_holm = float(q)
    return sorted(found, key=lambda f: f.p_value)


def probe_signature(model: Model, logs: list[Trajectory], probe: "SpeedProbe") -> Signature | None:
    """The residual signature that shows a probe's dependence (``learners.model.probes``): ``model``'s smoothed
    forward speed relative to its own prediction (smoothed / predicted forward displacement - 1, on the frames
    that walk forward or back at least half the median speed) against the fitted probe's factor - 1 (e.g.
    0.11 cos(heading) + 0.05 sin(heading)). A dependence the model lacks shows as binned means rising with it,
    attenuated: the smoothed displacement of one frame stays near the model's, the effect adds up over many."""
    batch = make_batch(logs)
    post = e_step(model, batch, "compiled", DEFAULT_GATE)
    lo = model.lower(batch)
    p = batch.frame_to_pose
    smoothed = rel_disp(post.mu_gamma[p], post.mu_gamma[p + 1] - lo.offset)[:, 0]
    fwd = lo.disp[:, 0]
    moving = np.abs(fwd) > 1e-9
    if not moving.any():
        return None
    walk = np.abs(fwd) >= 0.5 * np.median(np.abs(fwd[moving]))
    return _binned("forward speed / predicted - 1", f"{probe.name} factor - 1", smoothed[walk] / fwd[walk] - 1.0,
                   (probe.basis @ probe.coef)[walk])
