"""Nothing a user had is lost on the newer commands (issue 22): import never overwrites its
dataset, diagnose never leaves a mixed folder, a refused experiment rerun never empties results."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from aibo.cli import main
from tests._errors import one_line_error as _one_line_error
from tests.test_mrclam import tiny_dataset


def _alias(kind: str, target: Path, tmp_path: Path) -> Path:
    """A path naming ``target``: itself, ``..``, a symlink or a hard link to it."""
    if kind == "same":
        return target
    if kind == "dotdot":
        return target.parent / ".." / target.parent.name / target.name
    alias = tmp_path / f"{kind}.npz"
    if kind == "symlink":
        alias.symlink_to(target)
    else:
        os.link(target, alias)
    return alias


@pytest.mark.parametrize("name", ["Robot1_Odometry.dat", "Barcodes.dat", "Robot2_Measurement.dat"])
@pytest.mark.parametrize("kind", ["same", "dotdot", "symlink", "hardlink"])
def test_import_mrclam_never_overwrites_its_dataset(kind, name, tmp_path, capsys):
    (tmp_path / "data").mkdir()
    data = tiny_dataset(tmp_path / "data")
    target = data / name
    if not target.exists():  # another robot's file: still the dataset's
        target.write_text("# robot 2\n")
    before = {p.name: p.read_bytes() for p in data.iterdir()}
    out = _alias(kind, target, tmp_path)
    assert main(["import", "mrclam", str(data), "--robot", "1", "--out", str(out)]) == 2
    _one_line_error(capsys, f"--out {out}", name, "never overwritten")
    assert {p.name: p.read_bytes() for p in data.iterdir()} == before


def test_import_mrclam_refuses_huge_values(tmp_path, capsys):
    (tmp_path / "data").mkdir()
    data = tiny_dataset(tmp_path / "data")
    lines = (data / "Landmark_Groundtruth.dat").read_text().splitlines()
    lines[5] = "7 1e300 -1.0 0 0"
    (data / "Landmark_Groundtruth.dat").write_text("\n".join(lines) + "\n")
    assert main(["import", "mrclam", str(data), "--robot", "1", "--out", str(tmp_path / "x.npz")]) == 2
    _one_line_error(capsys, "Landmark_Groundtruth.dat", "line 6", "column 2", "1e+300")
    assert not (tmp_path / "x.npz").exists()


@pytest.fixture(scope="module")
def blind_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("diag") / "log.npz"
    assert main(["collect", "--steps", "3000", "--seed", "2", "--blind", "--out", str(path)]) == 0
    return path


def _diagnose(log, out, *extra: str) -> int:
    return main(["diagnose", str(log), "--out", str(out), "--candidates", "floor_drift", "--jobs", "1",
                 "--replicas", "0", *extra])


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_diagnose_folder_appears_whole_or_not_at_all(blind_log, tmp_path, monkeypatch, capsys):
    from aibo import diagnose_report

    out = tmp_path / "D"
    assert _diagnose(blind_log, out) == 0
    assert "calibrated.png" not in capsys.readouterr().out  # --replicas 0: not written, not claimed
    first = _snapshot(out)
    assert set(first) == {"report.json", "model.json", "report.html", "signatures.png", "gap.png", "innovations.png"}
    # every candidate carries its checks' trail, and its flag is read off it
    for c in json.loads(first["report.json"])["candidates"]:
        assert c["checks"][0]["name"] == "likelihood ratio" and c["checks"][0]["p"] == c["p_value"]
        assert c["significant"] == all(v["passed"] for v in c["checks"] if v["decides"])
    assert "likelihood ratio" in first["report.html"].decode()

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(diagnose_report, "html_page", full_disk)  # fails after model.json and the figures
    assert _diagnose(blind_log, out, "--seed", "3") == 2
    assert _snapshot(out) == first  # the earlier diagnosis, untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["D"]  # no temp folder left
    monkeypatch.undo()
    assert _diagnose(blind_log, out, "--seed", "3") == 0
    assert set(_snapshot(out)) == set(first) and _snapshot(out)["model.json"] != first["model.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["D"]


def test_diagnose_refuses_a_folder_with_other_files(blind_log, tmp_path, capsys):
    out = tmp_path / "D"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert _diagnose(blind_log, out) == 2
    _one_line_error(capsys, "--out", "notes.txt", "replaced whole")
    assert (out / "notes.txt").read_text() == "mine"


def test_a_killed_swap_leaves_the_old_folder_and_its_temp_is_cleaned(tmp_path):
    """A process killed inside ``atomic_folder`` leaves the old folder whole; its temp folder is
    removed by the next write beside it once the process is gone and the grace has passed."""
    import subprocess
    import sys
    import time

    from aibo_core.atomic import DEAD_OWNER_GRACE_S, atomic_folder

    target = tmp_path / "out"
    target.mkdir()
    (target / "a.txt").write_text("old")
    code = ("import os, sys; from aibo_core.atomic import atomic_folder\n"
            "with atomic_folder(sys.argv[1]) as tmp:\n"
            "    (tmp / 'a.txt').write_text('new'); os.kill(os.getpid(), 9)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(target)], cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == -9
    assert (target / "a.txt").read_text() == "old"
    left = [p for p in tmp_path.iterdir() if p.name != "out"]
    assert len(left) == 1 and left[0].is_dir()
    old = time.time() - DEAD_OWNER_GRACE_S - 5
    os.utime(left[0], (old, old))
    with atomic_folder(target) as tmp:
        (tmp / "b.txt").write_text("newer")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert sorted(p.name for p in target.iterdir()) == ["b.txt"]


@pytest.mark.parametrize("value", [",", " , "])
def test_diagnose_refuses_empty_candidates(value, blind_log, tmp_path, capsys):
    assert main(["diagnose", str(blind_log), "--out", str(tmp_path / "D"), "--candidates", value]) == 2
    _one_line_error(capsys, "--candidates", "no effect named")
    assert not (tmp_path / "D").exists()


def test_diagnose_candidates_take_all_and_defaults_as_the_catalogue_and_the_default_set():
    """``--candidates all`` is every effect of the catalogue, ``defaults`` the effects tried without the option (so
    ``defaults,heavy_tailed_noise`` adds one), each effect once; an unknown name is refused naming the keywords."""
    from aibo.commands.diagnose import candidates
    from aibo.errors import CLIError
    from learners.model.effects import EFFECT_MODELS

    defaults = candidates(None)
    assert candidates("all") == sorted(EFFECT_MODELS) and candidates("defaults") == defaults
    assert "heavy_tailed_noise" not in defaults
    assert candidates("defaults,heavy_tailed_noise") == defaults + ["heavy_tailed_noise"]
    assert candidates("floor_drift,defaults") == ["floor_drift"] + [n for n in defaults if n != "floor_drift"]
    with pytest.raises(CLIError, match="valid choices: all, defaults, "):
        candidates("defaults,nope")


@pytest.mark.parametrize("value", ["1", "2"])
def test_diagnose_refuses_too_few_replicas_to_reject_anything(value, blind_log, tmp_path, capsys):
    """With fewer than 3 replicas the disagreement threshold is infinite: refused, not a silent '0 disagree'."""
    with pytest.raises(SystemExit) as stop:  # refused by argparse, before any work
        main(["diagnose", str(blind_log), "--out", str(tmp_path / "D"), "--replicas", value])
    assert stop.value.code == 2
    _one_line_error(capsys, "--replicas", "at least 3", f"got {value}")
    assert not (tmp_path / "D").exists()


def test_diagnose_and_learn_refuse_the_same_log_twice(blind_log, tmp_path, capsys):
    link = tmp_path / "link.npz"
    link.symlink_to(blind_log)
    assert main(["diagnose", str(blind_log), str(link), "--out", str(tmp_path / "D")]) == 2
    _one_line_error(capsys, f"log {link}", "same file", "once")
    assert main(["learn", str(blind_log), str(blind_log), "--out", str(tmp_path / "m.json")]) == 2
    _one_line_error(capsys, "same file", "once")


@pytest.mark.parametrize("command", ["learn", "diagnose"])
def test_a_byte_identical_copy_of_a_log_is_refused(command, blind_log, tmp_path, capsys):
    """Links were refused, copies were not: the copy's sightings counted twice."""
    import shutil

    copy = tmp_path / "copy.npz"
    shutil.copyfile(blind_log, copy)
    out = tmp_path / ("m.json" if command == "learn" else "D")
    assert main([command, str(blind_log), str(copy), "--out", str(out)]) == 2
    _one_line_error(capsys, f"log {copy} holds the same bytes as log {blind_log}", "once")
    assert not out.exists()


