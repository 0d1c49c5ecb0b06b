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
  or landmark listed twice with different meanings is refused, as are a file of another kind (another count of
  columns: ``COLUMNS``), a fractional id, a bearing beyond a full turn (``csv_import.check_bearings``) and a lag not
  well below the log's span (``MAX_LAG_FRACTION``); errors name the line in the file (1-based, comment lines
  counted). It carries neither the start pose
  nor any ``field``: the learner must find its start from the sightings, as on any real robot.
"""

from __future__ import annotations

import os
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

from .csv_import import check_bearings
from .geometry import wrap
from .timed_log import (  # noqa: F401 (pose_valid: re-exported)
    LogSourceError,
    after_frame_end,
    held_average,
    increasing,
    nearest_frame_end,
    pose_valid,
    truth_at,
)
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


#: Each file's columns (by role), the ones the import reads: errors name them. Landmark_Groundtruth.dat may hold two
#: more, the x and y std-dev (m), which are not read (``EXTRA_COLUMNS``).
COLUMNS = {"barcodes": ("subject", "barcode"), "landmarks": ("subject", "x m", "y m"),
           "odometry": ("time s", "v m/s", "omega rad/s"), "measurement": ("time s", "barcode", "range m", "bearing rad"),
           "groundtruth": ("time s", "x m", "y m", "theta rad")}
EXTRA_COLUMNS = {"landmarks": 2}
#: Columns that hold ids (subject or barcode numbers): a fraction is refused, not truncated to another id.
ID_COLUMNS = {"barcodes": (0, 1), "landmarks": (0,), "measurement": (1,)}


def _data_lines(path: Path) -> list[tuple[int, list[str]]]:
    """(number of the line in the file, 1-based as an editor counts them, comment lines included; its fields) of every
    line holding data (anything before a ``#`` but blanks): what the errors name."""
    with open(path, encoding="utf-8", errors="replace") as f:
        return [(n, fields) for n, line in enumerate(f, 1) if (fields := line.split("#", 1)[0].split())]


def _line(path: Path, row: int) -> int:
    """The line in the file (``_data_lines``) of data row ``row`` (0-based)."""
    return _data_lines(path)[row][0]


def _numbers(count: int) -> str:
    return f"{count} number" + ("" if count == 1 else "s")


def _column(col: int, names: tuple[str, ...]) -> str:
    """``column N (its name)`` of 0-based ``col``, as the errors name it."""
    return f"column {col + 1}" + (f" ({names[col]})" if col < len(names) else "")


def _not_a_table(path: Path, names: tuple[str, ...]) -> MRCLAMError:
    """The error of a file NumPy cannot read as a table: the first line whose count of fields differs from the
    others', or the first field that is not a number, by its line in the file."""
    rows = _data_lines(path)
    widths = Counter(len(fields) for _, fields in rows)
    width = widths.most_common(1)[0][0] if widths else 0
    for n, fields in rows:
        if len(fields) != width:
            return MRCLAMError(f"{path}: line {n} has {_numbers(len(fields))}, the others {width} (a file cut short "
                               "or edited?)")
        for col, cell in enumerate(fields):
            try:
                float(cell)
            except ValueError:
                return MRCLAMError(f"{path}: line {n}, {_column(col, names)}: {cell!r} is not a number")
    return MRCLAMError(f"{path}: not a table of numbers")


def _read(path: Path, role: str) -> np.ndarray:
    """The columns ``COLUMNS[role]`` of a dataset file; MRCLAMError (one line naming the file, and the line in it)
    for a missing or unreadable file, one of another kind (another count of columns), a value that is not a finite
    number of magnitude <= ``MAX_ABS``, or an id (``ID_COLUMNS``) that is not an integer."""
    names = COLUMNS[role]
    ncols = len(names)
    widths = (ncols, ncols + EXTRA_COLUMNS[role]) if role in EXTRA_COLUMNS else (ncols,)
    if not path.is_file():
        raise MRCLAMError(f"{path}: file not found (an MRCLAM dataset folder holds Barcodes.dat, "
                          "Landmark_Groundtruth.dat and RobotN_{Odometry,Measurement,Groundtruth}.dat)")
    try:
        with warnings.catch_warnings():  # numpy warns of an empty file; the error below says it in one line
            warnings.simplefilter("ignore", UserWarning)
            a = np.loadtxt(path, comments="#", ndmin=2)
    except ValueError:
        raise _not_a_table(path, names) from None
    want = " or ".join(str(w) for w in widths)
    what = f" ({', '.join(names)})"
    if len(a) == 0:
        raise MRCLAMError(f"{path}: no data rows (expected rows of {want} numbers{what})")
    if a.shape[1] not in widths:
        raise MRCLAMError(f"{path}: expected rows of {want} numbers{what}, got rows of {a.shape[1]} ({len(a)} rows): "
                          "a file of another kind?")
    a = a[:, :ncols]
    bad = ~(np.abs(a) <= MAX_ABS)  # also NaN
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise MRCLAMError(f"{path}: line {_line(path, row)}, {_column(col, names)}: {float(a[row, col])!r} is not a "
                          f"finite number of magnitude <= {MAX_ABS:g}")
    for col in ID_COLUMNS.get(role, ()):
        fraction = np.flatnonzero(a[:, col] != np.round(a[:, col]))
        if len(fraction):
            row = int(fraction[0])
            raise MRCLAMError(f"{path}: line {_line(path, row)}, {_column(col, names)}: {float(a[row, col])!r} is not "
                              "an integer")
    return a


def _unique_rows(a: np.ndarray) -> tuple[np.ndarray, int]:
    """(``a`` without rows that repeat an earlier row exactly, in the original order; how many were dropped)."""
    _, first = np.unique(a, axis=0, return_index=True)
    keep = np.sort(first)
    return a[keep], len(a) - len(keep)


def _one_to_one(keys: np.ndarray, values: np.ndarray, path: Path, key: str, value: str) -> dict[int, int]:
    """{key: value} of a table's two columns; MRCLAMError naming the file and both lines when a key is listed with two
    values (its sightings would go to one of them silently). A row repeated exactly is harmless."""
    out: dict[int, int] = {}
    first: dict[int, int] = {}
    for i, (k, v) in enumerate(zip(keys.tolist(), values.tolist())):
        k, v = int(k), int(v)
        first.setdefault(k, i)
        if out.setdefault(k, v) != v:
            raise MRCLAMError(f"{path}: {key} {k} is listed for {value} {out[k]} and for {value} {v} (lines "
                              f"{_line(path, first[k])} and {_line(path, i)}); each {key} must name one")
    return out


def _listed_once(subjects: np.ndarray, path: Path) -> None:
    """MRCLAMError naming the file and both lines when a landmark's subject is listed twice (which position holds?)."""
    first: dict[int, int] = {}
    for i, s in enumerate(subjects.tolist()):
        if first.setdefault(s, i) != i:
            raise MRCLAMError(f"{path}: subject {s} is listed on line {_line(path, first[s])} and on line "
                              f"{_line(path, i)}; each landmark must be listed once")


#: The longest ``lag_s`` (``--lag``), as a fraction of the log's span: the first ``lag_s`` seconds of the log take the
#: first command (nothing is known of the commands before it), so a lag must be well below the log's length.
MAX_LAG_FRACTION = 0.1


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
    barcodes = _read(folder / names["barcodes"], "barcodes").astype(np.int64)
    lm_table = _read(folder / names["landmarks"], "landmarks")
    odo = _read(folder / names["odometry"], "odometry")
    meas = _read(folder / names["measurement"], "measurement")
    try:  # a bearing beyond a full turn is degrees (or no bearing), as the other importers refuse it
        check_bearings(folder / names["measurement"], meas[:, 3],
                       lambda i: f"line {_line(folder / names['measurement'], i)}, column 4 (bearing rad)")
    except LogSourceError as exc:
        raise MRCLAMError(str(exc)) from None
    # the Vicon file is optional: without it the log carries no pose (a run to learn from, not to score)
    has_truth = (folder / names["groundtruth"]).exists()
    gt = _read(folder / names["groundtruth"], "groundtruth") if has_truth else np.zeros((0, 4))

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
    if abs(lag_s) >= MAX_LAG_FRACTION * T * dt:
        raise MRCLAMError(f"--lag {lag_s:g}: the log of robot {robot} is {T * dt:g} s long; a lag must be well "
                          f"below that (less than {MAX_LAG_FRACTION:.0%} of it, {MAX_LAG_FRACTION * T * dt:g} s): its "
                          f"first {abs(lag_s):g} s would all take one command")
    edges = t0 + dt * np.arange(T + 1)
    controls = held_average(odo[:, 0] + lag_s, odo[:, 1:3] * [1000.0, 1.0], edges)

    # landmarks: subjects 6-20 in the order of Landmark_Groundtruth.dat
    subjects = lm_table[:, 0].astype(np.int64)
    landmarks = lm_table[:, 1:3] * 1000.0
    subject_of = _one_to_one(barcodes[:, 1], barcodes[:, 0], folder / names["barcodes"], "barcode", "subject")
    _listed_once(subjects, folder / names["landmarks"])
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
