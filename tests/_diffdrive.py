"""A second, independent log generator: a wheeled differential-drive robot with continuous
(v mm/s, omega rad/s) commands and a range-and-bearing sensor seeing several landmarks per frame.

It shares nothing with ``aibo_gym`` (no head pan, no field, no walls, other noise, other rates), so
a learner that works on its logs does not depend on our simulator's choices.

True motion per frame (robot frame, dt s): velocity = FEATURES(v, omega) @ TRUE_W, with
FEATURES = [v, omega, v |omega|, |omega|, 1] (the ``diff_drive`` feature map); plus Gaussian slip.
Sensor: range = d + N(0, 40 mm), bearing = true bearing + N(0, 0.02 rad), for landmarks within
4 m and 0.9 rad of the heading, each seen with probability 0.4 per frame.
"""

from __future__ import annotations

import numpy as np

from aibo_core.geometry import wrap
from aibo_core.trajectory import Trajectory

#: rows: v, omega, v|omega|, |omega|, 1; columns: vx mm/s, vy mm/s, vtheta rad/s
TRUE_W = np.array([
    [0.92, 0.015, 0.0002],
    [0.0, 12.0, 0.95],
    [-0.12, 0.0, 0.0],
    [0.0, 0.0, 0.01],
    [4.0, -2.0, 0.003],
])


def velocity(commands: np.ndarray) -> np.ndarray:
    """(N, 3) true velocities (mm/s, mm/s, rad/s) for commands (N, 2) = (v mm/s, omega rad/s)."""
    v, w = commands[:, 0], commands[:, 1]
    return np.stack([v, w, v * np.abs(w), np.abs(w), np.ones_like(v)], axis=1) @ TRUE_W


def range_biases(T: int, n_landmarks: int, dt: float, sigma_rel: float, tau_s: float, seed: int,
                 stream: int = 7) -> np.ndarray:
    """(T, n_landmarks) relative range biases: per landmark a first-order Gauss-Markov process of stationary standard
    deviation ``sigma_rel`` and correlation time ``tau_s`` (s), drawn from its own stream (seed ``seed``, ``stream``)."""
    rng = np.random.default_rng([seed, stream])
    phi = np.exp(-dt / tau_s)
    b = np.empty((T, n_landmarks))
    b[0] = rng.normal(0.0, sigma_rel, n_landmarks)
    for t in range(1, T):
        b[t] = phi * b[t - 1] + rng.normal(0.0, sigma_rel * np.sqrt(1.0 - phi * phi), n_landmarks)
    return b


def diff_drive_log(seconds: float = 600.0, dt: float = 0.05, seed: int = 0,
                   drift_mm_s: tuple[float, float] = (0.0, 0.0),
                   range_bias: tuple[float, float] | None = None,
                   turn_gain: tuple[float, float] | None = None,
                   bearing_bias: tuple[float, float] | None = None,
                   sensor: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Trajectory:
    """A log of ``seconds`` with commands held 1-3 s, wandering among 8 landmarks in a 6 m square;
    ``drift_mm_s``: a hidden world-frame drift (mm/s), recorded nowhere in the log; ``range_bias``: (sigma_rel, tau_s)
    of a slowly varying relative bias per landmark on the range (``range_biases``; range = d (1 + b) + noise; the
    rest of the log is the same as without it), as ``landmark_bias`` models it; ``turn_gain``: (sigma, tau_s) of an
    error of the turn's gain, the same process on its own stream (each frame turns by its true turn times (1 + g));
    ``bearing_bias``: (sigma rad, tau_s) of a bias per landmark added to its bearings, the same process on its own;
    ``sensor``: where the sensor sits on the robot (x mm forward, y mm left, yaw rad), the sightings measured from there
    (which landmarks are in view is decided from the robot's origin, so the same landmarks are seen wherever it sits)."""
    rng = np.random.default_rng(seed)
    T = int(round(seconds / dt))
    landmarks = rng.uniform(-3000.0, 3000.0, size=(8, 2))
    bias = np.zeros((T, 8)) if range_bias is None else range_biases(T, 8, dt, *range_bias, seed)
    gain = np.zeros((T, 1)) if turn_gain is None else range_biases(T, 1, dt, *turn_gain, seed, stream=11)
    offset = np.zeros((T, 8)) if bearing_bias is None else range_biases(T, 8, dt, *bearing_bias, seed, stream=13)
    pose = np.zeros((T + 1, 3))
    controls = np.zeros((T, 2))
    frames, marks, values = [], [], []
    cmd, hold = np.zeros(2), 0
    for t in range(T):
        x, y, th = pose[t]
        if hold <= 0:
            home = wrap(np.arctan2(-y, -x) - th) if np.hypot(x, y) > 2000 else rng.uniform(-1, 1)
            cmd = np.array([rng.uniform(-100.0, 400.0), np.clip(home + rng.normal(0, 0.3), -1.2, 1.2)])
            hold = int(rng.integers(20, 60))
        hold -= 1
        controls[t] = cmd
        vel = velocity(cmd[None])[0] * dt * np.array([1.0, 1.0, 1.0 + gain[t, 0]]) + rng.normal(0.0, [2.0, 2.0, 0.005])
        c, s = np.cos(th), np.sin(th)
        pose[t + 1] = (x + c * vel[0] - s * vel[1] + drift_mm_s[0] * dt, y + s * vel[0] + c * vel[1] + drift_mm_s[1] * dt,
                       th + vel[2])
        dx, dy = (landmarks - pose[t + 1, :2]).T
        d = np.hypot(dx, dy)
        bearing = wrap(np.arctan2(dy, dx) - pose[t + 1, 2])
        c1, s1 = np.cos(pose[t + 1, 2]), np.sin(pose[t + 1, 2])
        sx = pose[t + 1, 0] + c1 * sensor[0] - s1 * sensor[1]
        sy = pose[t + 1, 1] + s1 * sensor[0] + c1 * sensor[1]
        ds = np.hypot(landmarks[:, 0] - sx, landmarks[:, 1] - sy)
        bs = wrap(np.arctan2(landmarks[:, 1] - sy, landmarks[:, 0] - sx) - pose[t + 1, 2] - sensor[2])
        for b in np.flatnonzero((d > 300) & (d < 4000) & (np.abs(bearing) < 0.9) & (rng.random(8) < 0.4)):
            frames.append(t)
            marks.append(b)
            values.append((ds[b] * (1.0 + bias[t, b]) + rng.normal(0, 40.0), wrap(bs[b] + offset[t, b] + rng.normal(0, 0.02))))
    return Trajectory(dt=dt, landmarks=landmarks, sighting_frame=np.array(frames), sighting_landmark=np.array(marks),
                      sighting_value=np.array(values).reshape(-1, 2), sensor_kind="range_mm", controls=controls,
                      control_names=("v_mm_s", "omega_rad_s"), pose=pose,
                      meta={"generator": "tests/_diffdrive.py", "seed": seed})  # no word of the drift
