"""The ``aibo`` command (``aibo/cli.py``) and its subcommands (``aibo/commands/``).

One BLAS thread per process unless the user sets otherwise: the work is parallel over processes
(``aibo diagnose``'s candidates, the sweeps' workers, pytest-xdist's workers), and every matrix here is
small, so OpenBLAS's own threads only oversubscribe the cores. Measured on 2 cores shared with other
jobs: ``aibo learn`` on a 15-minute log 15.0 -> 11.3-12.2 s wall (7.0 -> 5.0-5.5 s CPU), ``aibo
diagnose`` on a 10-minute log 134 -> 117 s wall (71 -> 55 s CPU); on the idle machine the same within noise
(learn 5.1-5.8 s either way over 5 runs each; diagnose 39.7 -> 38.2 s). Set before NumPy is imported
(``aibo`` is imported before ``aibo.cli``); ``OMP_NUM_THREADS`` (PyTorch's) is left alone.
"""

import os

#: Environment variables of the BLAS libraries NumPy and SciPy load, set to one thread unless already set.
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

for _var in BLAS_THREAD_VARS:
    os.environ.setdefault(_var, "1")
