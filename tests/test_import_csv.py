"""``aibo import csv``: the documented layout (commands.csv, detections.csv, landmarks.csv, truth.csv) on a small
synthetic drive; its errors, one line each (the MRCLAM round trip: tests/test_import_bag.py)."""

from __future__ import annotations

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_core.geometry import wrap
from tests._bags import drive, write_csv


def _import(folder, out) -> int:
    return main(["import", "csv", str(folder), "--out", str(out), "--dt", "0.1"])


def test_the_layout_gives_the_drive(tmp_path):
    rows = drive(seconds=6.0)
    assert _import(write_csv(tmp_path / "log", rows), tmp_path / "log.npz") == 0
    log = trajectory.load(tmp_path / "log.npz")
    assert log.n_frames == 59 and log.control_names == ("v_mm_s", "omega_rad_s") and log.sensor_kind == "range_mm"
    np.testing.assert_allclose(log.controls, rows.commands[:59, 1:] * [1000.0, 1.0], atol=1e-9)  # held over whole frames
    np.testing.assert_allclose(log.landmarks, rows.landmarks[:, 1:] * 1000.0)
    # sightings at t = 1000 + 0.2 k: the frame whose end is nearest; the one at t0 itself is outside the log
    assert log.meta["dropped"]["sightings_outside_span"] == 3 and log.n_sightings == len(rows.detections) - 3
    np.testing.assert_array_equal(log.sighting_frame[:3], [1, 1, 1])
    np.testing.assert_allclose(log.sighting_value[:, 0], rows.detections[3:, 2] * 1000.0, atol=1e-9)
    np.testing.assert_allclose(1000.0 + 0.1 * (log.sighting_frame + 1) + log.sighting_time, rows.detections[3:, 0],
                               atol=1e-9)  # each sighting's time kept: its frame's end plus sighting_time
    i = np.searchsorted(rows.truth[:, 0], 1000.0 + 0.1 * np.arange(60) - 1e-9)
    np.testing.assert_allclose(log.pose[:, :2], rows.truth[i, 1:3] * 1000.0, atol=1e-9)
    np.testing.assert_allclose(wrap(log.pose[:, 2] - rows.truth[i, 3]), 0.0, atol=1e-9)
    assert log.meta["t0_s"] == 1000.0 and log.meta["source"]["files"] == ["commands.csv", "detections.csv",
                                                                          "landmarks.csv", "truth.csv"]


def test_truth_is_optional_and_unknown_ids_are_counted(tmp_path, capsys):
    rows = drive()
    rows.detections[5, 1] = 42
    assert _import(write_csv(tmp_path / "log", rows, truth=False), tmp_path / "log.npz") == 0
    log = trajectory.load(tmp_path / "log.npz")
    assert log.pose is None and log.meta["unknown_ids"] == [42] and log.meta["dropped"]["sightings_unknown_id"] == 1
    assert "no truth; dropped: sightings unknown id 1" in capsys.readouterr().out


def _degrees(text: str) -> str:
    """detections.csv with its first bearing given in degrees (1 rad)."""
    lines = text.splitlines()
    cells = lines[1].split(",")
    cells[3] = f"{np.degrees(1.0):.6g}"
    return "\n".join([lines[0], ",".join(cells), *lines[2:]]) + "\n"


def _milliseconds(text: str) -> str:
    """commands.csv with its times in milliseconds."""
    lines = text.splitlines()
    rows = [line.split(",") for line in lines[1:]]
    return "\n".join([lines[0]] + [",".join([f"{float(r[0]) * 1000:.1f}", *r[1:]]) for r in rows]) + "\n"


def _shifted(seconds: float):
    """An edit moving every time of a file by ``seconds`` (another clock)."""
    def edit(text: str) -> str:
        lines = text.splitlines()
        rows = [line.split(",") for line in lines[1:]]
        return "\n".join([lines[0]] + [",".join([f"{float(r[0]) + seconds:.3f}", *r[1:]]) for r in rows]) + "\n"
    return edit


