"""scripts/diagnose_power.py: how a run counts (a pair both named and within tolerance, a false alarm)."""

from __future__ import annotations

import sys

from tests._scripts import load_script


def _load():
    return load_script("diagnose_power")


def test_a_pair_that_meets_the_walls_names_wall_contact_too():
    dp = _load()
    label, hidden, walls = dp.PAIRS[0]
    assert walls and list(hidden) == ["floor_drift"]
    run = {"effect": label, "params": hidden, "walls": True, "named": ["floor_drift"],
           "values": {"floor_drift": {"drift_mm_s": [14.0, -11.0]}}}
    assert dp.pair_ok(run) == (False, False)
    run["named"] = ["wall_contact", "floor_drift"]
    assert dp.pair_ok(run) == (True, True)
    run["values"]["floor_drift"]["drift_mm_s"] = [9.0, -10.0]  # 6 mm/s off: outside the 5 mm/s tolerance
    assert dp.pair_ok(run) == (True, False)


def test_wall_contact_is_no_false_alarm_where_the_walls_are_met():
    dp = _load()
    assert not dp.false_alarm({"named": ["wall_contact"], "walls": True})
    assert dp.false_alarm({"named": ["wall_contact"], "walls": False})
    assert dp.false_alarm({"named": ["wall_contact", "velocity_fade"], "walls": True})


def test_a_second_process_keeps_its_runs_in_its_own_file(tmp_path, monkeypatch):
    """``--first-power-seed N`` writes runs-from-N.jsonl: a second process never rewrites the first one's runs.jsonl
    (each rewrote the whole file from what it had read, dropping the other's runs); the tables read both."""
    from aibo_core.atomic import read_jsonl

    dp = _load()
    monkeypatch.setattr(dp, "one", lambda effect, params, seed, minutes, preset, walls, effects=None, candidates=None: {
        "effect": effect or "none", "params": params, "seed": seed, "preset": preset, "walls": walls, "named": [],
        "seconds": 0.0})
    seen = []
    monkeypatch.setattr(dp, "summarize", lambda runs, out: seen.append(len(runs)))
    common = ["--seeds", "0", "--effects", "actuation_lag", "--out", str(tmp_path)]
    for argv in (["--power-seeds", "1"], ["--first-power-seed", "1", "--power-seeds", "2"], ["--power-seeds", "2"]):
        monkeypatch.setattr(sys, "argv", ["diagnose_power.py", *argv, *common])
        dp.main()
    assert len(read_jsonl(tmp_path / "runs.jsonl")) == 3 and len(read_jsonl(tmp_path / "runs-from-1.jsonl")) == 3
    assert seen == [3, 6, 6]  # the third run finds seed 1's runs in the other file: nothing to do again


def test_the_study_runs_with_the_commands_default_candidates_when_asked(tmp_path, monkeypatch):
    """``--candidates defaults``: what ``aibo diagnose`` tries without ``--candidates`` (not the effects it tries only
    when asked for); "all": every effect (None); a list is checked against the catalogue."""
    import pytest

    from aibo.commands.diagnose import candidates
    from learners.model.effects import EFFECT_MODELS

    dp = _load()
    assert dp.chosen_candidates("all") == sorted(EFFECT_MODELS)
    assert dp.chosen_candidates("defaults") == list(candidates(None))
    assert "heavy_tailed_noise" not in dp.chosen_candidates("defaults")
    assert dp.chosen_candidates("floor_drift,wall_contact") == ["floor_drift", "wall_contact"]
    given = []
    monkeypatch.setattr(dp, "one", lambda *a, candidates=None, **k: given.append(candidates) or {
        "effect": "none", "params": None, "seed": a[2], "preset": a[4], "walls": a[5], "named": [], "seconds": 0.0})
    monkeypatch.setattr(dp, "summarize", lambda runs, out: None)
    monkeypatch.setattr(sys, "argv", ["diagnose_power.py", "--seeds", "1", "--power-seeds", "0", "--candidates",
                                      "defaults", "--out", str(tmp_path)])
    dp.main()
    assert given == [list(candidates(None))]
    with pytest.raises(SystemExit, match="unknown effect 'nope'"):
        dp.chosen_candidates("floor_drift,nope")
