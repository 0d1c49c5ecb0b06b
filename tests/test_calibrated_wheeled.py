"""Wheeled logs end to end: ``aibo collect --env wheeled``, ``aibo learn`` recovering the true weights, and the
calibrated simulator of a continuous-command model (``aibo collect --model --replay``), also on an MRCLAM log."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_core.features import features
from aibo_gym.collect_wheeled import TRACKING_TAU_S, tracking_command
from experiments.calibrated import predictive_check, replay_log, simulator_config, simulator_env, smoothed_paths
from experiments.calibrated_wheeled import image_frames
from learners.model.catalogue import ActuationLag
from learners.model.io import load_model
from tests._logs import MRCLAM_DATA as DATA

#: the simulated robot (rows v, omega, v|omega|, |omega|, 1; columns vx mm/s, vy mm/s, vtheta rad/s): 15% slow,
#: 20% short on turns, loses speed while turning, drifts in its turn; far from its commands' face value. Its forward
#: speed is the ``unicycle``'s (gain v + loss on arcs v |omega|: ``aibo_core.features.ZERO_CELLS``), so both action
#: models can hold it
WEIGHTS = [[0.85, 0.0, 0.0005], [0.0, 0.0, 0.8], [-0.3, 0.0, 0.0], [0.0, 0.0, 0.02], [0.0, 0.0, -0.01]]


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A 10-minute simulated log and the models ``aibo learn`` fits to it."""
    folder = tmp_path_factory.mktemp("wheeled")
    log = folder / "sim.npz"
    config = json.dumps({"weights": WEIGHTS, "start_pose": "random"})
    assert main(["collect", "--env", "wheeled", "--steps", "6000", "--seed", "7", "--config", config, "--out", str(log)]) == 0
    models = {}
    for action_model in ("unicycle", "features"):
        models[action_model] = folder / f"{action_model}.json"
        assert main(["learn", str(log), "--action-model", action_model, "--out", str(models[action_model])]) == 0
    return log, models


def driven_errors(velocity, commands: np.ndarray) -> np.ndarray:
    """(3,) RMS velocity error over the driven ``commands`` (N, 2) as a fraction of each true component's span
    (vy: absolute, mm/s). The driven ones, not a grid over their ranges: the waypoint driver turns hard only when
    slow (|omega| > 0.3 rad/s on 11% of the frames), so a grid's fast sharp turns are extrapolation, where the
    weakly determined loss on arcs (v |omega|, standard error 0.11 on seed 7) decides the error."""
    true = features("diff_drive", commands) @ np.array(WEIGHTS)
    rms = np.sqrt(np.mean((velocity(commands) - true) ** 2, axis=0))
    return np.array([rms[0] / np.ptp(true[:, 0]), rms[1], rms[2] / np.ptp(true[:, 2])])


def test_collected_log_is_a_wheeled_robot_log(sim):
    tr = trajectory.load(sim[0])
    assert tr.controls.shape == (6000, 2) and tr.control_names == ("v_mm_s", "omega_rad_s") and tr.actions is None
    assert tr.sensor_kind == "range_mm" and tr.dt == pytest.approx(0.1) and tr.pose.shape == (6001, 3)
    assert tr.controls[:, 0].min() >= 0.0 and tr.controls[:, 0].max() <= 86.0 and np.abs(tr.controls[:, 1]).max() <= 0.57
    assert np.bincount(tr.sighting_frame).max() >= 3  # several landmarks in one image
    truth = tr.truth
    assert truth["feature_map"] == "diff_drive" and truth["weights"] == WEIGHTS
    assert truth["sensor"] == {"model": "curve", "basis": "power", "coef": [0.0, 1.0]}
    assert tr.meta["generator"].endswith("WheeledRobot-v0") and tr.meta["policy"] == "waypoints"