@pytest.mark.parametrize("name,edit,expected", [
    ("commands", lambda text: text.replace("omega_rad_s", "w"), "commands.csv: header 't,v_m_s,w' lacks column 'omega_rad_s'"),
    ("detections", lambda text: text.replace(",11,", ",eleven,", 1), "detections.csv: row 2, column 'id': 'eleven' is not a finite"),
    ("detections", lambda text: text.replace(",11,", ",11.5,", 1), "detections.csv: row 2, column 'id': 11.5 is not an integer"),
    ("truth", lambda text: text.replace("1000.05,", "999.0,", 1), "truth.csv: row 3: time 999.0 s is earlier than the row before"),
    ("landmarks", lambda text: text + "11,0.0,0.0\n", "landmarks.csv: column 'id': landmark 11 appears more than once (rows 2, "),
    ("commands", lambda text: text.splitlines()[0] + "\n", "commands.csv: no data rows after the header"),
    ("detections", lambda text: "", "detections.csv: empty"),
    ("commands", lambda text: text.replace("1000.1,", "nan,", 1), "commands.csv: row 3, column 't': 'nan' is not a finite"),
    ("commands", lambda text: text.replace("1000.1,", "\n\n1000.1,", 1).replace("1000.2,", ",", 1),
     "commands.csv: row 6, column 't': empty"),  # the row's line in the file, blank lines counted
    ("detections", lambda text: text.replace("range_m,bearing_rad", "range_m,range_m,bearing_rad"),
     "detections.csv: header 't,id,range_m,range_m,bearing_rad' names column 'range_m' more than once"),
    ("detections", _degrees, "detections.csv: row 2, column 'bearing_rad': bearing 57.2958 is more than a full turn"),
    ("commands", _milliseconds, "commands.csv: column 't': the commands are a median 100 s apart"),
    ("detections", _shifted(-100.0), "none of the 90 detections can be used: 90 outside the commands' span 1000-1005.9 s "
     "(the detections' times 900-905.8 s: another clock"),
    ("landmarks", lambda text: text.replace("\n11,", "\n111,").replace("\n12,", "\n112,").replace("\n13,", "\n113,"),
     "none of the 90 detections can be used: 90 of ids the map does not hold (ids 11, 12, 13; the map's 111, 112, 113)"),
])
def test_bad_files_are_one_line(tmp_path, capsys, name, edit, expected):
    folder = write_csv(tmp_path / "log", drive())
    path = folder / f"{name}.csv"
    path.write_text(edit(path.read_text()))
    assert _import(folder, tmp_path / "log.npz") == 2
    err = capsys.readouterr().err
    assert err.startswith("aibo: error: ") and err.count("\n") == 1 and expected in err, err
    assert not (tmp_path / "log.npz").exists()


def test_a_missing_folder_or_file(tmp_path, capsys):
    assert _import(tmp_path / "nope", tmp_path / "log.npz") == 2
    assert "no such folder" in capsys.readouterr().err
    folder = write_csv(tmp_path / "log", drive())
    (folder / "commands.csv").unlink()
    assert _import(folder, tmp_path / "log.npz") == 2
    assert "commands.csv: file not found" in capsys.readouterr().err


def test_a_sensor_away_from_the_origin_is_moved_to_it(tmp_path):
    """A drive seen by a sensor 0.25 m ahead, 0.05 m left and turned 0.3 rad, imported with its ``--sensor-pose``:
    the sightings the same drive gives with the sensor at the origin, to rounding (without the option, off by more
    than 0.2 m in range)."""
    pose = (0.25, 0.05, 0.3)
    at_origin, mounted = drive(seconds=6.0), drive(seconds=6.0, sensor=pose)
    assert _import(write_csv(tmp_path / "origin", at_origin), tmp_path / "origin.npz") == 0
    folder = write_csv(tmp_path / "mounted", mounted)
    assert main(["import", "csv", str(folder), "--out", str(tmp_path / "moved.npz"), "--sensor-pose", "0.25,0.05,0.3"]) == 0
    assert _import(folder, tmp_path / "as_is.npz") == 0
    origin, moved, as_is = (trajectory.load(tmp_path / f"{n}.npz") for n in ("origin", "moved", "as_is"))
    np.testing.assert_allclose(moved.sighting_value[:, 0], origin.sighting_value[:, 0], atol=1e-6)
    np.testing.assert_allclose(wrap(moved.sighting_value[:, 1] - origin.sighting_value[:, 1]), 0.0, atol=1e-9)
    assert np.max(np.abs(as_is.sighting_value[:, 0] - origin.sighting_value[:, 0])) > 200.0
    assert moved.meta["sensor_pose"] == {"x_m": 0.25, "y_m": 0.05, "yaw_rad": 0.3}
    assert origin.meta["sensor_pose"] == {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0}



