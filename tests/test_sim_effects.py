"""The effect catalogue's simulator twins against known answers, the frame context, the own streams."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aibo_gym.catalogue import REFERENCE_DISTANCE_MM
from aibo_gym.collect import collect
from aibo_gym.context import NO_COMMAND
from aibo_gym.effects import EFFECTS, Effect, register_effect
from aibo_gym.envs import AiboBeaconsEnv

#: The catalogue (the simulator twins in ``aibo_gym.catalogue``): name -> its parameter names.
CATALOGUE = {name: sorted(cls.defaults) for name, cls in EFFECTS.items() if cls.__module__ == "aibo_gym.catalogue"}
EXACT_SENSING = {"sigma_height": 0.0, "sigma_angle": 0.0, "detect_prob": 1.0}
DT = 1 / 30


def still_robot(velocities: dict[int, list[float]], **config) -> AiboBeaconsEnv:
    """No slip; the given actions' velocities (mm/s, mm/s, rad/s), the others zero."""
    v = np.zeros((40, 3))
    for a, vel in velocities.items():
        v[a] = vel
    return AiboBeaconsEnv({"velocities": v, "slip_std": [0, 0, 0], **config})


def run(env: AiboBeaconsEnv, actions, seed: int = 0) -> tuple[np.ndarray, list[dict]]:
    info = env.reset(seed=seed)[1]
    poses, infos = [info["pose"]], []
    for a in actions:
        info = env.step(a)[4]
        poses.append(info["pose"])
        infos.append(info)
    return np.array(poses), infos


def true_geometry(tr) -> tuple[np.ndarray, np.ndarray]:
    """(distance mm, bearing rad from the heading) of each sighting's beacon from the true pose."""
    pose = tr.pose[tr.sighting_frame + 1]
    b = tr.landmarks[tr.sighting_landmark]
    d = np.hypot(b[:, 0] - pose[:, 0], b[:, 1] - pose[:, 1])
    return d, np.arctan2(b[:, 1] - pose[:, 1], b[:, 0] - pose[:, 0]) - pose[:, 2]


def wrapped(a: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * a))


# ---------------------------------------------------------------- the contract
def test_catalogue_names_and_parameters_are_the_contract():
    """Every simulator twin has a learner twin of the same name and parameter names, and back."""
    from learners.model.effects import EFFECT_MODELS

    assert len(CATALOGUE) >= 10 and set(CATALOGUE) == set(EFFECT_MODELS)
    for name, params in CATALOGUE.items():
        assert sorted(EFFECT_MODELS[name].PARAMS) == params, name
        doc = EFFECTS[name].__doc__
        assert "Residual signature" in doc and len(doc.strip().splitlines()[0]) > 20


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_defaults_are_neutral(name):
    base = collect(None, 1500, seed=3)
    neutral = collect({"effects": {name: {}}}, 1500, seed=3)
    for key in ("pose", "sighting_frame", "sighting_landmark", "sighting_value"):
        np.testing.assert_array_equal(getattr(neutral, key), getattr(base, key))
    assert set(neutral.truth["effects"][name]) == set(CATALOGUE[name])


@pytest.mark.parametrize("name", sorted(n for n, p in CATALOGUE.items() if p))
def test_unknown_parameter_names_the_valid_ones(name):
    with pytest.raises(ValueError, match=f"effect '{name}': unknown parameter 'wrong' .*{CATALOGUE[name][0]}"):
        AiboBeaconsEnv({"effects": {name: {"wrong": 1.0}}})


