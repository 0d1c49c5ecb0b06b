"""The compiled E-step kernels' input arguments: the lowered arrays and the batch, checked and made
contiguous float64 (shared by ``estep`` and ``augmented``)."""

from __future__ import annotations

import numpy as np

from learners.inference.batch import Batch
from learners.inference.kernels.algebra import _f64
from learners.inference.lowered import BASIS_INVERSE, BASIS_POWER, Lowered


def _inputs(lo: Lowered, batch: Batch, gate: float | None) -> tuple:
    """The kernel's input arguments (checked, contiguous float64), up to and including the gate."""
    n_logs = batch.n_logs
    if len(lo.init_mean) != n_logs or len(lo.init_cov) != n_logs:
        raise ValueError(f"lowered model has {len(lo.init_mean)} initial states for {n_logs} logs")
    n, n_s = batch.n_frames, batch.n_sightings
    frame_start = np.ascontiguousarray(batch.frame_start, dtype=np.int64)
    sight_start = np.ascontiguousarray(batch.sight_start, dtype=np.int64)
    used = np.ascontiguousarray(batch.used, dtype=np.bool_)
    if sight_start.shape != (n + 1,) or used.shape != (n_s,):
        raise ValueError("batch.sight_start must have N + 1 entries and batch.used one per sighting")
    if lo.basis not in (BASIS_POWER, BASIS_INVERSE):
        raise ValueError(f"unknown sensor basis {lo.basis}")
    coef = _f64(lo.coef).reshape(-1)
    if coef.size == 0:
        coef = np.zeros(1)
    return (
        frame_start, sight_start, _f64(lo.disp, (n, 3)), _f64(lo.offset, (n, 3)), _f64(lo.cov_scale, (n,)),
        _f64(lo.cov, (3, 3)), int(lo.basis), coef, float(lo.sigma_size) ** 2, float(lo.sigma_bearing) ** 2,
        _f64(batch.sight_xy, (n_s, 2)), _f64(batch.sight_value, (n_s, 2)), used,
        _f64(lo.size_scale, (n_s,)), _f64(lo.size_offset, (n_s,)), _f64(lo.size_var_factor, (n_s,)),
        _f64(lo.bearing_offset, (n_s,)), _f64(lo.bearing_var_factor, (n_s,)),
        _f64(lo.init_mean, (n_logs, 3)), _f64(lo.init_cov, (n_logs, 3, 3)),
        gate is not None, float(gate) if gate is not None else np.inf,
    )  # fmt: skip