def test_diagnose_action_model_is_checked_against_the_log(blind_log, tmp_path, capsys):
    assert main(["diagnose", str(blind_log), "--out", str(tmp_path / "D"), "--action-model", "unicycle"]) == 2
    _one_line_error(capsys, "--action-model unicycle", str(blind_log), "discrete")


def test_report_page_with_infinite_z(tmp_path):
    """A statistic whose replicas all agree and the measured value differs has z = +-inf (null in
    report.json): the page and the text say so instead of crashing."""
    from aibo.diagnose_report import html_page
    from aibo_core.atomic import json_text

    check = {"replicas": 8, "disagree_z": 3.9, "failed_replicas": [],
             "statistics": [{"statistic": "sightings per frame", "z": None}],
             "disagreements": [{"statistic": "sightings per frame", "z": float("inf")}]}
    report = {"effects": [], "candidates": [], "gap_metric": "g", "gap_before": 1.0, "gap_after": 1.0,
              "calibrated_simulation": {"before": check, "after": check},
              "unexplained": [{"statistic": "sightings per frame", "z": None, "effect": "e", "why_not_named": "w"}]}
    html_page(tmp_path / "r.html", report, "text", [])
    assert "z = +-inf" in (tmp_path / "r.html").read_text()
    assert '"z": null' in json_text(report)


def _strict_json(path: Path):
    import json

    def refuse(constant):
        raise ValueError(f"{path}: {constant} is not JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "s"
    argv = ["experiment", "policies", "--policies", "uniform", "--minutes", "0.2", "--seeds", "2", "--out", str(out),
            "--max-iter", "5", "--holdout-minutes", "0", "--backend", "serial"]
    assert main(argv) == 0
    return out, argv


@pytest.mark.parametrize("bad, expect", [
    (["--config", '{"nope": 1}'], ["--config", "nope"]),
    (["--config", '{"robot_seed": -3}'], ["--config", "robot_seed"]),
    (["--minutes", "inf"], ["--minutes", "inf"]),
    (["--minutes", "nan"], ["--minutes"]),
    (["--policy-params", '{"uniform": 5}'], ["--policy-params", "uniform", "JSON object"]),
])
def test_a_refused_sweep_rerun_touches_no_result(bad, expect, sweep, capsys):
    out, argv = sweep
    capsys.readouterr()
    before = {name: (out / name).read_bytes() for name in ("results.jsonl", "summary.json")}
    assert len(before["results.jsonl"].splitlines()) == 2
    assert main(argv + bad) == 2
    _one_line_error(capsys, *expect)
    assert {name: (out / name).read_bytes() for name in before} == before


def test_a_bad_record_is_one_line_and_a_nan_is_null(sweep, capsys):
    import json

    out, argv = sweep
    record = next((out / "runs").glob("*/record.json"))
    good = record.read_text()
    try:
        record.write_text("[1, 2]")
        assert main(argv) == 2
        _one_line_error(capsys, str(record), "not a JSON object")
        rec = json.loads(good)
        del rec["vx_rel"]
        record.write_text(json.dumps(rec))
        assert main(argv) == 2
        _one_line_error(capsys, str(record), "'vx_rel'")
        rec = json.loads(good)
        rec["vy_rel"] = float("nan")
        record.write_text(json.dumps(rec))  # Python writes NaN, which is not JSON
        assert main(argv) == 0
        summary = _strict_json(out / "summary.json")
        assert summary["policies"]["uniform"]["0.2"]["vy_rel"]["mean"] is None
        assert all(_strict_json_line(line) for line in (out / "results.jsonl").read_text().splitlines())
    finally:
        record.write_text(good)


def _strict_json_line(line: str):
    import json

    return json.loads(line, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))