@pytest.mark.parametrize("effects, words", [
    ({"false_sightings": {"rate": 0.6}}, ["'rate'", "[0, 0.5]"]),
    ({"actuation_lag": {"lag_s": -0.1}}, ["'lag_s'", "[0, inf]"]),
    ({"beacon_height_scale": {"scale": [1.0, 2.0]}}, ["'scale'", "4 beacons"]),
    ({"beacon_height_scale": {"scale": [1.0, 0.0, 1.0, 1.0]}}, ["'scale'"]),
    ({"off_center_shrink": {"k": 5.0}}, ["'k'", "fov"]),
    ({"landmark_bearing_offset": {"offset_rad": [0.01, -0.01]}}, ["'offset_rad'", "4 beacons"]),
    ({"landmark_bearing_offset": {"offset_rad": [0.01, 4.0, 0.0, 0.0]}}, ["'offset_rad'", "[-3.14159, 3.14159]"]),
    ({"floor_drift": {"drift_mm_s": [1.0]}}, ["'drift_mm_s'", "2 numbers"]),
])
def test_bad_parameters_give_one_clear_line(effects, words):
    with pytest.raises(ValueError) as err:
        AiboBeaconsEnv({"effects": effects})
    assert "\n" not in str(err.value) and all(w in str(err.value) for w in words)


def test_wall_contact_needs_walls():
    with pytest.raises(ValueError, match="'wall_contact'.*'walls'.*'none'"):
        AiboBeaconsEnv({"walls": "none", "effects": {"wall_contact": {}}})


# ---------------------------------------------------------------- context and streams
@pytest.fixture
def recorder():
    @register_effect
    class Recorder(Effect):
        name = "test_recorder"
        frames: list = []

        def motion(self, m, frame):
            assert frame.pose_after is None and frame.wall_contact is False
            return m

        def sense(self, sightings, frame):
            Recorder.frames.append((frame.index, frame.time, frame.command, frame.previous_command,
                                    frame.command_start, frame.since_command, frame.pose_before,
                                    frame.pose_after, frame.head_pan, frame.wall_contact, frame.field, frame.dt))
            return sightings

    yield Recorder
    EFFECTS.pop("test_recorder")


def test_the_frame_context(recorder):
    env = still_robot({16: [300.0, 0.0, 0.0]}, start_pose=[2680.0, 0.0, 0.0], effects={"test_recorder": {}})
    poses, infos = run(env, [5, 5, 16, 16, 16, 5])
    f = recorder.frames
    assert [r[0] for r in f] == list(range(6)) and [r[1] for r in f] == pytest.approx([t * DT for t in range(6)])
    assert [r[2] for r in f] == [5, 5, 16, 16, 16, 5]
    assert [r[3] for r in f] == [NO_COMMAND, NO_COMMAND, 5, 5, 5, 16]
    assert [r[4] for r in f] == [0, 0, 2, 2, 2, 5]
    assert [r[5] for r in f] == pytest.approx([0, DT, 0, DT, 2 * DT, 0])
    assert [r[6] for r in f] == [tuple(p) for p in poses[:-1]] and [r[7] for r in f] == [tuple(p) for p in poses[1:]]
    assert [r[8] for r in f] == [i["head_pan"] for i in infos]
    assert [r[9] for r in f] == [False, False, False, False, True, False]  # 2680 + 3 * 10 mm passes the wall at 2700
    assert [i["wall_contact"] for i in infos] == [r[9] for r in f]
    assert f[0][10] == (5400.0, 3600.0) and f[0][11] == DT


def test_an_effect_with_its_own_draws_leaves_the_base_stream_alone():
    base = collect(None, 3000, seed=8)
    noisy = collect({"effects": {"false_sightings": {"rate": 0.3}, "angle_bias": {"bias_rad": 0.0}}}, 3000, seed=8)
    np.testing.assert_array_equal(noisy.pose, base.pose)
    real = np.setdiff1d(np.arange(noisy.n_sightings), noisy.truth["spurious_sightings"])
    assert len(real) == base.n_sightings and len(real) < noisy.n_sightings
    np.testing.assert_array_equal(noisy.sighting_frame[real], base.sighting_frame)
    np.testing.assert_array_equal(noisy.sighting_value[real], base.sighting_value)
    again = collect({"effects": {"false_sightings": {"rate": 0.3}}}, 3000, seed=8)
    np.testing.assert_array_equal(again.sighting_value, noisy.sighting_value)
    other = collect({"effects": {"false_sightings": {"rate": 0.3}}}, 3000, seed=9)
    assert other.truth["spurious_sightings"] != noisy.truth["spurious_sightings"]


