"""What a log's contents can do to ``aibo learn`` / ``aibo diagnose``, end to end through the command:
a malformed ``meta.truth`` never crashes a fit (a one-line note, the model written, no scores); data too
thin for a fit and a start model that does not fit the log are one error line naming the file and the
field; the help names the log format that is written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aibo.cli import build_parser, main
from aibo_core import trajectory

FAST = ["--max-iter", "3", "--starts", "1", "--no-alias-search"]


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "log.npz"
    assert main(["collect", "--steps", "1800", "--seed", "2", "--out", str(path)]) == 0
    return path


def _with_truth(log, tmp_path, truth, name: str = "bad.npz"):
    """A copy of ``log`` whose meta.truth is ``truth`` (the rest of the file unchanged)."""
    tr = trajectory.load(log)
    tr.meta = {**tr.meta, "truth": truth}
    path = tmp_path / name
    trajectory.save(tr, path)
    return path


def _truth(log) -> dict:
    return json.loads(json.dumps(trajectory.load(log).truth))


def _malformed(log) -> list[tuple[str, object]]:
    """Malformed truths, each with the field the note must name."""
    good = _truth(log)
    return [
        ("meta.truth", 5),
        ("meta.truth", {k: v for k, v in good.items() if k != "velocities"}),  # a key missing
        ("meta.truth.velocities", {**good, "velocities": good["velocities"][:10]}),  # wrong shape
        ("meta.truth.sigma_height", {**good, "sigma_height": "1 px"}),
        ("meta.truth.sensor", {**good, "sensor": "pinhole"}),
        ("meta.truth.sensor.coef", {**good, "sensor": {"model": "curve", "basis": "inverse", "coef": []}}),
    ]


def test_malformed_truth_never_crashes_a_fit(log, tmp_path, capsys):
    assert main(["learn", str(log), "--out", str(tmp_path / "good.json"), *FAST]) == 0
    assert "vx RMS / range" in capsys.readouterr().out  # a usable truth scores the fit
    for i, (field, truth) in enumerate(_malformed(log)):
        bad = _with_truth(log, tmp_path, truth, f"bad{i}.npz")
        out = tmp_path / f"model{i}.json"
        code = main(["learn", str(bad), "--out", str(out), "--plots", str(tmp_path / f"plots{i}"), *FAST])
        cap = capsys.readouterr()
        assert code == 0, (field, cap.err)
        notes = [line for line in cap.err.splitlines() if line.startswith("aibo: note:")]
        assert len(notes) == 1 and f"{bad}: field '{field}': " in notes[0], (field, cap.err)
        assert "Traceback" not in cap.err and "vx RMS / range" not in cap.out
        assert json.loads(out.read_text())["format"] == "aibo-model/1"
        assert (tmp_path / f"plots{i}" / "sensor_model.png").stat().st_size > 0


def _short_log(tmp_path, sightings: int, name: str):
    """A 20-second log keeping only its first ``sightings`` sightings."""
    from aibo_gym.collect import collect

    tr = collect({"noise": "paper-sim"}, steps=600, seed=4)
    tr.sighting_frame, tr.sighting_landmark = tr.sighting_frame[:sightings], tr.sighting_landmark[:sightings]
    tr.sighting_value = tr.sighting_value[:sightings]
    path = tmp_path / name
    trajectory.save(tr, path)
    return path


@pytest.mark.parametrize("sightings", [0, 1, 5, 30])
def test_too_few_sightings_name_the_file_and_field(tmp_path, capsys, sightings):
    path = _short_log(tmp_path, sightings, f"short{sightings}.npz")
    n = trajectory.load(path).n_sightings
    assert n == sightings
    assert main(["learn", str(path), "--out", str(tmp_path / "m.json"), *FAST]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"aibo: error: {path}: field 'sighting_frame': the logs hold {n} sightings; a sensor model of 5 "
                   "parameters needs at least 125 (25 per parameter): record a longer log"]
    assert not (tmp_path / "m.json").exists()


def test_too_few_sightings_in_diagnose_name_the_file(tmp_path, capsys):
    path = _short_log(tmp_path, 30, "short.npz")
    assert main(["diagnose", str(path), "--out", str(tmp_path / "d"), "--replicas", "0", "--jobs", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"aibo: error: {path}: field 'sighting_frame': the logs hold ")


def test_a_start_model_that_does_not_fit_names_both_files(log, tmp_path, capsys):
    model = tmp_path / "m.json"
    assert main(["learn", str(log), "--out", str(model), *FAST]) == 0
    m = json.loads(model.read_text())
    m["action_model"]["velocities"] = m["action_model"]["velocities"][:39]
    init = tmp_path / "m39.json"
    init.write_text(json.dumps(m))
    capsys.readouterr()
    assert main(["learn", str(log), "--init", str(init), "--out", str(tmp_path / "x.json"), *FAST]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"aibo: error: {init}: field 'action_model.velocities': the model has 39 commands, the log "
                   f"40 ({log}: field 'attempted')"]


def test_a_start_model_of_the_other_kind_names_both_files(log, tmp_path, capsys):
    """A model of discrete commands given for a log of velocity commands (``aibo learn --init``), and a model whose
    sensor is another's (``check_model_fits``, the one check for --init and ``aibo export tum``): both fields named."""
    from dataclasses import replace

    from learners.em.learner import check_model_fits
    from learners.em.support import StartModelError
    from learners.model.io import load_model

    model = tmp_path / "m.json"
    wheeled = tmp_path / "wheeled.npz"
    assert main(["learn", str(log), "--out", str(model), *FAST]) == 0
    assert main(["collect", "--env", "wheeled", "--steps", "300", "--seed", "1", "--out", str(wheeled)]) == 0
    capsys.readouterr()
    assert main(["learn", str(wheeled), "--init", str(model), "--out", str(tmp_path / "x.json"), *FAST]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"aibo: error: {model}: field 'action_model.feature_map': a model of discrete commands (actions), "
                   f"the log holds velocity commands (controls) ({wheeled}: field 'controls')"]
    fitted = load_model(model)
    with pytest.raises(StartModelError, match="the model's sensor measures range_mm, the log's height_px") as caught:
        check_model_fits(replace(fitted, sensor=replace(fitted.sensor, kind="range_mm")), [trajectory.load(log)])
    assert (caught.value.model_field, caught.value.field) == ("sensor_model.kind", "sensor_kind")


def test_help_names_the_format_written():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name in ("learn", "diagnose"):
        text = sub.choices[name].format_help()
        assert "aibo-trajectory/2 logs" in text and "aibo-trajectory/1 logs" not in text, name


def test_truth_problem_accepts_what_the_simulator_writes(log):
    from learners.metrics import truth_problem

    good = _truth(log)
    assert truth_problem(good, 40) is None
    assert truth_problem({**good, "velocities": np.zeros((40, 3)).tolist()}, 39) is not None
