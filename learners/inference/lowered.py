"""Moved to ``learners.arrays.lowered`` (the arrays model and inference exchange); this name is kept so that
existing imports keep working. Import from ``learners.arrays.lowered``."""

from learners.arrays.lowered import BASIS_INVERSE, BASIS_POWER, ExtraStates, Lowered, curve  # noqa: F401
