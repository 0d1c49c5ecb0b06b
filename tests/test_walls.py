"""Wall models: the robot never ends a frame off the field (clamp, pymunk); none terminates."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aibo_gym.envs import AiboBeaconsEnv

HALF_L, HALF_W = 2700.0, 1800.0


def drive(config: dict, action: int, frames: int, seed: int = 0) -> tuple[np.ndarray, list[bool]]:
    env = AiboBeaconsEnv(config)
    _, info = env.reset(seed=seed)
    poses, terms = [info["pose"]], []
    for _ in range(frames):
        _, _, term, _, info = env.step(action)
        poses.append(info["pose"])
        terms.append(term)
        if term:
            break
    return np.array(poses), terms


@pytest.mark.parametrize("walls", ["clamp", "pymunk"])
@pytest.mark.parametrize("heading", [0.0, math.pi / 4, 2.0, -math.pi / 2])
def test_driving_into_a_wall_never_leaves_the_field(walls, heading):
    config = {"walls": walls, "start_pose": [0.0, 0.0, heading], "big_slip_prob": 0.2}
    poses, terms = drive(config, 16, 2000)  # action 16: straight ahead, full speed
    assert len(poses) == 2001 and not any(terms)
    assert np.all(np.abs(poses[:, 0]) <= HALF_L) and np.all(np.abs(poses[:, 1]) <= HALF_W)
    assert np.max(np.abs(poses[:, 0]) / HALF_L + np.abs(poses[:, 1]) / HALF_W) > 0.9  # it got there
    if walls == "pymunk":  # the body (radius 150 mm) stays inside the walls
        assert np.all(np.abs(poses[:, 0]) <= HALF_L - 150 + 1e-6)
        assert np.all(np.abs(poses[:, 1]) <= HALF_W - 150 + 1e-6)


@pytest.mark.parametrize("walls", ["clamp", "pymunk"])
def test_huge_slips_never_leave_the_field(walls):
    config = {"walls": walls, "big_slip_prob": 1.0, "big_slip_std": [400.0, 400.0, 1.0]}
    poses, terms = drive(config, 3, 2000)
    assert np.all(np.abs(poses[:, 0]) <= HALF_L) and np.all(np.abs(poses[:, 1]) <= HALF_W)


def _diagonal(walls: str) -> np.ndarray:
    v = np.zeros((40, 3))
    v[0] = [300.0, 300.0, 0.0]  # 45 deg into the +x wall, robot facing +x
    config = {"walls": walls, "velocities": v, "slip_std": [0, 0, 0], "start_pose": [2300.0, -1000.0, 0.0]}
    poses, _ = drive(config, 0, 120)
    return poses


def test_pymunk_slides_along_the_wall():
    poses = _diagonal("pymunk")
    # 300 mm/s * 4 s = 1200 mm of y if nothing stopped it; it meets the wall after ~0.83 s
    assert poses[-1, 0] == pytest.approx(HALF_L - 150, abs=1.0)
    assert poses[-1, 1] - poses[0, 1] > 0.9 * 1200
    assert np.all(np.diff(poses[:, 1]) > 0)  # progress along the wall in every frame
    np.testing.assert_array_equal(poses[:, 2], 0.0)  # walls never turn the robot


def test_clamp_holds_the_position_on_the_edge():
    poses = _diagonal("clamp")
    assert poses[-1, 0] == HALF_L
    assert poses[-1, 1] - poses[0, 1] == pytest.approx(1200.0)


def test_none_terminates_when_leaving():
    poses, terms = drive({"walls": "none"}, 16, 2000)
    assert terms[-1] is True and not any(terms[:-1])
    assert abs(poses[-1, 0]) > HALF_L or abs(poses[-1, 1]) > HALF_W
    assert np.all(np.abs(poses[:-1, 0]) <= HALF_L) and np.all(np.abs(poses[:-1, 1]) <= HALF_W)
    assert len(terms) < 400  # ~2.7 m at ~0.35 m/s


def test_pymunk_is_deterministic_across_resets():
    env = AiboBeaconsEnv({"walls": "pymunk", "start_pose": [2400.0, 1500.0, 0.5]})
    runs = []
    for _ in range(2):
        env.reset(seed=3)
        runs.append([env.step(k % 40)[4]["pose"] for k in range(300)])
    np.testing.assert_array_equal(runs[0], runs[1])
