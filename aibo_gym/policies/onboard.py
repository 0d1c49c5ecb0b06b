"""What the robot knows onboard while it explores: its pose estimate and the data gathered so far.

:class:`OnboardTracker` is fed, frame by frame, the command executed and the sightings reported
(beacon, height px, angle rad): nothing else, never the true pose. It keeps

* an onboard EKF (:class:`~aibo_gym.policies.localizer.EKFLocalizer`'s equations in plain floats,
  :class:`~aibo_gym.policies.fast_ekf.FastEKF`) predicting with the
  *nominal* velocities (attempted x ``nominal_max``) and correcting with the nominal pinhole;
* frames executed per command, sightings per command;
* the coverage cells visited: (command x beacon-distance bin x bearing bin), the distance from the
  sighting's height through the nominal pinhole (``NOMINAL_HEIGHT_PX_MM / height``) in
  ``N_DIST_BINS`` equal bins over ``range_mm``, the bearing (angle from the body heading) in
  ``N_BEARING_BINS`` equal bins over [-pi, pi).

Each :meth:`OnboardTracker.step` returns the exploration reward terms of that frame (the env's
``info["rewards"]``, see ``AiboBeaconsEnv``): ``balance``, ``coverage``, ``sightings``, ``wall``,
``info_gain``. :meth:`OnboardTracker.features` is the observation of the hold-level explorer
(:mod:`aibo_gym.explorer`) and of the ``sb3`` policy, built from the same numbers.

It also predicts, for every command, the path of holding it (nominal velocities) and the
sightings expected on that path (head-pan schedule, field of view, range, detection
probability): what the ``informed`` policy and the field-keeping rule use.
"""

from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np

from aibo_core.actions import N_ACTIONS

from ..config import sensor_sigmas
from ..robot import nominal_velocities, wrap_angle
from .fast_ekf import FastEKF
from .localizer import NOMINAL_HEIGHT_PX_MM

N_DIST_BINS = 6
N_BEARING_BINS = 8
N_CELLS = N_ACTIONS * N_DIST_BINS * N_BEARING_BINS
WALL_MARGIN_MM = 300.0  # the ``wall`` term grows from 0 at this distance of the estimate to the edge to 1 at the edge
FEATURES_VERSION = "onboard-v1"
N_FEATURES = 10 + 2 * N_ACTIONS
LOG_N = math.log(N_ACTIONS)


