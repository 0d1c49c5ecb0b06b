"""Residual signatures: the residuals of a fit (smoothed sighting residuals, smoothed motion residuals)
against the variables a missing effect shows up in. Each (residual, variable) pair gets binned means
and a one-way analysis-of-variance p-value (bins of equal counts; landmarks as categories).

These are descriptive: neighbouring frames' residuals are correlated, so p-values are optimistic;
they rank where to look, the candidate search decides.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import stats

from aibo_core.geometry import rel_disp, wrap
from aibo_core.trajectory import Trajectory
from learners.arrays.batch import Batch, make_batch
from learners.arrays.posterior import Posterior
from learners.em.estep import e_step
from learners.em.options import DEFAULT_GATE
from learners.inference.augmented import size_factor_moments
from learners.model.model import Model

if TYPE_CHECKING:
    from learners.model.probes import SpeedProbe

N_BINS = 8


@dataclass
class Signature:
    residual: str  # e.g. "size (sigma)", "bearing (sigma)", "|size| (sigma)", "forward motion (sigma)"
    variable: str  # e.g. "distance (mm)"
    centers: list[float]  # bin centres (or landmark index)
    means: list[float]  # mean residual per bin (sigma units)
    errors: list[float]  # standard error per bin
    p_value: float

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _binned(name: str, variable: str, r: np.ndarray, x: np.ndarray, categorical: bool = False) -> Signature | None:
    ok = np.isfinite(r) & np.isfinite(x)
    r, x = r[ok], x[ok]
    if len(r) < 4 * N_BINS:
        return None
    if categorical:
        keys = np.unique(x)
        groups = [r[x == k] for k in keys]
        centers = keys.astype(float)
    else:
        edges = np.unique(np.quantile(x, np.linspace(0, 1, N_BINS + 1)))
        if len(edges) < 3:
            return None
        idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
        groups = [r[idx == k] for k in range(len(edges) - 1)]
        centers = np.array([np.mean(x[idx == k]) if np.any(idx == k) else np.nan for k in range(len(edges) - 1)])
    groups = [g for g in groups if len(g) > 1]
    if len(groups) < 2:
        return None
    p = float(stats.f_oneway(*groups).pvalue)
    return Signature(name, variable, [float(c) for c in centers[: len(groups)]], [float(np.mean(g)) for g in groups],
                     [float(np.std(g) / np.sqrt(len(g))) for g in groups], p if np.isfinite(p) else 1.0)


def sighting_residuals(model: Model, batch: Batch, post: Posterior) -> dict[str, np.ndarray]:
    """Per sighting, at the smoothed means: normalized size and bearing residuals and the variables."""
    lo = model.lower(batch)
    pose = post.mu_gamma[batch.sight_pose]
    dx, dy = (batch.sight_xy - pose[:, :2]).T
    d = np.hypot(dx, dy)
    factor, _ = size_factor_moments(lo, batch, post)  # 1 without states; else the smoothed 1 + b (landmark_bias)
    pred = lo.size_scale * factor * model.sensor.mean(d) + lo.size_offset
    sd = model.sensor.sigma_size * np.sqrt(lo.size_var_factor)
    bearing = wrap(np.arctan2(dy, dx) - pose[:, 2] + lo.bearing_offset)
    frame = batch.sight_frame
    out = {
        "size": (batch.sight_value[:, 0] - pred) / sd,
        "bearing": wrap(batch.sight_value[:, 1] - bearing) / (model.sensor.sigma_bearing * np.sqrt(lo.bearing_var_factor)),
        "distance (mm)": d,
        "elapsed time (min)": batch.frame_time[frame] / 60.0,
        "time since command change (s)": (frame - batch.command_start[frame]) * batch.dt,
        "landmark": batch.sight_landmark.astype(float),
        "world heading (rad)": wrap(pose[:, 2]),
    }
    if batch.head_pan is not None:
        out["position in the image (rad)"] = wrap(batch.sight_value[:, 1] - batch.head_pan[frame])
    used = batch.used
    return {k: v[used] for k, v in out.items()}


def motion_residuals(model: Model, batch: Batch, post: Posterior, field: np.ndarray | None) -> dict[str, np.ndarray]:
    """Per frame: smoothed robot-frame displacement minus the model's, in motion-noise std, and variables."""
    lo = model.lower(batch)
    p = batch.frame_to_pose
    s0, s1 = post.mu_gamma[p], post.mu_gamma[p + 1]
    r = (rel_disp(s0, s1 - lo.offset) - lo.disp) / np.sqrt(np.diag(lo.cov))
    out = {
        "forward motion": r[:, 0], "lateral motion": r[:, 1], "turn": r[:, 2],
        "elapsed time (min)": batch.frame_time / 60.0,
        "time since command change (s)": (np.arange(batch.n_frames) - batch.command_start) * batch.dt,
        "world heading (rad)": wrap(s0[:, 2]),
    }
    if field is not None:
        half = np.asarray(field, float) / 2
        out["distance to walls (mm)"] = np.min(np.stack([half[0] - np.abs(s1[:, 0]), half[1] - np.abs(s1[:, 1])]), axis=0)
    return out


def signatures(model: Model, logs: list[Trajectory]) -> list[Signature]:
    """Every (residual, variable) signature of ``model`` on ``logs``, most significant first."""
    batch = make_batch(logs)
    post = e_step(model, batch, "compiled", DEFAULT_GATE)
    batch = batch.with_used(batch.used & ~(post.mahal2 > DEFAULT_GATE))
    found: list[Signature] = []
    s = sighting_residuals(model, batch, post)
    for res in ("size", "bearing"):
        for var in [k for k in s if k not in ("size", "bearing")]:
            found.append(_binned(f"{res} (sigma)", var, s[res], s[var], categorical=var == "landmark"))
    found.append(_binned("|size| (sigma)", "distance (mm)", np.abs(s["size"]), s["distance (mm)"]))
    m = motion_residuals(model, batch, post, logs[0].field)
    for res in ("forward motion", "lateral motion", "turn"):
        for var in [k for k in m if k not in ("forward motion", "lateral motion", "turn")]:
            found.append(_binned(f"{res} (sigma)", var, m[res], m[var]))
    return sorted([f for f in found if f is not None], key=lambda f: f.p_value)


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
