"""Scores of a learned model against a real log's ground truth (``pose``, e.g. Vicon in MRCLAM).

Pure functions of (model, logs). Three models are compared:

- ``face value``: the commands taken at their word (v_actual = v_cmd, omega_actual = omega_cmd, no
  lateral motion; range = true distance), the baseline every user has without learning. Its noise
  (needed by the smoother) is the learned model's, so only the mean functions differ;
- ``learned``: the model under test;
- ``fit to Vicon``: the same model class fitted to the ground truth directly (the action weights
  regressed on window velocities, the sensor curve on the true distances): the yardstick.

Measures (poses inside ground-truth gaps, ``meta["pose_gaps"]``, are left out):

- velocity: over non-overlapping windows of ``window_s`` (1 s by default, so the ~0.2 s command
  lag and Vicon jitter average out), the model's travel (per-frame displacements composed) against
  the travel measured from ``pose``, both as forward / lateral / turn rates in the window's
  mid-heading frame; RMS in mm/s and rad/s, and relative to each measured component's range;
- range curve: RMS over the observed true distances of the model's mean range minus the curve of
  the same basis fitted to (true distance, measured range); noise: the model's sigmas beside the
  residual standard deviations of that fit (range mm, bearing rad);
- smoothed pose: RMS position (mm) and heading (rad) error of the E-step's smoothed poses. Sightings whose
  innovation's Mahalanobis^2 exceeds ``gate`` are not applied, for every model alike: by default the fit's own
  outlier gate (``DEFAULT_GATE``, 50; ``gate=None`` applies every sighting). Neither is right everywhere. Ungated,
  one gross outlier decides the score: MRCLAM robot 5's misread at 618 s (Mahalanobis^2 53,000) takes the
  diagnosed model's track 5.6 m off, 1507 mm RMS against 130 mm gated (the face value 1049 / 466). Gated, a track
  that drifts rejects every later sighting and never returns: robot 3 at face value from a start 6.6 m off was
  679 mm ungated, 982 gated. Since the start comes from the whole log's first sightings (``search.base_fit``) no
  robot locks out (face value ungated / gated: 461 / 349, 577 / 464, 620 / 500, 540 / 577, 1049 / 466 mm), so the
  default is the gate, as a filter run on the robot would have it;
- motion noise: over the same windows, the true travel's error against the model's prediction from the true start
  pose, over the model's own standard deviation of it (``motion_noise_scores``; forward, lateral, heading): what a
  simulator driven with the model gets right about how far its robot wanders. On MRCLAM's five robots (whole logs,
  ``aibo learn``'s defaults; ``scripts/mrclam_diagnose.py``) the forward and lateral noise are several times too
  wide, the heading's right: sensor errors that persist over seconds, which the model has no state for, taken up
  as motion noise (docs/results.md, "The twin's motion noise against Vicon").
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from aibo_core.geometry import motion, rel_disp, rel_disp_jac, wrap
from aibo_core.timed_log import pose_valid
from aibo_core.trajectory import VELOCITY_CONTROLS, Trajectory
from learners.arrays.batch import make_batch
from learners.arrays.lowered import fit_polynomial
from learners.em.options import DEFAULT_GATE
from learners.model.model import Model

COLUMNS = ("face value", "learned", "fit to Vicon")


def face_value_model(model: Model) -> Model:
    """``model`` with its action means replaced by the commands' face value (vx = v, vtheta = omega)
    and its range curve by range = distance; noise and start beliefs kept."""
    a = model.action
    if a.discrete or a.feature_map not in ("diff_drive", "unicycle") or tuple(a.control_names) != VELOCITY_CONTROLS:
        raise ValueError(f"face value needs a diff_drive or unicycle model of controls {VELOCITY_CONTROLS}")
    w = np.zeros_like(a.weights)
    w[0, 0], w[1, 2] = a.dt, a.dt  # per-frame displacement = velocity x dt
    coef = np.zeros_like(model.sensor.coef)
    if model.sensor.kind != "range_mm" or model.sensor.basis != "power":
        raise ValueError("face value needs a range sensor in the power basis")
    coef[1] = 1.0
    return model.with_(action=a.with_values(weights=w), sensor=replace(model.sensor, coef=coef), effects=())


def _windows(tr: Trajectory, window_s: float) -> np.ndarray:
    """(n, 2) [first frame, end frame) of non-overlapping windows free of ground-truth gaps."""
    W = max(1, int(round(window_s / tr.dt)))
    starts = np.arange(0, tr.n_frames - W + 1, W)
    bad = np.concatenate([[0], np.cumsum(~pose_valid(tr))])
    keep = bad[starts + W + 1] - bad[starts] == 0
    return np.stack([starts[keep], starts[keep] + W], axis=1)


def _as_rates(rel: np.ndarray, seconds: float) -> np.ndarray:
    """Relative displacements (n, 3) in the start frame -> forward, lateral, turn rates in the
    window's mid-heading frame."""
    half = rel[:, 2] / 2
    c, s = np.cos(half), np.sin(half)
    return np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]], axis=1) / seconds


