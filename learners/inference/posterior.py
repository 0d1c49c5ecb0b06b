"""Moved to ``learners.arrays.posterior`` (the arrays model and inference exchange); this name is kept so that
existing imports keep working. Import from ``learners.arrays.posterior``."""

from learners.arrays.posterior import ExtraMoments, Posterior  # noqa: F401
