"""aibo-trajectory/2 (and /1, converted on read): round trip and every validation error (each naming
the file and the field)."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from aibo_core.trajectory import Trajectory, TrajectoryError, blind, head, load, save, to_arrays
from aibo_gym.collect import collect
from tests._logs import frame_view


@pytest.fixture(scope="module")
def tr() -> Trajectory:
    return collect(None, 400, seed=0)


def arrays(tr: Trajectory) -> dict:
    return {k: np.array(v, copy=True) for k, v in to_arrays(tr).items()}


def arrays_v1(tr: Trajectory) -> dict:
    obs, beacon = frame_view(tr)
    return {"format": np.array("aibo-trajectory/1"), "dt": np.array(tr.dt), "actions": tr.actions.copy(),
            "obs": obs, "beacon": beacon, "head_pan": tr.head_pan.copy(), "beacons": tr.landmarks.copy(),
            "field": tr.field.copy(), "attempted": tr.attempted.copy(), "pose": tr.pose.copy(),
            "meta": np.array(json.dumps(tr.meta))}


FIELDS = ("actions", "attempted", "sighting_frame", "sighting_landmark", "sighting_value", "landmarks", "head_pan",
          "field", "pose")


def test_round_trip(tr, tmp_path):
    path = tmp_path / "log.npz"
    save(tr, path)
    back = load(path)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(tr, name))
    assert back.dt == tr.dt and back.meta == json.loads(json.dumps(tr.meta)) and back.sensor_kind == "height_px"
    assert back.truth["sensor"]["height_px_mm"] == 57000.0
    save(blind(tr), tmp_path / "blind.npz")
    b = load(tmp_path / "blind.npz")
    assert b.pose is None and b.truth is None and b.meta["seed"] == 0


def test_blind_drops_what_names_the_hidden_effect(tr):
    from dataclasses import replace

    meta = {"seed": 3, "truth": {"effects": {"angle_bias": {"bias_rad": 0.05}}},
            "config": {"noise": "aibo", "field": [5400.0, 3600.0], "effects": {"angle_bias": {"bias_rad": 0.05}}}}
    b = blind(replace(tr, meta=meta))
    assert b.pose is None and "truth" not in b.meta and "angle_bias" not in json.dumps(b.meta)
    assert b.meta == {"seed": 3, "config": {"noise": "aibo", "field": [5400.0, 3600.0]}}
    assert meta["config"]["effects"] and meta["truth"]  # the input is not changed
    assert blind(replace(tr, meta={"source": "a real robot"})).meta == {"source": "a real robot"}


def test_v1_files_load_as_v2(tr, tmp_path):
    path = tmp_path / "old.npz"
    np.savez_compressed(path, **arrays_v1(tr))
    back = load(path)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(tr, name))


def test_continuous_log_with_several_sightings_per_frame(tmp_path):
    T = 50
    log = Trajectory(dt=0.1, landmarks=np.array([[0.0, 1000.0], [500.0, -800.0]]),
                     sighting_frame=np.array([0, 0, 3, 7, 7, 7]), sighting_landmark=np.array([0, 1, 1, 0, 1, 0]),
                     sighting_value=np.tile([1500.0, 0.3], (6, 1)), sensor_kind="range_mm",
                     controls=np.random.default_rng(0).normal(size=(T, 2)), control_names=("v_mm_s", "omega_rad_s"))
    save(log, tmp_path / "c.npz")
    back = load(tmp_path / "c.npz")
    assert back.control_names == ("v_mm_s", "omega_rad_s") and back.sensor_kind == "range_mm"
    np.testing.assert_array_equal(back.controls, log.controls)
    np.testing.assert_array_equal(back.sighting_frame, log.sighting_frame)
    assert back.actions is None and back.field is None and back.head_pan is None and back.n_frames == T
    short = head(back, 4)
    assert short.n_frames == 4 and short.n_sightings == 3


@pytest.mark.parametrize("names,controls,expected", [
    (("omega_rad_s", "v_mm_s"), None, "columns are v_mm_s, omega_rad_s in that order"),
    (("v_mm_s", "v_mm_s"), None, "a name repeated"),
    (("v_mm_s", "omega_rad_s"), (7, 0, 1e9), "v_mm_s 1e+09 at row 7 is beyond 100000 (a velocity command in mm/s)"),
    (("v_mm_s", "omega_rad_s"), (3, 1, -500.0), "omega_rad_s -500 at row 3 is beyond 100"),
])
def test_velocity_commands_are_checked(names, controls, expected):
    """Velocity commands: their columns in the documented order, and values no ground robot commands (a corrupt
    value, or another unit) refused by field before a fit's filter overflows on them."""
    C = np.random.default_rng(0).normal(size=(20, 2))
    if controls is not None:
        C[controls[0], controls[1]] = controls[2]
    log = Trajectory(dt=0.1, landmarks=np.array([[0.0, 1000.0]]), sighting_frame=np.array([0]),
                     sighting_landmark=np.array([0]), sighting_value=np.array([[1500.0, 0.3]]), sensor_kind="range_mm",
                     controls=C, control_names=names)
    with pytest.raises(TrajectoryError, match="log.npz: field '(controls|control_names)'") as err:
        log.validate("log.npz")
    assert expected in str(err.value)


