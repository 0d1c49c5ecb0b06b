"""Collect an ``aibo-trajectory/2`` log by running ``AiboBeacons-v0`` with an exploration policy."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from aibo_core.actions import attempted_velocities
from aibo_core.trajectory import Trajectory

from . import ENV_ID, __version__
from .envs.aibo_beacons import AiboBeaconsEnv
from .policies import make_policy as _make_policy
from .policies import validate_policy


def truth_of(env: AiboBeaconsEnv, spurious: list[int] | None = None) -> dict[str, Any]:
    """The ground truth of a (reset) env, as recorded in ``meta["truth"]`` (a contract: keep keys).

    velocities: 40 x 3 true velocities (mm/s, mm/s, rad/s); motion_noise_std: per-frame
    robot-frame slip std (mm, mm, rad); motion_noise_cov (only with config ``slip_cov``, which then
    replaces the std): the 3 x 3 slip covariance (mm^2, rad^2);
    big_slip_prob; sensor: pinhole model with height_px_mm = focal_px * beacon_height_mm (height
    px = height_px_mm / d mm), or ``{"model": "curve", "basis", "coef"}`` (config ``sensor_curve``);
    sigma_height px; sigma_angle rad; effects: validated effect parameters; start_pose;
    spurious_sightings (only when an enabled effect can create sightings, ``env.max_sightings`` > 1):
    the indices into the log's sighting arrays of the spurious (false) sightings.
    """
    cfg = env.config
    truth = {
        "velocities": env.velocities.tolist(),
        "motion_noise_std": list(cfg["slip_std"]),
        "big_slip_prob": cfg["big_slip_prob"],
        "sensor": ({"model": "pinhole", "height_px_mm": cfg["focal_px"] * cfg["beacon_height_mm"]}
                   if cfg["sensor_curve"] is None else {"model": "curve", **cfg["sensor_curve"]}),
        "sigma_height": env.sigma_height,
        "sigma_angle": env.sigma_angle,
        "effects": copy.deepcopy(cfg["effects"]),
        "start_pose": [float(v) for v in env.start_pose],
    }
    if cfg["slip_cov"] is not None:
        truth["motion_noise_cov"] = [list(row) for row in cfg["slip_cov"]]
    if env.max_sightings > 1:
        truth["spurious_sightings"] = [] if spurious is None else [int(i) for i in spurious]
    return truth


def _record_sightings(
    sightings: dict[str, Any], t: int, frame: list[int], landmark: list[int],
    value: list[tuple[float, float]], spurious: list[int],
) -> None:
    """Append every sighting of frame ``t`` (``info["sightings"]``) to the log's lists, in report order."""
    for j in range(sightings["count"]):
        if sightings["spurious"][j]:
            spurious.append(len(frame))
        frame.append(t)
        landmark.append(int(sightings["beacon"][j]))
        value.append((float(sightings["height"][j]), float(sightings["angle"][j])))


def policy_spec(policy: Any, localizer: str | None = None, params: dict[str, Any] | None = None) -> dict[str, Any]:
    """The validated spec ``{name, params}`` of ``policy`` (a name, ``"sb3:PATH"`` or a spec) with
    ``params`` and ``localizer`` (for policies that have one) merged in."""
    spec = validate_policy(policy)
    extra = dict(params or {})
    if localizer is not None:
        if "localizer" not in spec["params"]:
            if localizer != "ekf":
                raise ValueError(f"policy '{spec['name']}' always uses its onboard EKF (localizer {localizer!r} not available)")
        else:
            extra["localizer"] = localizer
    return validate_policy({"name": spec["name"], "params": {**spec["params"], **extra}})


def make_policy(policy: Any, config: dict[str, Any], seed: int, localizer: str | None = None):
    """A policy by name or spec (``aibo_gym.policies``); ValueError naming the valid choices otherwise."""
    return _make_policy(policy_spec(policy, localizer), config, seed)


