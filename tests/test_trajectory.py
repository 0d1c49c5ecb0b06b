"""aibo-trajectory/1: round trip and every validation error (each naming the file and the field)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aibo_gym.collect import collect
from aibo_gym.trajectory import FORMAT, Trajectory, TrajectoryError, blind, load, save


@pytest.fixture(scope="module")
def tr() -> Trajectory:
    return collect(None, 400, seed=0)


def arrays(tr: Trajectory) -> dict:
    return {
        "format": np.array(FORMAT),
        "dt": np.array(tr.dt),
        "actions": tr.actions.copy(),
        "obs": tr.obs.copy(),
        "beacon": tr.beacon.copy(),
        "head_pan": tr.head_pan.copy(),
        "beacons": tr.beacons.copy(),
        "field": tr.field.copy(),
        "attempted": tr.attempted.copy(),
        "pose": tr.pose.copy(),
        "meta": np.array(json.dumps(tr.meta)),
    }


def test_round_trip(tr, tmp_path):
    path = tmp_path / "log.npz"
    save(tr, path)
    back = load(path)
    for name in ("actions", "obs", "beacon", "head_pan", "beacons", "field", "attempted", "pose"):
        np.testing.assert_array_equal(getattr(back, name), getattr(tr, name))
    assert back.dt == tr.dt and back.meta == json.loads(json.dumps(tr.meta))
    assert back.truth["sensor"]["height_px_mm"] == 57000.0
    save(blind(tr), tmp_path / "blind.npz")
    b = load(tmp_path / "blind.npz")
    assert b.pose is None and b.truth is None and b.meta["seed"] == 0


def _seen_row(tr) -> int:
    return int(np.flatnonzero(tr.beacon >= 0)[0])


def _unseen_row(tr) -> int:
    return int(np.flatnonzero(tr.beacon < 0)[0])


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
        "missing key": (drop("beacon"), "beacon"),
        "unknown key": (replace("extra", np.zeros(3)), "extra"),
        "wrong format string": (replace("format", np.array("aibo-trajectory/2")), "format"),
        "format not a string": (replace("format", np.array(1.0)), "format"),
        "action above 39": (setitem("actions", 3, 40), "actions"),
        "negative action": (setitem("actions", 0, -1), "actions"),
        "beacon index outside beacons": (
            lambda a: a["beacon"].__setitem__(_seen_row(tr), 4), "beacon"),
        "NaN obs for a seen beacon": (
            lambda a: a["obs"].__setitem__(_seen_row(tr), np.nan), "obs"),
        "obs where no beacon": (
            lambda a: a["obs"].__setitem__(_unseen_row(tr), [20.0, 0.1]), "obs"),
        "infinite obs": (lambda a: a["obs"].__setitem__((_seen_row(tr), 0), np.inf), "obs"),
        "infinite head_pan": (setitem("head_pan", 5, -np.inf), "head_pan"),
        "NaN pose": (setitem("pose", 2, np.nan), "pose"),
        "short head_pan": (replace("head_pan", lambda a: a["head_pan"][:-1]), "head_pan"),
        "short obs": (replace("obs", lambda a: a["obs"][:-1]), "obs"),
        "pose not T+1": (replace("pose", lambda a: a["pose"][: len(a["actions"])]), "pose"),
        "float actions": (replace("actions", lambda a: a["actions"].astype(float)), "actions"),
        "string obs": (replace("obs", lambda a: a["obs"].astype(str)), "obs"),
        "attempted wrong shape": (replace("attempted", np.zeros((39, 3))), "attempted"),
        "beacons wrong shape": (replace("beacons", np.zeros((4, 3))), "beacons"),
        "non-positive dt": (replace("dt", np.array(0.0)), "dt"),
        "dt not a scalar": (replace("dt", np.array([0.1, 0.2])), "dt"),
        "negative field": (replace("field", np.array([5400.0, -1.0])), "field"),
        "bad JSON meta": (replace("meta", np.array("{not json")), "meta"),
        "meta not an object": (replace("meta", np.array("[1, 2]")), "meta"),
    }


@pytest.mark.parametrize("case", list(_broken(None)))
def test_validation_errors_name_file_and_field(tr, tmp_path, case):
    change, field = _broken(tr)[case]
    a = arrays(tr)
    change(a)
    path = tmp_path / "bad.npz"
    np.savez_compressed(path, **a)
    with pytest.raises(TrajectoryError) as err:
        load(path)
    msg = str(err.value)
    assert str(path) in msg
    assert f"field '{field}'" in msg


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
    bad = Trajectory(tr.dt, tr.actions.copy(), tr.obs, tr.beacon, tr.head_pan, tr.beacons, tr.field, tr.attempted)
    bad.actions[0] = 99
    with pytest.raises(TrajectoryError, match=r"mine\.npz: field 'actions'"):
        bad.validate("mine.npz")


def test_save_invalid_leaves_existing_file_intact(tr, tmp_path):
    path = tmp_path / "log.npz"
    save(tr, path)
    before = path.read_bytes()
    bad = Trajectory(tr.dt, tr.actions.copy(), tr.obs, tr.beacon, tr.head_pan, tr.beacons, tr.field, tr.attempted,
                     tr.pose, tr.meta)
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