def test_same_log_same_bytes(tr, tmp_path):
    save(tr, tmp_path / "a.npz")
    save(tr, tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()


def _broken(tr):
    """name -> (function changing the arrays dict, field the error must name)."""
    def drop(key):
        return lambda a: a.pop(key)

    def setitem(key, idx, value):
        def f(a):
            a[key][idx] = value
        return f

    def replace(key, value):
        def f(a):
            a[key] = value(a) if callable(value) else value
        return f

    return {
        "missing key": (drop("sighting_value"), "sighting_value"),
        "unknown key": (replace("extra", np.zeros(3)), "extra"),
        "wrong format string": (replace("format", np.array("aibo-trajectory/9")), "format"),
        "format not a string": (replace("format", np.array(1.0)), "format"),
        "action above 39": (setitem("actions", 3, 40), "actions"),
        "negative action": (setitem("actions", 0, -1), "actions"),
        "both actions and controls": (replace("controls", lambda a: np.zeros((len(a["actions"]), 2))), "actions"),
        "landmark index outside landmarks": (setitem("sighting_landmark", 0, 4), "sighting_landmark"),
        "sighting frame outside the log": (setitem("sighting_frame", -1, 400), "sighting_frame"),
        "sighting frames going back": (setitem("sighting_frame", 1, 0), "sighting_frame"),
        "NaN sighting": (setitem("sighting_value", (0, 0), np.nan), "sighting_value"),
        "negative height": (setitem("sighting_value", (0, 0), -3.0), "sighting_value"),
        "unwrapped bearing": (setitem("sighting_value", (0, 1), 4.0), "sighting_value"),
        "sighting lengths disagree": (replace("sighting_value", lambda a: a["sighting_value"][:-1]), "sighting_value"),
        "unknown sensor kind": (replace("sensor_kind", np.array("lidar")), "sensor_kind"),
        "infinite head_pan": (setitem("head_pan", 5, -np.inf), "head_pan"),
        "NaN pose": (setitem("pose", 2, np.nan), "pose"),
        "short head_pan": (replace("head_pan", lambda a: a["head_pan"][:-1]), "head_pan"),
        "pose not T+1": (replace("pose", lambda a: a["pose"][: len(a["actions"])]), "pose"),
        "float actions": (replace("actions", lambda a: a["actions"].astype(float)), "actions"),
        "string values": (replace("sighting_value", lambda a: a["sighting_value"].astype(str)), "sighting_value"),
        "attempted wrong shape": (replace("attempted", np.zeros((40, 2))), "attempted"),
        "action beyond the attempted table": (replace("attempted", np.zeros((3, 3))), "actions"),
        "landmarks wrong shape": (replace("landmarks", np.zeros((4, 3))), "landmarks"),
        "non-positive dt": (replace("dt", np.array(0.0)), "dt"),
        "dt in milliseconds": (replace("dt", np.array(33.3)), "dt"),
        "dt not a scalar": (replace("dt", np.array([0.1, 0.2])), "dt"),
        "negative field": (replace("field", np.array([5400.0, -1.0])), "field"),
        "bad JSON meta": (replace("meta", np.array("{not json")), "meta"),
        "meta not an object": (replace("meta", np.array("[1, 2]")), "meta"),
        "object array": (replace("meta", np.array([{"a": 1}], dtype=object)), "meta"),
    }


def _broken_v1(tr):
    return {
        "v1 missing beacon": (lambda a: a.pop("beacon"), "beacon"),
        "v1 NaN obs for a seen beacon": (lambda a: a["obs"].__setitem__(tr.sighting_frame[0], np.nan), "obs"),
        "v1 obs where no beacon": (
            lambda a: a["obs"].__setitem__(np.flatnonzero(a["beacon"] < 0)[0], [20.0, 0.1]), "obs"),
        "v1 short obs": (lambda a: a.__setitem__("obs", a["obs"][:-1]), "obs"),
    }


def _save_any(path, a):
    if a["meta"].dtype == object:  # np.savez_compressed pickles object arrays
        np.savez(path, **a)
    else:
        np.savez_compressed(path, **a)


@pytest.mark.parametrize("case", list(_broken(None)) + list(_broken_v1(None)))
def test_validation_errors_name_file_and_field(tr, tmp_path, case):
    change, field = {**_broken(tr), **_broken_v1(tr)}[case]
    a = arrays_v1(tr) if case.startswith("v1") else arrays(tr)
    change(a)
    path = tmp_path / "bad.npz"
    _save_any(path, a)
    with pytest.raises(TrajectoryError) as err:
        load(path)
    msg = str(err.value)
    assert str(path) in msg
    assert f"field '{field}'" in msg


def _corrupt(tr, tmp_path, how):
    path = tmp_path / "log.npz"
    save(tr, path)
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("sighting_value.npy")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    if how == "flip":
        data[start + info.compress_size // 2] ^= 0xFF
    elif how == "truncate":
        data = data[: start + info.compress_size // 2]
    elif how == "header":
        raw = bytearray(np.lib.format.magic(1, 0))
        path2 = tmp_path / "h.npz"
        with zipfile.ZipFile(path2, "w") as zf:
            zf.writestr("sighting_value.npy", bytes(raw) + b"\x10\x00{garbage header}")
        return path2
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("how", ["flip", "truncate", "header"])
def test_corrupt_files_give_one_line(tr, tmp_path, how):
    path = _corrupt(tr, tmp_path, how)
    with pytest.raises(TrajectoryError) as err:
        load(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_declared_size_is_checked_before_reading(tmp_path):
    """A small file whose header declares a huge array is refused from the header alone."""
    path = tmp_path / "huge.npz"
    header = {"descr": "<f8", "fortran_order": False, "shape": (2**40, 2)}
    with zipfile.ZipFile(path, "w") as zf:
        with zf.open("sighting_value.npy", "w") as f:
            np.lib.format.write_array_header_1_0(f, header)
            f.write(b"\0" * 64)
    with pytest.raises(TrajectoryError, match="sighting_value"):
        load(path)


def test_not_a_zip_file(tmp_path):
    path = tmp_path / "notes.npz"
    path.write_text("this is not a log\n")
    with pytest.raises(TrajectoryError) as err:
        load(path)
    assert str(path) in str(err.value) and "npz" in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(TrajectoryError, match="not found"):
        load(tmp_path / "nope.npz")


def test_validate_in_memory_names_source_and_field(tr):
    bad = blind(tr)
    bad.actions = tr.actions.copy()
    bad.actions[0] = 99
    with pytest.raises(TrajectoryError, match=r"mine\.npz: field 'actions'"):
        bad.validate("mine.npz")


def test_save_invalid_leaves_existing_file_intact(tr, tmp_path):
    path = tmp_path / "log.npz"
    save(tr, path)
    before = path.read_bytes()
    bad = blind(tr)
    bad.actions = tr.actions.copy()
    bad.actions[7] = 40
    with pytest.raises(TrajectoryError) as err:
        save(bad, path)
    assert str(path) in str(err.value) and "'actions'" in str(err.value)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.npz"]  # no temp file left


def test_failed_write_leaves_existing_file_intact(tr, tmp_path, monkeypatch):
    path = tmp_path / "log.npz"
    save(tr, path)
    before = path.read_bytes()

    calls = []

    def explode(member, array, **kw):  # the disk fills up after the first array is half-written
        calls.append(1)
        member.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(np.lib.format, "write_array", explode)
    with pytest.raises(OSError, match="disk full"):
        save(tr, path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.npz"]


def test_saved_files_get_the_usual_permissions(tr, tmp_path):
    import os
    import stat

    path = tmp_path / "log.npz"
    save(tr, path)
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask
