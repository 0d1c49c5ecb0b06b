"""The MRCLAM importer (on small files written here, and on the real dataset when present), the
start-pose estimate from sightings, and the scoring against ground truth."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_core.mrclam import MRCLAMError, import_robot, pose_valid
from learners.em.start import initial_from_sightings, initial_state_for, pose_candidates
from learners.model.initial import DEFAULT_INITIAL
from tests._logs import MRCLAM_DATA as DATA

HEADER = "# a\n# b\n# c\n# d\n"


def _write(folder: Path, name: str, rows) -> None:
    (folder / name).write_text(HEADER + "\n".join(" \t".join(f"{v}" for v in r) for r in rows) + "\n")


def tiny_dataset(folder: Path) -> Path:
    """Robot 1 driving straight at 0.1 m/s for 10 s past 3 landmarks, with the dataset's oddities."""
    _write(folder, "Barcodes.dat", [(1, 5), (2, 14), (6, 63), (7, 81), (8, 7)])
    _write(folder, "Landmark_Groundtruth.dat", [(6, 2.0, 1.0, 0, 0), (7, 4.0, -1.0, 0, 0), (8, 6.0, 1.0, 0, 0)])
    t0 = 100.0
    odo = [(t0 + 0.5 * k, 0.1, 0.0) for k in range(21)]
    odo.insert(5, odo[4])  # a repeated row
    odo.insert(9, (t0 + 1.0, 0.1, 0.0))  # a row back in time
    _write(folder, "Robot1_Odometry.dat", odo)
    gt = [(t0 - 1 + 0.02 * k, 0.1 * max(0.0, 0.02 * k - 1), 0.0, 0.0) for k in range(600) if not 200 <= k < 215]
    _write(folder, "Robot1_Groundtruth.dat", gt)
    meas = [(t0 + 0.3, 63, 2.2, 0.46), (t0 + 0.3, 81, 4.1, -0.25), (t0 + 0.3, 14, 1.0, 0.1),  # robot 2
            (t0 + 1.0, 34, 3.0, 0.0),  # unknown barcode
            (t0 + 2.04, 7, 5.9, 0.2), (t0 - 3.0, 63, 2.0, 0.4), (t0 + 30.0, 63, 2.0, 0.4)]  # last two outside
    _write(folder, "Robot1_Measurement.dat", meas)
    return folder


def test_import_tiny_dataset(tmp_path):
    tr = import_robot(tiny_dataset(tmp_path), 1, dt=0.1)
    assert tr.control_names == ("v_mm_s", "omega_rad_s") and tr.sensor_kind == "range_mm"
    assert tr.n_frames == 100  # 10 s of commands
    np.testing.assert_allclose(tr.controls, [[100.0, 0.0]] * 100)
    np.testing.assert_allclose(tr.landmarks, [[2000, 1000], [4000, -1000], [6000, 1000]])
    np.testing.assert_array_equal(tr.sighting_frame, [2, 2, 19])  # frame whose end is nearest
    np.testing.assert_allclose(tr.sighting_time, [0.0, 0.0, 0.04], atol=1e-9)  # its time after that end (s)
    np.testing.assert_array_equal(tr.sighting_landmark, [0, 1, 2])
    np.testing.assert_allclose(tr.sighting_value[:, 0], [2200, 4100, 5900])
    d = tr.meta["dropped"]
    assert (d["sightings_of_robots"], d["sightings_unknown_barcode"], d["unknown_barcodes"]) == (1, 1, [34])
    assert d["sightings_outside_span"] == 2
    assert (d["odometry_rows_repeated"], d["odometry_rows_backward"]) == (1, 1)
    assert tr.meta["source"]["robot"] == 1 and "field" not in tr.meta and tr.field is None
    np.testing.assert_allclose(tr.pose[:, 0], 10.0 * np.arange(101), atol=1e-6)  # x = 100 mm/s t
    gaps = tr.meta["pose_gaps"]
    assert gaps["count"] == 1 and gaps["longest_s"] == pytest.approx(0.32)
    valid = pose_valid(tr)
    assert not valid[[30, 31, 32]].any() and valid[[29, 34]].all() and valid.sum() == 101 - gaps["poses_flagged"]
    trajectory.save(tr, tmp_path / "log.npz")
    back = trajectory.load(tmp_path / "log.npz")
    assert back.meta["pose_gaps"]["flagged_runs"] == gaps["flagged_runs"]
    np.testing.assert_array_equal(back.sighting_time, tr.sighting_time)


