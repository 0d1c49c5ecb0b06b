"""Compiled (numba) twin of the E-step and the M-steps.

Same contract and equations as the plain-NumPy reference (``smoother.smooth``,
``action_mstep`` and ``sensor_mstep``); docs/em-math.md is the specification. Everything runs
inside ``@njit`` kernels over flat arrays, looping over the logs of the batch inside the
kernel; 3x3 and 2x2 algebra is written out by hand (no np.linalg, no per-frame allocation).
A non-finite value makes the wrappers raise ``FloatingPointError`` naming the log and frame.

Layout (one concept per module; import the public functions from this package):
- ``algebra``: constants, kernel status codes, small 3x3 algebra on tuples (a 3x3 matrix is a
  row-major 9-tuple, a vector a 3-tuple), ``_wrap``, ``_horner``, array load/store, and the
  Python-side helpers shared by the wrappers (``_f64``, ``_raise``, ``_scratch``);
- ``fasttrig``: branch-free cos/sin (``_cos_sin*``) and ``_atan2``, with their constants;
- ``estep``: the E-step kernel (forward EKF, backward information filter, combination) and
  its wrapper ``smooth_compiled``;
- ``mstep``: the fused M-step kernels and wrappers: ``action_update_compiled``,
  ``sensor_update_compiled``.
"""

from __future__ import annotations

from learners.em.kernels.estep import smooth_compiled
from learners.em.kernels.mstep import action_update_compiled, sensor_update_compiled

__all__ = ["smooth_compiled", "action_update_compiled", "sensor_update_compiled"]
