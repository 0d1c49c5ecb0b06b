"""The compiled E-step kernels' inputs, grouped by what they belong to (shared by ``estep`` and
``augmented``): ``FrameInputs`` (the motion: per log and per frame) and ``SightingInputs`` (the
sensor: per sighting, and the sensor's constants). Each is a NamedTuple of checked, contiguous
float64 arrays, which numba passes by name: an edit of one field cannot silently shift the others,
as it could in a flat list of positional arguments."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.lowered import BASIS_INVERSE, BASIS_POWER, Lowered
from learners.inference.kernels.algebra import _f64


class FrameInputs(NamedTuple):
    """The motion: L logs, N frames (P = N + L poses)."""

    frame_start: np.ndarray  # (L + 1,) int64: each log's first frame (its first pose is frame_start[k] + k)
    disp: np.ndarray  # (N, 3) mm, mm, rad: each frame's displacement in the robot frame
    offset: np.ndarray  # (N, 3) mm, mm, rad: added to the pose after the displacement (world frame)
    cov_scale: np.ndarray  # (N,): each frame's factor on the motion noise
    cov_sd: np.ndarray  # (N, 3): each frame's factors on its standard deviations (Sigma_i = cov_scale D Sigma_A D)
    sig_a: np.ndarray  # (3, 3) mm^2, mm^2, rad^2: motion noise per frame (robot frame), Sigma_A
    init_mean: np.ndarray  # (L, 3) mm, mm, rad: each log's initial pose belief
    init_cov: np.ndarray  # (L, 3, 3)


class SightingInputs(NamedTuple):
    """The sensor: S sightings (CSR by frame) and the sensor's constants."""

    sight_start: np.ndarray  # (N + 1,) int64: frame i's sightings are sight_start[i] .. sight_start[i + 1] - 1
    xy: np.ndarray  # (S, 2) mm: the sighted landmark's position
    value: np.ndarray  # (S, 2): the measured size (px or mm) and bearing (rad)
    used: np.ndarray  # (S,) bool: sightings the filter may apply
    size_scale: np.ndarray  # (S,): factor on the sensor curve f(d)
    size_offset: np.ndarray  # (S,) px or mm: added to the size
    size_var_factor: np.ndarray  # (S,): factor on the size variance
    bearing_offset: np.ndarray  # (S,) rad: added to the bearing
    bearing_var_factor: np.ndarray  # (S,): factor on the bearing variance
    basis: int  # BASIS_POWER or BASIS_INVERSE: the sensor curve's basis
    coef: np.ndarray  # (degree + 1,): the sensor curve's coefficients in that basis
    var_s: float  # px^2 or mm^2: the size variance
    var_b: float  # rad^2: the bearing variance
    use_gate: bool  # skip a sighting whose mahal2 exceeds ``gate``
    gate: float  # squared Mahalanobis distance (inf without a gate)


def kernel_inputs(lo: Lowered, batch: Batch, gate: float | None) -> tuple[FrameInputs, SightingInputs]:
    """The kernels' inputs from a lowered model and a batch, checked and made contiguous float64."""
    n_logs = batch.n_logs
    if len(lo.init_mean) != n_logs or len(lo.init_cov) != n_logs:
        raise ValueError(f"lowered model has {len(lo.init_mean)} initial states for {n_logs} logs")
    n, n_s = batch.n_frames, batch.n_sightings
    sight_start = np.ascontiguousarray(batch.sight_start, dtype=np.int64)
    used = np.ascontiguousarray(batch.used, dtype=np.bool_)
    if sight_start.shape != (n + 1,) or used.shape != (n_s,):
        raise ValueError("batch.sight_start must have N + 1 entries and batch.used one per sighting")
    if lo.basis not in (BASIS_POWER, BASIS_INVERSE):
        raise ValueError(f"unknown sensor basis {lo.basis}")
    coef = _f64(lo.coef).reshape(-1)
    if coef.size == 0:
        coef = np.zeros(1)
    frames = FrameInputs(
        frame_start=np.ascontiguousarray(batch.frame_start, dtype=np.int64), disp=_f64(lo.disp, (n, 3)),
        offset=_f64(lo.offset, (n, 3)), cov_scale=_f64(lo.cov_scale, (n,)), cov_sd=_f64(lo.cov_sd, (n, 3)),
        sig_a=_f64(lo.cov, (3, 3)),
        init_mean=_f64(lo.init_mean, (n_logs, 3)), init_cov=_f64(lo.init_cov, (n_logs, 3, 3)))
    sightings = SightingInputs(
        sight_start=sight_start, xy=_f64(batch.sight_xy, (n_s, 2)), value=_f64(batch.sight_value, (n_s, 2)),
        used=used, size_scale=_f64(lo.size_scale, (n_s,)), size_offset=_f64(lo.size_offset, (n_s,)),
        size_var_factor=_f64(lo.size_var_factor, (n_s,)), bearing_offset=_f64(lo.bearing_offset, (n_s,)),
        bearing_var_factor=_f64(lo.bearing_var_factor, (n_s,)), basis=int(lo.basis), coef=coef,
        var_s=float(lo.sigma_size) ** 2, var_b=float(lo.sigma_bearing) ** 2, use_gate=gate is not None,
        gate=float(gate) if gate is not None else np.inf)
    return frames, sightings