def test_a_dataset_without_ground_truth_imports_without_a_pose(tmp_path, capsys):
    """A run without Vicon (or a copy that left the large files out): the same sightings and commands, no pose, the log
    to the last command, and the import line says there is nothing to score against."""
    folder = tiny_dataset(tmp_path)
    _write(folder, "Robot1_Odometry.dat", [(100.0 + 0.5 * k, 0.1, 0.0) for k in range(25)])  # 12 s: past the truth's end
    with_truth = import_robot(folder, 1, dt=0.1)
    (folder / "Robot1_Groundtruth.dat").unlink()
    tr = import_robot(folder, 1, dt=0.1)
    assert tr.pose is None and "pose_gaps" not in tr.meta
    assert (with_truth.n_frames, tr.n_frames) == (109, 120)  # the truth ends at 10.98 s; the commands at 12 s
    np.testing.assert_array_equal(tr.sighting_frame, [2, 2, 19])
    np.testing.assert_allclose(tr.controls[:109], with_truth.controls)
    assert "Robot1_Groundtruth.dat" not in tr.meta["source"]["files"]
    assert main(["import", "mrclam", str(folder), "--robot", "1", "--out", str(tmp_path / "log.npz")]) == 0
    assert "no ground truth (no Robot1_Groundtruth.dat)" in capsys.readouterr().out
    assert trajectory.load(tmp_path / "log.npz").pose is None


def test_commands_are_averaged_over_frames(tmp_path):
    """A command change inside a frame: the frame's control is the time average (exact travel)."""
    tiny_dataset(tmp_path)
    _write(tmp_path, "Robot1_Odometry.dat", [(100.0, 0.1, 0.0), (100.25, 0.2, 0.5), (101.0, 0.2, 0.5)])
    tr = import_robot(tmp_path, 1, dt=0.1)
    np.testing.assert_allclose(tr.controls[:, 0], [100, 100, 150, 200, 200, 200, 200, 200, 200, 200])
    np.testing.assert_allclose(tr.controls[2, 1], 0.25)