def measured_window_velocities(tr: Trajectory, window_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(windows (n, 2), velocities (n, 3) mm/s, mm/s, rad/s) measured from ``pose``."""
    win = _windows(tr, window_s)
    p0, p1 = tr.pose[win[:, 0]], tr.pose[win[:, 1]]
    c, s = np.cos(p0[:, 2]), np.sin(p0[:, 2])
    d = p1 - p0
    rel = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], wrap(d[:, 2])], axis=1)
    return win, _as_rates(rel, (win[0, 1] - win[0, 0]) * tr.dt if len(win) else 1.0)


def model_window_velocities(model: Model, tr: Trajectory, win: np.ndarray) -> np.ndarray:
    """(n, 3) the model's velocities over the windows: its per-frame displacements composed, after the effects
    that act on the commands (a lag shifts them) or scale the motion, as the model predicts them."""
    commands, scale = model.effective_commands(make_batch([tr]))
    disp = model.action.displacements(commands)
    if scale is not None:
        disp = disp * scale
    W = int(win[0, 1] - win[0, 0])
    pose = np.zeros((len(win), 3))
    for k in range(W):
        d = disp[win[:, 0] + k]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        pose += np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
    return _as_rates(pose, W * tr.dt)


def fit_action_to_truth(model: Model, logs: list[Trajectory], window_s: float = 1.0) -> Model:
    """The action weights regressed on the measured window velocities (window-mean features)."""
    phi, vel = [], []
    for tr in logs:
        win, v = measured_window_velocities(tr, window_s)
        f = model.action.features(tr.controls)
        cum = np.concatenate([np.zeros((1, f.shape[1])), np.cumsum(f, axis=0)])
        phi.append((cum[win[:, 1]] - cum[win[:, 0]]) / (win[:, 1] - win[:, 0])[:, None])
        vel.append(v)
    phi_all, vel_all = np.concatenate(phi), np.concatenate(vel)
    w = model.action.constrained([phi_all] * 3, vel_all, np.linalg.lstsq(phi_all, vel_all, rcond=None)[0])
    w = w * model.action.dt
    return model.with_(action=model.action.with_values(weights=w), effects=())  # of the raw commands: no lag


def velocity_scores(model: Model, logs: list[Trajectory], window_s: float = 1.0) -> dict[str, float]:
    """RMS velocity error over windows (module docstring): ``vx_rms`` mm/s, ``vy_rms`` mm/s,
    ``vtheta_rms`` rad/s and ``*_rel`` (fractions of the measured ranges)."""
    err, meas = [], []
    for tr in logs:
        win, v = measured_window_velocities(tr, window_s)
        err.append(model_window_velocities(model, tr, win) - v)
        meas.append(v)
    err, meas = np.concatenate(err), np.concatenate(meas)
    rms = np.sqrt(np.mean(err**2, axis=0))
    span = np.ptp(meas, axis=0)
    out = {f"{n}_rms": float(r) for n, r in zip(("vx", "vy", "vtheta"), rms)}
    out.update({f"{n}_rel": float(r / s) for n, r, s in zip(("vx", "vy", "vtheta"), rms, span)})
    out["windows"] = float(len(err))
    return out


def window_travel_errors(model: Model, tr: Trajectory, window_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Over the non-overlapping windows of ``window_s`` free of ground-truth gaps: ((n, 3) the true travel minus the
    model's prediction from the true pose at the window's start, (n, 3) the model's standard deviation of that
    travel), both in the start's robot frame (forward mm, lateral mm, heading rad). The prediction is the filter's
    prediction step run open loop: the lowered model's per-frame displacements and world offsets composed (effects
    on the commands, e.g. a lag, included) and its per-frame covariances propagated to first order from zero."""
    if tr.pose is None:
        raise ValueError("the motion noise against ground truth needs a log with ground truth ('pose')")
    win = _windows(tr, window_s)
    lo = model.lower(make_batch([tr]))
    cov = lo.frame_cov()
    mean, P = tr.pose[win[:, 0]].copy(), np.zeros((len(win), 3, 3))
    for k in range(int(win[0, 1] - win[0, 0]) if len(win) else 0):
        i = win[:, 0] + k
        g, F, R = motion(mean, lo.disp[i])
        mean = g + lo.offset[i]
        P = F @ P @ np.swapaxes(F, 1, 2) + R @ cov[i] @ np.swapaxes(R, 1, 2)
    start = tr.pose[win[:, 0]]
    err = rel_disp(start, tr.pose[win[:, 1]]) - rel_disp(start, mean)
    err[:, 2] = wrap(err[:, 2])
    _, L2, _ = rel_disp_jac(start, mean)  # the travel's derivative in the end pose: R3(-theta0)
    var = np.einsum("nij,njk,nik->ni", L2, P, L2)  # the diagonal of L2 P L2^T
    return err, np.sqrt(np.maximum(var, 0.0))


#: ``motion_noise_scores``' ratios (forward, lateral, heading), each beside its ``noise_sd_*``
NOISE_KEYS = ("noise_fwd", "noise_lat", "noise_head")


def motion_noise_scores(model: Model, logs: list[Trajectory], window_s: float = 1.0) -> dict[str, float]:
    """The model's motion noise against ground truth (``window_travel_errors``): per component, the RMS of the travel
    errors over the RMS of the model's standard deviations, ``noise_fwd``, ``noise_lat``, ``noise_head``. 1: the
    model's noise is the size of its errors over ``window_s``; below 1 the model's robot wanders more than the
    measured one (a twin driven with it is too noisy); above 1 the model is overconfident (its means err, over the
    window, by more than its noise allows, or its noise is too small). ``noise_sd_fwd`` (mm),
    ``noise_sd_lat`` (mm), ``noise_sd_head`` (rad): the model's RMS standard deviations."""
    pairs = [window_travel_errors(model, tr, window_s) for tr in logs]
    err, sd = np.concatenate([e for e, _ in pairs]), np.concatenate([s for _, s in pairs])
    if not len(err):  # no window of window_s free of ground-truth gaps: nothing measured, said as NaN
        return {key: float("nan") for k in NOISE_KEYS for key in (k, k.replace("noise_", "noise_sd_"))}
    rms_err, rms_sd = np.sqrt(np.mean(err**2, axis=0)), np.sqrt(np.mean(sd**2, axis=0))
    out = {}
    for k, e, s in zip(NOISE_KEYS, rms_err, rms_sd):
        out[k] = float(e / s) if s > 0 else float("nan")
        out[k.replace("noise_", "noise_sd_")] = float(s)
    return out


#: frames: the command's change this long after the frame whose turn error ``command_feedback`` correlates it with
FEEDBACK_FRAMES_LATER = 1


def command_feedback(model: Model, logs: list[Trajectory]) -> dict[str, float] | None:
    """Whether the logs' commands answer the motion, from ground truth: the correlation of each frame's turn error (the
    true heading change less the model's, rad) with the commanded turn rate's change ``FEEDBACK_FRAMES_LATER`` frame
    later, over the frames whose poses are valid. A robot's response is causal, so where the commands are open loop
    (independent of the motion's errors) it is 0 within ``sd_open_loop`` = 1 / sqrt(pairs); a controller that steers
    on the pose raises its command after the robot turned short (negative; the MRCLAM robots -0.10 to -0.16 against
    Vicon; simulated closed loops -0.03 to -0.12: docs/results.md, "A driver that steers on its pose"). None without
    truth or without a commanded turn rate (``VELOCITY_CONTROLS``)."""
    errors, changes, k = [], [], FEEDBACK_FRAMES_LATER
    for tr in logs:
        if tr.pose is None or tr.controls is None or tuple(tr.control_names or ()) != VELOCITY_CONTROLS:
            return None
        turn = model.lower(make_batch([tr])).disp[:, 2]
        error = wrap(np.diff(tr.pose[:, 2])) - turn
        valid = pose_valid(tr)
        ok = valid[:-1] & valid[1:]
        change = np.diff(tr.controls[:, 1], prepend=tr.controls[0, 1])
        keep = ok[:-k] & ok[k:]
        errors.append(error[:-k][keep])
        changes.append(change[k:][keep])
    e, c = np.concatenate(errors), np.concatenate(changes)
    if len(e) < 10 or np.std(e) == 0 or np.std(c) == 0:
        return None
    return {"frames_later": FEEDBACK_FRAMES_LATER, "correlation": float(np.corrcoef(e, c)[0, 1]),
            "sd_open_loop": float(1.0 / np.sqrt(len(e))), "pairs": int(len(e))}


def truth_at_sightings(tr: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """((S,) bool, (S, 3) pose): the true pose when each sighting was made and whether it is known. At its frame's
    end, or with a ``sighting_time`` that far between the end pose and the boundary pose before (or after) it (x, y
    linearly, the heading the shorter way round); known when both poses are outside the ground truth's gaps."""
    f = tr.sighting_frame + 1
    valid = pose_valid(tr)
    if tr.sighting_time is None:
        return valid[f], tr.pose[f]
    a = tr.sighting_time / tr.dt  # frames after the end pose (negative: before it)
    other = np.clip(np.where(a < 0, f - 1, f + 1), 0, tr.n_frames)
    w = np.where(other == f, 0.0, np.abs(a))
    p0, p1 = tr.pose[f], tr.pose[other]
    step = np.concatenate([p1[:, :2] - p0[:, :2], wrap(p1[:, 2] - p0[:, 2])[:, None]], axis=1)
    return valid[f] & (valid[other] | (w == 0.0)), p0 + w[:, None] * step


def _true_sightings(logs: list[Trajectory]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """((S,) bool over every log's sightings: with a known true pose; and ``true_sightings``' three arrays of those)."""
    known, d, z, eb = [], [], [], []
    for tr in logs:
        ok, pose = truth_at_sightings(tr)
        p = pose[ok]
        L = tr.landmarks[tr.sighting_landmark[ok]]
        known.append(ok)
        d.append(np.hypot(L[:, 0] - p[:, 0], L[:, 1] - p[:, 1]))
        z.append(tr.sighting_value[ok, 0])
        eb.append(wrap(tr.sighting_value[ok, 1] - (np.arctan2(L[:, 1] - p[:, 1], L[:, 0] - p[:, 0]) - p[:, 2])))
    return np.concatenate(known), np.concatenate(d), np.concatenate(z), np.concatenate(eb)


def true_sightings(logs: list[Trajectory]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(true distance mm, measured range mm, bearing residual rad) of the sightings with a known true pose, each at
    the pose when it was made (``truth_at_sightings``)."""
    return _true_sightings(logs)[1:]


def measured_sensor(model: Model, logs: list[Trajectory]) -> tuple[np.ndarray, float, float, tuple[float, float]]:
    """(curve coefficients in the model's basis and degree, range sd mm, bearing sd rad, distance
    range mm) fitted to the true distances; gross outliers (> 5 sd) left out of the sds."""
    d, z, eb = true_sightings(logs)
    x = d if model.sensor.basis == "power" else 1.0 / d
    deg = len(model.sensor.coef) - 1
    coef = fit_polynomial(x, z, np.ones_like(d), deg)
    res = z - replace(model.sensor, coef=coef).mean(d)
    keep = np.abs(res) < 5 * np.std(res)  # gross outliers (0.1% of MRCLAM's rows) out of the sds
    keep = np.abs(res) < 5 * np.std(res[keep])
    eb_keep = np.abs(eb) < 5 * np.std(eb)
    lo, hi = np.percentile(d, [1, 99])
    return coef, float(np.std(res[keep])), float(np.std(eb[eb_keep])), (float(lo), float(hi))


def sensor_scores(model: Model, logs: list[Trajectory]) -> dict[str, float]:
    """``range_curve_rms`` mm (vs the curve fitted to truth, over its 1-99% distances),
    ``range_rms`` mm (measured range minus the model's mean at the true distance, its effects' scale and offset of
    each sighting applied), the model's
    ``sigma_range`` and ``sigma_bearing``."""
    coef, _, _, (lo, hi) = measured_sensor(model, logs)
    grid = np.linspace(lo, hi, 400)
    truth = replace(model.sensor, coef=coef).mean(grid)
    ok, d, z, _ = _true_sightings(logs)
    # each sighting's scale and offset of the model's effects (a range's shrink), not its move to the sighting's time:
    # the true distance is the one at that time already
    lowered = model.lower(make_batch([replace(tr, sighting_time=None) for tr in logs]))
    mean = lowered.size_scale[ok] * model.sensor.mean(d) + lowered.size_offset[ok]
    return {"range_curve_rms": float(np.sqrt(np.mean((model.sensor.mean(grid) - truth) ** 2))),
            "range_rms": float(np.sqrt(np.mean((z - mean) ** 2))),
            "sigma_range": float(model.sensor.sigma_size), "sigma_bearing": float(model.sensor.sigma_bearing)}


def smoothed_poses(model: Model, logs: list[Trajectory], gate: float | None = DEFAULT_GATE) -> tuple[list[np.ndarray], float]:
    """(the E-step's smoothed poses per log, (T+1, 3) [x mm, y mm, theta rad]; the log-likelihood), sightings beyond
    ``gate`` (Mahalanobis^2; by default the fit's gate; None: every sighting applied) not applied."""
    from learners.em.estep import e_step, weighed_on

    batch = make_batch(logs)
    post = e_step(weighed_on(model, batch), batch, "compiled", gate)  # a mixture's weights on these logs
    return [post.mu_gamma[a:b] for a, b in zip(batch.pose_start[:-1], batch.pose_start[1:])], float(post.loglik)


def pose_scores(model: Model, logs: list[Trajectory], gate: float | None = DEFAULT_GATE) -> dict[str, float]:
    """RMS position (mm) and heading (rad) error of the smoothed poses against ``pose``; sightings beyond ``gate``
    (Mahalanobis^2; by default the fit's gate; None: every sighting applied) are not (module docstring)."""
    tracks, loglik = smoothed_poses(model, logs, gate)
    err_xy, err_th = [], []
    for tr, mu in zip(logs, tracks):
        ok = pose_valid(tr)
        err_xy.append(np.hypot(*(mu[ok, :2] - tr.pose[ok, :2]).T))
        err_th.append(wrap(mu[ok, 2] - tr.pose[ok, 2]))
    e, t = np.concatenate(err_xy), np.concatenate(err_th)
    return {"pose_rms": float(np.sqrt(np.mean(e**2))), "heading_rms": float(np.sqrt(np.mean(t**2))),
            "loglik": loglik}


def score(model: Model, logs: list[Trajectory], window_s: float = 1.0) -> dict[str, dict[str, float]]:
    """{column: {measure: value}} for the face value, the learned model and the fit to Vicon."""
    if any(tr.pose is None for tr in logs):
        raise ValueError("scoring needs logs with ground truth ('pose')")
    face = face_value_model(model)
    fitted = fit_action_to_truth(model, logs, window_s)
    coef, s_range, s_bearing, _ = measured_sensor(model, logs)
    fitted = fitted.with_(sensor=replace(model.sensor, coef=coef, sigma_size=s_range, sigma_bearing=s_bearing))
    out = {}
    for name, m in zip(COLUMNS, (face, model, fitted)):
        row = velocity_scores(m, logs, window_s)
        row.update(sensor_scores(m, logs))
        row.update(pose_scores(m, logs))
        out[name] = row
    # the motion noise is the learned model's alone: the other columns borrow it, beside means it was not fitted with
    out["learned"].update(motion_noise_scores(model, logs, window_s))
    out["face value"].update(sigma_range=float("nan"), sigma_bearing=float("nan"))
    return out


ROWS = [
    ("vx RMS (mm/s)", "vx_rms", "{:.2f}"),
    ("vx RMS / range", "vx_rel", "{:.2%}"),
    ("vy RMS (mm/s)", "vy_rms", "{:.2f}"),
    ("vtheta RMS (rad/s)", "vtheta_rms", "{:.4f}"),
    ("vtheta RMS / range", "vtheta_rel", "{:.2%}"),
    ("range curve RMS (mm)", "range_curve_rms", "{:.1f}"),
    ("range residual RMS (mm)", "range_rms", "{:.1f}"),
    ("sigma range (mm)", "sigma_range", "{:.1f}"),
    ("sigma bearing (deg)", "sigma_bearing", "deg"),
    ("smoothed pose RMS (mm)", "pose_rms", "{:.1f}"),
    ("smoothed heading RMS (deg)", "heading_rms", "deg"),
    ("forward error / model sd", "noise_fwd", "{:.2f}"),
    ("lateral error / model sd", "noise_lat", "{:.2f}"),
    ("heading error / model sd", "noise_head", "{:.2f}"),
]


def score_table(scores: dict[str, dict[str, float]]) -> str:
    """The scores as a text table (one column per model; for ``fit to Vicon`` the sigmas are the
    measured ones)."""
    width = max(14, *(len(c) + 2 for c in scores))
    lines = [f"{'against ground truth':28s}" + "".join(f"{c:>{width}s}" for c in scores)]
    for label, key, fmt in ROWS:
        cells = []
        for col in scores.values():
            v = col.get(key, float("nan"))
            cells.append("-" if not np.isfinite(v) else (f"{np.degrees(v):.2f}" if fmt == "deg" else fmt.format(v)))
        lines.append(f"{label:28s}" + "".join(f"{s:>{width}s}" for s in cells))
    n = int(next(iter(scores.values())).get("windows", 0))
    lines.append(f"(velocities over {n} windows of 1 s, and the travel's error over each against the model's standard "
                 "deviation from the true start: 1 when the motion noise is right, below 1 when the model's robot "
                 "wanders more than the measured one; poses in ground-truth gaps left out)")
    return "\n".join(lines)