class OnboardTracker:
    """The onboard state of one episode (see the module docstring). ``cfg``: a full env config."""

    def __init__(self, cfg: dict[str, Any]) -> None:
        self.cfg = cfg
        self.dt = float(cfg["dt"])
        self.nominal = nominal_velocities(cfg["nominal_max"])
        self._disp = (self.nominal * self.dt).tolist()
        sh, sa = sensor_sigmas(cfg)
        self.ekf = FastEKF(cfg["beacons"], sh, sa, cfg["slip_std"])
        self.beacons = np.asarray(cfg["beacons"], dtype=float)
        self.half = (0.5 * cfg["field"][0], 0.5 * cfg["field"][1])
        self.rmin, self.rmax = cfg["range_mm"]
        self.counts = np.zeros(N_ACTIONS, dtype=np.int64)
        self.seen = np.zeros(N_ACTIONS, dtype=np.int64)  # sightings while holding each command
        self.cells = np.zeros(N_CELLS, dtype=bool)
        self.steps = 0
        self._slogs = 0.0  # sum over commands of c log c (entropy of command use, incrementally)

    def reset(self) -> None:
        self.counts[:] = 0
        self.seen[:] = 0
        self.cells[:] = False
        self.steps = 0
        self._slogs = 0.0
        sp = self.cfg["start_pose"]
        if sp == "random":  # unknown start: field centre, broad prior
            self.ekf.reset([0.0, 0.0, 0.0], [self.half[0], self.half[1], math.pi])
        else:
            self.ekf.reset(sp, [50.0, 50.0, 0.05])

    # ------------------------------------------------------------------ per frame
    def entropy(self) -> float:
        """Entropy of the command use so far over log(40): 1 when all 40 are used equally."""
        t = self.steps
        return 0.0 if t == 0 else (math.log(t) - self._slogs / t) / LOG_N

    def cell(self, action: int, height: float, angle: float) -> int:
        d = NOMINAL_HEIGHT_PX_MM / height if height > 0 else math.inf
        db = min(max(int((d - self.rmin) / (self.rmax - self.rmin) * N_DIST_BINS), 0), N_DIST_BINS - 1)
        bb = min(int((wrap_angle(angle) + math.pi) / (2 * math.pi) * N_BEARING_BINS), N_BEARING_BINS - 1)
        return (action * N_DIST_BINS + db) * N_BEARING_BINS + bb

    def step(self, action: int, sightings: Iterable[tuple[int, float, float]]) -> dict[str, float]:
        """Account for one frame (command executed, its sightings); the reward terms of the frame."""
        h0 = self.entropy()
        c = int(self.counts[action])
        self._slogs += (c + 1) * math.log(c + 1) - (c * math.log(c) if c else 0.0)
        self.counts[action] = c + 1
        self.steps += 1
        balance = self.entropy() - h0
        self.ekf.predict(self._disp[action])
        n = 0
        new = 0
        gain = 0.0
        for beacon, height, angle in sightings:
            n += 1
            k = self.cell(action, height, angle)
            if not self.cells[k]:
                self.cells[k] = True
                new += 1
            before = self.ekf.logdet()
            if self.ekf.correct(int(beacon), float(height), float(angle)):
                gain += 0.5 * (before - self.ekf.logdet())
        self.seen[action] += n
        x, y = self.ekf.m[0], self.ekf.m[1]
        edge = min(self.half[0] - abs(x), self.half[1] - abs(y))
        wall = -min(max(1.0 - edge / WALL_MARGIN_MM, 0.0), 1.0)
        return {"balance": balance, "coverage": new / N_CELLS, "sightings": float(n), "wall": wall, "info_gain": gain}

    # ------------------------------------------------------------------ features
    def features(self, max_steps: int) -> np.ndarray:
        """(N_FEATURES,) float32 in [-5, 5]: the explorer's observation (``FEATURES_VERSION``).

        [x / half length, y / half width, cos theta, sin theta, std x / 1000 mm, std y / 1000 mm,
        std theta / pi, elapsed fraction of ``max_steps``, sin and cos of the head-pan phase,
        per command: 40 x share of frames used (clipped at 5), per command: sightings per frame held].
        """
        x, y, th = self.ekf.pose
        sd = np.sqrt(np.maximum(np.diag(self.ekf.cov), 0.0))
        phase = 2 * math.pi * self.steps * self.dt / self.cfg["pan_period"]
        head = [x / self.half[0], y / self.half[1], math.cos(th), math.sin(th), sd[0] / 1000.0, sd[1] / 1000.0,
                sd[2] / math.pi, self.steps / max(max_steps, 1), math.sin(phase), math.cos(phase)]
        share = self.counts * (N_ACTIONS / max(self.steps, 1))
        rate = self.seen / np.maximum(self.counts, 1)
        out = np.concatenate([np.asarray(head), share, rate])
        return np.clip(out, -5.0, 5.0).astype(np.float32)

    # ------------------------------------------------------------------ predictions
    def predict_holds(self, hold_s: float, points: int) -> tuple[np.ndarray, np.ndarray]:
        """Predicted (40, points, 2) positions (mm) and (40, points) headings of holding each command
        for ``hold_s`` from the current estimate, with the nominal velocities (midpoint arcs)."""
        pose = self.ekf.pose
        h = hold_s / points
        x = np.full(N_ACTIONS, float(pose[0]))
        y = np.full(N_ACTIONS, float(pose[1]))
        th = np.full(N_ACTIONS, float(pose[2]))
        vx, vy, vth = self.nominal.T
        xy = np.empty((N_ACTIONS, points, 2))
        heading = np.empty((N_ACTIONS, points))
        for k in range(points):
            mid = th + 0.5 * vth * h
            c, s = np.cos(mid), np.sin(mid)
            x = x + (c * vx - s * vy) * h
            y = y + (s * vx + c * vy) * h
            th = th + vth * h
            xy[:, k, 0], xy[:, k, 1], heading[:, k] = x, y, th
        return xy, heading

    def violation(self, xy: np.ndarray, margin_mm: float) -> np.ndarray:
        """(40,) how far (mm) each predicted path goes beyond the field shrunk by ``margin_mm``."""
        hl, hw = self.half[0] - margin_mm, self.half[1] - margin_mm
        over = np.maximum(np.abs(xy[..., 0]) - hl, 0.0) + np.maximum(np.abs(xy[..., 1]) - hw, 0.0)
        return over.max(axis=1)

    def expected_sightings(self, xy: np.ndarray, heading: np.ndarray, hold_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Expected sightings over each predicted hold (40,) and, per path point, the (distance,
        bearing) of the beacon expected in view (40, points, 2; NaN when none): the camera's rule
        (nearest the image centre within fov/2 and ``range_mm``) on the head-pan schedule."""
        n, points = heading.shape
        h = hold_s / points
        t = (self.steps + (np.arange(points) + 0.5) * h / self.dt) * self.dt
        pan = self.cfg["pan_amplitude"] * np.sin(2 * np.pi * t / self.cfg["pan_period"])
        dx = self.beacons[None, None, :, 0] - xy[..., None, 0]
        dy = self.beacons[None, None, :, 1] - xy[..., None, 1]
        d = np.hypot(dx, dy)
        bearing = np.angle(np.exp(1j * (np.arctan2(dy, dx) - heading[..., None])))
        off = np.abs(np.angle(np.exp(1j * (bearing - pan[None, :, None]))))
        ok = (d >= self.rmin) & (d <= self.rmax) & (off <= 0.5 * self.cfg["fov"])
        off = np.where(ok, off, np.inf)
        best = off.argmin(axis=2)
        any_ok = ok.any(axis=2)
        frames_per_point = h / self.dt
        expected = (any_ok * frames_per_point * self.cfg["detect_prob"]).sum(axis=1)
        sel = np.take_along_axis(np.stack([d, bearing], axis=-1), best[..., None, None], axis=2)[:, :, 0, :]
        sel = np.where(any_ok[..., None], sel, np.nan)
        return expected, sel
