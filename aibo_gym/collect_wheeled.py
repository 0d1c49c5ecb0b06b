"""Collect an ``aibo-trajectory/2`` log by running ``WheeledRobot-v0``: with the random-waypoint driver
(:mod:`aibo_gym.policies.waypoints`), or replaying a measured log's continuous commands.

The log has ``controls`` (T, k) with the env's ``control_names``, ``sensor_kind="range_mm"``, every
sighting of every frame, the true ``pose``, no ``field`` unless the env has walls, and
``meta["truth"]`` (:func:`truth_of`). A sighting whose measured range is not positive (possible only
with a large noise or an offset near the camera) cannot be logged (the format wants sizes > 0): it is
dropped and counted in ``meta["dropped_nonpositive_ranges"]``.
"""

from __future__ import annotations

import copy
from typing import Any, Callable

import numpy as np

from aibo_core.trajectory import Trajectory

from . import WHEELED_ENV_ID, __version__
from .collect import _check_steps
from .envs.wheeled_robot import WheeledRobotEnv
from .policies.waypoints import WaypointDriver, validate_waypoint_params


def truth_of(env: WheeledRobotEnv, spurious: list[int] | None = None) -> dict[str, Any]:
    """The ground truth of a (reset) env, as recorded in ``meta["truth"]``.

    feature_map, control_names; weights: F x 3 true velocity per unit feature (mm/s, mm/s, rad/s; the
    learner's per-frame weights are these x dt); motion_noise_cov: 3 x 3 per-frame robot-frame
    covariance (mm^2, rad^2); sensor: ``{"model": "curve", "basis", "coef"}`` (range mm of distance mm);
    sigma_range_mm; sigma_bearing rad; effects: validated effect parameters; start_pose;
    spurious_sightings (only when an effect can create sightings): indices into the log's sightings.
    """
    cfg = env.config
    truth = {
        "feature_map": cfg["feature_map"],
        "control_names": list(cfg["control_names"]),
        "weights": env.weights.tolist(),
        "motion_noise_cov": [list(row) for row in cfg["motion_cov"]],
        "sensor": {"model": "curve", **copy.deepcopy(cfg["sensor_curve"])},
        "sigma_range_mm": float(cfg["sigma_range_mm"]),
        "sigma_bearing": float(cfg["sigma_bearing"]),
        "effects": copy.deepcopy(cfg["effects"]),
        "start_pose": [float(v) for v in env.start_pose],
    }
    if env.max_sightings > env.n_landmarks:
        truth["spurious_sightings"] = [] if spurious is None else [int(i) for i in spurious]
    return truth


def collect_wheeled(config: dict[str, Any] | None, steps: int, seed: int,
                    policy_params: dict[str, Any] | None = None) -> Trajectory:
    """Drive ``WheeledRobot-v0`` (``config``) to random waypoints for ``steps`` frames (fewer if it
    terminates) and return the log; ``policy_params``: the driver's (:mod:`aibo_gym.policies.waypoints`)."""
    _check_steps(steps)
    env = WheeledRobotEnv(config)
    params = validate_waypoint_params(policy_params)
    driver = WaypointDriver(env.config, seed, **params)
    meta = {"policy": "waypoints", "policy_params": params, "localizer": "truth"}
    return _run(env, driver.reset, driver.act, steps, seed, None, meta)


#: The commands a tracking replay can steer: forward speed (mm/s) and turn rate (rad/s).
TRACKED_CONTROLS = ("v_mm_s", "omega_rad_s")
#: The tracking replay's time constant (s): a position or heading error off the reference path is steered out over
#: about this long. Slow beside the motion's own timing (lag, response time: tenths of a second) and the check's
#: motion horizons (1-5 s), fast beside the drift of an open-loop replay (metres over minutes). Measured on MRCLAM
#: robot 3 (docs/results.md, "The twin's replays follow the robot's path"): replays of its commands 34-58% of the time
#: outside the landmarks' box (the robot: 96%), tracking at 10 s (corrected where the command changes) a median 72-88 mm
#: off Vicon's path.
TRACKING_TAU_S = 10.0
#: Below this forward speed (mm/s) the lateral error's gain is held at its value here (it divides by the speed).
TRACKING_MIN_SPEED_MM_S = 50.0


