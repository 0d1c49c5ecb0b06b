"""scripts/exploration_paired.py: paired relative differences per seed, their mean and standard error."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests._scripts import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "exploration_paired.py"


def _load():
    return load_script("exploration_paired")


def _records():
    errors = {"random-balanced": [2.0, 4.0, 3.0], "informed": [1.0, 3.0, 3.0], "learned": [1.0, 2.0, 1.5]}
    return [{"policy": p, "minutes": 5.0, "seed": s + 1, "vel_rel_mean": e, "vx_rel": e, "vy_rel": 2 * e}
            for p, es in errors.items() for s, e in enumerate(es)]


def test_paired_differences_mean_and_standard_error():
    rows = {r["policy"]: r for r in _load().compare(_records(), ["random-balanced", "informed"], "vel_rel_mean")}
    d = np.array([1 / 2, 2 / 4, 1.5 / 3]) - 1  # learned / random-balanced - 1, per seed
    assert rows["learned"]["vs random-balanced"] == pytest.approx(d.mean())
    assert rows["learned"]["vs random-balanced se"] == pytest.approx(d.std(ddof=1) / np.sqrt(3))
    assert rows["learned"]["vs random-balanced wins"] == 3 and rows["learned"]["vs random-balanced n"] == 3
    assert rows["informed"]["vs random-balanced wins"] == 2  # a tie is not a win
    assert "vs informed" not in rows["informed"] and rows["learned"]["error"] == pytest.approx(1.5)
    vxy = {r["policy"]: r for r in _load().compare(_records(), ["random-balanced"], "vxy")}
    assert vxy["learned"]["error"] == pytest.approx(1.5 * 1.5)  # (vx + vy) / 2


def test_cli_prints_the_table_and_the_verdict(tmp_path):
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in _records()))
    out = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path), "--json", str(tmp_path / "rows.json")],
                         capture_output=True, text=True, check=True).stdout
    assert "| learned | 5 | 3 |" in out and "learned at 5 min: target MET" in out
    assert "informed at 5 min" not in out  # a baseline is not judged against itself
    assert len(json.loads((tmp_path / "rows.json").read_text())) == 3