# ---------------------------------------------------------------- motion twins
def test_actuation_lag_delays_each_command_by_lag_s():
    env = still_robot({1: [300.0, 0.0, 0.0], 2: [0.0, -150.0, 0.0]}, effects={"actuation_lag": {"lag_s": 0.1}})
    poses, _ = run(env, [1] * 10 + [2] * 10)
    step = np.diff(poses[:, :2], axis=0)
    expected = np.array([[0.0, 0.0]] * 3 + [[10.0, 0.0]] * 10 + [[0.0, -5.0]] * 7)  # 0.1 s = 3 frames late
    np.testing.assert_allclose(step, expected, atol=1e-9)


def test_floor_drift_moves_a_stationary_robot_in_the_world_frame():
    env = still_robot({}, start_pose=[0.0, 0.0, math.pi / 3], effects={"floor_drift": {"drift_mm_s": [30.0, -60.0]}})
    poses, _ = run(env, [7] * 30)
    np.testing.assert_allclose(np.diff(poses[:, :2], axis=0), [[1.0, -2.0]] * 30, atol=1e-9)
    np.testing.assert_allclose(poses[:, 2], math.pi / 3)


def test_velocity_fade_loses_the_stated_fraction_per_minute():
    env = still_robot({0: [0.0, 0.0, 0.6]}, effects={"velocity_fade": {"fade_per_min": 0.5}})
    poses, _ = run(env, [0] * 4000)
    turn = wrapped(np.diff(poses[:, 2]))
    assert turn[0] == pytest.approx(0.6 * DT)
    assert turn[900] == pytest.approx(0.6 * DT * 0.75)  # 30 s: a quarter lost
    assert turn[1800] == pytest.approx(0.6 * DT * 0.5, abs=1e-12)  # 1 min: half
    assert np.all(turn[3600:] == 0.0)  # 2 min: standing


@pytest.mark.parametrize("walls", ["clamp", "pymunk"])
def test_wall_contact_the_walls_stop_the_robot(walls):
    config = {"walls": walls, "start_pose": [2000.0, 0.0, 0.0], "effects": {"wall_contact": {}}}
    poses, infos = run(still_robot({16: [300.0, 0.0, 0.0]}, **config), [16] * 120)
    edge = 2700.0 - (150.0 if walls == "pymunk" else 0.0)
    first = int(np.argmax(2000.0 + 10.0 * np.arange(1, 121) > edge + 1e-6))
    assert [i["wall_contact"] for i in infos] == [False] * first + [True] * (120 - first)
    np.testing.assert_allclose(poses[first + 1 :, 0], edge)


# ---------------------------------------------------------------- sensing twins
def test_angle_bias_shifts_every_bearing_by_exactly_the_bias():
    base = collect(EXACT_SENSING, 3000, seed=2)
    biased = collect({**EXACT_SENSING, "effects": {"angle_bias": {"bias_rad": 0.2}}}, 3000, seed=2)
    np.testing.assert_array_equal(biased.sighting_value[:, 0], base.sighting_value[:, 0])
    np.testing.assert_allclose(wrapped(biased.sighting_value[:, 1] - base.sighting_value[:, 1]), 0.2, atol=1e-12)