def test_learning_recovers_the_true_weights(sim, capsys):
    """RMS velocity error over the driven commands as a fraction of the vx / vtheta spans. Measured (10 min,
    seed 7): unicycle 1.8% / 0.51%, features 2.6% / 0.50% (vy 1.2 mm/s); the commands at face value are
    off by 14% / 4.9%."""
    log, models = sim
    driven = trajectory.load(log).controls
    face = driven_errors(lambda c: np.column_stack([c[:, 0], np.zeros(len(c)), c[:, 1]]), driven)
    assert face[0] > 0.1 and face[2] > 0.04, face
    for action_model, path in models.items():
        m = load_model(path)
        err = driven_errors(m.action.velocity, driven)
        assert err[0] < 0.03 and err[2] < 0.02, (action_model, err)
        assert err[1] < (1e-12 if action_model == "unicycle" else 4.0), (action_model, err)  # mm/s
        assert m.sensor.kind == "range_mm" and m.sensor.sigma_size == pytest.approx(50.0, rel=0.05)
        assert m.sensor.sigma_bearing == pytest.approx(0.02, rel=0.05)
        d = np.linspace(1000.0, 6000.0, 20)
        assert np.abs(m.sensor.mean(d) - d).max() < 30.0  # mm; the true range is d
    assert np.all(load_model(models["unicycle"]).action.weights[:, 1] == 0.0)


def test_the_calibrated_simulator_is_built_from_the_model_and_the_log(sim):
    log, models = sim
    tr, m = trajectory.load(log), load_model(models["unicycle"])
    assert simulator_env(m) == "WheeledRobot-v0"
    cfg = simulator_config(m, tr)
    np.testing.assert_allclose(cfg["weights"], m.action.weights / m.action.dt)
    np.testing.assert_allclose(cfg["motion_cov"], m.action.cov)
    assert cfg["feature_map"] == "unicycle" and cfg["sensor_curve"]["coef"] == m.sensor.coef.tolist()
    assert cfg["sigma_range_mm"] == m.sensor.sigma_size and cfg["sigma_bearing"] == m.sensor.sigma_bearing
    assert cfg["beacons"] == tr.landmarks.tolist() and cfg["walls"] == "open" and cfg["max_steps"] == 6000
    assert cfg["start_pose"] == pytest.approx(m.init[0].mean.tolist())
    made = tr.meta["config"]
    assert all(cfg[k] == made[k] for k in ("fov", "range_mm", "detect_prob"))  # a log of this simulator: its camera
    lagged = m.with_effect(ActuationLag(0.3))
    effects = simulator_config(lagged, tr)["effects"]  # the range's shrink, fitted on every range sensor, is ~0 here
    assert set(effects) == {"actuation_lag", "off_center_shrink"} and effects["actuation_lag"] == {"lag_s": 0.3}
    assert abs(effects["off_center_shrink"]["k"]) < 0.05


def test_replay_takes_the_logs_controls_and_image_frames_and_is_seeded(sim):
    log, models = sim
    tr, m = trajectory.load(log), load_model(models["unicycle"])
    first = replay_log(m, tr, seed=3)
    np.testing.assert_array_equal(first.controls, tr.controls)
    assert first.n_frames == tr.n_frames and set(first.sighting_frame) <= set(np.flatnonzero(image_frames(tr)))
    again, other = replay_log(m, tr, seed=3), replay_log(m, tr, seed=4)
    np.testing.assert_array_equal(again.pose, first.pose)
    np.testing.assert_array_equal(again.sighting_value, first.sighting_value)
    assert not np.array_equal(other.pose, first.pose)
    # the same seed draws the same noise: with the model's lag the path changes, and only by the lag
    lagged = replay_log(m.with_effect(ActuationLag(0.3)), tr, seed=3)
    np.testing.assert_array_equal(lagged.pose[0], first.pose[0])
    assert np.abs(lagged.pose[1:, :2] - first.pose[1:, :2]).max() > 10.0