def collect(
    config: dict[str, Any] | None,
    steps: int,
    seed: int,
    policy: Any = "random-balanced",
    localizer: str | None = None,
    progress: bool = False,
    policy_params: dict[str, Any] | None = None,
) -> Trajectory:
    """Run the env for ``steps`` frames (fewer if it terminates) and return the log.

    ``policy``: a policy spec (``aibo_gym.policies``: a name, ``"sb3:AGENT.zip"``, ``{"name",
    "params"}``); ``policy_params`` and ``localizer`` override its parameters.

    The env is stepped unwrapped (no wrapper overhead); the result equals stepping
    ``gym.make("AiboBeacons-v0", config=config)`` reset with ``seed`` and the same policy.
    """
    _check_steps(steps)
    env = AiboBeaconsEnv(config)
    spec = policy_spec(policy, localizer, policy_params)
    pol = _make_policy(spec, env.config, seed)
    meta = {"policy": spec["name"], "policy_params": spec["params"], "localizer": spec["params"].get("localizer", "ekf")}
    return _run(env, pol.reset, pol.act, steps, seed, None, progress, meta)


def replay(
    config: dict[str, Any] | None,
    actions: np.ndarray,
    seed: int,
    head_pan: np.ndarray | None = None,
    source: str = "",
    progress: bool = False,
) -> Trajectory:
    """Step the env through the given commands (a measured log's ``actions``) and return the log.

    ``head_pan`` (rad, one per step): the pans to use instead of the config's sinusoid (a measured
    log's); ``source`` is recorded in ``meta["replay_of"]``. The episode ends early only if the env
    terminates (``walls="none"``).
    """
    actions = np.asarray(actions)
    if actions.ndim != 1 or len(actions) == 0 or not np.issubdtype(actions.dtype, np.integer):
        raise ValueError("replay: actions must be a non-empty 1-d array of command indices")
    env = AiboBeaconsEnv(dict(config or {}, max_steps=len(actions)))
    it = iter(actions.tolist())
    options = None if head_pan is None else {"head_pan": head_pan}
    meta = {"policy": "replay", "policy_params": {}, "localizer": "none", "replay_of": source}
    return _run(env, lambda info: None, lambda obs, info: next(it), len(actions), seed, options, progress, meta)


def _check_steps(steps: Any) -> None:
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"steps must be a positive integer, got {steps!r}")


def _run(env: AiboBeaconsEnv, reset, act, steps: int, seed: int, options: dict[str, Any] | None,
         progress: bool, meta: dict[str, Any]) -> Trajectory:
    """Reset ``env`` with ``seed`` (and ``options``), call ``reset(info)``, step ``act(obs, info)`` for
    up to ``steps`` frames and record the log; ``meta`` adds the policy's keys to the log's meta."""
    obs, info = env.reset(seed=seed, options=options)
    reset(info)
    actions = np.empty(steps, dtype=np.int64)
    s_frame: list[int] = []
    s_landmark: list[int] = []
    s_value: list[tuple[float, float]] = []
    s_spurious: list[int] = []
    pan = np.empty(steps)
    pose = np.empty((steps + 1, 3))
    pose[0] = info["pose"]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, unit="frame", desc="collect")
    n = 0
    for t in range(steps):
        a = act(obs, info)
        obs, _, terminated, truncated, info = env.step(a)
        actions[t] = a
        _record_sightings(info["sightings"], t, s_frame, s_landmark, s_value, s_spurious)
        pan[t] = info["head_pan"]
        pose[t + 1] = info["pose"]
        n = t + 1
        if bar is not None and n % 1000 == 0:
            bar.update(1000)
        if terminated or truncated:
            break
    if bar is not None:
        bar.update(n - bar.n)
        bar.close()
    meta = {
        "generator": f"aibo_gym {__version__} {ENV_ID}",
        "seed": seed,
        **meta,
        "config": copy.deepcopy(env.config),
        "truth": truth_of(env, s_spurious),
    }
    return Trajectory(
        dt=env.dt,
        landmarks=np.asarray(env.config["beacons"], dtype=float),
        sighting_frame=np.asarray(s_frame, dtype=np.int64),
        sighting_landmark=np.asarray(s_landmark, dtype=np.int64),
        sighting_value=np.asarray(s_value, dtype=float).reshape(-1, 2),
        sensor_kind="height_px",
        actions=actions[:n],
        attempted=attempted_velocities(),
        head_pan=pan[:n],
        field=np.asarray(env.config["field"], dtype=float),
        pose=pose[: n + 1],
        meta=meta,
    )
