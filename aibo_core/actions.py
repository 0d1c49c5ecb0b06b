"""The 40 discrete walk actions of the paper (section IV-A).

Each action asks the robot to walk "as fast as possible" in one direction of the
(vx, vy, vtheta) space, i.e. on the unit sphere vx^2 + vy^2 + vtheta^2 = 1 of
normalized velocities. Action index ``8*i + j`` uses

    a = A_TURN[i]       in {-1/2, -1/6, 0, 1/6, 1/2}   (normalized turn rate)
    b = B_DIRECTION[j]  in {0, pi/4, ..., -pi/4}        (direction of travel, rad)

and the attempted normalized velocities are
``(sqrt(1-a^2) cos b, sqrt(1-a^2) sin b, a)``.
"""

from __future__ import annotations

import numpy as np

N_ACTIONS = 40
A_TURN = np.array([-1 / 2, -1 / 6, 0.0, 1 / 6, 1 / 2])
B_DIRECTION = np.array(
    [0.0, np.pi / 4, np.pi / 2, 3 * np.pi / 4, np.pi, -3 * np.pi / 4, -np.pi / 2, -np.pi / 4]
)


def action_index(i: int, j: int) -> int:
    """Index of the action with turn ``A_TURN[i]`` and direction ``B_DIRECTION[j]``."""
    if not (0 <= i < len(A_TURN) and 0 <= j < len(B_DIRECTION)):
        raise ValueError(f"action (i={i}, j={j}) outside the 5 x 8 table")
    return 8 * i + j


def attempted_velocities() -> np.ndarray:
    """Attempted normalized velocities, shape (40, 3): columns vx, vy, vtheta in [-1, 1]."""
    a = np.repeat(A_TURN, len(B_DIRECTION))
    b = np.tile(B_DIRECTION, len(A_TURN))
    r = np.sqrt(1.0 - a**2)
    return np.stack([r * np.cos(b), r * np.sin(b), a], axis=1)
