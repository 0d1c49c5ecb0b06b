"""The paper's exploration policy: every ``hold_s`` seconds a new random action, with priority on
staying on the field and on the actions used least so far (Stronger & Stone, section IV-A).

At each decision the policy predicts, for every candidate action, the path of holding it for
``hold_s`` from its current pose estimate, using the attempted velocities scaled to the nominal
maxima (355 mm/s, 420 mm/s, pi/2 rad/s: the robot does not know its true action model). A
candidate is *safe* when every predicted point stays inside the field shrunk by ``margin_mm``.
Among the safe candidates it takes one with the fewest frames executed so far (ties broken by its
own seeded RNG). If none is safe it takes the one whose path leaves the field the least.

The pose estimate is ``info["pose"]`` (``localizer="truth"``) or an onboard EKF
(``localizer="ekf"``, :class:`~aibo_gym.policies.localizer.EKFLocalizer`) fed with the policy's
own actions and the sightings in the observation.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from aibo_core.actions import N_ACTIONS

from ..config import make_config, sensor_sigmas
from ..robot import nominal_velocities
from .localizer import EKFLocalizer

LOCALIZERS = ("truth", "ekf")
PATH_POINTS = 25  # predicted points per candidate path


class RandomBalancedPolicy:
    """Random, balanced, field-keeping action choice (policy spec name ``random-balanced``).

    Args:
        env_config_or_params: the env config (partial or full; merged with the defaults).
        seed: seed of the policy's own RNG (independent of the env's RNG for the same integer).
        hold_s: seconds each chosen action is held.
        localizer: ``"truth"`` or ``"ekf"``.
        margin_mm: safety margin kept from the field edge by the predicted paths, mm.
    """

    name = "random-balanced"
    defaults = {"hold_s": 5.0, "localizer": "truth", "margin_mm": 300.0}
    choices = {"localizer": LOCALIZERS}

    def __init__(
        self,
        env_config_or_params: dict[str, Any] | None,
        seed: int | None = None,
        hold_s: float = 5.0,
        localizer: str = "truth",
        margin_mm: float = 300.0,
    ) -> None:
        if localizer not in LOCALIZERS:
            raise ValueError(f"localizer {localizer!r} (valid choices: {', '.join(map(repr, LOCALIZERS))})")
        if not hold_s > 0:
            raise ValueError(f"hold_s must be positive seconds, got {hold_s!r}")
        self.cfg = make_config(env_config_or_params)
        self.localizer = localizer
        self.hold_s = float(hold_s)
        self.margin = float(margin_mm)
        self.dt = self.cfg["dt"]
        self.hold_frames = max(1, int(round(self.hold_s / self.dt)))
        self.n_beacons = len(self.cfg["beacons"])
        self.nominal = nominal_velocities(self.cfg["nominal_max"])  # mm/s, mm/s, rad/s
        self._nominal_disp = (self.nominal * self.dt).tolist()
        self.rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0x9011C7,)))
        self.counts = np.zeros(N_ACTIONS, dtype=np.int64)  # frames executed per action
        self.ekf: EKFLocalizer | None = None
        if localizer == "ekf":
            sh, sa = sensor_sigmas(self.cfg)
            self.ekf = EKFLocalizer(self.cfg["beacons"], sh, sa, self.cfg["slip_std"])
        self._action: int | None = None
        self._left = 0

    # ------------------------------------------------------------------ API
    def reset(self, info: dict[str, Any] | None = None) -> None:
        """Start an episode (``info`` from ``env.reset``): clear counts and the localizer."""
        self.counts[:] = 0
        self._action, self._left = None, 0
        if self.ekf is not None:
            sp = self.cfg["start_pose"]
            if sp == "random":  # unknown start: field centre, broad prior
                hl, hw = self.cfg["field"][0] / 2, self.cfg["field"][1] / 2
                self.ekf.reset([0.0, 0.0, 0.0], [hl, hw, math.pi])
            else:
                self.ekf.reset(sp, [50.0, 50.0, 0.05])

    def act(self, obs: np.ndarray, info: dict[str, Any] | None = None) -> int:
        """The action for this frame, given the last observation and info."""
        pose = self._update_pose(obs, info)
        if self._left <= 0:
            self._action = self.choose(pose)
            self._left = self.hold_frames
        self._left -= 1
        self.counts[self._action] += 1
        return int(self._action)

    @property
    def pose_estimate(self) -> np.ndarray | None:
        """The pose the policy currently believes (x mm, y mm, theta rad)."""
        return None if self.ekf is None else self.ekf.pose

    # ------------------------------------------------------------------ internals
    def _update_pose(self, obs: np.ndarray, info: dict[str, Any] | None) -> np.ndarray:
        if self.ekf is None:
            if info is None or "pose" not in info:
                raise ValueError("localizer='truth' needs info['pose']; use localizer='ekf' without it")
            return np.asarray(info["pose"], dtype=float)
        if self._action is not None:
            self.ekf.predict(self._nominal_disp[self._action])
        b = self.n_beacons
        if obs[b + 2] > 0.5:
            self.ekf.correct(int(np.argmax(obs[:b])), float(obs[b]), float(obs[b + 1]))
        return self.ekf.pose

    def predicted_paths(self, pose: np.ndarray) -> np.ndarray:
        """(40, PATH_POINTS, 2) predicted positions (mm) of holding each action for ``hold_s``."""
        h = self.hold_s / PATH_POINTS
        x = np.full(N_ACTIONS, float(pose[0]))
        y = np.full(N_ACTIONS, float(pose[1]))
        th = np.full(N_ACTIONS, float(pose[2]))
        vx, vy, vth = self.nominal.T
        out = np.empty((N_ACTIONS, PATH_POINTS, 2))
        for k in range(PATH_POINTS):
            mid = th + 0.5 * vth * h  # midpoint heading: accurate arcs with few points
            c, s = np.cos(mid), np.sin(mid)
            x = x + (c * vx - s * vy) * h
            y = y + (s * vx + c * vy) * h
            th = th + vth * h
            out[:, k, 0], out[:, k, 1] = x, y
        return out

    def violation(self, pose: np.ndarray) -> np.ndarray:
        """(40,) how far (mm) each candidate's predicted path goes beyond the field minus margin."""
        paths = self.predicted_paths(pose)
        hl = self.cfg["field"][0] / 2 - self.margin
        hw = self.cfg["field"][1] / 2 - self.margin
        over = np.maximum(np.abs(paths[..., 0]) - hl, 0.0) + np.maximum(np.abs(paths[..., 1]) - hw, 0.0)
        return over.max(axis=1)

    def choose(self, pose: np.ndarray) -> int:
        """A new action: safe first, then least used, ties at random."""
        viol = self.violation(pose)
        safe = viol <= 0.0
        if safe.any():
            candidates = np.flatnonzero(safe)
            counts = self.counts[candidates]
            candidates = candidates[counts == counts.min()]
        else:
            candidates = np.flatnonzero(viol == viol.min())
        return int(self.rng.choice(candidates))