def test_import_errors_are_one_line(tmp_path, capsys):
    with pytest.raises(MRCLAMError, match="no such folder"):
        import_robot(tmp_path / "nope", 1)
    with pytest.raises(MRCLAMError, match="numbered 1-5"):
        import_robot(tiny_dataset(tmp_path), 6)
    with pytest.raises(MRCLAMError, match="Robot2_Odometry.dat: file not found"):
        import_robot(tmp_path, 2)
    assert main(["import", "mrclam", str(tmp_path), "--robot", "3", "--out", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("aibo: error: ") and err.count("\n") == 1 and "Robot3_" in err


def test_start_pose_from_sightings():
    """A log without a field or simulator start gets its start from the first sightings; simulated
    logs keep the simulator's start (so their fits are unchanged)."""
    from tests._diffdrive import diff_drive_log
    from tests._logs import sim_log

    tr = diff_drive_log(60.0, seed=1)  # starts at (0, 0, 0); no field, no config
    est = initial_from_sightings(tr)
    assert est is not None
    err = np.abs(est.mean - tr.pose[0])
    std = np.sqrt(np.diag(est.cov))
    assert np.all(err <= 3 * std) and err[0] < 300 and err[1] < 300, (est.mean, std)
    sim = sim_log(600)
    np.testing.assert_array_equal(initial_state_for(sim).mean, DEFAULT_INITIAL.mean)
    np.testing.assert_array_equal(initial_state_for(sim).cov, DEFAULT_INITIAL.cov)


def test_a_fit_far_from_the_commands_face_value_says_it_may_be_wrong():
    """``face_value_warnings``: silent for velocities near the commands (robots 1, 2, 3, 5 of MRCLAM depart
    by 7-24% of the commanded range), a warning for robot 4's world (forward speed -335 mm/s per rad/s)."""
    from learners.em.support import face_value_departure, face_value_warnings
    from learners.model.action import ActionModel
    from learners.model.model import Model
    from learners.model.sensor import SensorModel

    rng = np.random.default_rng(0)
    controls = np.column_stack([rng.uniform(0, 90, 2000), rng.uniform(-0.6, 0.6, 2000)])
    a = ActionModel.zeros(5, 0.1, "unicycle", ("v_mm_s", "omega_rad_s"))
    w = np.zeros((5, 3))
    w[0, 0], w[1, 2], w[4, 0] = 0.1 * 1.05, 0.1 * 0.9, 0.1 * 3.0  # 5% fast, 10% short of the turn, 3 mm/s offset
    sensor = SensorModel.start("range_mm")
    good = Model(a.with_values(weights=w), sensor, (DEFAULT_INITIAL,))
    assert face_value_warnings(good, controls) == [] and max(face_value_departure(good, controls)) < 0.15
    w_bad = w.copy()
    w_bad[1, 0], w_bad[3, 0] = -0.1 * 335.0, 0.1 * 103.0  # robot 4's learned omega and |omega| gains (mm/s per rad/s)
    bad = face_value_warnings(Model(a.with_values(weights=w_bad), sensor, (DEFAULT_INITIAL,)), controls)
    assert len(bad) == 1 and "may be wrong" in bad[0]
    assert face_value_departure(Model(ActionModel.zeros(3, 0.1, "linear", ("a", "b")), sensor, (DEFAULT_INITIAL,)),
                                controls) is None  # controls of unknown meaning: no face value


needs_data = pytest.mark.skipif(not (DATA / "Robot1_Odometry.dat").is_file(),
                                reason=f"MRCLAM Dataset 7 not found at {DATA} (see README, 'Real robot logs (MRCLAM)')")


@pytest.mark.realdata
@needs_data
def test_real_robot1_learned_beats_face_value(tmp_path, capsys):
    """Robot 1, first 5 minutes: import, learn (diff_drive and unicycle, range sensor), score against Vicon.

    Measured (dt 0.1 s; forward-velocity RMS over 1 s windows): face value 14.2, diff_drive
    9.5, unicycle 9.8 mm/s before the lag search; 11.4 and 12.3 with the range curve held and the gate judged under
    the face value (see the bar below); 8.9 and 6.6 at 2026-11-28, 9.4 and 6.1 with the curve freed from the held fit
    (the default since). With
    the lag the default search keeps (0.2 s), the turn rate, worse than the face value without it, beats it. Lateral
    velocity: diff_drive wiggles sideways (29.3 mm/s RMS) where the unicycle, like the face value, has
    none (1.95 vs 1.99 mm/s): it must stay within 0.5 mm/s of the face value. The turn rate, range
    curve and smoothed poses are NOT better than the face value on this data (docs/results.md, "Real robot logs (MRCLAM)").
    """
    from learners import load_model
    from learners.scoring import score

    log = tmp_path / "r1.npz"
    assert main(["import", "mrclam", str(DATA), "--robot", "1", "--seconds", "300", "--out", str(log)]) == 0
    tr = trajectory.load(log)
    scores = {}
    for action_model in ("features", "unicycle"):
        model = tmp_path / f"r1_{action_model}.json"
        assert main(["learn", str(log), "--action-model", action_model, "--out", str(model)]) == 0
        captured = capsys.readouterr()
        assert "face value" in captured.out and "smoothed pose RMS" in captured.out
        assert "may be wrong" not in captured.err
        # the real map is right: the map check names no landmark (learners.em.map_check; Dataset 1's swap:
        # docs/results.md, "Landmarks where the map does not put them")
        assert "the map and the sightings disagree" not in captured.err
        assert json.loads(model.read_text())["info"]["map_check"] == []
        # the motion noise against Vicon, the learned model's alone ("-" where a column borrows its noise): the
        # unicycle's robot (the default) wanders sideways ten times more than the real one (0.10; docs/results.md, "The
        # twin's motion noise"); the diff_drive's sideways mean errs as much as its noise is wide (1.08)
        lateral = next(ln for ln in captured.out.splitlines() if ln.startswith("lateral error / model sd")).split()
        assert lateral[-3] == "-" and lateral[-1] == "-", lateral
        assert (float(lateral[-2]) < 0.3) == (action_model == "unicycle"), lateral
        m = load_model(model)
        scores[action_model] = s = score(m, [tr])
        # 0.9x: this excerpt holds one biased pass (5 sightings at 93-95 s, ranges 360-490 mm short) that the paper's
        # gate, judged at the zero-velocity start, pruned by chance (then 7.5 and 7.7 mm/s); judged under the face value
        # (the default) it stays and the models reach 11.4 and 12.3 vs 14.2 (whole log: 5.9 vs 11.9; docs/results.md)
        assert s["learned"]["vx_rms"] < 0.9 * s["face value"]["vx_rms"], s
        # the lag search (default for velocity commands) keeps a lag, and the turn rate then beats the face value
        # (without it the learned turn gain was attenuated and the model turned worse than the commands)
        assert m.effect("actuation_lag") is not None and m.effect("actuation_lag").lag_s > 0
        assert s["learned"]["vtheta_rms"] < s["face value"]["vtheta_rms"], s
        assert "actuation lag:" in captured.out
        # the public API, in mm/s, rad/s, mm (straight runs at 67 mm/s: measured 67.6 mm/s on Vicon)
        v = m.action.velocity(np.array([[67.0, 0.0]]))
        assert v.shape == (1, 3) and abs(v[0, 0] - 67.6) < 5.0, v
        assert abs(m.sensor.mean(np.array([3000.0]))[0] - 3000.0) < 500.0
    # the range errors drift per landmark (issue 17): said in one line, with what to run. With the curve held at the
    # distance the size errors' lag-1 autocorrelation per landmark is 0.31 on this excerpt; freed (the default) the
    # curve takes the ranges' common excess and it falls below the warning's bar here (the whole logs: 0.16-0.28 on
    # four robots, docs/results.md)
    assert main(["learn", str(log), "--range-curve", "held", "--out", str(tmp_path / "held.json")]) == 0
    captured = capsys.readouterr()
    assert "correlate from sighting to sighting" in captured.err and "aibo diagnose" in captured.err
    uni = scores["unicycle"]
    assert np.all(load_model(tmp_path / "r1_unicycle.json").action.weights[:, 1] == 0.0)
    assert uni["learned"]["vy_rms"] < uni["face value"]["vy_rms"] + 0.5, uni


def test_forward_speed_that_depends_on_the_turn_direction_says_it_may_be_wrong():
    """``mirror_warnings``: silent for a wheeled robot's forward speed (a small wheel mismatch, 3 mm/s per rad/s),
    a warning for MRCLAM robot 4's learned world (-155 mm/s per rad/s of omega in the forward row, within 40% of
    the face value so ``face_value_warnings`` is silent)."""
    from learners.em.support import mirror_asymmetry, mirror_warnings
    from learners.model.action import ActionModel
    from learners.model.model import Model
    from learners.model.sensor import SensorModel

    rng = np.random.default_rng(0)
    controls = np.column_stack([rng.uniform(0, 90, 2000), rng.uniform(-0.6, 0.6, 2000)])
    a = ActionModel.zeros(5, 0.1, "unicycle", ("v_mm_s", "omega_rad_s"))
    w = np.zeros((5, 3))
    w[0, 0], w[1, 2], w[1, 0], w[3, 0] = 0.1, 0.1 * 0.93, 0.1 * 3.0, -0.1 * 8.0
    sensor = SensorModel.start("range_mm")
    assert mirror_warnings(Model(a.with_values(weights=w), sensor, (DEFAULT_INITIAL,)), controls) == []
    w[1, 0], w[3, 0] = -0.1 * 155.0, 0.1 * 120.0  # robot 4's learned omega and |omega| gains with the range curve held
    bad = Model(a.with_values(weights=w), sensor, (DEFAULT_INITIAL,))
    assert mirror_asymmetry(bad, controls) > 0.3 and "turn direction" in mirror_warnings(bad, controls)[0]


@pytest.mark.realdata
@needs_data
def test_real_robot3_the_gate_judged_at_the_face_value_keeps_the_right_world():
    """Robot 3, training half of the whole log (the held-out split of docs/results.md; ~10 s): the paper's
    first-iteration gate, judged at the zero-velocity start model, pruned 1585 of 2204 sightings (on the whole log 9:
    the gate's verdict hangs on which sightings come first) and EM ended in a wrong world (forward speed 34 mm/s RMS
    vs 14.6 at face value, turn rate 0.079 vs 0.061 rad/s, smoothed pose 3.6 m). Judged under the commands' face
    value it prunes 87, and with the range curve held at range = distance the model beats the commands on forward
    speed and turn rate."""
    from dataclasses import replace

    from learners.arrays.batch import make_batch
    from learners.discrepancy.split import training_log
    from learners.em.learner import EMLearner, face_value_gate
    from learners.em.options import EMOptions
    from learners.scoring import face_value_model, velocity_scores

    tr = import_robot(DATA, 3, dt=0.1)
    train = training_log(tr)
    learner = EMLearner(EMOptions(uncertainty=False, range_curve="held"))
    batch = make_batch([train])
    start = learner.start_params([train], None, batch, "unicycle")
    assert face_value_gate(batch, start, 50.0).mean() < 0.1
    res = learner.fit([train], action_model="unicycle")
    np.testing.assert_array_equal(res.params.sensor.coef, start.sensor.coef)  # held: range = distance
    assert res.info["face_value_gate_pruned"] < 0.1 * train.n_sightings
    # no warning of a wrong world; only that the range errors drift per landmark (no bias states in this model)
    assert [w for w in res.info["warnings"] if "correlate from sighting to sighting" not in w] == []
    assert len(res.info["warnings"]) == 1, res.info["warnings"]
    got, face = velocity_scores(res.params, [tr]), velocity_scores(face_value_model(res.params), [tr])
    assert got["vx_rms"] < 0.8 * face["vx_rms"] and got["vtheta_rms"] < face["vtheta_rms"], (got, face)
    # the paper's gate and a free curve from the training half's window's best pose (the start before
    # ``chosen_start_pose``): the wrong world (kept to show the test can fail)
    old = EMLearner(replace(EMOptions(uncertainty=False), range_curve="free", face_value_gate=False), check_field=False)
    was = old.fit([train], action_model="unicycle", initial=(initial_from_sightings(train),))
    assert was.pruned_observations > 0.5 * train.n_sightings
    assert velocity_scores(was.params, [tr])["vx_rms"] > face["vx_rms"]


def test_the_pose_score_leaves_gross_outliers_out_by_default():
    """A burst of gross range outliers (3x the distance, as a misread landmark) takes the smoother off its track
    (``gate=None``); with the fit's gate, the default (sightings beyond it not applied), the pose error is the clean
    log's."""
    from dataclasses import replace

    from learners.arrays.batch import make_batch
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions
    from learners.scoring import face_value_model, pose_scores
    from tests._diffdrive import diff_drive_log

    clean = diff_drive_log(120.0, seed=3)
    start = EMLearner(EMOptions()).start_params([clean], None, make_batch([clean]))
    model = face_value_model(start.with_(sensor=replace(start.sensor, sigma_size=40.0, sigma_bearing=0.02)))
    values = clean.sighting_value.copy()
    burst = slice(len(values) // 2, len(values) // 2 + 8)
    values[burst, 0] *= 3.0
    bad = replace(clean, sighting_value=values)
    ok = pose_scores(model, [clean], gate=None)["pose_rms"]
    gated, ungated = pose_scores(model, [bad])["pose_rms"], pose_scores(model, [bad], gate=None)["pose_rms"]
    assert gated == pytest.approx(ok, rel=0.1), (ok, gated)
    assert ungated > 2.0 * gated, (gated, ungated)


@pytest.mark.realdata
@needs_data
def test_real_robot3_diagnose_starts_from_the_whole_logs_first_sightings():
    """``search.base_fit``: robot 3's first sightings (2.1-3.8 s) all fall in the first held-out block, so its
    training half's first window is later (13.8-16.7 s), turning, of three landmarks 0.35 m apart, and puts the
    start metres off; EM kept a start 6.5 m off and the diagnosed model's pose error was 1042 mm. From the whole
    log's first sightings the base fit starts within a metre of Vicon's first pose and its smoothed track is
    within 400 mm RMS (measured 378 mm, the commands' face value 362; the diagnosed model's is in docs/results.md)."""
    from dataclasses import replace

    from learners.discrepancy.fitting import fit
    from learners.discrepancy.search import base_fit
    from learners.discrepancy.split import training_log
    from learners.em.options import EMOptions
    from learners.scoring import pose_scores

    tr = import_robot(DATA, 3, dt=0.1)
    opts = replace(EMOptions(seed=0, lag_search=False), uncertainty=False)
    assert np.hypot(*(initial_from_sightings(training_log(tr)).mean[:2] - tr.pose[0, :2])) > 3000.0
    model = base_fit([tr], opts)
    assert np.hypot(*(model.init[0].mean[:2] - tr.pose[0, :2])) < 1000.0, model.init[0].mean
    assert pose_scores(model, [tr])["pose_rms"] < 400.0
    # the training half's own window's best pose (before): the wrong side of the landmarks, kept to show the test can
    # fail (given as the start, EM keeps it)
    was = fit([training_log(tr)], None, opts, initial=(initial_from_sightings(training_log(tr)),))
    assert np.hypot(*(was.init[0].mean[:2] - tr.pose[0, :2])) > 3000.0, was.init[0].mean
    assert pose_scores(was, [tr])["pose_rms"] > 2.0 * pose_scores(model, [tr])["pose_rms"]


@pytest.mark.realdata
@needs_data
def test_real_robot3_learn_chooses_the_first_pose_the_whole_log_agrees_with():
    """``learners.em.starts.chosen_start_pose``: robot 3's first 10 minutes, training half (its first sightings in a
    held-out block, its first window three landmarks 0.35 m apart). The window's best pose is their mirror image;
    ``aibo learn``'s start is the candidate the commands' face value agrees with, and EM ends where the robot was.
    Measured 2026-11-28: from the mirror, bearing noise 0.095 rad, the log-likelihood 8,656 nats lower (-14,856 against
    -6,199), 87 sightings gated out, pose 1,000s of mm off; from the chosen start 0.0054 rad, the pose RMS against
    Vicon 82 mm. Robots 1, 2, 4, 5 and the whole logs keep the window's best."""
    from learners.arrays.batch import make_batch
    from learners.discrepancy.split import training_log
    from learners.em.estep import e_step
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions
    from learners.scoring import pose_scores

    tr = import_robot(DATA, 3, seconds=600.0)
    train = training_log(tr)
    candidates = pose_candidates(train)
    assert len(candidates) >= 2 and np.hypot(*(candidates[0].mean[:2] - tr.pose[0, :2])) > 3000.0
    opts = EMOptions(uncertainty=False)
    chosen = EMLearner(opts, check_field=False).fit([train]).params
    mirror = EMLearner(opts, check_field=False).fit([train], initial=(candidates[0],)).params
    assert chosen.sensor.sigma_bearing < 0.02 < mirror.sensor.sigma_bearing
    assert pose_scores(chosen, [tr])["pose_rms"] < 200.0
    batch = make_batch([train])
    gain = e_step(chosen, batch, "compiled", None).loglik - e_step(mirror, batch, "compiled", None).loglik
    assert gain > 1000.0, gain


def test_the_first_poses_candidates_hold_both_sides_of_a_row_of_landmarks():
    """``pose_candidates`` on a known answer: three landmarks in a row (x = 0, 0.35 m apart) seen from 2.9 m in front
    of them; the same ranges hold 2.9 m behind them, with the bearings mirrored. The true pose comes first (its
    bearings fit), within 100 mm and 0.02 rad; its mirror image is a candidate too, 5.8 m away."""
    landmarks = np.array([[0.0, -350.0], [0.0, 0.0], [0.0, 350.0]])
    pose = np.array([2900.0, 100.0, np.pi])
    seen = np.tile(np.arange(3), 3)
    d = landmarks[seen] - pose[:2]
    values = np.stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0]) - pose[2]], axis=1)
    values[:, 1] = np.arctan2(np.sin(values[:, 1]), np.cos(values[:, 1]))
    tr = trajectory.Trajectory(dt=0.1, landmarks=landmarks, sighting_frame=np.repeat(np.arange(3) * 10, 3),
                               sighting_landmark=seen, sighting_value=values, sensor_kind="range_mm",
                               controls=np.zeros((40, 2)), control_names=("v_mm_s", "omega_rad_s"))
    found = pose_candidates(tr)
    assert len(found) >= 2
    assert np.hypot(*(found[0].mean[:2] - pose[:2])) < 100.0
    assert abs(np.angle(np.exp(1j * (found[0].mean[2] - pose[2])))) < 0.02
    assert min(np.hypot(c.mean[0] + 2900.0, c.mean[1] - 100.0) for c in found[1:]) < 300.0