def test_the_tracking_law_steers_each_error_out_over_its_time_constant():
    """Known answers of ``tracking_command`` (Kanayama's law with gains 1 / tau): no error, the command as measured;
    a target 100 mm ahead, 100 / tau mm/s faster; a heading error of +pi/2, no forward speed and 1 / tau rad/s more
    turn; 100 mm to the left at 100 mm/s, 100 / (tau^2 100) rad/s more turn; the errors read in the robot's frame."""
    tau, cmd = TRACKING_TAU_S, np.array([100.0, 0.2])
    pose = np.array([1000.0, -500.0, 0.3])
    np.testing.assert_allclose(tracking_command(cmd, pose, pose), cmd)
    ahead = pose + [100 * np.cos(0.3), 100 * np.sin(0.3), 0.0]
    np.testing.assert_allclose(tracking_command(cmd, pose, ahead), [100.0 + 100.0 / tau, 0.2])
    np.testing.assert_allclose(tracking_command(cmd, pose, pose + [0, 0, np.pi / 2]), [0.0, 0.2 + 1.0 / tau], atol=1e-12)
    left = pose + [-100 * np.sin(0.3), 100 * np.cos(0.3), 0.0]
    np.testing.assert_allclose(tracking_command(cmd, pose, left), [100.0, 0.2 + 100.0 / (tau * tau * 100.0)])
    wrapped = tracking_command(cmd, pose, pose + [0, 0, 2 * np.pi + 0.1])  # the heading error wrapped: +0.1 rad
    np.testing.assert_allclose(wrapped, [100.0 * np.cos(0.1), 0.2 + np.sin(0.1) / tau])


def test_a_tracking_replay_follows_the_smoothed_path_where_an_open_loop_one_drifts(sim):
    """The calibrated check's replicas (``smoothed_paths``): the model's smoothed path of the measured log is the
    reference; a replay steered along it stays near the robot's path, the open-loop replay of the same commands and
    noise drifts (seed 7's 10 minutes: median 51 mm against 907 mm off the true path); the log records the commands
    executed, the measured ones with corrections of a few percent, changing where the measured ones change (on 10% of
    the frames here); seeded; a reference that does not fit refused."""
    log, models = sim
    tr, m = trajectory.load(log), load_model(models["unicycle"])
    (ref,) = smoothed_paths(m, [tr])
    off = lambda pose: float(np.median(np.hypot(*(pose[:, :2] - tr.pose[:, :2]).T)))  # noqa: E731
    assert off(ref) < 50.0
    tracked, open_loop = replay_log(m, tr, seed=3, path=ref, steer=True), replay_log(m, tr, seed=3, path=ref)
    assert off(tracked.pose) < 150.0 and off(open_loop.pose) > 4 * off(tracked.pose)
    changes = lambda c: np.any(np.diff(c, axis=0) != 0, axis=1)  # noqa: E731
    np.testing.assert_array_equal(changes(tracked.controls), changes(tr.controls))  # corrected where the log changes
    correction = np.sqrt(np.mean((tracked.controls - tr.controls) ** 2, axis=0))
    assert np.all(correction > 0) and np.all(correction < 0.15 * np.sqrt(np.mean(tr.controls ** 2, axis=0)))
    assert tracked.meta["policy"] == "tracking replay" and open_loop.meta["policy"] == "replay"
    np.testing.assert_array_equal(replay_log(m, tr, seed=3, path=ref, steer=True).pose, tracked.pose)
    with pytest.raises(ValueError, match="a reference path needs"):
        replay_log(m, tr, seed=3, path=ref[:-1], steer=True)


def test_the_check_with_tracked_replicas_runs_them_along_the_path(sim):
    """``predictive_check(tracking=True)``: every replica steered (none failed), and their sightings per frame those
    of a robot on the measured path: within 5% of the log's (seed 7: 2.7%; open loop 9.8% short)."""
    log, models = sim
    tr, m = trajectory.load(log), load_model(models["unicycle"])
    check = predictive_check(m, [tr], replicas=3, tracking=True)
    assert not check.failed and check.replicas.shape[0] == 3
    i = check.names.index("sightings per frame")
    assert abs(check.replicas[:, i].mean() / check.measured[i] - 1.0) < 0.05


