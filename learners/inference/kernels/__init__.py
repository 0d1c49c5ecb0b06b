"""Compiled (numba) twin of the E-step and the M-step statistics.

Same contract and equations as the plain-NumPy reference (``reference.smooth``,
``action_stats`` and ``sensor_stats``) on the lowered arrays (``Lowered``); docs/em-math.md is the
specification. Everything runs inside ``@njit`` kernels over flat arrays, looping over the logs of
the batch inside the kernel; 3x3 and 2x2 algebra is written out by hand (no np.linalg, no per-frame
allocation). A non-finite value makes the wrappers raise ``FloatingPointError`` naming the log and
frame.

Layout (one concept per module; import the public functions from this package):
- ``algebra``: constants, kernel status codes, small 3x3 algebra on tuples (a 3x3 matrix is a
  row-major 9-tuple, a vector a 3-tuple), ``_wrap``, ``_horner``, ``_curve`` (the sensor curve in
  either basis), array load/store, and the Python-side helpers shared by the wrappers (``_f64``,
  ``_raise``, ``_scratch``);
- ``fasttrig``: branch-free cos/sin (``_cos_sin*``) and ``_atan2``, with their constants;
- ``structured``: the E-step's structured 3x3 algebra and sighting linearization;
- ``estep``: the E-step kernel (forward EKF, backward information filter, combination) and
  its wrapper ``smooth_compiled``;
- ``action``: the fused action statistics ``action_statistics_compiled`` and ``residual_cov_compiled``;
- ``sensor``: the fused sensor curve fit ``sensor_update_compiled``;
- ``augmented``: the E-step with extra states (pose plus K scalar states, ``Lowered.extra``: forward EKF and
  Rauch-Tung-Striebel), dispatched to by ``smooth_compiled`` and ``innovations_compiled``;
- ``augmented_stats``: its action statistics ``displacement_statistics_compiled``;
- ``arguments``: the kernels' inputs by name, ``FrameInputs`` and ``SightingInputs`` (``kernel_inputs``);
- ``cache``: the on-disk cache flushed when any kernel source changes (numba sees only a kernel's own file).
"""

from __future__ import annotations

from learners.inference.kernels.action import (
    action_statistics_compiled,
    residual_cov_compiled,
    table_means_compiled,
    table_residual_cov_compiled,
)
from learners.inference.kernels.algebra import release_scratch
from learners.inference.kernels.estep import innovations_compiled, smooth_compiled
from learners.inference.kernels.sensor import sensor_update_compiled


def _flush_stale_caches() -> None:
    """Before any kernel runs: every kernel's cache flushed if any kernel source changed (module ``cache``)."""
    from pathlib import Path

    from learners.inference.kernels import (
        action,
        algebra,
        augmented,
        augmented_stats,
        cache,
        estep,
        fasttrig,
        sensor,
        structured,
    )

    modules = (action, algebra, augmented, augmented_stats, estep, fasttrig, sensor, structured)
    cache.flush_if_changed(cache.cached_dispatchers(modules), cache.sources_digest(Path(__file__).parent))


_flush_stale_caches()

__all__ = ["smooth_compiled", "innovations_compiled", "action_statistics_compiled", "residual_cov_compiled",
           "sensor_update_compiled", "table_means_compiled", "table_residual_cov_compiled", "release_scratch"]
