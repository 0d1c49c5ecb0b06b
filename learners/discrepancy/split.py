"""Held-out data: interleaved time blocks (odd blocks held out), so both halves see every command,
every part of the field and every stretch of time."""

from __future__ import annotations

import numpy as np

from aibo_core.trajectory import Trajectory

#: Block length (s): short, so both halves see every command (held 5 s) and every part of the field,
#: and the fit on the training half never dead-reckons long (30 s blocks degraded its EKF).
BLOCK_S = 2.0


def heldout_mask(tr: Trajectory, block_s: float = BLOCK_S) -> np.ndarray:
    """(S,) bool: the sightings in odd time blocks of ``block_s`` seconds."""
    block = np.floor(tr.sighting_frame * tr.dt / block_s).astype(np.int64)
    return block % 2 == 1


def training_log(tr: Trajectory, block_s: float = BLOCK_S) -> Trajectory:
    """The log with the held-out sightings removed (commands and frames kept)."""
    keep = ~heldout_mask(tr, block_s)
    return tr.with_sightings(keep)
