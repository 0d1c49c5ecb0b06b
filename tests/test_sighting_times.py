"""Sightings made between frame ends (``sighting_time``; ``learners.arrays.sighting_times``): kept by the log format and
the importers, predicted at their own time by every model, and on a generator whose camera runs on its own clock, the
bearing noise EM finds is the camera's, not the camera's plus the turn over the time to the frame's end."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from aibo_core import trajectory
from aibo_core.geometry import wrap
from aibo_core.timed_log import Streams, build
from aibo_core.trajectory import Trajectory, TrajectoryError
from learners.arrays.batch import make_batch
from learners.arrays.lowered import Lowered
from learners.arrays.sighting_times import at_sighting_times

BEARING_SD, RANGE_SD = 0.01, 20.0  # rad, mm: the asynchronous generator's camera


def asynchronous_drive(seconds: float = 300.0, camera_hz: float = 7.3, seed: int = 0) -> Streams:
    """A unicycle driven by (v mm/s, omega rad/s) commands held 1-3 s (turns up to 1.2 rad/s, back towards the middle
    when more than 2 m out), integrated every ms with a little velocity noise, and a range-and-bearing camera on its own
    clock (``camera_hz``, each shot jittered by up to 10 ms) seeing 6 landmarks within 4 m and 0.9 rad: the streams an
    importer reads (``aibo_core.timed_log``), the true pose every ms."""
    rng = np.random.default_rng(seed)
    step = 0.001
    landmarks = rng.uniform(-3000.0, 3000.0, (6, 2))
    command_t, commands, poses = [], [], [np.zeros(3)]
    t = 0.0
    while t < seconds:
        x, y, th = poses[-1]
        home = wrap(np.arctan2(-y, -x) - th) if np.hypot(x, y) > 2000.0 else rng.uniform(-1.0, 1.0)
        cmd = np.array([rng.uniform(100.0, 400.0), np.clip(home + rng.normal(0.0, 0.3), -1.2, 1.2)])
        n = int(round(rng.uniform(1.0, 3.0) / step))
        v, omega = (cmd + np.repeat(rng.normal(0.0, [20.0, 0.05], (n // 10 + 1, 2)), 10, axis=0)[:n]).T  # per 10 ms
        heading = th + np.cumsum(omega * step)
        before = np.concatenate([[th], heading[:-1]])
        poses += list(np.stack([x + np.cumsum(v * np.cos(before) * step), y + np.cumsum(v * np.sin(before) * step),
                                heading], axis=1))
        command_t.append(t)
        commands.append(cmd)
        t += n * step
    pose = np.array(poses)
    times = np.arange(len(pose)) * step
    shots = np.arange(0.05, min(seconds, times[-1]) - 0.1, 1.0 / camera_hz)
    shots = shots + rng.uniform(-0.01, 0.01, len(shots))
    seen_t, seen_lm, seen_z = [], [], []
    for i in np.rint(shots / step).astype(int):
        dx, dy = landmarks[:, 0] - pose[i, 0], landmarks[:, 1] - pose[i, 1]
        d, b = np.hypot(dx, dy), wrap(np.arctan2(dy, dx) - pose[i, 2])
        for m in np.flatnonzero((d > 300.0) & (d < 4000.0) & (np.abs(b) < 0.9)):
            seen_t.append(times[i])
            seen_lm.append(m)
            seen_z.append((d[m] + rng.normal(0.0, RANGE_SD), wrap(b[m] + rng.normal(0.0, BEARING_SD))))
    return Streams(command_t=np.array(command_t), commands=np.array(commands), sighting_t=np.array(seen_t),
                   sighting_landmark=np.array(seen_lm, dtype=np.int64), sighting_value=np.array(seen_z).reshape(-1, 2),
                   landmarks=landmarks, truth_t=times, truth=np.stack([pose[:, 0] / 1000.0, pose[:, 1] / 1000.0,
                                                                        pose[:, 2]], axis=1))


def test_the_importer_keeps_each_sightings_time_from_its_frames_end():
    s = asynchronous_drive(seconds=20.0)
    tr = build(s, 0.1, {}, "asynchronous drive")
    assert tr.sighting_time is not None and np.all(np.abs(tr.sighting_time) <= 0.05 + 1e-9)
    ends = (tr.sighting_frame + 1) * 0.1  # the first command at 0 s: frame k ends at (k + 1) dt
    inside = s.sighting_t[s.sighting_t < (tr.n_frames + 0.5) * 0.1]  # the rest is after the last frame: dropped
    np.testing.assert_allclose(np.sort(ends + tr.sighting_time), np.sort(inside), atol=1e-9)


def test_the_log_format_keeps_sighting_times_and_refuses_one_beyond_a_frame(tmp_path):
    tr = build(asynchronous_drive(seconds=20.0), 0.1, {}, "asynchronous drive")
    trajectory.save(tr, tmp_path / "log.npz")
    back = trajectory.load(tmp_path / "log.npz")
    np.testing.assert_array_equal(back.sighting_time, tr.sighting_time)
    keep = np.arange(tr.n_sightings) % 3 == 0
    part = tr.with_sightings(keep)
    np.testing.assert_array_equal(part.sighting_time, tr.sighting_time[keep])
    assert part.n_sightings == keep.sum() and part.sighting_value.shape == (keep.sum(), 2)
    bad = tr.sighting_time.copy()
    bad[3] = 0.15
    with pytest.raises(TrajectoryError, match=r"sighting_time.*row 3.*more than a frame"):
        Trajectory(**{**tr.__dict__, "sighting_time": bad}).validate("log.npz")
    with pytest.raises(TrajectoryError, match=r"sighting_time.*shape"):
        Trajectory(**{**tr.__dict__, "sighting_time": bad[:-1]}).validate("log.npz")


@pytest.mark.parametrize("tau", [-0.05, 0.03])
def test_the_prediction_moved_to_the_sightings_time_is_the_geometry_there_to_first_order(tau):
    """A robot at the frame's end pose moving at (v_x, v_y, omega) = (300 mm/s, 20 mm/s, 0.8 rad/s): the bearing and
    range predicted from the end pose plus the correction equal the exact ones from the pose tau s away, to within the
    second-order term (|tau| omega)^2 / 2 (and its like for the range)."""
    dt = 0.1
    vel = np.array([300.0, 20.0, 0.8])
    end, landmark = np.array([100.0, -50.0, 0.4]), np.array([1800.0, 900.0])

    def seen_from(pose):
        dx, dy = landmark - pose[:2]
        return np.hypot(dx, dy), wrap(np.arctan2(dy, dx) - pose[2])

    th = end[2] + vel[2] * tau  # the pose tau s after the end, moving on along the arc (first order is enough here)
    mid = end[2] + vel[2] * tau / 2
    c, s = np.cos(mid), np.sin(mid)
    there = np.array([end[0] + (c * vel[0] - s * vel[1]) * tau, end[1] + (s * vel[0] + c * vel[1]) * tau, th])
    r_end, b_end = seen_from(end)
    r_true, b_true = seen_from(there)
    log = Trajectory(dt=dt, landmarks=landmark[None], sighting_frame=np.array([0]), sighting_landmark=np.array([0]),
                     sighting_value=np.array([[r_true, b_true]]), sensor_kind="range_mm", controls=np.zeros((1, 2)),
                     control_names=("v_mm_s", "omega_rad_s"), sighting_time=np.array([tau]))
    batch = make_batch([log])
    lo = Lowered.plain(vel[None] * dt, np.eye(3), 0, np.array([0.0, 1.0]), 1.0, 1.0, np.zeros(3), np.eye(3), 1)
    at_sighting_times(lo, batch, range_sensor=True)
    assert abs(wrap(b_end + lo.bearing_offset[0] - b_true)) < (vel[2] * tau) ** 2 + 1e-4
    assert abs(r_end + lo.size_offset[0] - r_true) < 0.5  # mm, against a move of |tau| x 300 mm/s = 9-15 mm
    assert abs(b_end - b_true) > 0.02  # uncorrected: the turn alone moved it by 24-40 mrad


def test_a_log_without_sighting_times_is_predicted_at_the_frames_end():
    tr = build(asynchronous_drive(seconds=20.0), 0.1, {}, "asynchronous drive")
    plain = make_batch([replace(tr, sighting_time=None)])
    assert plain.sight_time is None
    lo = Lowered.plain(np.ones((tr.n_frames, 3)), np.eye(3), 0, np.array([0.0, 1.0]), 1.0, 1.0, np.zeros(3), np.eye(3),
                       tr.n_sightings)
    before = (lo.bearing_offset, lo.size_offset)
    at_sighting_times(lo, plain, range_sensor=True)
    assert lo.bearing_offset is before[0] and lo.size_offset is before[1]


@pytest.mark.slow
def test_on_a_camera_with_its_own_clock_em_finds_the_cameras_bearing_noise():
    """5 minutes, frames of 0.1 s, the camera at 7.3 Hz: a sighting is up to 50 ms from its frame's end, where a turn
    of up to 1.2 rad/s moves a bearing by up to 60 mrad. Predicted at the frame's end, EM takes that up as heading
    noise: 27 mrad per frame for the generator's 1.6 (sqrt(10) x 0.05 rad/s x 10 ms), the turns widening the bearing
    innovations ("|bearing| vs commanded turn rate" p = 9e-54), 2,206 nats less likely. At each sighting's own time:
    1.8 mrad, p = 0.35, and the bearing noise the camera's 10 mrad either way (10.7 / 10.8). Scored against the truth
    (``learners.scoring``), the true pose is taken when each sighting was made."""
    from learners.discrepancy.signatures import TURN_RATE, signatures
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions
    from learners.scoring import measured_sensor

    tr = build(asynchronous_drive(), 0.1, {}, "asynchronous drive")
    found = {}
    for name, log in (("own time", tr), ("frame end", replace(tr, sighting_time=None))):
        model = EMLearner(EMOptions(starts=1, uncertainty=False), check_field=False).fit([log]).params
        turn = [s.p_value for s in signatures(model, [log]) if s.residual == "|bearing| (sigma)" and s.variable == TURN_RATE]
        found[name] = (model.sensor.sigma_bearing, turn[0], float(np.sqrt(model.action.cov[2, 2])))
    heading_sd = np.sqrt(10) * 0.05 * 0.01  # rad per 0.1 s frame: ten 10 ms pieces of 0.05 rad/s noise
    assert abs(found["own time"][2] / heading_sd - 1.0) < 0.25 and found["frame end"][2] > 5 * heading_sd, found
    assert found["frame end"][1] < 1e-6 < 1e-3 < found["own time"][1], found
    assert abs(found["own time"][0] / BEARING_SD - 1.0) < 0.1, found
    # the truth's side too: the bearing error against the true pose when each sighting was made is the camera's (10.3
    # mrad), against the pose at its frame's end 25.4
    measured = {name: measured_sensor(model, [log])[2] for name, log in (("own time", tr), ("frame end", replace(
        tr, sighting_time=None)))}
    assert abs(measured["own time"] / BEARING_SD - 1.0) < 0.1 and measured["frame end"] > 2 * BEARING_SD, measured
