"""The effects extension point."""

from __future__ import annotations

import numpy as np
import pytest

from aibo_gym.collect import collect
from aibo_gym.effects import EFFECTS, Effect, register_effect
from aibo_gym.envs import AiboBeaconsEnv


def test_height_bias_shifts_heights_by_exactly_its_offset():
    base = collect(None, 3000, seed=7)
    biased = collect({"effects": {"height_bias": {"offset_px": 2.5}}}, 3000, seed=7)
    np.testing.assert_array_equal(base.pose, biased.pose)
    np.testing.assert_array_equal(base.sighting_frame, biased.sighting_frame)
    np.testing.assert_array_equal(base.sighting_landmark, biased.sighting_landmark)
    assert base.n_sightings > 500
    np.testing.assert_allclose(biased.sighting_value[:, 0] - base.sighting_value[:, 0], 2.5, atol=1e-12)
    np.testing.assert_array_equal(biased.sighting_value[:, 1], base.sighting_value[:, 1])
    assert biased.truth["effects"] == {"height_bias": {"offset_px": 2.5}}
    assert base.truth["effects"] == {}


def test_drift_adds_a_constant_robot_frame_displacement():
    config = {"velocities": np.zeros((40, 3)), "slip_std": [0, 0, 0], "start_pose": [0.0, 0.0, np.pi / 2],
              "effects": {"drift": {"disp": [2.0, 0.0, 0.0]}}}
    env = AiboBeaconsEnv(config)
    env.reset(seed=0)
    for _ in range(10):
        pose = env.step(0)[4]["pose"]
    np.testing.assert_allclose(pose, [0.0, 20.0, np.pi / 2], atol=1e-9)


def test_default_params_are_filled_in():
    tr = collect({"effects": {"drift": {}}}, 5, seed=0)
    assert tr.truth["effects"] == {"drift": {"disp": [0.0, 0.0, 0.0]}}


def test_unknown_effect_and_param_errors():
    with pytest.raises(ValueError) as err:
        AiboBeaconsEnv({"effects": {"wobble": {}}})
    assert "'wobble'" in str(err.value) and "height_bias" in str(err.value) and "drift" in str(err.value)
    with pytest.raises(ValueError) as err:
        AiboBeaconsEnv({"effects": {"height_bias": {"offset": 1.0}}})
    assert "'offset'" in str(err.value) and "offset_px" in str(err.value)
    with pytest.raises(ValueError, match="offset_px"):
        AiboBeaconsEnv({"effects": {"height_bias": {"offset_px": "big"}}})
    with pytest.raises(ValueError, match="disp"):
        AiboBeaconsEnv({"effects": {"drift": {"disp": [1.0, 2.0]}}})


def test_a_new_effect_plugs_in_by_name():
    @register_effect
    class Mirror(Effect):
        name = "test_mirror"
        defaults = {"scale": 1.0}

        def sense(self, sightings, frame):
            for s in sightings:
                s.angle = -self.params["scale"] * s.angle
            return sightings

    try:
        base = collect(None, 2000, seed=1)
        mirrored = collect({"effects": {"test_mirror": {}}}, 2000, seed=1)
        np.testing.assert_allclose(mirrored.sighting_value[:, 1], -base.sighting_value[:, 1], atol=1e-12)
    finally:
        EFFECTS.pop("test_mirror")
