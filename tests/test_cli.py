"""The ``aibo`` command end to end: collect, learn, reproduce --quick, and bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory


def aibo(*args: str) -> subprocess.CompletedProcess:
    """Run the installed console script's module as a user would (a fresh process)."""
    return subprocess.run([sys.executable, "-m", "aibo.cli", *args], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def log_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "log.npz"
    r = aibo("collect", "--steps", "3000", "--seed", "2", "--out", str(path), "--plot", str(path.with_suffix(".png")))
    assert r.returncode == 0, r.stderr
    assert "3000 frames" in r.stdout
    return path


def test_collect_writes_a_valid_log_and_figure(log_path):
    tr = trajectory.load(log_path)
    assert tr.n_frames == 3000 and tr.pose is not None and tr.truth is not None
    assert log_path.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_collect_blind_has_no_truth(tmp_path):
    out = tmp_path / "b.npz"
    assert main(["collect", "--steps", "200", "--seed", "1", "--blind", "--preset", "aibo", "--out", str(out)]) == 0
    tr = trajectory.load(out)
    assert tr.pose is None and "truth" not in tr.meta
    assert tr.meta["config"]["noise"] == "aibo"


def test_collect_blind_does_not_name_the_hidden_effect(tmp_path):
    """A blind log keeps its field and camera settings but nothing that names the hidden effect."""
    out = tmp_path / "b.npz"
    config = '{"effects": {"floor_drift": {"drift_mm_s": [15.0, -10.0]}}, "noise": "aibo"}'
    assert main(["collect", "--steps", "200", "--seed", "1", "--blind", "--config", config, "--out", str(out)]) == 0
    with np.load(out, allow_pickle=False) as raw:
        stored = " ".join(str(raw[k]) for k in raw.files)
    assert "floor_drift" not in stored and "drift_mm_s" not in stored
    tr = trajectory.load(out)
    assert "effects" not in tr.meta["config"] and "truth" not in tr.meta and tr.pose is None
    assert tr.meta["config"]["noise"] == "aibo" and tr.meta["config"]["field"] == [5400.0, 3600.0]
    seen = main(["collect", "--steps", "200", "--seed", "1", "--config", config, "--out", str(tmp_path / "s.npz")])
    assert seen == 0 and trajectory.load(tmp_path / "s.npz").meta["config"]["effects"] == {
        "floor_drift": {"drift_mm_s": [15.0, -10.0]}}  # not blind: kept


def test_collect_same_seed_same_bytes(tmp_path):
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    for p in (a, b):
        assert main(["collect", "--steps", "300", "--seed", "9", "--out", str(p)]) == 0
    assert a.read_bytes() == b.read_bytes()


def test_learn_writes_model_and_plots(log_path, tmp_path, capsys):
    out = tmp_path / "model.json"
    code = main(["learn", str(log_path), "--out", str(out), "--max-iter", "30", "--patience", "10",
                 "--plots", str(tmp_path / "plots")])
    assert code == 0
    doc = json.loads(out.read_text())
    assert doc["format"] == "aibo-model/1" and doc["learner"] == "em"
    assert len(doc["loglik"]) == doc["iterations"] <= 30
    text = capsys.readouterr().out
    assert "vx RMS / range" in text and "paper" in text  # the error table for logs with truth
    for name in ("loglik.png", "sensor_model.png", "velocity_error.png"):
        assert (tmp_path / "plots" / name).stat().st_size > 1000
    assert not (tmp_path / "model.json.checkpoint.npz").exists()
    # a learned model is a valid start for another fit
    assert main(["learn", str(log_path), "--out", str(tmp_path / "m2.json"), "--init", str(out),
                 "--max-iter", "3", "--learner", "em"]) == 0


def test_learn_oracle(log_path, tmp_path):
    out = tmp_path / "oracle.json"
    assert main(["learn", str(log_path), "--learner", "oracle", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["learner"] == "oracle"


def _bad_log(tmp_path, log_path):
    data = dict(np.load(log_path))
    data["actions"] = data["actions"].copy()
    data["actions"][5] = 40
    bad = tmp_path / "bad.npz"
    np.savez(bad, **data)
    return bad


@pytest.mark.parametrize("case", ["bad_log", "missing_log", "bad_init", "unknown_learner", "oracle_blind"])
def test_learn_bad_input_one_line_and_out_untouched(case, log_path, tmp_path):
    out = tmp_path / "model.json"
    out.write_text("precious")
    args = [str(log_path), "--out", str(out), "--max-iter", "2"]
    expect = str(log_path)
    if case == "bad_log":
        bad = _bad_log(tmp_path, log_path)
        args[0], expect = str(bad), "'actions'"
    elif case == "missing_log":
        args[0], expect = str(tmp_path / "nope.npz"), "file not found"
    elif case == "bad_init":
        (tmp_path / "init.json").write_text('{"format": "aibo-model/1"}')
        args += ["--init", str(tmp_path / "init.json")]
        expect = "field 'action_model': missing"
    elif case == "unknown_learner":
        args += ["--learner", "magic"]
        expect = "unknown learner 'magic'"
    elif case == "oracle_blind":
        blind = tmp_path / "blind.npz"
        trajectory.save(trajectory.blind(trajectory.load(log_path)), blind)
        args[0] = str(blind)
        args += ["--learner", "oracle"]
        expect = "needs true poses"
    r = aibo("learn", *args)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("aibo: error:") and expect in lines[0], r.stderr
    assert "Traceback" not in r.stderr
    assert out.read_text() == "precious"


def test_collect_bad_config_is_one_line(tmp_path):
    r = aibo("collect", "--steps", "10", "--out", str(tmp_path / "x.npz"), "--config", '{"walls": "glass"}')
    assert r.returncode == 2 and "walls" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "x.npz").exists()


def test_a_failed_fit_leaves_no_checkpoint_of_its_own(log_path, tmp_path, monkeypatch):
    """A fit that fails with an error deletes the checkpoints it wrote (the next run on the mended log stopped at
    "checkpoint is for other logs"); an earlier run's checkpoint that this one did not touch is kept."""
    from pathlib import Path

    from aibo.paths import checkpoint_path
    from learners.em import learner as em

    out = tmp_path / "m.json"
    ck = Path(checkpoint_path(out))
    earlier = Path(em.stage_checkpoint(ck, "spurious-1"))
    earlier.write_bytes(b"an earlier run's")

    def failing(self, logs, **kwargs):
        Path(self.checkpoint_path).write_bytes(b"this run's")
        Path(em.stage_checkpoint(self.checkpoint_path, "held")).write_bytes(b"this run's")
        raise em.EMDivergedError("EM converged to a world that does not fit the field", 1.0)

    monkeypatch.setattr(em.EMLearner, "fit", failing)
    assert main(["learn", str(log_path), "--out", str(out)]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == [earlier.name]
    assert earlier.read_bytes() == b"an earlier run's"


def test_python_dash_m_aibo_is_the_command(tmp_path):
    """``python -m aibo`` runs the same command: its exit status and its one-line errors."""
    r = subprocess.run([sys.executable, "-m", "aibo", "learn", str(tmp_path / "absent.npz"), "--out",
                        str(tmp_path / "m.json")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.startswith("aibo: error:") and "absent.npz" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "m.json").exists()
    r = subprocess.run([sys.executable, "-m", "aibo", "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "diagnose" in r.stdout


@pytest.mark.slow
def test_reproduce_quick_end_to_end(tmp_path):
    """--quick writes to its own folder by default (runs/reproduce-quick) and says it is not held to the bar."""
    r = subprocess.run([sys.executable, "-m", "aibo.cli", "reproduce", "--quick"], capture_output=True, text=True,
                       timeout=600, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]
    assert "not held to the paper's bar" in r.stdout
    tmp_path = tmp_path / "runs" / "reproduce-quick"
    assert "vx RMS / range" in r.stdout and "oracle" in r.stdout
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["quick"] and report["iterations"] >= 1
    assert report["em"]["vtheta_rel"] < 0.05  # a first look, not the bar
    # the velocity errors are held against the log's information bound, not against the oracle
    assert "x oracle" not in r.stdout and r.stdout.count("x bound") == 3
    assert set(report["bound"]) == {"vx_bound", "vy_bound", "vtheta_bound"}
    assert {"vx_rel<=1.5xbound", "vy_rel<=1.5xbound", "vtheta_rel<=1.5xbound"} <= set(report["bar"])
    for name in report["figures"]:
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"


def test_reproduce_quick_never_replaces_a_full_run(tmp_path, capsys):
    (tmp_path / "report.json").write_text('{"quick": false}')
    assert main(["reproduce", "--quick", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"--out {tmp_path}: holds a full run's results" in err and err.count("\n") == 1
    assert (tmp_path / "report.json").read_text() == '{"quick": false}'


def test_reproduce_exits_1_when_the_bar_is_missed(tmp_path, monkeypatch, capsys):
    """A full run (a 5-minute log here, to be short) held to a bar no fit meets: exit status 1, the missed items
    named; its results are still written."""
    from aibo.commands import reproduce

    monkeypatch.setattr(reproduce, "FULL_STEPS", reproduce.QUICK_STEPS)
    monkeypatch.setattr(reproduce, "BAR", {**reproduce.BAR, "vx_rel": 1e-9})
    assert main(["reproduce", "--out", str(tmp_path / "R")]) == 1
    captured = capsys.readouterr()
    assert "the bar is missed (vx_rel<=paper" in captured.err and "exit status 1" in captured.err
    assert "MISS vx_rel" in captured.out and json.loads((tmp_path / "R" / "report.json").read_text())["quick"] is False


@pytest.mark.slow
def test_bench_quick_writes_every_figure(tmp_path):
    out = tmp_path / "bench.json"
    r = aibo("bench", "--quick", "--json", str(out))
    assert r.returncode == 0, r.stderr
    rep = json.loads(out.read_text())
    e = rep["estep"]
    assert e["speedup"] == pytest.approx(e["numpy_s"] / e["compiled_s"]) and e["speedup"] > 1
    assert rep["compile_s"] > 0
    fit = rep["fits"]["default"]
    assert fit["iterations"] >= 1 and fit["wall_s"] > 0 and fit["per_iteration_ms"] > 0
    assert [row["frames"] for row in rep["scaling"]] == [2700, 9000]
    b = rep["bias_states"]
    assert b["states"] == 4 and b["action_stats_speedup"] == pytest.approx(b["action_stats_numpy_s"] / b["action_stats_compiled_s"])
    w = rep["workflows"]
    assert w["learn"]["wall_s"] > 0 and w["learn"]["command_wall_s"] > 0
    assert w["diagnose"]["wall_s"] > 0 and w["diagnose"]["named"] == ["actuation_lag"]
    d = w["diagnose"]  # where its time went: the report's stages, and the candidate that took longest
    assert d["seconds_by_stage"]["search"] > 0 and sum(d["seconds_by_stage"].values()) <= d["wall_s"]
    assert d["slowest_candidate"]["name"] in {"actuation_lag", "floor_drift"} and d["slowest_candidate"]["seconds"] > 0
    assert "its stages: search" in r.stdout and "the slowest candidate" in r.stdout
    assert all(row["peak_mb"] >= 0 and row["estep_s"] > 0 for row in rep["scaling"])


def test_learn_resumes_an_interrupted_run(log_path, tmp_path, capsys):
    """An interrupted `aibo learn` leaves OUT.checkpoint.npz; the same command resumes from it."""
    from aibo.cli import build_parser
    from aibo.commands.learn import make_learner

    out = tmp_path / "model.json"
    argv = ["learn", str(log_path), "--out", str(out), "--max-iter", "40", "--paper-recipe"]
    learner = make_learner(build_parser().parse_args(argv))
    learner.checkpoint_every = 5

    def interrupt(rec):
        if rec.iteration == 12:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        learner.fit([trajectory.load(log_path)], progress=interrupt)
    assert (tmp_path / "model.json.checkpoint.npz").exists() and not out.exists()
    assert main(argv) == 0
    assert "resumed from the checkpoint at iteration 10" in capsys.readouterr().out
    assert json.loads(out.read_text())["iterations"] <= 40
    assert not (tmp_path / "model.json.checkpoint.npz").exists()


def test_failed_model_write_keeps_the_checkpoint(log_path, tmp_path, monkeypatch):
    """The checkpoint is deleted only after the model is on disk."""
    import learners.model.io as model_io

    def disk_full(*a, **k):
        raise OSError("No space left on device")

    monkeypatch.setattr(model_io, "save_model", disk_full)
    out = tmp_path / "model.json"
    assert main(["learn", str(log_path), "--out", str(out), "--max-iter", "25"]) == 2
    assert not out.exists()
    assert (tmp_path / "model.json.checkpoint.npz").exists()


def test_reproduce_bar_is_the_information_bound_not_the_oracle():
    """A fit at the bound passes (the oracle, which sees the true poses, is ~2.2x below it); a fit 2x the
    bound is a MISS; without standard errors the velocities are not judged."""
    from aibo.commands.reproduce import check_bar

    paper_ok = {"sigma_height_rel": 0.01, "sigma_angle_rel": 0.01, "sensor_rms_px": 0.1}
    bound = {"vx_bound": 0.015, "vy_bound": 0.014, "vtheta_bound": 0.007}
    oracle = {"vx_rel": 0.015 / 2.2, "vy_rel": 0.014 / 2.2, "vtheta_rel": 0.007 / 2.2}
    at_bound = {**paper_ok, "vx_rel": 0.015, "vy_rel": 0.014, "vtheta_rel": 0.007}
    v = check_bar(at_bound, oracle, bound)
    assert all(v["passed"].values()) and not any("MISS" in line for line in v["lines"])
    twice = {**at_bound, "vx_rel": 0.030}
    v = check_bar(twice, oracle, bound)
    assert v["passed"]["vx_rel<=1.5xbound"] is False and v["passed"]["vy_rel<=1.5xbound"] is True
    assert any(line.startswith("  MISS vx_rel") for line in v["lines"])
    v = check_bar(twice, oracle, None)
    assert not any(k.endswith("bound") for k in v["passed"]) and not any("MISS" in line for line in v["lines"])
