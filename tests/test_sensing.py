"""Camera geometry and sensor noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aibo_gym.camera import Camera, head_pan
from aibo_gym.collect import collect
from aibo_gym.config import make_config
from aibo_gym.envs import AiboBeaconsEnv

EXACT = {"sigma_height": 0.0, "sigma_angle": 0.0, "detect_prob": 1.0}


def camera(beacons, **kw) -> Camera:
    cfg = make_config({"beacons": beacons, **EXACT, **kw})
    return Camera(cfg, 0.0, 0.0)


def polar(d, bearing):
    return [d * math.cos(bearing), d * math.sin(bearing)]


def test_pinhole_height_and_straight_ahead_angle():
    for d in (1300.0, 2000.0, 4100.0):
        s = camera([polar(d, 0.0)]).sight(0, 0, 0, 0, 0.0, 0.0, 0.0)
        assert (s.beacon, s.angle, s.spurious) == (0, 0.0, False)
        assert s.height == pytest.approx(57000.0 / d) == s.true_height and s.distance == pytest.approx(d)
    cam = camera([[2000.0, 0.0]], focal_px=100.0, beacon_height_mm=200.0)
    assert cam.sight(0, 0, 0, 0, 0.0, 0.0, 0.0).height == pytest.approx(10.0)


def test_sighting_truth_fields():
    cam = Camera(make_config({"beacons": [polar(2000, 0.3)]}), 1.0, 0.1)
    s = cam.sight(0, 0, 0, 0.5, 0.0, 2.0, -1.0)  # noises: +2 sigma height, -1 sigma angle
    assert s.height == pytest.approx(57000.0 / 2000 + 2.0) and s.true_height == pytest.approx(57000.0 / 2000)
    assert s.angle == pytest.approx(0.2) and s.bearing == pytest.approx(0.3)
    assert s.image_angle == pytest.approx(-0.2)  # the beacon is 0.2 rad right of the image centre


def test_outside_fov_not_seen():
    half = 0.99 / 2
    assert camera([polar(2000, half - 0.01)]).nearest_visible(0, 0, 0, 0) is not None
    assert camera([polar(2000, half + 0.01)]).nearest_visible(0, 0, 0, 0) is None
    assert camera([polar(2000, -half - 0.01)]).nearest_visible(0, 0, 0, 0) is None
    assert camera([polar(2000, math.pi)]).nearest_visible(0, 0, 0, 0) is None
    # the head pan moves the field of view; the angle stays relative to the body
    assert camera([polar(2000, 1.0)]).sight(0, 0, 0, 0.8, 0.0, 0.0, 0.0).angle == pytest.approx(1.0)
    assert camera([polar(2000, 1.0)]).nearest_visible(0, 0, 0, 0.4) is None


def test_outside_range_not_seen():
    assert camera([polar(1200, 0.0)]).nearest_visible(0, 0, 0, 0) is None
    assert camera([polar(4200, 0.0)]).nearest_visible(0, 0, 0, 0) is None
    assert camera([polar(4200, 0.0)], range_mm=[100, 5000]).nearest_visible(0, 0, 0, 0) is not None


def test_nearest_to_image_centre_is_chosen():
    # beacon 0 is closer in distance but further from the image centre
    cam = camera([polar(1500, 0.3), polar(3500, -0.1), polar(2500, 0.2)])
    s = cam.sight(0, 0, 0, 0, 0.0, 0.0, 0.0)
    assert s.beacon == 1 and s.angle == pytest.approx(-0.1) and s.height == pytest.approx(57000 / 3500)
    assert cam.sight(0, 0, 0, 0.22, 0.0, 0.0, 0.0).beacon == 2  # pan toward +0.22: beacon 2 (0.2) is nearest


def test_angle_is_ccw_positive_from_body_heading():
    cam = camera([[0.0, 2000.0], [0.0, -2000.0]])
    s = cam.sight(0, 0, 0, math.pi / 2, 0.0, 0.0, 0.0)
    assert s.beacon == 0 and s.angle == pytest.approx(math.pi / 2)  # left of the robot: positive
    s = cam.sight(0, 0, 0, -math.pi / 2, 0.0, 0.0, 0.0)
    assert s.beacon == 1 and s.angle == pytest.approx(-math.pi / 2)
    # robot facing +y, beacon to its right (+x): negative angle
    cam = camera([[2000.0, 0.0]])
    assert cam.sight(0, 0, math.pi / 2, -math.pi / 2, 0.0, 0.0, 0.0).angle == pytest.approx(-math.pi / 2)
    # angles are wrapped: beacon behind-left of a robot facing -x
    cam = camera([polar(2000, math.pi - 0.2)])
    assert cam.sight(0, 0, math.pi - 0.1, 0.0, 0.0, 0.0, 0.0).angle == pytest.approx(-0.1)


def test_detection_probability_draw():
    cam = camera([[2000.0, 0.0]], detect_prob=0.9)
    assert cam.sight(0, 0, 0, 0, 0.89, 0.0, 0.0) is not None
    assert cam.sight(0, 0, 0, 0, 0.91, 0.0, 0.0) is None


def test_head_pan():
    assert head_pan(0.0, 1.4, 3.0) == 0.0
    assert head_pan(0.75, 1.4, 3.0) == pytest.approx(1.4)
    assert head_pan(2.25, 1.4, 3.0) == pytest.approx(-1.4)


def test_env_sightings_match_true_geometry_without_noise():
    tr = collect(EXACT, 3000, seed=0)
    seen = tr.sighting_frame
    assert len(seen) > 1000
    pose = tr.pose[seen + 1]  # sighting of frame t is of pose t+1
    b = tr.landmarks[tr.sighting_landmark]
    d = np.hypot(b[:, 0] - pose[:, 0], b[:, 1] - pose[:, 1])
    bearing = np.arctan2(b[:, 1] - pose[:, 1], b[:, 0] - pose[:, 0]) - pose[:, 2]
    np.testing.assert_allclose(tr.sighting_value[:, 0], 57000.0 / d, rtol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (tr.sighting_value[:, 1] - bearing))), 0.0, atol=1e-9)
    assert np.all((d >= 1275) & (d <= 4175))
    off = np.angle(np.exp(1j * (tr.sighting_value[:, 1] - tr.head_pan[seen])))
    assert np.all(np.abs(off) <= 0.99 / 2 + 1e-9)
    np.testing.assert_allclose(tr.head_pan, 1.4 * np.sin(2 * np.pi * (np.arange(1, 3001) / 30) / 3.0), atol=1e-12)


@pytest.mark.parametrize("preset, sh, sa", [("paper-sim", 1.0, 0.5), ("aibo", 1.59, 0.0267)])
def test_noise_presets(preset, sh, sa):
    tr = collect({"noise": preset}, 12000, seed=1)
    seen = tr.sighting_frame
    pose = tr.pose[seen + 1]
    b = tr.landmarks[tr.sighting_landmark]
    d = np.hypot(b[:, 0] - pose[:, 0], b[:, 1] - pose[:, 1])
    bearing = np.arctan2(b[:, 1] - pose[:, 1], b[:, 0] - pose[:, 0]) - pose[:, 2]
    rh = tr.sighting_value[:, 0] - 57000.0 / d
    ra = np.angle(np.exp(1j * (tr.sighting_value[:, 1] - bearing)))
    assert np.std(rh) == pytest.approx(sh, rel=0.05)
    assert np.std(ra) == pytest.approx(sa, rel=0.06)  # wrapping barely matters at 0.5 rad
    assert abs(np.mean(rh)) < 0.05 * sh


def test_explicit_sigmas_override_preset():
    env = AiboBeaconsEnv({"noise": "aibo", "sigma_height": 2.0})
    assert (env.sigma_height, env.sigma_angle) == (2.0, 0.0267)


def test_detect_prob_fraction():
    tr = collect({"detect_prob": 0.5}, 6000, seed=3)
    full = collect({"detect_prob": 1.0}, 6000, seed=3)
    assert np.array_equal(tr.pose, full.pose)  # detection does not change the random stream
    visible = np.isin(np.arange(6000), full.sighting_frame)
    seen = np.isin(np.arange(6000), tr.sighting_frame)
    assert not np.any(seen & ~visible)
    assert np.mean(seen[visible]) == pytest.approx(0.5, abs=0.03)
