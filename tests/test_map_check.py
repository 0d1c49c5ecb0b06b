"""Landmarks whose sightings disagree with the map (``learners.em.map_check``): the bearings-only point on known
rays, and, through ``aibo learn``, two swapped ids and a moved landmark named on a simulated log where they were
made, and nothing named where there are none (MRCLAM Dataset 1's swap: docs/results.md, "Landmarks where the map does
not put them")."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_gym.collect_wheeled import collect_wheeled
from learners.arrays.batch import make_batch
from learners.em.map_check import MapDisagreement, check, map_warnings, triangulate

SWAPPED = (1, 4)  # landmarks (0, 2800) and (-2500, -2500) mm of WheeledRobot-v0's map, 84 and 102 of 3,962 sightings
MOVED = 7  # (2800, 0) mm: a map that says 1,500 mm further along y


def _log():
    return collect_wheeled({"start_pose": "random"}, 3000, seed=1)


def test_the_point_of_rays_through_one_point_is_that_point_even_with_a_tenth_of_the_rays_elsewhere():
    rng = np.random.default_rng(0)
    origins = rng.uniform(-3000, 3000, (200, 2))
    target = np.array([1000.0, -500.0])
    angles = np.arctan2(*(target - origins).T[::-1])
    point, sd = triangulate(origins, angles)
    np.testing.assert_allclose(point, target, atol=1e-6)
    assert sd < 1e-3
    stray = rng.random(200) < 0.1
    angles[stray] = np.arctan2(*(np.array([-2000.0, 2000.0]) - origins[stray]).T[::-1])
    assert np.hypot(*(triangulate(origins, angles)[0] - target)) < 1.0
    # parallel rays cross nowhere; rays that all point away from their crossing see nothing there
    assert triangulate(origins, np.zeros(200)) is None
    assert triangulate(origins, angles + np.pi) is None


def test_a_moved_landmark_is_placed_where_its_sightings_are_given_the_true_poses():
    """The check on its own, given the poses the log was made with and a fit that left out every sighting of MOVED
    (whose map position is 1,500 mm off): named, at no other landmark, placed within 100 mm of where it is."""
    tr = _log()
    landmarks = tr.landmarks.copy()
    landmarks[MOVED] += [0.0, 1500.0]
    batch = make_batch([replace(tr, landmarks=landmarks)])
    (found,) = check(batch, tr.pose, batch.sight_landmark != MOVED)
    assert (found.landmark, found.at_landmark, found.swapped) == (MOVED, None, False)
    assert found.bearing_error_rad > 0.2 and found.left_out == found.sightings
    assert np.hypot(*(np.array(found.seen_xy) - tr.landmarks[MOVED])) < 100.0 and found.seen_sd_mm < 50.0
    (line,) = map_warnings([found])
    assert "map position may be wrong" in line and f"landmark {MOVED} (map (2,800, 1,500) mm)" in line
    # sightings left out that still point at their map position are no map error (their sizes, their noise)
    assert check(make_batch([tr]), tr.pose, make_batch([tr]).sight_landmark != MOVED) == []


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    """``aibo learn``'s info on a 5-minute wheeled log as it was made, and with the ids of SWAPPED exchanged in its
    sightings (5% of them)."""
    tmp = tmp_path_factory.mktemp("map")
    tr = _log()
    a, b = SWAPPED
    ids = tr.sighting_landmark.copy()
    ids[tr.sighting_landmark == a], ids[tr.sighting_landmark == b] = b, a
    out = {}
    for name, log, options in (("right", tr, []), ("swapped", replace(tr, sighting_landmark=ids), []),
                               ("as given", replace(tr, sighting_landmark=ids), ["--no-map-repair"])):
        trajectory.save(log, tmp / "log.npz")
        assert main(["learn", str(tmp / "log.npz"), "--out", str(tmp / "model.json"), "--no-resume", *options]) == 0
        out[name] = json.loads((tmp / "model.json").read_text())
        assert sorted(p.name for p in tmp.iterdir()) == ["log.npz", "model.json"]  # no stage's checkpoint left behind
    return out


def test_a_log_whose_map_is_right_names_no_landmark(fits):
    info = fits["right"]["info"]
    assert info["map_check"] == [] and "map_repair" not in info
    assert not [w for w in info["warnings"] if "the map and the sightings disagree" in w]


def test_swapped_ids_are_exchanged_back_and_the_model_is_the_right_logs(fits):
    """The repaired log is the log as it was made, so the default's model is the right log's, number for number;
    ``--no-map-repair`` names the pair and keeps the map as given (a model fitted without their sightings)."""
    info = fits["swapped"]["info"]
    a, b = SWAPPED
    assert info["map_repair"] == {"exchanged": [[a, b, sum(d["sightings"] for d in info["map_check"])]]}
    assert fits["swapped"]["action_model"] == fits["right"]["action_model"]
    assert fits["swapped"]["sensor_model"] == fits["right"]["sensor_model"]
    said = [w for w in info["warnings"] if "fitted again" in w]
    assert len(said) == 1 and f"landmarks {a} and {b}'s ids exchanged in their 186 sightings" in said[0]
    given = fits["as given"]["info"]
    assert given["map_check"] == info["map_check"] and "map_repair" not in given
    assert fits["as given"]["action_model"] != fits["right"]["action_model"]


def test_swapped_ids_are_named_as_a_pair_in_one_line(fits):
    found = {d["landmark"]: d for d in fits["swapped"]["info"]["map_check"]}
    assert set(found) == set(SWAPPED)
    a, b = SWAPPED
    for lm, other in ((a, b), (b, a)):
        d = found[lm]
        assert d["swapped"] and d["at_landmark"] == other and d["left_out"] == d["sightings"]
        assert d["at_bearing_error_rad"] < 0.05 < 1.0 < d["bearing_error_rad"]
    (said,) = [w for w in fits["as given"]["info"]["warnings"] if "the map and the sightings disagree" in w]
    assert f"landmark {a} " in said and f"landmark {b}'s" in said and "ids look swapped" in said, said


def test_the_warnings_say_one_line_per_landmark_and_one_per_swapped_pair():
    pair = [MapDisagreement(1, 100, 90, (0.0, 0.0), 2.0, 2, 0.02, True, (5e3, 5e3), 20.0),
            MapDisagreement(2, 80, 80, (5e3, 5e3), 1.5, 1, 0.03, True, (0.0, 0.0), 30.0),
            MapDisagreement(4, 50, 40, (1e3, 0.0), 0.4, None, None, False, None, None)]
    lines = map_warnings(pair)
    assert len(lines) == 2 and "swapped" in lines[0] and "(80 of 80 left out)" in lines[0]
    assert "left out 40 of 50 sightings of landmark 4 (map (1,000, 0) mm)" in lines[1] and "put it at" not in lines[1]


@pytest.mark.slow
def test_aibo_diagnose_names_the_swap_and_runs_on_the_repaired_log(tmp_path):
    """The search's base model names the pair; the diagnosis runs on the repaired log, so it sets aside no more than
    a handful of sightings as gross errors (its own outliers: with the map as given, the two landmarks' 186)."""
    from tests._logs import diagnose

    tr = _log()
    a, b = SWAPPED
    ids = tr.sighting_landmark.copy()
    ids[tr.sighting_landmark == a], ids[tr.sighting_landmark == b] = b, a
    report = diagnose(tmp_path, replace(tr, sighting_landmark=ids), "actuation_lag")
    assert {d["landmark"] for d in report["map_check"]} == set(SWAPPED)
    assert report["map_repair"] == {"exchanged": [[a, b, 186]]}
    assert report["outliers"]["set_aside"] <= 0.01 * tr.n_sightings
    assert any("ids look swapped" in w for w in report["warnings"])
    assert any("fitted again" in w and f"landmarks {a} and {b}'s ids exchanged" in w for w in report["warnings"])