def _running(pid: int) -> bool:
    """True while ``pid`` runs (a zombie no one has reaped yet counts as ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


_PARENT = """
import sys, time
import multiprocessing as mp
from aibo_core.workers import process_pool

if __name__ == "__main__":
    ctx = mp.get_context(sys.argv[1])
    pool = process_pool(2, ctx)
    futures = [pool.submit(time.sleep, 120) for _ in range(2)]
    while len(pool._processes) < 2 or not all(p.pid for p in pool._processes.values()):
        time.sleep(0.05)
    time.sleep(1.0)  # the workers have run their initializer
    print(" ".join(str(pid) for pid in pool._processes), flush=True)
    time.sleep(120)
"""


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc")
@pytest.mark.parametrize("method", ["fork", "spawn"])  # diagnose's pools fork, the experiment pool spawns
def test_workers_exit_when_their_parent_is_killed(method, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "parent.py"
    script.write_text(_PARENT)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    parent = subprocess.Popen([sys.executable, str(script), method], stdout=subprocess.PIPE, text=True, env=env)
    try:
        pids = [int(p) for p in parent.stdout.readline().split()]
        assert len(pids) == 2 and all(_running(p) for p in pids)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 30
        while any(_running(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_running(p) for p in pids)
    finally:
        parent.kill()
        for pid in pids if "pids" in locals() else []:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


@pytest.fixture(scope="module")
def learned(blind_log, tmp_path_factory):
    """A model file learned from ``blind_log`` (a few iterations), as parsed JSON."""
    import json

    path = tmp_path_factory.mktemp("model") / "m.json"
    assert main(["learn", str(blind_log), "--out", str(path), "--max-iter", "3", "--starts", "1",
                 "--no-alias-search"]) == 0
    return json.loads(path.read_text())


def _write_model(doc: dict, path: Path, edit) -> Path:
    import copy
    import json

    doc = copy.deepcopy(doc)
    edit(doc)
    path.write_text(json.dumps(doc))
    return path


def _set(dotted: str, value):
    def edit(doc):
        node = doc
        *parents, last = dotted.split(".")
        for part in parents:
            node = node[int(part)] if isinstance(node, list) else node[part]
        node[int(last) if isinstance(node, list) else last] = value
    return edit


def _effects(*entries):
    return _set("effects", list(entries))


@pytest.mark.parametrize("edit, field, what", [
    (_set("sensor_model.coef", ["1", "2"]), "sensor_model.coef", "expected numbers"),
    (_set("sensor_model.sigma_angle", True), "sensor_model.sigma_angle", "expected numbers"),
    (_set("action_model.dt", "0.033"), "action_model.dt", "expected numbers"),
    (_set("action_model.velocities.0.0", 1e300), "action_model.velocities", "larger than"),
    (_set("action_model.motion_cov", [[1e300, 0, 0], [0, 1e300, 0], [0, 0, 1e300]]), "action_model.motion_cov",
     "larger than"),
    (_set("action_model.motion_cov", [[1e14, 0, 0], [0, 1, 0], [0, 0, -1]]), "action_model.motion_cov",
     "positive definite"),
    (_set("action_model.motion_cov", [[1e14, 0, 0], [0, 1e14, 0], [0, 0, 1e14]]), "action_model.motion_cov",
     "standard deviation above 10000 mm"),
    (_effects({"name": "actuation_lag", "parameters": {"lag_s": -5}}), "effects.actuation_lag.parameters.lag_s",
     "must be in [0, 60]"),
    (_effects({"name": "false_sightings", "parameters": {"rate": 5}}), "effects.false_sightings.parameters.rate",
     "must be in [0, 0.5]"),
    (_effects({"name": "false_sightings", "parameters": {"rate": 0}}), "effects.false_sightings.parameters.rate",
     "> 0"),
    (_effects({"name": "distance_dependent_noise", "parameters": {"exponent": -1}}),
     "effects.distance_dependent_noise.parameters.exponent", "must be in"),
    (_effects({"name": "actuation_lag", "parameters": {"lag_s": [0.1, 0.2]}}),
     "effects.actuation_lag.parameters.lag_s", "expected a number"),
    (_effects({"name": "floor_drift", "parameters": {"drift_mm_s": 3.0}}),
     "effects.floor_drift.parameters.drift_mm_s", "a list of 2 numbers"),
    (_effects({"name": "floor_drift", "parameters": {"drift_mm_s": [1e300, 0]}}),
     "effects.floor_drift.parameters.drift_mm_s", "larger than"),
    (_effects({"name": "actuation_lag", "parameters": {"lag_s": "0.1"}}), "effects.actuation_lag.parameters.lag_s",
     "expected numbers"),
    (_effects({"name": "actuation_lag", "parameters": {"lag_s": 0.1}}, {"name": "actuation_lag",
                                                                       "parameters": {"lag_s": 0.2}}),
     "effects", "2 times"),
])
def test_a_bad_model_file_is_one_line_naming_its_field(edit, field, what, learned, blind_log, tmp_path, capsys):
    init = _write_model(learned, tmp_path / "bad.json", edit)
    assert main(["learn", str(blind_log), "--init", str(init), "--out", str(tmp_path / "m.json")]) == 2
    _one_line_error(capsys, str(init), f"'{field}'", what)
    assert not (tmp_path / "m.json").exists()


@pytest.mark.parametrize("entry, field, what", [
    ({"name": "beacon_height_scale", "parameters": {"scale": [1.0, 1.0]}}, "effects.beacon_height_scale.parameters.scale",
     "these logs need"),
    ({"name": "wall_contact", "parameters": {}}, "effects.wall_contact", "field"),
])
def test_an_init_model_the_log_cannot_use_is_one_line(entry, field, what, learned, blind_log, tmp_path, capsys):
    from dataclasses import replace

    from aibo_core import trajectory

    log = tmp_path / "nofield.npz"
    trajectory.save(replace(trajectory.load(blind_log), field=None), log)
    init = _write_model(learned, tmp_path / "init.json", _effects(entry))
    assert main(["learn", str(log), "--init", str(init), "--out", str(tmp_path / "m.json")]) == 2
    _one_line_error(capsys, f"{init}: field '{field}'", what, str(log))


def test_an_init_model_with_other_control_names_is_refused(tmp_path, capsys):
    from aibo_core import trajectory
    from aibo_core.mrclam import import_robot
    from learners.arrays.batch import make_batch
    from learners.model.io import save_model
    from learners.model.model import start_model

    (tmp_path / "data").mkdir()
    tr = import_robot(tiny_dataset(tmp_path / "data"), 1, dt=0.1)
    trajectory.save(tr, tmp_path / "log.npz")
    model = start_model(make_batch([tr]), tr.dt, tr.sensor_kind, control_names=("left_mm_s", "right_mm_s"))
    save_model(tmp_path / "init.json", model, {"learner": "test"})
    assert main(["learn", str(tmp_path / "log.npz"), "--init", str(tmp_path / "init.json"),
                 "--out", str(tmp_path / "m.json")]) == 2
    _one_line_error(capsys, f"{tmp_path / 'init.json'}: field 'action_model.control_names'", "left_mm_s", "v_mm_s",
                    f"{tmp_path / 'log.npz'}: field 'control_names'")


def test_replay_refuses_a_log_of_another_frame_rate(learned, blind_log, tmp_path, capsys):
    import json
    from dataclasses import replace

    from aibo_core import trajectory

    model = tmp_path / "m.json"
    model.write_text(json.dumps(learned))
    log = tmp_path / "slow.npz"
    trajectory.save(replace(trajectory.load(blind_log), dt=0.1), log)
    assert main(["collect", "--model", str(model), "--replay", str(log), "--out", str(tmp_path / "r.npz")]) == 2
    _one_line_error(capsys, f"--replay {log}", "'dt'", "0.1 s", "0.0333333 s")
    assert not (tmp_path / "r.npz").exists()
    assert main(["collect", "--model", str(model), "--replay", str(blind_log), "--out", str(tmp_path / "r.npz")]) == 0


@pytest.mark.parametrize("fail", ["fsync", "mkstemp"])
def test_write_errors_name_the_output(fail, blind_log, tmp_path, monkeypatch, capsys):
    """A full disk (no file named) or a read-only folder (our temp file named): the error names the
    output the user asked for."""
    import tempfile

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    def read_only(*args, dir=None, **kwargs):
        raise PermissionError(13, "Permission denied", os.path.join(dir, ".aibo-1-abcdefgh.tmp"))

    out = tmp_path / "o.npz"
    if fail == "fsync":
        monkeypatch.setattr(os, "fsync", full)
    else:
        monkeypatch.setattr(tempfile, "mkstemp", read_only)
    assert main(["collect", "--steps", "30", "--out", str(out)]) == 2
    line = _one_line_error(capsys, f"(writing {out})")
    assert ".tmp" not in line and not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == []


def test_reproduce_never_mixes_two_runs(tmp_path, monkeypatch, capsys):
    """Another run's checkpoint is never read (no failure naming an option reproduce lacks), a failed
    run leaves the earlier folder whole, and a completed one leaves no checkpoint behind."""
    from argparse import Namespace

    from aibo.commands import reproduce

    monkeypatch.setattr(reproduce, "QUICK_STEPS", 3000)
    out = tmp_path / "R"
    first = ["reproduce", "--quick", "--out", str(out), "--seed", "2"]
    other = Namespace(seed=3, paper_recipe=False, quick=True)
    leftover = reproduce.run_checkpoint(out, other, 3000)  # an interrupted run of another seed
    leftover.parent.mkdir(parents=True)
    leftover.write_bytes(b"not a checkpoint of this run")
    assert main(first) == 0
    assert "resumed" not in capsys.readouterr().out
    old = _snapshot(out)
    assert set(old) == set(reproduce.OUTPUTS)  # the other run's checkpoint went with the old folder

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(reproduce, "write_plots", full_disk)  # after log.npz and the models are written
    fourth = ["reproduce", "--quick", "--out", str(out), "--seed", "4"]
    assert main(fourth) == 2
    checkpoint = reproduce.run_checkpoint(out, Namespace(seed=4, paper_recipe=False, quick=True), 3000)
    assert {k: v for k, v in _snapshot(out).items() if k != checkpoint.name} == old  # the old run, whole
    assert checkpoint.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["R"]
    monkeypatch.undo()
    monkeypatch.setattr(reproduce, "QUICK_STEPS", 3000)
    capsys.readouterr()
    assert main(fourth) == 0  # the identical run resumes, and says so
    assert f"resumed from the checkpoint {checkpoint}" in capsys.readouterr().out
    assert set(_snapshot(out)) == set(reproduce.OUTPUTS) and _snapshot(out)["log.npz"] != old["log.npz"]


def test_reproduce_refuses_a_folder_with_other_files(tmp_path, capsys):
    (tmp_path / "R").mkdir()
    (tmp_path / "R" / "thesis.tex").write_text("mine")
    assert main(["reproduce", "--quick", "--out", str(tmp_path / "R")]) == 2
    _one_line_error(capsys, "thesis.tex", "replaced whole")


def test_config_takes_a_json_file_too(tmp_path, capsys):
    import json

    from aibo_core import trajectory

    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps({"noise": "aibo", "robot_seed": 7}))
    assert main(["collect", "--steps", "30", "--config", str(cfg), "--out", str(tmp_path / "a.npz")]) == 0
    meta = trajectory.load(tmp_path / "a.npz").meta["config"]
    assert meta["robot_seed"] == 7 and meta["noise"] == "aibo"
    capsys.readouterr()
    (tmp_path / "bad.json").write_text('{"noise": ')
    for value, expect in ((str(tmp_path / "missing.json"), ["neither inline JSON", "missing.json"]),
                          (str(tmp_path / "bad.json"), ["--config", "bad.json", "not valid JSON"]),
                          ('{"noise": NaN}', ["inline JSON", "non-finite"])):
        with pytest.raises(SystemExit) as stop:  # refused by argparse, before any work
            main(["collect", "--steps", "30", "--config", value, "--out", str(tmp_path / "b.npz")])
        assert stop.value.code == 2
        _one_line_error(capsys, "argument --config", *expect)


def test_velocity_of_one_command_like_mean_of_one_distance(learned, tmp_path):
    import json

    import numpy as np

    from learners.model.io import load_model

    (tmp_path / "m.json").write_text(json.dumps(learned))
    model = load_model(tmp_path / "m.json")
    one = model.action.velocity(7)
    assert one.shape == (3,) and np.array_equal(one, model.action.velocity([7])[0])
    assert np.array_equal(model.action.velocity(np.int64(7)), one)
    assert np.shape(model.sensor.mean(1500.0)) == ()
    with pytest.raises(ValueError, match="outside"):
        model.action.velocity(99)


def test_velocity_of_one_continuous_command():
    import numpy as np

    from learners.model.action import ActionModel

    act = ActionModel(np.array([[1.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 0.2]]), np.eye(3), 0.1, "linear", ("v", "w"))
    assert np.allclose(act.velocity([100.0, 0.5]), act.velocity([[100.0, 0.5]])[0])
    assert act.velocity([100.0, 0.5]).shape == (3,)


def test_diagnose_reports_candidates_the_log_cannot_support(blind_log, tmp_path, capsys):
    import json
    from dataclasses import replace

    from aibo_core import trajectory

    log = tmp_path / "nofield.npz"
    trajectory.save(replace(trajectory.load(blind_log), field=None), log)
    out = tmp_path / "D"
    assert main(["diagnose", str(log), "--out", str(out), "--candidates", "floor_drift,wall_contact",
                 "--jobs", "1", "--replicas", "0"]) == 0
    text = capsys.readouterr().out
    assert "wall_contact: not tried" in text and "field" in text
    report = json.loads((out / "report.json").read_text())
    assert list(report["not_tried"]) == ["wall_contact"]
    assert [c["name"] for c in report["candidates"]] == ["floor_drift"]
    # which start the final fit kept: both fits' likelihoods, the larger one's marked
    starts = report["final_fit_starts"]
    assert [s["start"] for s in starts] == ["the search's model", "aibo learn's model with the search's effects"]
    assert [s["kept"] for s in starts] == [s["loglik"] == max(t["loglik"] for t in starts) for s in starts]
    assert "the final fit on the whole log(s) kept the fit from" in text


def test_diagnose_says_when_every_replica_failed(blind_log, tmp_path, monkeypatch, capsys):
    from experiments import calibrated

    def fails(model, logs, seed, paths=None, steer=False):
        raise ValueError("the replica's fit diverged")

    monkeypatch.setattr(calibrated, "replica_statistics", fails)
    out = tmp_path / "D"
    assert _diagnose(blind_log, out, "--replicas", "3") == 0
    text = capsys.readouterr().out
    assert "statistics disagree" not in text
    assert text.count("no comparison: 0 of 3 replicas ran (3 failed") == 2
    assert "calibrated.png" not in text and not (out / "calibrated.png").exists()


def test_the_calibrated_check_after_the_named_effects_is_of_the_model_written(blind_log, tmp_path, monkeypatch):
    """The twin judged "after" is model.json (the final fit on the whole log, the simulator a user drives), not the
    search's fit of the training half; "before" is the base model's."""
    import numpy as np

    from experiments import calibrated
    from learners.model.io import load_model, model_to_json

    checked = []

    def records(model, logs, replicas, seed, jobs, progress=None, tracking=False):
        checked.append(model)
        steered.append(tracking)
        return calibrated.Check(["s"], np.zeros(1), np.zeros((replicas, 1)))

    steered = []
    monkeypatch.setattr(calibrated, "predictive_check", records)
    out = tmp_path / "D"
    assert _diagnose(blind_log, out, "--replicas", "3") == 0
    assert len(checked) == 2 and steered == [False, False]  # open loop unless --tracked-replicas
    written = model_to_json(load_model(out / "model.json"))
    assert model_to_json(checked[1]) == written and model_to_json(checked[0]) != written


def test_report_page_leads_with_the_verdict(tmp_path):
    from aibo.diagnose_report import html_page

    report = {"effects": [{"name": "actuation_lag", "parameters": {"lag_s": 0.2}}], "candidates": [],
              "gap_metric": "heldout_nll_per_sighting", "gap_before": 3.0, "gap_after": 2.5}
    html_page(tmp_path / "r.html", report, "text", [])
    page = (tmp_path / "r.html").read_text()
    verdict = page.index("Verdict: the base model misses <b>actuation_lag</b> (lag_s 0.2 (lag_s on a grid of step 0.1")
    assert verdict < page.index("better by 0.5000 nats per sighting") < page.index("adjusted for every pair tried")
    html_page(tmp_path / "n.html", {**report, "effects": []}, "text", [])
    assert "Verdict: <b>no missing effect found</b>" in (tmp_path / "n.html").read_text()
    starts = [{"start": "the search's model", "loglik": -1000.0, "kept": False},
              {"start": "aibo learn's model with the search's effects", "loglik": -987.5, "kept": True}]
    html_page(tmp_path / "s.html", {**report, "final_fit_starts": starts}, "text", [])
    assert ("kept the fit from aibo learn&#x27;s model with the search&#x27;s effects, more likely by 12.5 nats than "
            "from the search&#x27;s model") in (tmp_path / "s.html").read_text()


def test_report_page_states_units_the_grid_step_and_which_candidate_was_named(tmp_path):
    """The base's shift in its units, a grid parameter's interval with the grid's step, and a "named" column."""
    from aibo.diagnose_report import html_page

    lag = {"value": 0.2, "se": None, "interval_95": [0.1, 0.3], "grid_step": 0.1, "method": "profile likelihood"}
    shift = {"velocities_rms": [24.4, 19.7, 0.038], "velocities_max_abs": [50.0, 40.0, 0.1],
             "velocities_key": "action_model.velocities", "sensor_curve_max_abs": 1.5, "sensor_unit": "px",
             "sensor_distances_mm": [300.0, 3000.0]}
    cand = {"round": 1, "gain_train": 90.0, "gain_heldout": 80.0, "p_value": 1e-39, "significant": True,
            "identifiable": True, "note": ""}
    report = {"effects": [{"name": "actuation_lag", "parameters": {"lag_s": 0.2}, "intervals": {"lag_s": lag}}],
              "candidates": [dict(cand, name="actuation_lag", named=True), dict(cand, name="velocity_fade", named=False)],
              "gap_metric": "heldout_nll_per_sighting", "gap_before": 3.0, "gap_after": 2.5, "base_change": shift}
    html_page(tmp_path / "r.html", report, "text", [])
    page = (tmp_path / "r.html").read_text()
    assert "lag_s [0.1, 0.3] (profile over a grid of step 0.1)" in page
    assert page.count("grid of step") == 1  # said once, by the interval (not again beside the value)
    assert "by 24.4 mm/s, 19.7 mm/s, 0.038 rad/s RMS over the commands" in page
    assert "and the sensor curve by at most 1.5 px over 300-3000 mm" in page
    assert "<th>named</th>" in page and page.count("<b>named</b>") == 1
    # a curve the effects left where it was (a range sensor's, held) was 'moved by at most 0 mm'
    html_page(tmp_path / "h.html", {**report, "base_change": {**shift, "sensor_curve_max_abs": 0.0}}, "text", [])
    held = (tmp_path / "h.html").read_text()
    assert "and left the sensor curve as it was" in held and "at most 0 " not in held


