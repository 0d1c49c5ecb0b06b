"""A log as the ``AiboBeacons-v0`` episode that produced it, for offline RL (e.g. a Minari dataset).

:func:`episode_from_log` rebuilds, from an ``aibo-trajectory/2`` log of discrete commands, what the
env returned while the log was recorded: the observations (built by the env's own ``_observation``
from the log's sightings, head pan and commands), the actions, the rewards (the env's, replayed with
its onboard tracker when the log's config asks for a reward; else 0), terminations and truncations,
and per-step infos. Nothing is simulated again: every value comes from the log.

=============  ==========================  =====================================================
key            shape, type                 meaning
=============  ==========================  =====================================================
observations   (T+1, B+7) float32          ``observation_space`` rows; row 0 = the reset's
actions        (T,) int64                  command per frame (``Discrete(40)``)
rewards        (T,) float64                the env's reward (0 with config ``reward="none"``)
terminations   (T,) bool                   True at the last frame only if the robot left the
                                           field with ``walls="none"`` (the env's termination)
truncations    (T,) bool                   True at the last frame otherwise (the log ended)
infos          dict of (T+1, ...) arrays   ``head_pan`` rad; ``sightings``: ``count``,
                                           ``beacon`` (-1 unused), ``height`` px, ``angle`` rad
                                           (K rows, K = most sightings in one frame, >= 1);
                                           ``pose`` (mm, mm, rad) when the log has the true
                                           pose; ``rewards`` (the terms) with a reward
=============  ==========================  =====================================================
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from aibo_core.trajectory import Trajectory

from .context import Sighting
from .envs.aibo_beacons import AiboBeaconsEnv


class LogNotSupported(ValueError):
    """A log that has no ``AiboBeacons-v0`` episode; the message names the log and the field."""


@dataclass
class Episode:
    """One episode's arrays (see the module docstring); ``config`` is the env config it used."""

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray
    infos: dict[str, Any]
    config: dict[str, Any]


def log_config(tr: Trajectory, source: str = "<log>") -> dict[str, Any]:
    """The env config a log was recorded with: its ``meta["config"]``, else one built from the log
    (its landmarks, field and ``dt``; the rest the defaults). LogNotSupported if the env rejects it."""
    if isinstance(tr.meta.get("config"), dict):
        config = copy.deepcopy(tr.meta["config"])
    else:
        config = {"beacons": np.asarray(tr.landmarks).tolist(), "dt": float(tr.dt)}
        if tr.field is not None:
            config["field"] = np.asarray(tr.field).tolist()
    try:
        return AiboBeaconsEnv(config).config
    except ValueError as err:
        raise LogNotSupported(f"{source}: field 'meta': its env config is not one AiboBeacons-v0 accepts ({err})") from None


def episode_from_log(tr: Trajectory, source: str = "<log>") -> Episode:
    """The episode of ``tr`` (see the module docstring); LogNotSupported naming ``source`` and the
    field for a log without one (continuous commands, range sensors, no head pan, other landmarks)."""
    _check_supported(tr, source)
    env = AiboBeaconsEnv(log_config(tr, source))
    if len(env.config["beacons"]) != len(tr.landmarks) or not np.allclose(env.config["beacons"], tr.landmarks):
        raise LogNotSupported(f"{source}: field 'landmarks': they differ from the beacons of the log's config")
    T = tr.n_frames
    actions = np.asarray(tr.actions, dtype=np.int64)
    rows = _frame_rows(tr)
    pans = np.concatenate([[env._pan(0)], np.asarray(tr.head_pan, dtype=float)])
    obs = np.empty((T + 1, env.observation_space.shape[0]), dtype=np.float32)
    obs[0] = env._observation([], pans[0], None)
    for t in range(T):
        first = [] if rows[t].size == 0 else [_sighting(tr, rows[t][0])]
        obs[t + 1] = env._observation(first, pans[t + 1], int(actions[t]))
    rewards, terms = _rewards(env, tr, actions, rows)
    terminated = _left_field(env, tr)
    terminations = np.zeros(T, dtype=bool)
    truncations = np.zeros(T, dtype=bool)
    (terminations if terminated else truncations)[-1] = True
    infos: dict[str, Any] = {"head_pan": pans, "sightings": _sightings_info(tr, rows)}
    if tr.pose is not None:
        infos["pose"] = np.asarray(tr.pose, dtype=float)
    if terms is not None:
        infos["rewards"] = terms
    return Episode(obs, actions, rewards, terminations, truncations, infos, env.config)


