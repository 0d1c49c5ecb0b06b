"""Feature maps of continuous commands: the mean velocity of a command is ``features(command) @ weights``.

Shared by the simulator (``aibo_gym``: the true motion of a velocity-commanded robot) and the learners
(``learners.model.action``: the action model fitted to a log), so both mean the same thing by a name.
NumPy only. Commands are (N, k) arrays in the units the log declares (``control_names``), e.g.
[v mm/s, omega rad/s]; ``weights`` are (F, 3) (vx, vy, vtheta per unit feature, robot frame).

=============  =====================  ========================================================
name           command                features (F)
=============  =====================  ========================================================
``diff_drive`` (v mm/s, omega rad/s)  [v, omega, v |omega|, |omega|, 1]
``unicycle``   (v mm/s, omega rad/s)  the ``diff_drive`` features; the lateral (vy) column of
                                      the weights is held at exactly 0 (``ZERO_OUTPUTS``)
``linear``     any k numbers          [c_1, ..., c_k, 1]
=============  =====================  ========================================================
"""

from __future__ import annotations

from typing import Callable

import numpy as np


def diff_drive(c: np.ndarray) -> np.ndarray:
    """(N, 5) features [v, omega, v |omega|, |omega|, 1] of (N, 2) commands [v, omega]."""
    v, w = c[:, 0], c[:, 1]
    aw = np.abs(w)
    return np.stack([v, w, v * aw, aw, np.ones_like(v)], axis=1)


def linear(c: np.ndarray) -> np.ndarray:
    """(N, k + 1) features [c_1, ..., c_k, 1] of (N, k) commands."""
    return np.concatenate([c, np.ones((len(c), 1))], axis=1)


#: name -> (features of (N, k) continuous commands, number of features for k inputs; -1: k not accepted)
FEATURE_MAPS: dict[str, tuple[Callable[[np.ndarray], np.ndarray], Callable[[int], int]]] = {
    "diff_drive": (diff_drive, lambda k: 5 if k == 2 else -1),
    "unicycle": (diff_drive, lambda k: 5 if k == 2 else -1),
    "linear": (linear, lambda k: k + 1),
}

#: name -> output columns (0 x, 1 y, 2 theta) whose weights are held at exactly 0
ZERO_OUTPUTS: dict[str, tuple[int, ...]] = {"unicycle": (1,)}
#: name -> {output column: feature rows held at exactly 0 in it}. ``unicycle``: the forward speed has no omega and no
#: |omega| term (a differential drive turning in place does not move forward whichever way it turns; with them EM
#: traded heading for speed on MRCLAM robot 4: -155 mm/s per rad/s where Vicon says +2.9; docs/results.md, "Why
#: robots 3 and 4 ended in wrong worlds"), and no constant (a robot commanded v = 0 does not creep forward; fitted on
#: one half of an MRCLAM log the constant came out anywhere in -23..+20 mm/s and cost the other half: RMS forward
#: error over the five robots' 15 half-to-half and whole-log fits 0.59 -> 0.55 of the face value's, lower on 4 of 5
#: robots, so on every leave-one-robot-out choice; docs/results.md, "The forward speed's constant").
#: Its forward speed is gain v + loss on arcs v |omega|. Nor does it turn without a command (the turn rate's constant):
#: fitted on MRCLAM robot 4's second half with `distance_dependent_noise`, the constant came out at +0.091 rad/s
#: beside -0.37 on |omega| (learn's: +0.003, -0.12), the two nearly collinear over the commands the half holds, and
#: the other half's turn rate had 1.55x learn's error; held at 0, no worse than learn's on all 10 half-to-half fits
#: and the whole-log fits within 2% of the free constant's on every robot (docs/results.md, "The turn rate's
#: constant"). A veer while driving is the turn rate's v term.
ZERO_CELLS: dict[str, dict[int, tuple[int, ...]]] = {"unicycle": {0: (1, 3, 4), 2: (4,)}}


def n_features(name: str, k: int) -> int:
    """Number of features of map ``name`` for k-dimensional commands; ValueError when it takes no such commands."""
    if name not in FEATURE_MAPS:
        raise ValueError(f"unknown feature map {name!r} (valid choices: {', '.join(FEATURE_MAPS)})")
    n = FEATURE_MAPS[name][1](k)
    if n < 0:
        raise ValueError(f"feature map '{name}' takes 2 controls (v mm/s, omega rad/s), got {k}")
    return n


def features(name: str, commands: np.ndarray) -> np.ndarray:
    """(N, F) features of (N, k) commands under map ``name``."""
    c = np.asarray(commands, dtype=float)
    n_features(name, c.shape[1])
    return FEATURE_MAPS[name][0](c)