def test_a_path_is_smoothed_only_for_a_blind_log_whose_camera_is_measured(sim, monkeypatch):
    """``camera_paths``: a log made by the simulator carries its camera (``meta["config"]``) and one with true poses is
    measured at them, so neither is smoothed (the E-step not run at all); a blind log of another source gets the
    model's smoothed path, (T + 1, 3) and near its true poses."""
    import experiments.calibrated as calibrated

    log, models = sim
    tr, m = trajectory.load(log), load_model(models["unicycle"])
    made_here, foreign = replace(tr, pose=None), replace(tr, meta={k: v for k, v in tr.meta.items() if k != "config"})
    real = replace(foreign, pose=None)

    def refused(*_):
        raise AssertionError("smoothed where no path is needed")

    with monkeypatch.context() as mp:
        mp.setattr(calibrated, "smoothed_paths", refused)
        assert calibrated.camera_paths(m, [made_here]) == [None] and calibrated.camera_paths(m, [foreign]) == [None]
    (path,) = calibrated.camera_paths(m, [real])
    assert path.shape == (tr.n_frames + 1, 3)
    assert np.median(np.hypot(*(path[:, :2] - tr.pose[:, :2]).T)) < 300.0


def test_the_cameras_detection_by_distance_is_measured_at_the_true_or_a_given_path():
    """A log whose camera detects 0.8 at 1.5 m and 0.2 at 6 m (linear between): ``measured_camera`` reads the table
    back at its bins' distances (within 0.06), the same at a path 30 mm off the truth, and nothing without a path.
    Among 60 landmarks, so that every frame has a sighting: the images are the frames with one, and with the default
    8 a frame seeing none is taken for no image, which biases every bin up (0.95 for 0.75 at 1.2 m)."""
    from aibo_gym.collect_wheeled import collect_wheeled
    from experiments.calibrated_wheeled import measured_camera

    truth = [[1500.0, 0.8], [6000.0, 0.2]]
    landmarks = np.random.default_rng(0).uniform(-4000.0, 4000.0, (60, 2)).tolist()
    config = {"detect_by_distance": truth, "start_pose": "random", "beacons": landmarks, "sigma_bearing": 0.002}
    tr = collect_wheeled(config, 6000, seed=3)
    cam = measured_camera(tr, 50.0)
    d, p = np.array(cam["detect_by_distance"]).T
    assert len(d) == 8 and np.all(np.diff(d) > 0)
    np.testing.assert_allclose(p, np.interp(d, *np.array(truth).T), atol=0.06)
    shifted = tr.pose + [30.0, 0.0, 0.0]
    np.testing.assert_allclose(np.array(measured_camera(tr, 50.0, shifted)["detect_by_distance"])[:, 1], p, atol=0.03)
    blind = replace(tr, pose=None)
    assert "detect_by_distance" not in measured_camera(blind, 50.0) and "detect_prob" not in measured_camera(blind, 50.0)
    # the angle's factor flat but in the last bin, which holds the measured field of view's excess over the camera's
    np.testing.assert_allclose(np.array(cam["detect_by_angle"])[:-1, 1], 1.0, atol=0.05)


def test_the_cameras_detection_by_angle_is_measured_as_a_factor_beside_the_distances():
    """A camera that detects 0.5 (1.2 - |a|) at the angle a off the heading, whatever the distance: the distance's
    table flat (within 0.03 of its mean), its mean times the angle's factor the truth at the angle bins' centres
    (within 0.02; the last bin, at the field of view's edge, left out: the measured field of view is wider than the
    camera's by the bearing noise and a margin, where nothing is seen)."""
    from aibo_gym.collect_wheeled import collect_wheeled
    from experiments.calibrated_wheeled import measured_camera

    landmarks = np.random.default_rng(0).uniform(-4000.0, 4000.0, (60, 2)).tolist()
    config = {"detect_prob": 0.5, "detect_by_angle": [[0.0, 1.2], [0.6, 0.6]], "start_pose": "random",
              "beacons": landmarks, "sigma_bearing": 0.002}
    cam = measured_camera(collect_wheeled(config, 6000, seed=3), 50.0)
    p = np.array(cam["detect_by_distance"])[:, 1]
    a, g = np.array(cam["detect_by_angle"]).T
    np.testing.assert_allclose(p, p.mean(), atol=0.03)
    np.testing.assert_allclose((p.mean() * g)[:-1], (0.5 * (1.2 - a))[:-1], atol=0.02)