def tracking_command(command: np.ndarray, pose: np.ndarray, target: np.ndarray,
                     tau_s: float = TRACKING_TAU_S) -> np.ndarray:
    """The measured command (v mm/s, omega rad/s) corrected towards ``target`` [x mm, y mm, theta rad] from ``pose``
    (Kanayama et al. 1990's tracking law with gains 1 / tau): with the errors in the robot's frame (e_x ahead, e_y
    left, e_theta), v = v_r cos(e_theta) + e_x / tau and omega = omega_r + sin(e_theta) / tau + e_y / (tau^2 max(|v_r|,
    TRACKING_MIN_SPEED_MM_S))."""
    v, omega = float(command[0]), float(command[1])
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = target[0] - pose[0], target[1] - pose[1]
    ex, ey = c * dx + s * dy, -s * dx + c * dy
    eth = float(np.angle(np.exp(1j * (target[2] - pose[2]))))
    speed = max(abs(v), TRACKING_MIN_SPEED_MM_S)
    return np.array([v * np.cos(eth) + ex / tau_s, omega + np.sin(eth) / tau_s + ey / (tau_s * tau_s * speed)])


def replay_wheeled(config: dict[str, Any] | None, controls: np.ndarray, seed: int,
                   images: np.ndarray | None = None, source: str = "",
                   reference: np.ndarray | None = None) -> Trajectory:
    """Step ``WheeledRobot-v0`` through the given commands (a measured log's ``controls``, (T, k)) and
    return the log. ``images`` (T,) bool: the frames that take an image (e.g. the measured log's frames
    with a sighting); None: the config's schedule. The action space is widened to hold the commands.

    ``reference`` (T + 1, 3) poses [x mm, y mm, theta rad] (e.g. a model's smoothed path of the measured log): each
    command is corrected towards the reference's pose at the end of its frame (``tracking_command``), as the
    measured robot steered on its own pose, where the measured command changes (held between, so the replay's
    commands change where the log's do); the log records the commands executed. Only for the commands
    ``TRACKED_CONTROLS``; None: the commands open loop, as measured."""
    controls = np.asarray(controls, dtype=float)
    if controls.ndim != 2 or len(controls) == 0 or not np.isfinite(controls).all():
        raise ValueError("replay: controls must be a non-empty (T, k) array of finite numbers")
    cfg = dict(config or {}, max_steps=len(controls))
    lo = np.minimum(controls.min(axis=0), cfg.get("control_low", controls.min(axis=0)))
    hi = np.maximum(controls.max(axis=0), cfg.get("control_high", controls.max(axis=0)))
    hi = np.where(hi > lo, hi, lo + 1.0)
    if reference is not None:
        lo, hi = lo - 0.5 * (hi - lo), hi + 0.5 * (hi - lo)  # room for the corrections
    cfg["control_low"], cfg["control_high"] = lo.tolist(), hi.tolist()
    env = WheeledRobotEnv(cfg)
    if reference is not None:
        reference = np.asarray(reference, dtype=float)
        names = tuple(env.config["control_names"])
        if names != TRACKED_CONTROLS or reference.shape != (len(controls) + 1, 3):
            raise ValueError(f"replay: a reference path needs the commands {TRACKED_CONTROLS} and (T + 1, 3) poses; "
                             f"got {names} and {reference.shape}")
    options = None if images is None else {"images": np.asarray(images, bool)}
    meta = {"policy": "replay", "policy_params": {}, "localizer": "none", "replay_of": source}
    if reference is None:
        rows = iter(controls)
        return _run(env, lambda info: None, lambda obs, info: next(rows), len(controls), seed, options, meta)
    state: dict[str, Any] = {"t": 0, "held": None}

    def reset(info: dict[str, Any]) -> None:
        state.update(t=0, held=None)

    def act(obs: Any, info: dict[str, Any]) -> np.ndarray:
        # corrected only where the measured command changes, held between: the replay's commands change where the
        # log's do, and "time since a command change" means the same in both (a correction on every frame would
        # make every frame a change)
        t = state["t"]
        state["t"] += 1
        if state["held"] is None or np.any(controls[t] != controls[t - 1]):
            state["held"] = np.clip(tracking_command(controls[t], info["pose"], reference[t + 1]), lo, hi)
        return state["held"]

    meta.update(policy="tracking replay", policy_params={"tau_s": TRACKING_TAU_S}, localizer="truth")
    return _run(env, reset, act, len(controls), seed, options, meta)