def _check_supported(tr: Trajectory, source: str) -> None:
    if not tr.discrete:
        raise LogNotSupported(f"{source}: field 'controls': the log has continuous commands; AiboBeacons-v0 episodes "
                              "have the 40 discrete walk commands (field 'actions') only")
    if tr.sensor_kind != "height_px":
        raise LogNotSupported(f"{source}: field 'sensor_kind': {tr.sensor_kind!r}; the AiboBeacons-v0 observation "
                              "carries a beacon height in px ('height_px' logs only)")
    if tr.head_pan is None:
        raise LogNotSupported(f"{source}: field 'head_pan': missing; the AiboBeacons-v0 observation carries the head pan")
    if tr.n_frames == 0:
        raise LogNotSupported(f"{source}: field 'actions': the log has no frames")


def _frame_rows(tr: Trajectory) -> list[np.ndarray]:
    """Per frame, the indices of its sightings in the log (in report order)."""
    frames = np.asarray(tr.sighting_frame, dtype=np.int64)
    starts = np.searchsorted(frames, np.arange(tr.n_frames + 1))
    return [np.arange(starts[t], starts[t + 1]) for t in range(tr.n_frames)]


def _sighting(tr: Trajectory, i: int) -> Sighting:
    """Sighting ``i`` of the log as the env's record (the truth fields, unknown here, NaN)."""
    h, a = tr.sighting_value[i]
    nan = math.nan
    return Sighting(int(tr.sighting_landmark[i]), float(h), float(a), nan, nan, nan, nan)


def _rewards(env: AiboBeaconsEnv, tr: Trajectory, actions: np.ndarray, rows: list[np.ndarray]):
    """(rewards (T,), {term: (T+1,)} or None): the env's reward, replayed through its onboard
    tracker from the log's commands and sightings; zeros and None with ``reward="none"``."""
    T = len(actions)
    if env.tracker is None:
        return np.zeros(T), None
    env.tracker.reset()
    names = [name for name, _ in env._weights]
    terms = {name: np.zeros(T + 1) for name in names}
    rewards = np.zeros(T)
    value = np.asarray(tr.sighting_value, dtype=float)
    landmark = np.asarray(tr.sighting_landmark)
    for t in range(T):
        seen = [(int(landmark[i]), float(value[i, 0]), float(value[i, 1])) for i in rows[t]]
        frame = env.tracker.step(int(actions[t]), seen)
        rewards[t] = sum(w * frame[name] for name, w in env._weights)
        for name in names:
            terms[name][t + 1] = frame[name]
    return rewards, terms


def _left_field(env: AiboBeaconsEnv, tr: Trajectory) -> bool:
    """The env's termination: with ``walls="none"``, the last true pose is off the field."""
    if env.config["walls"] != "none" or tr.pose is None:
        return False
    x, y = tr.pose[-1][:2]
    return bool(env.walls.outside(float(x), float(y)))


def _sightings_info(tr: Trajectory, rows: list[np.ndarray]) -> dict[str, np.ndarray]:
    """``infos["sightings"]`` as the env's (K rows per step, -1/0 in unused rows; the reset's empty)."""
    T = len(rows)
    k = max([1] + [r.size for r in rows])
    count = np.zeros(T + 1, dtype=np.int64)
    beacon = np.full((T + 1, k), -1, dtype=np.int64)
    height = np.zeros((T + 1, k))
    angle = np.zeros((T + 1, k))
    for t, r in enumerate(rows):
        n = r.size
        count[t + 1] = n
        beacon[t + 1, :n] = tr.sighting_landmark[r]
        height[t + 1, :n] = tr.sighting_value[r, 0]
        angle[t + 1, :n] = tr.sighting_value[r, 1]
    return {"count": count, "beacon": beacon, "height": height, "angle": angle}
