"""Moved to ``learners.arrays.batch`` (the arrays model and inference exchange); this name is kept so that
existing imports keep working. Import from ``learners.arrays.batch``."""

from learners.arrays.batch import Batch, make_batch  # noqa: F401
