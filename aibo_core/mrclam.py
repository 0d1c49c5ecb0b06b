"""Import one robot of the UTIAS MRCLAM dataset (Leung et al., IJRR 2011) as an aibo-trajectory/2 log.

NumPy only. The folder holds ``Barcodes.dat``, ``Landmark_Groundtruth.dat`` and, per robot N,
``RobotN_Odometry.dat`` (velocity COMMANDS: time s, v m/s, omega rad/s, each held until the next
row), ``RobotN_Measurement.dat`` (time s, barcode, range m, bearing rad) and
``RobotN_Groundtruth.dat`` (Vicon: time s, x m, y m, theta rad).

What the log gets (frames of ``dt`` seconds from the first command, ``t0``):

- ``controls`` (T, 2) = [v mm/s, omega rad/s], ``control_names`` ``("v_mm_s", "omega_rad_s")``: the
  command held between rows, averaged over each frame (exact integral of the zero-order hold, so
  the commanded travel per frame is kept whatever ``dt``);
- sightings of the 15 landmarks (subjects 6-20, mapped through ``Barcodes.dat``) at the frame whose
  end is nearest their image time (several per frame allowed), that time from the frame's end in
  ``sighting_time`` (s, within +-dt / 2); ``sensor_kind="range_mm"``
  (range m -> mm), bearing wrapped to [-pi, pi]; ``landmarks`` (15, 2) in mm;
- ``pose`` (T+1, 3): Vicon ground truth interpolated at the frame boundaries (x, y linear, theta
  unwrapped); poses inside a ground-truth dropout longer than ``GAP_S`` are flagged in
  ``meta["pose_gaps"]``, as are poses before the first or after the last ground-truth row (held at it).
  The log ends at the earlier of the last command and the last ground-truth row. Without
  ``RobotN_Groundtruth.dat`` (a run without Vicon, or a copy that left the large files out) the log has
  no ``pose`` and no ``pose_gaps``, and ends at the last command: a log to learn from, not to score;
- ``meta``: the source (dataset, robot, files, ``t0``), every count of what was dropped (sightings of
  other robots, unknown barcodes, non-positive ranges, sightings outside the log span, measurement rows
  repeated exactly, repeated or backward odometry/ground-truth rows) and the ground-truth gaps. A barcode
  or landmark listed twice with different meanings is refused. It carries neither the start pose
  nor any ``field``: the learner must find its start from the sightings, as on any real robot.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from .geometry import wrap
from .timed_log import after_frame_end, held_average, increasing, nearest_frame_end, pose_valid, truth_at  # noqa: F401 (pose_valid: re-exported)
from .trajectory import VELOCITY_CONTROLS, Trajectory

#: Subjects 1-5 are the robots, 6-20 the landmarks (Barcodes.dat).
ROBOTS = (1, 2, 3, 4, 5)
CONTROL_NAMES = VELOCITY_CONTROLS
#: Largest magnitude of any number in the dataset's tables (times are ~1.3e9 s; anything larger is no
#: measurement and would overflow the learner's arithmetic).
MAX_ABS = 1e12
#: Default frame length (s); see docs/results.md "Real robot logs (MRCLAM)" for the speed/accuracy measurement.
DEFAULT_DT = 0.1


class MRCLAMError(ValueError):
    """A missing folder, file or robot, or an unreadable file (one line naming it)."""


def _read(path: Path, ncols: int) -> np.ndarray:
    if not path.is_file():
        raise MRCLAMError(f"{path}: file not found (an MRCLAM dataset folder holds Barcodes.dat, "
                          "Landmark_Groundtruth.dat and RobotN_{Odometry,Measurement,Groundtruth}.dat)")
    try:
        with warnings.catch_warnings():  # numpy warns of an empty file; the error below says it in one line
            warnings.simplefilter("ignore", UserWarning)
            a = np.loadtxt(path, comments="#", ndmin=2)
    except ValueError as exc:
        raise MRCLAMError(f"{path}: not a table of numbers ({exc})") from None
    if len(a) == 0:
        raise MRCLAMError(f"{path}: no data rows (expected rows of {ncols} numbers)")
    if a.shape[1] < ncols:
        raise MRCLAMError(f"{path}: expected rows of {ncols} numbers, got shape {a.shape}")
    bad = ~(np.abs(a[:, :ncols]) <= MAX_ABS)  # also NaN
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise MRCLAMError(f"{path}: row {row + 1} of the data, column {col + 1}: {a[row, col]!r} is not a finite "
                          f"number of magnitude <= {MAX_ABS:g}")
    return a[:, :ncols]


def _unique_rows(a: np.ndarray) -> tuple[np.ndarray, int]:
    """(``a`` without rows that repeat an earlier row exactly, in the original order; how many were dropped)."""
    _, first = np.unique(a, axis=0, return_index=True)
    keep = np.sort(first)
    return a[keep], len(a) - len(keep)


def _one_to_one(keys: np.ndarray, values: np.ndarray, path: Path, key: str, value: str) -> dict[int, int]:
    """{key: value} of a table's two columns; MRCLAMError naming the file when a key is listed with two values (its
    sightings would go to one of them silently). A row repeated exactly is harmless."""
    out: dict[int, int] = {}
    for k, v in zip(keys.tolist(), values.tolist()):
        k, v = int(k), int(v)
        if out.setdefault(k, v) != v:
            raise MRCLAMError(f"{path}: {key} {k} is listed for {value} {out[k]} and for {value} {v}; each {key} "
                              "must name one")
    return out


def file_names(robot: int) -> dict[str, str]:
    """The dataset files the import of robot ``robot`` reads, by role."""
    return {"barcodes": "Barcodes.dat", "landmarks": "Landmark_Groundtruth.dat",
            "odometry": f"Robot{robot}_Odometry.dat", "measurement": f"Robot{robot}_Measurement.dat",
            "groundtruth": f"Robot{robot}_Groundtruth.dat"}


def dataset_files(folder: str | os.PathLike) -> list[Path]:
    """Every file of the MRCLAM dataset in ``folder`` (all robots'), whether present or not: the
    files no output may replace."""
    names = {name for robot in ROBOTS for name in file_names(robot).values()}
    return [Path(folder) / name for name in sorted(names)]


def import_robot(folder: str | os.PathLike, robot: int, dt: float = DEFAULT_DT, start_s: float = 0.0,
                 seconds: float | None = None, lag_s: float = 0.0) -> Trajectory:
    """Robot ``robot`` of the MRCLAM dataset in ``folder`` as an aibo-trajectory/2 log (module docstring).

    ``start_s``: skip this many seconds after the first command; ``seconds``: keep at most this long.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise MRCLAMError(f"{folder}: no such folder (give the MRCLAM dataset folder, e.g. MRCLAM_Dataset7)")
    if robot not in ROBOTS:
        raise MRCLAMError(f"--robot {robot}: MRCLAM robots are numbered {ROBOTS[0]}-{ROBOTS[-1]}")
    if not (np.isfinite(dt) and dt > 0):
        raise MRCLAMError(f"--dt {dt}: must be a positive number of seconds")
    names = file_names(robot)
    barcodes = _read(folder / names["barcodes"], 2).astype(np.int64)
    lm_table = _read(folder / names["landmarks"], 3)
    odo = _read(folder / names["odometry"], 3)
    meas = _read(folder / names["measurement"], 4)
    # the Vicon file is optional: without it the log carries no pose (a run to learn from, not to score)
    has_truth = (folder / names["groundtruth"]).exists()
    gt = _read(folder / names["groundtruth"], 4) if has_truth else np.zeros((0, 4))

    keep, odo_rep, odo_back = increasing(odo[:, 0])
    odo = odo[keep]
    keep, gt_rep, gt_back = increasing(gt[:, 0]) if has_truth else (slice(None), 0, 0)
    gt = gt[keep]
    tables = [("odometry", odo, odo_rep, odo_back)]
    if has_truth:
        tables.append(("groundtruth", gt, gt_rep, gt_back))
    for role, rows, rep, back in tables:
        if len(rows) < 2:
            raise MRCLAMError(f"{folder / names[role]}: fewer than 2 usable rows (times must increase: {rep} "
                              f"repeated and {back} backward in time were dropped)")
    meas, meas_dup = _unique_rows(meas)

    t0 = float(odo[0, 0]) + float(start_s)
    t_end = min(float(odo[-1, 0]), float(gt[-1, 0])) if has_truth else float(odo[-1, 0])
    if seconds is not None:
        t_end = min(t_end, t0 + float(seconds))
    T = int(np.floor((t_end - t0) / dt + 1e-9))
    if T < 1:
        raise MRCLAMError(f"robot {robot}: the log span from {start_s} s holds no frame of {dt} s")
    edges = t0 + dt * np.arange(T + 1)
    controls = held_average(odo[:, 0] + lag_s, odo[:, 1:3] * [1000.0, 1.0], edges)

    # landmarks: subjects 6-20 in the order of Landmark_Groundtruth.dat
    subjects = lm_table[:, 0].astype(np.int64)
    landmarks = lm_table[:, 1:3] * 1000.0
    subject_of = _one_to_one(barcodes[:, 1], barcodes[:, 0], folder / names["barcodes"], "barcode", "subject")
    _one_to_one(subjects, np.arange(len(subjects)), folder / names["landmarks"], "subject", "row")
    lm_index = {int(s): i for i, s in enumerate(subjects)}
    subj = np.array([subject_of.get(int(b), -1) for b in meas[:, 1]], dtype=np.int64)
    is_robot = np.isin(subj, ROBOTS)
    unknown = (subj < 0) | (~is_robot & ~np.isin(subj, subjects))
    landmark = np.array([lm_index.get(int(s), -1) for s in subj], dtype=np.int64)
    bad_range = ~is_robot & ~unknown & (meas[:, 2] <= 0)
    frame = nearest_frame_end(meas[:, 0], t0, dt)
    inside = (frame >= 0) & (frame < T)
    use = ~is_robot & ~unknown & ~bad_range & inside
    order = np.flatnonzero(use)[np.argsort(frame[use], kind="stable")]
    values = np.stack([meas[order, 2] * 1000.0, wrap(meas[order, 3])], axis=1)

    # ground truth at the frame boundaries, gaps flagged
    pose, pose_gaps = truth_at(gt[:, 0], gt[:, 1], gt[:, 2], gt[:, 3], edges) if has_truth else (None, None)

    meta = {
        "generator": "aibo_core.mrclam",
        "source": {"dataset": folder.resolve().name, "robot": int(robot),
                   "files": sorted(v for k, v in names.items() if has_truth or k != "groundtruth"),
                   "citation": "Leung, Halpern, Barfoot, Liu: The UTIAS Multi-Robot Cooperative Localization "
                               "and Mapping Dataset, IJRR 30(8), 2011",
                   "t0_unix_s": t0, "start_s": float(start_s), "seconds": T * dt},
        "landmark_subjects": subjects.tolist(),
        "dropped": {
            "sightings_of_robots": int(is_robot.sum()),
            "sightings_unknown_barcode": int(unknown.sum()),
            "unknown_barcodes": sorted({int(b) for b in meas[unknown, 1]}),
            "sightings_nonpositive_range": int(bad_range.sum()),
            "sightings_outside_span": int((~is_robot & ~unknown & ~bad_range & ~inside).sum()),
            "odometry_rows_repeated": odo_rep, "odometry_rows_backward": odo_back,
            "groundtruth_rows_repeated": gt_rep, "groundtruth_rows_backward": gt_back,
            "measurement_rows_duplicated": meas_dup,
        },
    }
    if has_truth:
        meta["pose_gaps"] = pose_gaps
    tr = Trajectory(dt=float(dt), landmarks=landmarks, sighting_frame=frame[order],
                    sighting_landmark=landmark[order], sighting_value=values, sensor_kind="range_mm",
                    sighting_time=after_frame_end(meas[order, 0], frame[order], t0, dt),
                    controls=controls, control_names=CONTROL_NAMES, pose=pose, meta=meta)
    return tr.validate(f"MRCLAM robot {robot}")