@pytest.mark.parametrize("wheeled", [False, True])
def test_landmark_bearing_offset_shifts_each_beacons_bearings_by_its_offset(wheeled):
    """Both envs: the same seed with and without the offsets, every bearing moved by its beacon's offset exactly."""
    from aibo_gym.collect_wheeled import collect_wheeled

    if wheeled:
        offset = [0.03, -0.02, 0.01, 0.0, -0.01, 0.02, -0.03, 0.005]  # the wheeled env's default field: 8 landmarks
        base = collect_wheeled({}, 1500, seed=2)
        shifted = collect_wheeled({"effects": {"landmark_bearing_offset": {"offset_rad": offset}}}, 1500, seed=2)
    else:
        offset = [0.03, -0.02, 0.01, 0.0]
        base = collect(EXACT_SENSING, 3000, seed=2)
        shifted = collect({**EXACT_SENSING, "effects": {"landmark_bearing_offset": {"offset_rad": offset}}}, 3000, seed=2)
    np.testing.assert_array_equal(shifted.sighting_landmark, base.sighting_landmark)
    np.testing.assert_array_equal(shifted.sighting_value[:, 0], base.sighting_value[:, 0])
    moved = wrapped(shifted.sighting_value[:, 1] - base.sighting_value[:, 1])
    np.testing.assert_allclose(moved, np.array(offset)[base.sighting_landmark], atol=1e-12)
    assert len(set(base.sighting_landmark)) >= 4


def test_beacon_height_scale_multiplies_each_beacons_heights():
    scale = [1.0, 1.5, 0.8, 1.2]
    tr = collect({**EXACT_SENSING, "effects": {"beacon_height_scale": {"scale": scale}}}, 6000, seed=2)
    d, _ = true_geometry(tr)
    ratio = tr.sighting_value[:, 0] / (57000.0 / d)
    np.testing.assert_allclose(ratio, np.array(scale)[tr.sighting_landmark], rtol=1e-12)
    assert set(tr.sighting_landmark) == {0, 1, 2, 3}
    assert collect({"effects": {"beacon_height_scale": {}}}, 5, seed=0).truth["effects"] == {
        "beacon_height_scale": {"scale": [1.0, 1.0, 1.0, 1.0]}}


def test_off_center_shrink_matches_the_formula():
    tr = collect({**EXACT_SENSING, "effects": {"off_center_shrink": {"k": 0.8}}}, 6000, seed=4)
    d, bearing = true_geometry(tr)
    phi = wrapped(bearing - tr.head_pan[tr.sighting_frame])
    np.testing.assert_allclose(tr.sighting_value[:, 0], 57000.0 / d * (1 - 0.8 * phi**2), rtol=1e-12)
    assert np.abs(phi).max() > 0.4  # sightings reach the image edges (fov/2 = 0.495 rad)


def test_distance_dependent_noise_grows_as_distance_to_the_exponent():
    e = 1.5
    tr = collect({"effects": {"distance_dependent_noise": {"exponent": e}}}, 27000, seed=5)
    d, _ = true_geometry(tr)
    r = tr.sighting_value[:, 0] - 57000.0 / d
    assert np.std(r / (d / REFERENCE_DISTANCE_MM) ** e) == pytest.approx(1.0, rel=0.04)  # preset sigma at 2500 mm
    near, far = d < 2000, d > 3000
    expected = (np.sqrt(np.mean(d[near] ** (2 * e))) / np.sqrt(np.mean(d[far] ** (2 * e))))
    assert np.std(r[near]) / np.std(r[far]) == pytest.approx(expected, rel=0.1)
    assert expected < 0.6  # a large, detectable effect


def test_false_sightings_are_the_stated_fraction_and_plausible():
    tr = collect({"effects": {"false_sightings": {"rate": 0.2}}}, 12000, seed=6)
    spurious = np.zeros(tr.n_sightings, dtype=bool)
    spurious[tr.truth["spurious_sightings"]] = True
    assert spurious.mean() == pytest.approx(0.2, abs=0.02)
    assert np.any(np.bincount(tr.sighting_frame) == 2)  # several sightings in a frame
    off = wrapped(tr.sighting_value[spurious, 1] - tr.head_pan[tr.sighting_frame[spurious]])
    assert np.all(np.abs(off) <= 0.99 / 2 + 1e-9) and np.abs(off).max() > 0.45  # anywhere in the image
    h = tr.sighting_value[spurious, 0]
    assert np.all((h >= 57000 / 4175) & (h <= 57000 / 1275)) and set(tr.sighting_landmark[spurious]) == {0, 1, 2, 3}
