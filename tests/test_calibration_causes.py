"""scripts/calibration_causes.py share: a calibration row's false_sightings interval against the log's own share of
spurious sightings (the simulator's truth for the row's seed), beside the rate simulated."""

from __future__ import annotations

from aibo_core.atomic import write_jsonl
from aibo_gym.collect import collect
from tests._scripts import load_script


def test_share_compares_each_interval_with_its_logs_own_share_of_spurious_sightings(tmp_path, capsys):
    causes = load_script("calibration_causes")
    rows = []
    for k, seed in enumerate((8001, 8003)):
        tr = collect({"noise": "paper-sim", "effects": {"false_sightings": {"rate": 0.08}}}, 360, seed=seed)
        own = len(tr.meta["truth"]["spurious_sightings"]) / tr.n_sightings
        value = own + 0.01 * k  # the second estimate 0.01 above its log's share, its interval missing it
        rows.append({"effect": "false_sightings", "log": 2 * k + 1, "seed": seed, "preset": "paper-sim",
                     "minutes": 0.2, "params": {"rate": 0.08}, "named": ["false_sightings"],
                     "effects": [{"name": "false_sightings", "intervals": {"rate": {
                         "value": value, "se": 0.002, "interval_95": [value - 0.004, value + 0.004]}}}]})
    write_jsonl(tmp_path / "rows.jsonl", rows)
    causes.share(str(tmp_path))
    out = capsys.readouterr().out
    assert "paper-sim: 2 logs named it" in out and "the log's own share on 1;" in out
    assert "estimate - share +0.0050" in out and "mean SE 0.0020" in out