@pytest.mark.parametrize("option", ["--config", "--policy-params", "--policy"])
def test_every_file_a_command_reads_is_an_input(option, tmp_path, capsys):
    """JSON options given as files and sb3 agent files are inputs too (aibo.paths.declared_inputs)."""
    src = tmp_path / ("agent.zip" if option == "--policy" else "in.json")
    src.write_text("{}")
    value = f"sb3:{src}" if option == "--policy" else str(src)
    link = tmp_path / "link"
    link.symlink_to(src)
    assert main(["collect", "--steps", "30", option, value, "--out", str(link)]) == 2
    _one_line_error(capsys, f"--out {link}", str(src), "never overwritten")
    assert src.read_text() == "{}"


def test_an_agent_description_is_an_input_of_collect(tmp_path, capsys):
    (tmp_path / "agent.json").write_text("{}")
    assert main(["collect", "--steps", "30", "--policy", f"sb3:{tmp_path / 'agent.zip'}", "--out",
                 str(tmp_path / "agent.json")]) == 2
    _one_line_error(capsys, "agent.json", "never overwritten")


def test_atomic_folder_through_a_symlink_keeps_the_link(tmp_path):
    from aibo_core.atomic import atomic_folder

    real = tmp_path / "real"
    real.mkdir()
    (real / "a.txt").write_text("old")
    link = tmp_path / "link"
    link.symlink_to(real)
    with atomic_folder(link) as tmp:
        (tmp / "b.txt").write_text("new")
    assert link.is_symlink() and sorted(p.name for p in real.iterdir()) == ["b.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]


@pytest.mark.parametrize("out", ["agent.zip", "agent.json"])
def test_an_agent_named_in_policy_params_is_an_input_of_collect(out, tmp_path, capsys):
    """``--policy-params '{"path": AGENT}'`` names a file the policy reads: no output may replace it (or its .json)."""
    agent = tmp_path / "agent.zip"
    agent.write_bytes(b"PK agent")
    (tmp_path / "agent.json").write_text("{}")
    assert main(["collect", "--steps", "30", "--policy", "explorer", "--policy-params", f'{{"path": "{agent}"}}',
                 "--out", str(tmp_path / out)]) == 2
    _one_line_error(capsys, f"--out {tmp_path / out}", "--policy-params 'path'", "never overwritten")
    assert agent.read_bytes() == b"PK agent" and (tmp_path / "agent.json").read_text() == "{}"


def test_an_agent_named_in_policy_params_is_an_input_of_experiment(tmp_path, capsys):
    """The sweep's ``{policy: {"path": AGENT}}`` too: an agent named like one of its outputs is refused."""
    agent = tmp_path / "sweep" / "summary.json"
    agent.parent.mkdir()
    agent.write_text("{}")
    assert main(["experiment", "policies", "--policies", "explorer", "--seeds", "1", "--out", str(agent.parent),
                 "--policy-params", f'{{"explorer": {{"path": "{agent}"}}}}']) == 2
    _one_line_error(capsys, str(agent), "never overwritten")
    assert agent.read_text() == "{}"


def _exit_code(argv: list[str]) -> int:
    """``main(argv)``'s exit status, also when argparse refuses an option (SystemExit)."""
    try:
        return main(argv)
    except SystemExit as stop:
        return stop.code


@pytest.mark.parametrize("command", ["diagnose", "reproduce"])
@pytest.mark.parametrize("out", [".", "", "..", "sub/.."])
def test_an_output_folder_that_cannot_be_replaced_is_refused_first(command, out, tmp_path, monkeypatch, capsys):
    """The folder is replaced whole at the end: the current folder (or one holding it) cannot be, and the run's
    results were lost ('Device or resource busy' after the whole run)."""
    work = tmp_path / "work"
    (work / "sub").mkdir(parents=True)
    monkeypatch.chdir(work)
    log = work / "log.npz"
    log.write_bytes(b"")  # never read: refused before
    args = ["diagnose", str(log), "--out", out] if command == "diagnose" else ["reproduce", "--quick", "--out", out]
    assert _exit_code(args) == 2
    _one_line_error(capsys, "an empty name" if out == "" else "the output folder is replaced whole")
    assert sorted(p.name for p in work.iterdir()) == ["log.npz", "sub"]


@pytest.mark.parametrize("args", [["collect", "--steps", "30", "--out", ""], ["bench", "--quick", "--json", ""],
                                  ["collect", "--steps", "30", "--out", "x.npz", "--plot", ""],
                                  ["import", "mrclam", "", "--robot", "1", "--out", "x.npz"]])
def test_an_empty_file_name_is_refused_first(args, capsys):
    """An empty name was the current folder or ignored: bench --json '' ran to the end, then failed."""
    assert _exit_code(args) == 2
    _one_line_error(capsys, "an empty name")


@pytest.mark.parametrize("option, value", [("--holdout-minutes", "1e5"), ("--minutes", "5,1e9")])
def test_a_sweep_log_longer_than_collect_may_simulate_is_refused(option, value, tmp_path, capsys):
    """--holdout-minutes had no upper limit (1e5: hours and ~29 GB before any error)."""
    out = tmp_path / "sweep"
    assert main(["experiment", "policies", "--seeds", "1", "--out", str(out), option, value]) == 2
    _one_line_error(capsys, f"{option} {value if option == '--minutes' else '100000'}: ", "what aibo collect may simulate")
    assert not out.exists()


def test_an_action_model_other_than_the_inits_is_refused(tmp_path, capsys):
    """--action-model was silently overruled by --init's action model."""
    from aibo_core import trajectory
    from tests._diffdrive import diff_drive_log

    log, init = tmp_path / "log.npz", tmp_path / "init.json"
    trajectory.save(diff_drive_log(seconds=60.0), log)
    assert main(["learn", str(log), "--out", str(init), "--max-iter", "2", "--action-model", "unicycle"]) == 0
    capsys.readouterr()
    out = tmp_path / "m.json"
    assert main(["learn", str(log), "--init", str(init), "--action-model", "features", "--out", str(out)]) == 2
    _one_line_error(capsys, "--action-model features: --init", "'unicycle' action model")
    assert not out.exists()
    assert main(["learn", str(log), "--init", str(init), "--action-model", "unicycle", "--out", str(out),
                 "--max-iter", "2"]) == 0  # the same one: fine


def test_an_open_profile_interval_is_printed_as_open():
    """The profile interval's 'open' flags were dropped from the printed line (an end the profile never left
    read as a closed bound)."""
    from aibo.diagnose_report import interval_text

    iv = {"value": 0.3, "interval_95": [0.1, 0.5], "method": "profile likelihood, whole logs"}
    assert interval_text({"lag_s": {**iv, "open": [False, False]}}) == "95%: lag_s [0.1, 0.5] (profile)"
    assert interval_text({"lag_s": {**iv, "open": [False, True]}}) == "95%: lag_s [0.1, >=0.5] (profile, open above)"
    assert interval_text({"tau_s": {"value": 8.0, "interval_95": [6.9, 11.2], "open": [True, False]}}) == \
        "95%: tau_s [<=6.9, 11.2] (open below)"


def test_diagnose_help_names_every_effect_tried_only_when_asked_for(capsys):
    """``--candidates``' help lists the effects that are not default candidates (``EffectModel.DEFAULT_CANDIDATE``)."""
    from learners.model.effects import EFFECT_MODELS

    with pytest.raises(SystemExit):
        main(["diagnose", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    asked = [name for name, cls in EFFECT_MODELS.items() if not cls.DEFAULT_CANDIDATE]
    assert asked and all(name in text for name in asked), asked


def test_a_named_effect_the_final_fit_takes_to_nothing_is_warned_about():
    """``negligible_when_final``: false_sightings named on the training half, its rate in the whole-log fit so small that
    it stands for about one sighting (the false-alarm study's paper-sim log 3000: 0.0031 when named, 0.0003 final)."""
    from aibo.commands.diagnose import negligible_when_final
    from aibo_gym.collect import collect
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions
    from learners.model.catalogue_more import FalseSightings

    tr = collect({}, 600, seed=1)
    model = EMLearner(EMOptions(max_iter=3, uncertainty=False, alias_search=False)).fit([tr]).params
    named = [{"name": "false_sightings"}]
    tiny = negligible_when_final(model.with_effect(FalseSightings(0.0003)), named, [tr])
    assert len(tiny) == 1 and tiny[0].startswith("false_sightings: named, but in the final fit") and "negligible" in tiny[0]
    assert negligible_when_final(model.with_effect(FalseSightings(0.2)), named, [tr]) == []


def test_diagnose_warns_when_a_held_fit_beat_the_diagnosed_model():
    """A parameter whose interval records a fit held elsewhere more likely than the diagnosed model by more than
    1.92 nats (``beaten_by_nats``: the value stated is outside its own profile interval) becomes a warning naming the
    effect, the parameter and the nats; by less (the stop rules' slack) or none, no warning."""
    from learners.discrepancy.effect_sizes import short_of_maximum

    effects = [{"name": "distance_dependent_noise", "intervals": {"exponent": {"value": 0.31, "beaten_by_nats": 37.3}}},
               {"name": "actuation_lag", "intervals": {"lag_s": {"value": 0.2, "beaten_by_nats": 1.2}}},
               {"name": "velocity_fade", "intervals": {"fade_per_min": {"value": 0.02}}}]
    assert short_of_maximum(effects) == [
        "distance_dependent_noise: exponent 0.31 is not the likelihood's maximum: a fit with it held elsewhere is 37.3 "
        "nats more likely (more than the 95% interval's 1.92); the value stated may be off by more than its interval "
        "says"]


def test_an_arrays_interval_is_printed_as_its_half_widths_or_its_ends():
    """An array parameter's 95% interval (``interval_95``: [lows, highs]) was printed as 'SE [...]' after '95%:'."""
    from aibo.diagnose_report import interval_text

    iv = {"value": [1.01, 0.99], "se": [0.002, 0.003], "interval_95": [[1.0061, 0.9841], [1.0139, 0.9959]]}
    assert interval_text({"scale": {**iv, "clipped": False}}) == "95%: scale +- [0.0039, 0.0059]"
    clipped = {"value": [0.002, 0.01], "interval_95": [[0.0, 0.005], [0.006, 0.015]], "clipped": True}
    assert interval_text({"rate": clipped}) == "95%: rate [[0, 0.006], [0.005, 0.015]]"


def test_a_named_effects_warnings_are_in_its_entry_among_the_reports_and_marked_on_the_page(tmp_path, capsys):
    """``report.json["effects"][i]["warnings"]`` is what ``effect_sizes.read_with_care`` says of that entry (through
    the command: a 0.2 s lag, named); the page's verdict marks an effect with warnings "read with care" and not one
    without."""
    import json

    from aibo.diagnose_report import READ_WITH_CARE, html_page
    from learners.discrepancy.effect_sizes import read_with_care

    log, out = tmp_path / "lag.npz", tmp_path / "D"
    config = json.dumps({"effects": {"actuation_lag": {"lag_s": 0.2}}})
    assert main(["collect", "--steps", "3000", "--seed", "3", "--blind", "--config", config, "--out", str(log)]) == 0
    assert main(["diagnose", str(log), "--out", str(out), "--candidates", "actuation_lag", "--jobs", "1",
                 "--replicas", "0"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert [e["name"] for e in report["effects"]] == ["actuation_lag"]
    entry = report["effects"][0]
    assert entry["warnings"] == read_with_care(entry) and set(entry["warnings"]) <= set(report["warnings"])
    moved = {**entry, "parameters_when_named": {"lag_s": 0.6}}  # named far outside its final interval
    assert read_with_care(moved) and "moved it outside its interval" in read_with_care(moved)[0]
    base = {"candidates": [], "gap_metric": "heldout_nll_per_sighting", "gap_before": 3.0, "gap_after": 2.5}
    for warnings in ([], read_with_care(moved)):
        html_page(tmp_path / "p.html", {**base, "effects": [{**entry, "warnings": warnings}]}, "text", [])
        verdict = next(line for line in (tmp_path / "p.html").read_text().splitlines() if "Verdict:" in line)
        assert (READ_WITH_CARE in verdict) == bool(warnings)


def test_diagnose_scores_the_motion_noise_against_ground_truth_only_where_the_log_has_it(blind_log, tmp_path, capsys):
    """A log with its true pose (a simulated one, or a real one with motion capture): report.json's
    ``against_ground_truth`` holds the base and the diagnosed model's travel error over 1 s against their own sd
    (``learners.scoring.motion_noise_scores``; the fit never reads the pose), and the console says it; a blind log
    has none. On this 100 s log (40 commands, few sightings each) the models err more than they say (above 1)."""
    import json

    from aibo_core import trajectory

    sighted = tmp_path / "sighted.npz"
    assert main(["collect", "--steps", "3000", "--seed", "2", "--out", str(sighted)]) == 0
    assert trajectory.load(sighted).pose is not None
    assert _diagnose(sighted, tmp_path / "S") == 0
    text = capsys.readouterr().out
    truth = json.loads((tmp_path / "S" / "report.json").read_text())["against_ground_truth"]
    assert truth["window_s"] == 1.0 and set(truth) == {"window_s", "base", "diagnosed"}
    for row in (truth["base"], truth["diagnosed"]):
        assert set(row) == {"noise_fwd", "noise_lat", "noise_head"} and all(v > 1.0 for v in row.values()), truth
    assert "against the log's ground truth (not read by the fit)" in text
    assert _diagnose(blind_log, tmp_path / "B") == 0
    assert "against_ground_truth" not in json.loads((tmp_path / "B" / "report.json").read_text())
    assert "ground truth" not in capsys.readouterr().out
