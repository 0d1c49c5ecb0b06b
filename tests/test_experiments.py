"""The experiments layer: run(spec) -> record, backends giving identical records, resuming, the CLI sweep."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from aibo.cli import main
from experiments import executors
from experiments.executors import read_results, run_all
from experiments.policies import RECORD_KEYS
from experiments.run import RunSpec

TINY = {"learner": {"max_iter": 12}, "holdout_minutes": 0.2}


def _specs(seeds=(1, 2), policies=("uniform", "informed")):
    return [RunSpec(p, 0.3, s, {"robot_seed": 100 + s}, **TINY) for s in seeds for p in policies]


def _strip(records):
    return [{k: v for k, v in r.items() if k != "timing"} for r in records]


def test_record_has_the_contract_and_keeps_its_files(tmp_path):
    (rec,) = run_all(_specs(seeds=(1,), policies=("informed",)), tmp_path, backend="serial")
    assert set(RECORD_KEYS) <= set(rec)
    assert (tmp_path / rec["log"]).is_file() and (tmp_path / rec["model"]).is_file()
    assert rec["robot_seed"] == 101 and rec["iterations"] <= 12 and rec["heldout_loglik"] is not None
    assert read_results(tmp_path) == [rec]


def test_pool_gives_the_serial_records(tmp_path):
    specs = _specs()
    serial = run_all(specs, tmp_path / "serial", backend="serial")
    pool = run_all(specs, tmp_path / "pool", backend="pool", jobs=2)
    assert _strip(serial) == _strip(pool)
    assert [r["id"] for r in read_results(tmp_path / "pool")] == [s.normalized().run_id for s in specs]


@pytest.mark.slow
def test_ray_gives_the_serial_records(tmp_path):
    pytest.importorskip("ray", reason="Ray is the optional extra 'ray' (pip install -e '.[ray]')")
    specs = _specs(seeds=(1,))
    serial = run_all(specs, tmp_path / "serial", backend="serial")
    ray_records = run_all(specs, tmp_path / "ray", backend="ray", jobs=2)
    assert _strip(serial) == _strip(ray_records)


def test_interrupted_sweep_resumes_and_loses_nothing(tmp_path, monkeypatch):
    specs = _specs()
    real = executors.run_json
    calls = []

    def interrupted(spec_json, out):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(spec_json["policy"]["name"])
        return real(spec_json, out)

    monkeypatch.setattr(executors, "run_json", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_all(specs, tmp_path, backend="serial")
    first = read_results(tmp_path)
    assert len(first) == 2
    monkeypatch.setattr(executors, "run_json", lambda s, o: calls.append("again") or real(s, o))
    records = run_all(specs, tmp_path, backend="serial")
    assert calls.count("again") == 2  # only the two unfinished runs ran
    assert records[:2] == first  # finished records kept as they were
    assert _strip(records) == _strip(run_all(specs, tmp_path / "clean", backend="serial"))


def test_cli_sweep_end_to_end(tmp_path, capsys):
    out = tmp_path / "sweep"
    argv = ["experiment", "policies", "--policies", "uniform,random-balanced", "--minutes", "0.2,0.3", "--seeds", "2",
            "--out", str(out), "--max-iter", "8", "--holdout-minutes", "0.2", "--backend", "serial"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "| uniform | 0.3 | 2 |" in text and "| commands |" in text and "against random-balanced at 0.3 min" in text
    records = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert len(records) == 8 and all(set(RECORD_KEYS) <= set(r) for r in records)
    assert {r["policy"] for r in records} == {"uniform", "random-balanced"}
    rb = [r for r in records if r["policy"] == "random-balanced"]
    assert all(r["spec"]["policy"]["params"]["localizer"] == "ekf" for r in rb)  # onboard by default
    summary = json.loads((out / "summary.json").read_text())
    assert summary["policies"]["uniform"]["0.3"]["n"] == 2
    assert Path(out / "errors_vs_minutes.png").read_bytes()[:4] == b"\x89PNG"
    assert main(argv) == 0  # everything done: nothing rerun
    assert "[" not in capsys.readouterr().out.split("\n")[1]


def test_cli_bad_lists_are_one_line(tmp_path, capsys):
    assert main(["experiment", "policies", "--minutes", "5,x", "--out", str(tmp_path / "o")]) == 2
    assert "--minutes" in capsys.readouterr().err
    assert main(["experiment", "policies", "--policies", "nope", "--out", str(tmp_path / "o")]) == 2
    assert "'nope'" in capsys.readouterr().err
