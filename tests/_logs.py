"""Logs shared by the tests: simulated ones (built once per test session) and where the real MRCLAM data are."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from aibo_gym.collect import collect

#: MRCLAM Dataset 7 where ../shared/data holds it (the tests that read it skip where it is absent)
MRCLAM_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "mrclam7"


@lru_cache(maxsize=None)
def sim_log(steps: int = 6000, seed: int = 3, noise: str = "paper-sim", robot_seed: int = 0):
    """A random-balanced log with ground truth (returns the same object per arguments: do not mutate)."""
    return collect({"noise": noise, "robot_seed": robot_seed}, steps=steps, seed=seed)


def frame_view(tr):
    """The /1 view of a log with at most one sighting per frame: (obs (T, 2) NaN where none,
    beacon (T,) -1 where none)."""
    import numpy as np

    assert len(np.unique(tr.sighting_frame)) == tr.n_sightings, "several sightings in one frame"
    obs = np.full((tr.n_frames, 2), np.nan)
    beacon = np.full(tr.n_frames, -1)
    obs[tr.sighting_frame] = tr.sighting_value
    beacon[tr.sighting_frame] = tr.sighting_landmark
    return obs, beacon


def diagnose(tmp_path, tr, candidates: str, jobs: int = 2, replicas: int = 0) -> dict:
    """``aibo diagnose`` on the blinded log ``tr`` (saved under ``tmp_path``): its report.json, after
    checking that every output file was written. ``replicas``: of the calibrated simulator (0: not
    run, to keep the tests of the search short; tests/test_calibrated.py checks it)."""
    import json

    from aibo.cli import main
    from aibo_core.trajectory import blind, save

    log = tmp_path / "log.npz"
    save(blind(tr), log)
    out = tmp_path / "diag"
    assert main(["diagnose", str(log), "--out", str(out), "--candidates", candidates, "--jobs", str(jobs),
                 "--replicas", str(replicas)]) == 0
    report = json.loads((out / "report.json").read_text())
    for name in ("model.json", "report.html", "signatures.png", "gap.png") + (("calibrated.png",) if replicas else ()):
        assert (out / name).stat().st_size > 0
    assert "data:image/png;base64," in (out / "report.html").read_text()
    for e in report["effects"]:  # each named effect: its values, with an interval (or None) for every parameter
        assert set(e["intervals"]) == set(e["parameters"]) and set(e["parameters_when_named"]) == set(e["parameters"])
    assert (report["base_change"] is None) == (not report["effects"])
    tried = {c["name"] for c in report["candidates"]}  # what the disagreements left point at, never a tried effect
    assert not tried & {u["effect"] for u in report["untried_effects"]}
    assert (report["untried_candidates"] is None) == (not report["untried_effects"])
    for key in ("motion_gap_before", "motion_gap_after", "motion_excess_before", "motion_excess_after"):
        assert set(report[key]) == {"1", "2", "5"}, (key, report[key])  # horizons in seconds
    assert "Motion gap" in (out / "report.html").read_text()
    o = report["outliers"]  # the sightings the search set aside before any fit, said on the page too
    assert o["sightings"] == tr.n_sightings and 0 <= o["set_aside"] <= o["sightings"]
    assert o["share"] == (o["set_aside"] / o["sightings"]) and "set aside as gross errors" in (out / "report.html").read_text()
    shape = report["innovation_shape"]  # where the final model's innovations depart from its Gaussian
    assert shape["sightings"] > 0 and all(0.0 <= shape[k] <= 1.0 for k in ("nis_below_band", "nis_above_band"))
    assert len(shape["bearing"]["outside_95_by_turn_rate"]) == len(shape["turn_rate_edges_rad_s"]) - 1
    halves = shape["nis_by_repeat"]  # the NIS by the time since the landmark's last sighting: two halves of the whole
    assert halves["closer"]["sightings"] + halves["further"]["sightings"] == shape["sightings"]
    assert shape["repeat_split_s"] > 0 and (out / "innovations.png").stat().st_size > 0  # their quantile plot
    for h in halves.values():
        assert len(h["quantiles"]) == len(shape["quantile_probs"]) and np.all(np.diff(h["quantiles"]) >= 0)
    return report
