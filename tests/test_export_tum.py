"""``aibo export tum``: the smoothed poses ``aibo learn`` scores, and the log's truth, in the TUM format; evo's APE
(when evo is installed; CI installs it) equals the project's smoothed pose RMS on the same poses."""

from __future__ import annotations

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_core.geometry import wrap
from aibo_core.tum import frame_times, tum_text


def read_tum(path) -> np.ndarray:
    """(N, 8) rows t x y z qx qy qz qw of a TUM file."""
    return np.loadtxt(path, comments="#", ndmin=2)


def test_tum_lines_round_trip():
    t = 1.2484461883e9 + 0.1 * np.arange(4)
    pose = np.array([[1000.0, -2500.5, 0.3], [0.0, 0.0, -3.1], [12.25, 7.5, np.pi], [-1.0, 2.0, 2.5 + 2 * np.pi]])
    text = tum_text(t, pose, "a\nb")
    assert text.startswith("# a\n# b\n# timestamp x y z qx qy qz qw\n")
    rows = np.loadtxt(text.splitlines(), comments="#")
    np.testing.assert_allclose(rows[:, 0], t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(rows[:, 1:3], pose[:, :2] / 1000.0, rtol=1e-15)
    np.testing.assert_array_equal(rows[:, 3:6], 0.0)
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:8], axis=1), 1.0)
    yaw = 2 * np.arctan2(rows[:, 6], rows[:, 7])
    np.testing.assert_allclose(wrap(yaw - pose[:, 2]), 0.0, atol=1e-12)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """(log with truth and a flagged ground-truth gap, model fitted to it) as files."""
    from tests._diffdrive import diff_drive_log

    folder = tmp_path_factory.mktemp("tum")
    tr = diff_drive_log(60.0, seed=3)
    tr.meta = {"t0_s": 1700000000.25, "pose_gaps": {"flagged_runs": [[100, 119]]}}
    trajectory.save(tr, folder / "log.npz")
    assert main(["learn", str(folder / "log.npz"), "--out", str(folder / "model.json"), "--max-iter", "30"]) == 0
    return folder


def test_export_writes_the_smoothed_track_and_the_truth(fitted, tmp_path, capsys):
    from learners.model.io import load_model
    from learners.scoring import pose_scores, smoothed_poses

    log = trajectory.load(fitted / "log.npz")
    capsys.readouterr()
    assert main(["export", "tum", str(fitted / "log.npz"), "--model", str(fitted / "model.json"),
                 "--out", str(tmp_path / "est.tum"), "--truth", str(tmp_path / "gt.tum")]) == 0
    est, gt = read_tum(tmp_path / "est.tum"), read_tum(tmp_path / "gt.tum")
    model = load_model(fitted / "model.json")
    (track,), _ = smoothed_poses(model, [log])
    t = frame_times(log)
    assert t[0] == 1700000000.25 and len(est) == log.n_frames + 1 and len(gt) == log.n_frames + 1 - 20
    np.testing.assert_allclose(est[:, 0], t, rtol=0, atol=1e-6)
    np.testing.assert_allclose(est[:, 1:3] * 1000.0, track[:, :2], rtol=0, atol=1e-9)
    assert not np.isin(np.round(gt[:, 0], 3), np.round(t[100:120], 3)).any()  # the gap's poses left out
    rms = pose_scores(model, [log])["pose_rms"]
    err = np.hypot(*(est[np.isin(np.round(est[:, 0], 3), np.round(gt[:, 0], 3)), 1:3] - gt[:, 1:3]).T) * 1000.0
    assert np.sqrt(np.mean(err**2)) == pytest.approx(rms, rel=1e-9)
    assert f"smoothed pose RMS {rms:.1f} mm" in capsys.readouterr().out


def test_evo_ape_equals_the_smoothed_pose_rms(fitted, tmp_path):
    """evo's APE (translation, no alignment: the poses share the map's frame) on the exported files."""
    pytest.importorskip("evo", reason="evo not installed (a test-only tool, GPL: pip install evo; CI installs it)")
    from evo.core import metrics, sync
    from evo.tools import file_interface

    from learners.model.io import load_model
    from learners.scoring import pose_scores

    assert main(["export", "tum", str(fitted / "log.npz"), "--model", str(fitted / "model.json"),
                 "--out", str(tmp_path / "est.tum"), "--truth", str(tmp_path / "gt.tum")]) == 0
    ref = file_interface.read_tum_trajectory_file(str(tmp_path / "gt.tum"))
    est = file_interface.read_tum_trajectory_file(str(tmp_path / "est.tum"))
    ref, est = sync.associate_trajectories(ref, est)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rms = pose_scores(load_model(fitted / "model.json"), [trajectory.load(fitted / "log.npz")])["pose_rms"]
    assert ref.num_poses == 1201 - 20
    assert ape.get_statistic(metrics.StatisticsType.rmse) * 1000.0 == pytest.approx(rms, rel=1e-9)


def test_export_errors(fitted, tmp_path, capsys):
    log = trajectory.load(fitted / "log.npz")
    log.pose = None
    trajectory.save(log, tmp_path / "blind.npz")
    assert main(["export", "tum", str(tmp_path / "blind.npz"), "--model", str(fitted / "model.json"),
                 "--out", str(tmp_path / "est.tum"), "--truth", str(tmp_path / "gt.tum")]) == 2
    err = capsys.readouterr().err
    assert "blind.npz: field 'pose': missing" in err and err.count("\n") == 1
    assert not (tmp_path / "est.tum").exists()
    assert main(["export", "tum", str(fitted / "log.npz"), "--model", str(fitted / "model.json"),
                 "--out", str(fitted / "log.npz")]) == 2
    assert "an input is never overwritten" in capsys.readouterr().err


def test_a_model_of_the_other_kind_of_commands_is_named(fitted, tmp_path, capsys):
    """A model of discrete commands given for a log of velocity commands: one line naming the model's field and the
    log (it failed deep in the smoother with neither)."""
    assert main(["collect", "--steps", "300", "--seed", "1", "--out", str(tmp_path / "aibo.npz")]) == 0
    assert main(["learn", str(tmp_path / "aibo.npz"), "--out", str(tmp_path / "aibo.json"), "--max-iter", "3"]) == 0
    capsys.readouterr()
    assert main(["export", "tum", str(fitted / "log.npz"), "--model", str(tmp_path / "aibo.json"),
                 "--out", str(tmp_path / "est.tum")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "aibo.json: field 'action_model.feature_map': a model of discrete commands" in err
    assert "the log holds velocity commands (controls) (" in err and "log.npz: field 'controls')" in err
    assert not (tmp_path / "est.tum").exists()