def collect_closed_loop(config: dict[str, Any] | None, steps: int, seed: int, tau_s: float) -> Trajectory:
    """A driver that steers on the robot's pose on every frame: the waypoint driver's log (``collect_wheeled``, the
    same ``config``, ``steps`` and ``seed``) driven again, each frame's command its command corrected towards its
    path (``tracking_command`` with time constant ``tau_s`` s, on the true pose), so that every command answers the
    motion's own errors, as a robot's feedback controller's do (MRCLAM's commands change 67 times a second). The
    calibrated check replays the commands open loop; on such a log its timing statistic disagrees without any timing
    error in the robot (docs/results.md, "A driver that steers on its pose")."""
    _check_steps(steps)
    ref = collect_wheeled(config, steps, seed)
    controls = ref.controls
    lo, hi = controls.min(axis=0), controls.max(axis=0)
    lo, hi = lo - (hi - lo), hi + (hi - lo)  # room for the corrections
    env = WheeledRobotEnv(dict(config or {}, max_steps=len(controls), control_low=lo.tolist(), control_high=hi.tolist()))
    state = {"t": 0}

    def act(obs: Any, info: dict[str, Any]) -> np.ndarray:
        t = state["t"]
        state["t"] += 1
        return np.clip(tracking_command(controls[t], info["pose"], ref.pose[t + 1], tau_s), lo, hi)

    meta = {"policy": "closed loop", "policy_params": {"tau_s": tau_s}, "localizer": "truth"}
    return _run(env, lambda info: state.update(t=0), act, len(controls), seed, None, meta)


def _run(env: WheeledRobotEnv, reset: Callable, act: Callable, steps: int, seed: int,
         options: dict[str, Any] | None, meta: dict[str, Any]) -> Trajectory:
    """Reset ``env`` with ``seed`` (and ``options``), call ``reset(info)``, step ``act(obs, info)`` for up
    to ``steps`` frames and record the log; ``meta`` adds the policy's keys to the log's meta."""
    obs, info = env.reset(seed=seed, options=options)
    reset(info)
    controls = np.empty((steps, env.k))
    pose = np.empty((steps + 1, 3))
    pose[0] = info["pose"]
    frame: list[int] = []
    landmark: list[int] = []
    value: list[tuple[float, float]] = []
    spurious: list[int] = []
    dropped = 0
    n = 0
    for t in range(steps):
        obs, _, terminated, truncated, info = env.step(act(obs, info))
        controls[t] = info["command"]
        pose[t + 1] = info["pose"]
        s = info["sightings"]
        for j in range(s["count"]):
            if not s["range"][j] > 0:
                dropped += 1
                continue
            if s["spurious"][j]:
                spurious.append(len(frame))
            frame.append(t)
            landmark.append(int(s["beacon"][j]))
            value.append((float(s["range"][j]), float(s["bearing"][j])))
        n = t + 1
        if terminated or truncated:
            break
    cfg = env.config
    meta = {"generator": f"aibo_gym {__version__} {WHEELED_ENV_ID}", "seed": seed, **meta,
            "config": copy.deepcopy(cfg), "truth": truth_of(env, spurious), "dropped_nonpositive_ranges": dropped}
    walled = cfg["walls"] in ("clamp", "pymunk", "none")
    return Trajectory(
        dt=env.dt, landmarks=np.array(env.landmarks), sighting_frame=np.asarray(frame, dtype=np.int64),
        sighting_landmark=np.asarray(landmark, dtype=np.int64), sighting_value=np.asarray(value, float).reshape(-1, 2),
        sensor_kind="range_mm", controls=controls[:n], control_names=tuple(cfg["control_names"]),
        field=np.asarray(cfg["field"], float) if walled else None, pose=pose[: n + 1], meta=meta,
    ).validate(f"{WHEELED_ENV_ID} log")
