"""A robot's log as CSV files in one folder (no ROS needed) -> an aibo-trajectory/2 log.

NumPy only. The layout (docs/real-logs.md); every file starts with a header line naming its columns (any order,
extra columns ignored), times are seconds on one clock (any epoch), lengths metres, angles radians:

==================  ===================================  ==================================================
file                columns                              meaning
==================  ===================================  ==================================================
``commands.csv``    ``t, v_m_s, omega_rad_s``            velocity command, held until the next row
``detections.csv``  ``t, id, range_m, bearing_rad``      one landmark sighting per row; bearing CCW from the
                                                         robot's heading (positive: to the left)
``landmarks.csv``   ``id, x_m, y_m``                     the map: landmark positions in the world frame
``truth.csv``       ``t, x_m, y_m, theta_rad``           optional ground truth (e.g. motion capture): the
                                                         log's ``pose``, used only to score a fit
==================  ===================================  ==================================================

Times must not go back within a file (a repeated command or truth time: the first row kept, counted); a
detection of an id not in ``landmarks.csv`` is counted and dropped, not fatal. Frames, and detections measured by a
sensor away from the robot's origin (``SensorPose``), as in ``aibo_core.timed_log``.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

import numpy as np

from .timed_log import LogSourceError, SensorPose, Streams, build, first_backward, increasing
from .trajectory import Trajectory

FILES = {"commands": ("t", "v_m_s", "omega_rad_s"), "detections": ("t", "id", "range_m", "bearing_rad"),
         "landmarks": ("id", "x_m", "y_m"), "truth": ("t", "x_m", "y_m", "theta_rad")}
#: Largest magnitude of any number in a table (Unix times are ~2e9 s); anything larger is no measurement.
MAX_ABS = 1e12


def read_table(path: Path, columns: tuple[str, ...]) -> np.ndarray:
    """(n, len(columns)) float: the named columns of a CSV file with a header line; at least one row."""
    if not path.is_file():
        raise LogSourceError(f"{path}: file not found (a CSV log holds {', '.join(n + '.csv' for n in FILES)}; "
                             "truth.csv optional)")
    try:
        with open(path, newline="") as f:
            rows = [r for r in csv.reader(f) if r and any(c.strip() for c in r)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise LogSourceError(f"{path}: not readable as CSV ({exc})") from None
    if not rows:
        raise LogSourceError(f"{path}: empty (expected a header line: {','.join(columns)})")
    header = [c.strip() for c in rows[0]]
    missing = [c for c in columns if c not in header]
    if missing:
        raise LogSourceError(f"{path}: header {','.join(header)!r} lacks column {missing[0]!r} "
                             f"(expected {','.join(columns)})")
    if len(rows) < 2:
        raise LogSourceError(f"{path}: no data rows after the header")
    idx = [header.index(c) for c in columns]
    out = np.empty((len(rows) - 1, len(columns)))
    for i, row in enumerate(rows[1:]):
        for j, (k, name) in enumerate(zip(idx, columns)):
            cell = row[k].strip() if k < len(row) else ""
            try:
                out[i, j] = float(cell)
            except ValueError:
                out[i, j] = np.nan
            if not abs(out[i, j]) <= MAX_ABS:
                raise LogSourceError(f"{path}: row {i + 2}, column {name!r}: {cell!r} is not a finite number of "
                                     f"magnitude <= {MAX_ABS:g}")
    return out


def _ids(path: Path, column: np.ndarray) -> np.ndarray:
    bad = column != np.round(column)
    if bad.any():
        i = int(np.argmax(bad))
        raise LogSourceError(f"{path}: row {i + 2}, column 'id': {float(column[i])!r} is not an integer")
    return column.astype(np.int64)


def read_landmark_map(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """(ids (B,), positions (B, 2) mm) of a map file ``id,x_m,y_m``; ids unique."""
    path = Path(path)
    table = read_table(path, FILES["landmarks"])
    ids = _ids(path, table[:, 0])
    uniq, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        raise LogSourceError(f"{path}: column 'id': landmark {int(uniq[np.argmax(counts > 1)])} appears more than once")
    return ids, table[:, 1:3] * 1000.0


def landmark_index(ids: np.ndarray, map_ids: np.ndarray) -> np.ndarray:
    """(S,) int: each sighted id's row in the map, -1 for ids the map does not hold."""
    lookup = {int(i): k for k, i in enumerate(map_ids)}
    return np.array([lookup.get(int(i), -1) for i in ids], dtype=np.int64)


def ordered(path: Path | str, t: np.ndarray, what: str = "row") -> None:
    """Refuse (LogSourceError) times that go back: ``what`` names the unit counted (row, message)."""
    i = first_backward(t)
    if i is not None:
        first = 2 if what == "row" else 1  # CSV rows counted from the header's 1, messages from 1
        raise LogSourceError(f"{path}: {what} {i + first}: time {float(t[i])!r} s is earlier than the {what} before "
                             f"({float(t[i - 1])!r} s): times must not go back")


def dedupe(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(times, values, repeated count): rows repeating the time before dropped (the first kept)."""
    keep, repeated, _ = increasing(t)
    return t[keep], values[keep], repeated


def import_folder(folder: str | os.PathLike, dt: float, sensor: SensorPose = SensorPose()) -> Trajectory:
    """The CSV log in ``folder`` (module docstring) as an aibo-trajectory/2 log in frames of ``dt`` s, its detections
    measured by ``sensor``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise LogSourceError(f"{folder}: no such folder (give the folder holding commands.csv, detections.csv, "
                             "landmarks.csv and optionally truth.csv)")
    paths = {name: folder / f"{name}.csv" for name in FILES}
    map_ids, landmarks = read_landmark_map(paths["landmarks"])
    cmd = read_table(paths["commands"], FILES["commands"])
    det = read_table(paths["detections"], FILES["detections"])
    for name, table in (("commands", cmd), ("detections", det)):
        ordered(paths[name], table[:, 0])
    cmd_t, commands, cmd_rep = dedupe(cmd[:, 0], cmd[:, 1:3] * [1000.0, 1.0])
    ids = _ids(paths["detections"], det[:, 1])
    streams = Streams(command_t=cmd_t, commands=commands, sighting_t=det[:, 0],
                      sighting_landmark=landmark_index(ids, map_ids),
                      sighting_value=np.stack([det[:, 2] * 1000.0, det[:, 3]], axis=1), landmarks=landmarks)
    dropped: dict[str, Any] = {"command_rows_repeated": cmd_rep}
    if paths["truth"].exists():
        gt = read_table(paths["truth"], FILES["truth"])
        ordered(paths["truth"], gt[:, 0])
        streams.truth_t, streams.truth, dropped["truth_rows_repeated"] = dedupe(gt[:, 0], gt[:, 1:4])
    meta = {"generator": "aibo_core.csv_import",
            "source": {"folder": folder.resolve().name, "files": sorted(p.name for p in paths.values() if p.exists())},
            "landmark_ids": map_ids.tolist(), "dropped": dropped,
            "unknown_ids": sorted({int(i) for i in ids[streams.sighting_landmark < 0]})}
    return build(streams, dt, meta, str(folder), sensor)
