"""The range curve freed from the held fit (``aibo learn LOG --range-curve held --out held.json``, then ``aibo learn
LOG --range-curve free --init held.json``; in one command ``--range-curve freed``, the default): where a range sensor
reads a few percent long, the second fit finds its curve and the path; where it reads the distance, the curve stays
there (docs/results.md, "The range curve freed from the held fit")."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_gym.collect import collect
from aibo_gym.collect_wheeled import collect_wheeled
from learners.model.io import load_model
from learners.scoring import pose_scores, velocity_scores
from tests.test_mrclam import DATA, needs_data


def _held_then_freed(tr, tmp_path) -> tuple:
    log, held, freed = tmp_path / "log.npz", tmp_path / "held.json", tmp_path / "freed.json"
    trajectory.save(tr, log)
    assert main(["learn", str(log), "--range-curve", "held", "--out", str(held), "--no-resume"]) == 0
    assert main(["learn", str(log), "--range-curve", "free", "--init", str(held), "--out", str(freed), "--no-resume"]) == 0
    return load_model(held), load_model(freed)


@pytest.fixture(scope="module")
def drive():
    """A 5-minute wheeled log (10 frames a second, range = distance)."""
    return collect_wheeled({"start_pose": "random"}, 3000, seed=7)


def test_a_range_read_3_percent_long_plus_50_mm_is_found_and_the_path_follows(drive, tmp_path):
    """The log's ranges rewritten to 1.03 d + 50 mm (another sensor's calibration, not the simulator's): the freed
    curve reads 1,080 and 5,200 mm at 1 and 5 m within 2% (measured: 1,069 and 5,205), and its smoothed pose is less than
    half as far from the truth as the held curve's (measured: 14 against 131 mm RMS)."""
    values = drive.sighting_value.copy()
    values[:, 0] = 1.03 * values[:, 0] + 50.0
    tr = replace(drive, sighting_value=values)
    held, freed = _held_then_freed(tr, tmp_path)
    at = freed.sensor.mean(np.array([1000.0, 5000.0]))
    np.testing.assert_allclose(at, [1080.0, 5200.0], rtol=0.02)
    np.testing.assert_allclose(held.sensor.mean(np.array([1000.0, 5000.0])), [1000.0, 5000.0])
    assert pose_scores(freed, [tr])["pose_rms"] < 0.5 * pose_scores(held, [tr])["pose_rms"]


def test_range_curve_freed_is_the_two_commands_in_one(drive, tmp_path):
    """``aibo learn LOG --range-curve freed``: the held fit, then the curve freed from it, in one command; its curve is
    the two commands' (one start in the second stage, where ``--init`` screens three: the same optimum) and the held
    stage is recorded in the model's info."""
    values = drive.sighting_value.copy()
    values[:, 0] = 1.03 * values[:, 0] + 50.0
    tr = replace(drive, sighting_value=values)
    held, two = _held_then_freed(tr, tmp_path)
    one = tmp_path / "one.json"
    assert main(["learn", str(tmp_path / "log.npz"), "--out", str(one), "--no-resume"]) == 0  # the default
    model = load_model(one)
    grid = np.array([1000.0, 3000.0, 5000.0])
    np.testing.assert_allclose(model.sensor.mean(grid), two.sensor.mean(grid), rtol=0.002)
    stage = json.loads(one.read_text())["info"]["held_curve_fit"]
    np.testing.assert_allclose(stage["curve"], held.sensor.coef, rtol=1e-6, atol=1e-9)
    assert stage["iterations"] > 0 and np.isfinite(stage["loglik"])


def test_range_curve_freed_leaves_a_height_sensor_as_held(tmp_path):
    """A camera's heights (px) have no range curve to hold: ``freed`` is the default fit, number for number."""
    tr = collect(None, 1500, seed=4)
    log = tmp_path / "h.npz"
    trajectory.save(tr, log)
    for curve in ("held", "freed"):
        assert main(["learn", str(log), "--range-curve", curve, "--out", str(tmp_path / f"{curve}.json"),
                     "--no-resume"]) == 0
    a, b = load_model(tmp_path / "held.json"), load_model(tmp_path / "freed.json")
    np.testing.assert_array_equal(a.action.weights, b.action.weights)
    np.testing.assert_array_equal(a.sensor.coef, b.sensor.coef)