def _import_error(tmp_path, capsys) -> str:
    """``aibo import mrclam`` of robot 1 in ``tmp_path``: exit 2 and its one line of stderr (no warning before it)."""
    assert main(["import", "mrclam", str(tmp_path), "--robot", "1", "--out", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("aibo: error: ") and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("order", ["reversed", "one time"])
def test_ground_truth_without_two_increasing_times_is_one_line(tmp_path, capsys, order):
    tiny_dataset(tmp_path)
    gt = [(100.0 + 0.02 * k, 0.0, 0.0, 0.0) for k in range(600)]
    _write(tmp_path, "Robot1_Groundtruth.dat", gt[::-1] if order == "reversed" else [(100.0, *r[1:]) for r in gt])
    err = _import_error(tmp_path, capsys)
    assert "Robot1_Groundtruth.dat: fewer than 2 usable rows" in err and ("599 backward" in err or "599 repeated" in err)


def test_an_empty_file_is_one_line_without_numpys_warning(tmp_path, capsys):
    tiny_dataset(tmp_path)
    (tmp_path / "Robot1_Measurement.dat").write_text(HEADER)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's UserWarning would be raised here
        assert "Robot1_Measurement.dat: no data rows" in _import_error(tmp_path, capsys)


@pytest.mark.parametrize("name, rows, text", [
    ("Barcodes.dat", [(1, 5), (2, 14), (6, 63), (7, 81), (8, 7), (9, 63)], "barcode 63 is listed for subject 6 and for "
                                                                          "subject 9"),
    ("Landmark_Groundtruth.dat", [(6, 2.0, 1.0), (7, 4.0, -1.0), (6, 6.0, 1.0)], "subject 6 is listed on line 5 and "
                                                                                 "on line 7"),
])
def test_a_barcode_or_landmark_listed_twice_is_refused(tmp_path, capsys, name, rows, text):
    tiny_dataset(tmp_path)
    _write(tmp_path, name, rows)
    assert f"{name}: {text}" in _import_error(tmp_path, capsys)


def test_repeated_measurement_rows_count_once_and_are_reported(tmp_path):
    tiny_dataset(tmp_path)
    once = import_robot(tmp_path, 1, dt=0.1)
    rows = [(100.3, 63, 2.2, 0.46), (100.3, 81, 4.1, -0.25), (100.3, 63, 2.2, 0.46), (102.04, 7, 5.9, 0.2),
            (100.3, 81, 4.1, -0.25)]
    _write(tmp_path, "Robot1_Measurement.dat", rows)
    tr = import_robot(tmp_path, 1, dt=0.1)
    np.testing.assert_array_equal(tr.sighting_landmark, once.sighting_landmark)
    np.testing.assert_allclose(tr.sighting_value, once.sighting_value)
    assert tr.meta["dropped"]["measurement_rows_duplicated"] == 2


def test_poses_before_the_ground_truth_starts_are_flagged(tmp_path, capsys):
    """Ground truth starting 2 s after the first command: the first 20 poses were the first Vicon pose, unflagged,
    and the pose score counted them."""
    tiny_dataset(tmp_path)
    _write(tmp_path, "Robot1_Groundtruth.dat", [(102.0 + 0.02 * k, 0.2 + 0.002 * k, 0.0, 0.0) for k in range(500)])
    tr = import_robot(tmp_path, 1, dt=0.1)
    valid = pose_valid(tr)
    assert not valid[:20].any() and valid[21:].all()
    assert tr.meta["pose_gaps"]["poses_outside_groundtruth"] == 20
    assert main(["import", "mrclam", str(tmp_path), "--robot", "1", "--out", str(tmp_path / "x.npz")]) == 0
    assert "20 poses outside the ground truth's span flagged" in capsys.readouterr().out
