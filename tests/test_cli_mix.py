"""``aibo learn`` with several logs: incompatible logs are refused, other robots warned about."""

from __future__ import annotations

import pytest

from aibo.cli import main


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mix")
    variants = {
        "a": [], "a2": ["--seed", "2"], "aibo": ["--preset", "aibo"],
        "robot": ["--config", '{"robot_seed": 5}'],
        "beacons": ["--config", '{"beacons": [[1350, 1950], [-1350, 1950], [-1350, -1950], [1350, -1900]]}'],
        "dt": ["--config", '{"dt": 0.05}'],
    }
    for name, extra in variants.items():
        assert main(["collect", "--steps", "1800", "--out", str(folder / f"{name}.npz"), *extra]) == 0
    return {name: folder / f"{name}.npz" for name in variants}


def _learn(capsys, tmp_path, *paths) -> tuple[int, list[str]]:
    capsys.readouterr()
    code = main(["learn", *map(str, paths), "--learner", "oracle", "--out", str(tmp_path / "m.json")])
    return code, capsys.readouterr().err.strip().splitlines()


def test_logs_of_one_robot_learn_together_silently(logs, tmp_path, capsys):
    code, err = _learn(capsys, tmp_path, logs["a"], logs["a2"])
    assert code == 0 and err == []


@pytest.mark.parametrize("name, field", [("beacons", "landmarks"), ("dt", "dt")])
def test_incompatible_logs_are_refused(name, field, logs, tmp_path, capsys):
    code, err = _learn(capsys, tmp_path, logs["a"], logs[name])
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"aibo: error: {logs[name]}: field '{field}': differs from {logs['a']}")
    assert not (tmp_path / "m.json").exists()


@pytest.mark.parametrize("name, key", [("aibo", "noise"), ("robot", "robot_seed")])
def test_another_robot_or_noise_is_one_warning_line(name, key, logs, tmp_path, capsys):
    code, err = _learn(capsys, tmp_path, logs["a"], logs["a2"], logs[name])
    assert code == 0
    assert len(err) == 1 and err[0].startswith(f"aibo: warning: {logs[name]}: meta.config differs from {logs['a']}")
    assert f"{key} (" in err[0]
