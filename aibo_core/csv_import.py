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

Times must not go back in ``commands.csv`` and ``truth.csv`` (a repeated time: the first row kept, counted);
``detections.csv``'s rows may come in any order (per landmark, per camera) and are taken in time order. A detection
of an id not in ``landmarks.csv`` is counted and dropped, not fatal; a bearing beyond a full turn (degrees) and
commands a median of more than 10 s apart (milliseconds) are refused. Frames, and detections measured by a
sensor away from the robot's origin (``SensorPose``), as in ``aibo_core.timed_log``.
"""

from __future__ import annotations

import codecs
import csv
import io
import os
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np

from .timed_log import LogSourceError, SensorPose, Streams, build, first_backward, increasing
from .trajectory import Trajectory

FILES = {"commands": ("t", "v_m_s", "omega_rad_s"), "detections": ("t", "id", "range_m", "bearing_rad"),
         "landmarks": ("id", "x_m", "y_m"), "truth": ("t", "x_m", "y_m", "theta_rad")}
#: Largest magnitude of any number in a table (Unix times are ~2e9 s); anything larger is no measurement.
MAX_ABS = 1e12
#: Largest bearing magnitude (rad) of a detection: beyond a full turn it is degrees, most likely.
MAX_BEARING_RAD = 2.0 * np.pi
#: Largest median spacing (s) of the commands: a robot's velocity commands come at 1-100 Hz; 10 s apart is
#: milliseconds read as seconds (a 10 Hz stream's 100 ms), most likely.
MAX_COMMAND_SPACING_S = 10.0


class Table(NamedTuple):
    """A CSV file's named columns: ``values`` (n, columns) float and ``rows`` (n,) each row's line in the file (the
    header's is 1), the numbers errors give."""

    values: np.ndarray
    rows: np.ndarray


def _text(data: bytes) -> str:
    """A CSV file's bytes as text: UTF-16 after its byte-order mark (a spreadsheet's "Unicode text"), else UTF-8 (a
    byte-order mark, "CSV UTF-8", read as none), else Latin-1 (a Windows spreadsheet's "CSV": an accented note in a
    column the import does not read; the numbers and the column names it reads are ASCII in all three)."""
    if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return data.decode("utf-16")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def _delimiter(text: str) -> str:
    """The cells' separator: a comma, or where the header line holds none, a tab (a spreadsheet's "Unicode text",
    tab-separated) or a semicolon (a spreadsheet's "CSV" where the comma is the decimal mark: its numbers are
    refused by cell)."""
    header = next((line for line in text.splitlines() if line.strip()), "")
    if "," in header:
        return ","
    return "\t" if "\t" in header else ";" if ";" in header else ","


def _decimal_comma(cell: str) -> bool:
    """Whether ``cell`` is a number with a comma for its decimal point (``'2,5'``)."""
    try:
        float(cell.replace(",", ".", 1))
    except ValueError:
        return False
    return "," in cell


def read_table(path: Path, columns: tuple[str, ...]) -> Table:
    """The named columns of a CSV file with a header line; at least one row. Blank lines are skipped, the text read
    as ``_text`` says; errors name the row by its line in the file."""
    if not path.is_file():
        raise LogSourceError(f"{path}: file not found (a CSV log holds {', '.join(n + '.csv' for n in FILES)}; "
                             "truth.csv optional)")
    try:
        text = _text(path.read_bytes())
        reader = csv.reader(io.StringIO(text, newline=""), delimiter=_delimiter(text))
        rows = [(reader.line_num, r) for r in reader if r and any(c.strip() for c in r)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise LogSourceError(f"{path}: not readable as CSV ({exc})") from None
    if not rows:
        raise LogSourceError(f"{path}: empty (expected a header line: {','.join(columns)})")
    header = [c.strip() for c in rows[0][1]]
    missing = [c for c in columns if c not in header]
    if missing:
        raise LogSourceError(f"{path}: header {','.join(header)!r} lacks column {missing[0]!r} "
                             f"(expected {','.join(columns)})")
    twice = [c for c in columns if header.count(c) > 1]
    if twice:
        raise LogSourceError(f"{path}: header {','.join(header)!r} names column {twice[0]!r} more than once")
    if len(rows) < 2:
        raise LogSourceError(f"{path}: no data rows after the header")
    idx = [header.index(c) for c in columns]
    out = np.empty((len(rows) - 1, len(columns)))
    for i, (line, row) in enumerate(rows[1:]):
        for j, (k, name) in enumerate(zip(idx, columns)):
            cell = row[k].strip() if k < len(row) else ""
            try:
                out[i, j] = float(cell)
            except ValueError:
                out[i, j] = np.nan
            if not abs(out[i, j]) <= MAX_ABS:
                what = "empty" if not cell else f"{cell!r} is not a finite number of magnitude <= {MAX_ABS:g}" + (
                    " (a decimal comma? write the numbers with a decimal point)" if _decimal_comma(cell) else "")
                raise LogSourceError(f"{path}: row {line}, column {name!r}: {what}")
    return Table(out, np.array([line for line, _ in rows[1:]], dtype=np.int64))


def _ids(path: Path, table: Table, col: int = 0) -> np.ndarray:
    """Column ``col`` of ``table`` (ids) as integers; a fraction is refused."""
    column = table.values[:, col]
    bad = column != np.round(column)
    if bad.any():
        i = int(np.argmax(bad))
        raise LogSourceError(f"{path}: row {table.rows[i]}, column 'id': {float(column[i])!r} is not an integer")
    return column.astype(np.int64)


def read_landmark_map(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """(ids (B,), positions (B, 2) mm) of a map file ``id,x_m,y_m``; ids unique."""
    path = Path(path)
    table = read_table(path, FILES["landmarks"])
    ids = _ids(path, table)
    uniq, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        twice = int(uniq[np.argmax(counts > 1)])
        rows = ", ".join(str(r) for r in table.rows[ids == twice])
        raise LogSourceError(f"{path}: column 'id': landmark {twice} appears more than once (rows {rows})")
    return ids, table.values[:, 1:3] * 1000.0


def landmark_index(ids: np.ndarray, map_ids: np.ndarray) -> np.ndarray:
    """(S,) int: each sighted id's row in the map, -1 for ids the map does not hold."""
    lookup = {int(i): k for k, i in enumerate(map_ids)}
    return np.array([lookup.get(int(i), -1) for i in ids], dtype=np.int64)


def ordered(path: Path | str, t: np.ndarray, what: str = "row", numbers: np.ndarray | None = None) -> None:
    """Refuse (LogSourceError) times that go back: ``what`` names the unit counted (row, message), ``numbers`` each
    one's number (a CSV ``Table``'s rows; default: messages counted from 1)."""
    i = first_backward(t)
    if i is not None:
        number = int(numbers[i]) if numbers is not None else i + 1
        raise LogSourceError(f"{path}: {what} {number}: time {float(t[i])!r} s is earlier than the {what} before "
                             f"({float(t[i - 1])!r} s): times must not go back")


def dedupe(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(times, values, repeated count): rows repeating the time before dropped (the first kept)."""
    keep, repeated, _ = increasing(t)
    return t[keep], values[keep], repeated


def check_bearings(path: Path | str, bearings: np.ndarray, where: Callable[[int], str]) -> None:
    """Refuse bearings beyond a full turn (``MAX_BEARING_RAD``): degrees given for radians, most likely; ``where(i)``
    names the i-th (a CSV row, a message)."""
    beyond = np.flatnonzero(np.abs(bearings) > MAX_BEARING_RAD)
    if len(beyond):
        i = int(beyond[0])
        raise LogSourceError(f"{path}: {where(i)}: bearing {float(bearings[i]):g} is more than a full turn "
                             f"({len(beyond)} of {len(bearings)} bearings are): bearings are radians, not degrees")


def check_command_spacing(path: Path, t: np.ndarray) -> None:
    """Refuse commands a median of more than ``MAX_COMMAND_SPACING_S`` apart: times in milliseconds, most likely,
    which would make a log 1,000 times too long."""
    if len(t) > 2 and (gap := float(np.median(np.diff(t)))) > MAX_COMMAND_SPACING_S:
        raise LogSourceError(f"{path}: column 't': the commands are a median {gap:g} s apart (at most "
                             f"{MAX_COMMAND_SPACING_S:g}): times are seconds (milliseconds divided by 1000)")


def import_folder(folder: str | os.PathLike, dt: float, sensor: SensorPose = SensorPose()) -> Trajectory:
    """The CSV log in ``folder`` (module docstring) as an aibo-trajectory/2 log in frames of ``dt`` s, its detections
    measured by ``sensor``."""
    folder = Path(folder)
    if not folder.is_dir():
        what = "is a file, not a folder" if folder.is_file() else "no such folder"
        raise LogSourceError(f"{folder}: {what} (give the folder holding commands.csv, detections.csv, "
                             "landmarks.csv and optionally truth.csv)")
    paths = {name: folder / f"{name}.csv" for name in FILES}
    map_ids, landmarks = read_landmark_map(paths["landmarks"])
    cmd = read_table(paths["commands"], FILES["commands"])
    ordered(paths["commands"], cmd.values[:, 0], numbers=cmd.rows)
    check_command_spacing(paths["commands"], cmd.values[:, 0])
    cmd_t, commands, cmd_rep = dedupe(cmd.values[:, 0], cmd.values[:, 1:3] * [1000.0, 1.0])
    det = read_table(paths["detections"], FILES["detections"])
    ids = _ids(paths["detections"], det, 1)
    check_bearings(paths["detections"], det.values[:, 3], lambda i: f"row {det.rows[i]}, column 'bearing_rad'")
    order = np.argsort(det.values[:, 0], kind="stable")  # rows in any order: per landmark, per camera
    d, ids = det.values[order], ids[order]
    streams = Streams(command_t=cmd_t, commands=commands, sighting_t=d[:, 0],
                      sighting_landmark=landmark_index(ids, map_ids),
                      sighting_value=np.stack([d[:, 2] * 1000.0, d[:, 3]], axis=1), landmarks=landmarks)
    dropped: dict[str, Any] = {"command_rows_repeated": cmd_rep}
    if paths["truth"].exists():
        gt = read_table(paths["truth"], FILES["truth"])
        ordered(paths["truth"], gt.values[:, 0], numbers=gt.rows)
        streams.truth_t, streams.truth, dropped["truth_rows_repeated"] = dedupe(gt.values[:, 0], gt.values[:, 1:4])
    meta = {"generator": "aibo_core.csv_import",
            "source": {"folder": folder.resolve().name, "files": sorted(p.name for p in paths.values() if p.exists())},
            "landmark_ids": map_ids.tolist(), "dropped": dropped,
            "unknown_ids": sorted({int(i) for i in ids[streams.sighting_landmark < 0]})}
    return build(streams, dt, meta, str(folder), sensor)