def test_a_spreadsheet_export_imports_as_the_file(tmp_path):
    """A byte-order mark (Excel's "CSV UTF-8"), CRLF line ends, blank lines, and detections in no time order (sorted
    by landmark, as a per-landmark export): the same log as the plain files."""
    rows = drive(seconds=6.0)
    assert _import(write_csv(tmp_path / "plain", rows), tmp_path / "plain.npz") == 0
    folder = write_csv(tmp_path / "sheet", rows)
    for name in ("commands", "landmarks", "detections"):
        lines = (folder / f"{name}.csv").read_text().splitlines()
        if name == "detections":
            lines = [lines[0]] + sorted(lines[1:], key=lambda line: line.split(",")[1])
        (folder / f"{name}.csv").write_bytes(("\ufeff" + "\r\n\r\n".join(lines) + "\r\n").encode("utf-8"))
    assert _import(folder, tmp_path / "sheet.npz") == 0
    plain, sheet = (trajectory.load(tmp_path / f"{n}.npz") for n in ("plain", "sheet"))
    for field in ("controls", "landmarks", "sighting_frame", "sighting_landmark", "sighting_value", "sighting_time"):
        np.testing.assert_array_equal(getattr(sheet, field), getattr(plain, field), err_msg=field)


def test_other_spreadsheet_encodings_import_as_the_file(tmp_path, capsys):
    """A Windows spreadsheet's "CSV" (Latin-1, an accented note in a column not read), its "Unicode text" (UTF-16,
    tab-separated): the same log as the plain files. Semicolons with decimal commas: refused by row and column."""
    rows = drive(seconds=6.0)
    assert _import(write_csv(tmp_path / "plain", rows), tmp_path / "plain.npz") == 0
    plain = trajectory.load(tmp_path / "plain.npz")
    for kind in ("latin-1", "utf-16", "semicolon"):
        folder = write_csv(tmp_path / kind, rows)
        for name in ("commands", "landmarks", "detections"):
            lines = (folder / f"{name}.csv").read_text().splitlines()
            if kind == "latin-1":
                text = "\n".join([lines[0] + ",note"] + [line + ",caf\u00e9" for line in lines[1:]]) + "\n"
                (folder / f"{name}.csv").write_bytes(text.encode("latin-1"))
            elif kind == "utf-16":
                (folder / f"{name}.csv").write_bytes("\r\n".join(line.replace(",", "\t") for line in lines).encode("utf-16"))
            else:
                (folder / f"{name}.csv").write_text("\n".join(line.replace(",", ";").replace(".", ",") for line in lines))
        if kind == "semicolon":
            assert _import(folder, tmp_path / f"{kind}.npz") == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and "landmarks.csv: row 2, column 'x_m': '2,0' is not a finite number" in err
            assert "(a decimal comma? write the numbers with a decimal point)" in err
            continue
        assert _import(folder, tmp_path / f"{kind}.npz") == 0, capsys.readouterr().err
        log = trajectory.load(tmp_path / f"{kind}.npz")
        for field in ("controls", "landmarks", "sighting_frame", "sighting_landmark", "sighting_value"):
            np.testing.assert_array_equal(getattr(log, field), getattr(plain, field), err_msg=f"{kind}: {field}")


def test_a_sensor_behind_the_origin_is_given_after_a_space(tmp_path):
    """``--sensor-pose -0.25,0,0``: the value read as the option's (argparse alone takes it for an option)."""
    folder = write_csv(tmp_path / "log", drive(seconds=6.0))
    assert main(["import", "csv", str(folder), "--out", str(tmp_path / "l.npz"), "--sensor-pose", "-0.25,0,0"]) == 0
    assert trajectory.load(tmp_path / "l.npz").meta["sensor_pose"] == {"x_m": -0.25, "y_m": 0.0, "yaw_rad": 0.0}


def test_a_truth_row_at_the_last_frame_boundary_is_not_outside_it():
    """Commands and truth both at t = 0, 0.1, 0.2, 0.3: the last boundary, 0 + 3 x 0.1, is 0.30000000000000004 by
    rounding, past the last truth row; it is that row's time, not a pose outside the truth (``TIME_SLACK_S``)."""
    from aibo_core.timed_log import truth_at

    t = np.array([0.0, 0.1, 0.2, 0.3])
    edges = 0.0 + 0.1 * np.arange(4)
    assert edges[-1] > t[-1]
    _, gaps = truth_at(t, t, t, np.zeros(4), edges)
    assert gaps["poses_outside_groundtruth"] == 0 and gaps["poses_flagged"] == 0
    _, gaps = truth_at(t, t, t, np.zeros(4), np.append(edges, 0.4))
    assert gaps["poses_outside_groundtruth"] == 1 and gaps["flagged_runs"] == [[4, 4]]