def test_a_range_that_reads_the_distance_keeps_its_curve_when_freed(drive, tmp_path):
    _, freed = _held_then_freed(drive, tmp_path)
    np.testing.assert_allclose(freed.sensor.mean(np.array([1000.0, 5000.0])), [1000.0, 5000.0], rtol=0.01)


@pytest.mark.realdata
@needs_data
def test_on_mrclam_robot_2_the_freed_curve_reads_long_as_vicon_says_and_the_path_follows(tmp_path):
    """Robot 2's whole log: Vicon's ranges are 4.4-4.8% longer than the held curve (``scripts/mrclam_range_scale.py``);
    the freed curve reads 1,048 and 5,228 mm at 1 and 5 m straight ahead, the smoothed pose is 62 against 185 mm RMS
    and the forward speed 5.4 against 6.2 mm/s (``scripts/mrclam_range_curve.py``)."""
    from aibo_core.mrclam import import_robot

    tr = import_robot(DATA, 2)
    held, freed = _held_then_freed(tr, tmp_path)
    at = freed.sensor.mean(np.array([1000.0, 5000.0]))
    assert 1.02 < at[0] / 1000.0 < 1.07 and 1.02 < at[1] / 5000.0 < 1.07, at
    assert pose_scores(freed, [tr])["pose_rms"] < 0.5 * pose_scores(held, [tr])["pose_rms"]
    assert velocity_scores(freed, [tr])["vx_rms"] < 0.95 * velocity_scores(held, [tr])["vx_rms"]


def test_a_freed_fit_interrupted_in_its_free_stage_resumes_to_the_same_fit(drive, tmp_path):
    """Each stage keeps its own checkpoint (``stage_checkpoint(path, "held")`` and ``"held_face_value"``, the held stage
    from the face value, beside the fit's): a run stopped in the free stage finishes the held ones from their
    checkpoints and resumes the free one from its own, to the same numbers; all are deleted with the fit's."""
    from learners.em.learner import EMLearner, stage_checkpoint
    from learners.em.options import EMOptions

    opts = EMOptions(seed=0, uncertainty=False, range_curve="freed")
    full = EMLearner(opts).fit([drive])
    ckpt = tmp_path / "m.json.checkpoint.npz"
    firsts = []

    def stop_in_the_free_stage(rec):
        firsts.append(rec.iteration == 1)
        if sum(firsts) == 3 and rec.iteration == 9:  # the free stage's 9th (after the held stages from both starts)
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        EMLearner(opts, checkpoint_path=ckpt, checkpoint_every=4).fit([drive], progress=stop_in_the_free_stage)
    held = [tmp_path / stage_checkpoint(ckpt, stage) for stage in ("held", "held_face_value")]
    assert ckpt.exists() and all(h.exists() for h in held)
    learner = EMLearner(opts, checkpoint_path=ckpt, checkpoint_every=4)
    resumed = learner.fit([drive])
    assert 4 <= resumed.info["resumed_from"] < 9
    np.testing.assert_allclose(resumed.loglik, full.loglik, rtol=1e-12)
    np.testing.assert_allclose(resumed.params.sensor.coef, full.params.sensor.coef, rtol=1e-12)
    learner.discard_checkpoint()
    assert not ckpt.exists() and not any(h.exists() for h in held)


@pytest.mark.parametrize("kind", ["range_mm", "height_px"])
def test_a_warm_fit_with_the_curve_held_keeps_its_starts_curve_for_either_sensor(drive, kind):
    """``EMOptions.hold_curve`` (the first stage of ``aibo diagnose``'s final fit from learn's model): the start's
    curve, not range = distance (a range sensor's ``range_curve`` "freed" would otherwise free it) nor a refitted one;
    the rest is fitted. The start's curve reads 2% long, so a free fit would move it."""
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions

    tr = drive if kind == "range_mm" else collect(None, 1500, seed=4)
    opts = EMOptions(seed=0, lag_search=False, max_iter=6, uncertainty=False)
    first = EMLearner(opts).fit([tr]).params
    start = first.with_(sensor=first.sensor.with_values(coef=first.sensor.coef * 1.02))
    held = EMLearner(replace(opts, hold_curve=True), check_field=False).fit([tr], init=start).params
    free = EMLearner(opts, check_field=False).fit([tr], init=start).params
    np.testing.assert_array_equal(held.sensor.coef, start.sensor.coef)
    assert not np.array_equal(free.sensor.coef, start.sensor.coef)
    assert not np.array_equal(held.action.weights, start.action.weights)