def test_detection_tables_merge_tied_quantiles_and_need_two_bins_of_pairs():
    """Distances on three values (a grid of landmarks, say): one point per value, none for the empty bins between
    tied quantiles; a single angle: no angle table; fewer than 200 pairs in view: no table at all."""
    from experiments.calibrated_wheeled import detection_tables

    rng = np.random.default_rng(0)
    view = np.stack([rng.choice([1000.0, 2000.0, 3000.0], 2000), np.full(2000, 0.2)], axis=1)
    seen = view[rng.random(2000) < np.interp(view[:, 0], [1000.0, 3000.0], [0.8, 0.2])]
    tables = detection_tables(view, seen)
    d, p = np.array(tables["detect_by_distance"]).T
    np.testing.assert_array_equal(d, [1000.0, 2000.0, 3000.0])
    np.testing.assert_allclose(p, [0.8, 0.5, 0.2], atol=0.05)
    assert "detect_by_angle" not in tables
    assert detection_tables(view[:150], seen[:50]) == {}


def test_aibo_collect_replays_a_continuous_log_with_its_model(sim, tmp_path, capsys):
    log, models = sim
    out = tmp_path / "replay.npz"
    assert main(["collect", "--model", str(models["features"]), "--replay", str(log), "--out", str(out), "--seed", "2"]) == 0
    rep, tr = trajectory.load(out), trajectory.load(log)
    np.testing.assert_array_equal(rep.controls, tr.controls)
    assert rep.meta["replay_of"] == str(log) and rep.truth["feature_map"] == "diff_drive"
    # a log without true poses nor camera settings (a real robot's): its camera measured at the model's smoothed path
    real = tmp_path / "real.npz"
    trajectory.save(replace(trajectory.blind(tr), meta={}), real)
    assert main(["collect", "--model", str(models["features"]), "--replay", str(real), "--out", str(out), "--seed", "2"]) == 0
    camera = trajectory.load(out).meta["config"]
    assert camera["detect_prob"] == pytest.approx(0.9, abs=0.05)  # the simulated camera's (its default; seed 7: 0.88)
    assert len(camera["detect_by_distance"]) == 8
    # a model and a log (or --env) that do not go together: one line, exit 2, nothing written
    aibo_log = tmp_path / "aibo.npz"
    assert main(["collect", "--steps", "100", "--out", str(aibo_log)]) == 0
    capsys.readouterr()
    for argv in (["--replay", str(aibo_log)], ["--env", "aibo"]):
        assert main(["collect", "--model", str(models["features"]), *argv, "--out", str(tmp_path / "x.npz")]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("aibo: error:") and "\n" not in err
        assert not (tmp_path / "x.npz").exists()


needs_data = pytest.mark.skipif(not (DATA / "Robot2_Odometry.dat").is_file(),
                                reason=f"MRCLAM Dataset 7 not found at {DATA} (see README, 'Real robot logs')")


@pytest.mark.realdata
@needs_data
def test_an_mrclam_log_replays_in_its_calibrated_simulator(tmp_path):
    """Robot 2, 300 s: import, learn (unicycle), replay its controls and image frames through ``aibo collect``."""
    log, model, out = tmp_path / "r2.npz", tmp_path / "r2.json", tmp_path / "sim.npz"
    assert main(["import", "mrclam", str(DATA), "--robot", "2", "--seconds", "300", "--out", str(log)]) == 0
    assert main(["learn", str(log), "--action-model", "unicycle", "--out", str(model)]) == 0
    assert main(["collect", "--model", str(model), "--replay", str(log), "--out", str(out)]) == 0
    real, sim = trajectory.load(log), trajectory.load(out)
    np.testing.assert_array_equal(sim.controls, real.controls)
    assert sim.sensor_kind == "range_mm" and sim.n_frames == real.n_frames == 3000 and sim.n_sightings > 0
    assert set(sim.sighting_frame) <= set(np.flatnonzero(image_frames(real)))
    cfg = simulator_config(load_model(model), real)
    assert 0.0 < cfg["detect_prob"] <= 1.0 and cfg["fov"] == pytest.approx(2 * (np.abs(real.sighting_value[:, 1]).max() + 0.01))


@pytest.mark.slow
def test_a_driver_that_steers_on_its_pose_alone_makes_the_timing_statistic_disagree_and_tracked_replicas_agree():
    """A 5-minute log driven closed loop (every frame's command corrected towards the waypoint driver's path on the true
    pose, time constant 10 s: ``collect_closed_loop``), no lag and no response time in the robot: ``aibo learn`` finds
    no lag, yet the check's open-loop replicas leave "turn vs change of the commanded turn rate" (the commands answer
    the motion; seeds 4-11: z +5.5 to +9.2), and replicas steered by the same loop (``tracking``) do not (seed 4: -0.6;
    docs/results.md, "A driver that steers on its pose")."""
    from aibo_gym.collect_wheeled import collect_closed_loop
    from learners.discrepancy.signatures import CHANGE_OF
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions

    log = collect_closed_loop({"start_pose": "random"}, 3000, 4, TRACKING_TAU_S)
    model = EMLearner(EMOptions(seed=0, uncertainty=False)).fit([log]).params
    assert model.effect("actuation_lag") is None
    timing = f"turn (sigma) vs {CHANGE_OF['turn']} (strength)"
    open_loop = [n for n, _ in predictive_check(model, [log], replicas=16).disagreements()]
    tracked = [n for n, _ in predictive_check(model, [log], replicas=16, tracking=True).disagreements()]
    assert timing in open_loop and timing not in tracked, (open_loop, tracked)


def test_tracked_replicas_are_refused_for_commands_they_cannot_steer(tmp_path, capsys):
    """``aibo diagnose --tracked-replicas`` on a log of discrete actions: one line naming the option, the log and its
    commands, a non-zero exit, nothing written."""
    from aibo_core.trajectory import save
    from tests._logs import sim_log

    log = tmp_path / "aibo.npz"
    save(sim_log(300), log)
    capsys.readouterr()
    assert main(["diagnose", str(log), "--out", str(tmp_path / "d"), "--tracked-replicas"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--tracked-replicas" in err[0] and str(log) in err[0] and "discrete actions" in err[0], err
    assert not (tmp_path / "d").exists()


@pytest.mark.slow
def test_diagnose_with_tracked_replicas_passes_a_closed_loop_log_its_open_loop_check_fails(tmp_path):
    """End to end through ``aibo diagnose``: the closed-loop log of seed 4 (no effect): nothing named, and the timing
    statistic left by the open-loop replays, not by the tracked ones; the report says which replays it made."""
    from aibo_core.trajectory import save
    from aibo_gym.collect_wheeled import collect_closed_loop
    from learners.discrepancy.signatures import CHANGE_OF

    log = tmp_path / "closed.npz"
    save(collect_closed_loop({"start_pose": "random"}, 3000, 4, TRACKING_TAU_S), log)
    timing = f"turn (sigma) vs {CHANGE_OF['turn']} (strength)"
    left = {}
    for how, extra in (("open loop", []), ("tracked", ["--tracked-replicas"])):
        out = tmp_path / how.replace(" ", "_")
        assert main(["diagnose", str(log), "--out", str(out), *extra]) == 0
        report = json.loads((out / "report.json").read_text())
        assert report["effects"] == [] and report["calibrated_replays"] == how
        left[how] = [u["statistic"] for u in report["unexplained"]]
        assert ("steered along the model's smoothed path" in (out / "report.html").read_text()) == (how == "tracked")
    assert timing in left["open loop"] and timing not in left["tracked"], left
