"""Every test process (pytest-xdist's workers too) runs with one BLAS thread, as the ``aibo`` command does
(``aibo/__init__.py``): imported here, before any test module imports NumPy."""

import aibo  # noqa: F401
