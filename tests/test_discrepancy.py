"""The discrepancy workflow: the held-out score's math, the split, the signatures, and ``aibo diagnose``
naming hidden effects in blind logs (the simulator's twins; nothing in the file says which)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aibo.cli import main
from aibo_core.trajectory import blind, save
from aibo_gym.collect import collect
from learners.discrepancy.score import predictive_logdens
from learners.discrepancy.signatures import signatures
from learners.discrepancy.split import heldout_mask, training_log
from learners.em.fit import EMOptions, e_step
from learners.em.learner import EMLearner
from learners.inference.batch import make_batch
from tests._logs import sim_log


def test_predictive_densities_sum_to_the_e_step_likelihood():
    """Known answer: the one-step predictive densities of all sightings multiply to the likelihood."""
    tr = sim_log(3000)
    model = EMLearner(EMOptions(max_iter=20)).fit([tr]).params
    batch = make_batch([tr])
    post = e_step(model, batch, "compiled")
    ld = predictive_logdens(model.lower(batch), batch, post, np.arange(batch.n_sightings))
    assert ld.sum() == pytest.approx(post.loglik, rel=1e-10, abs=1e-6)


def test_interleaved_split_keeps_every_command_in_both_halves():
    tr = sim_log(18000)  # 10 minutes: each command held about three times
    held = heldout_mask(tr)
    assert 0.4 < held.mean() < 0.6
    train = training_log(tr)
    assert train.n_sightings == int((~held).sum()) and train.n_frames == tr.n_frames
    for half in (held, ~held):
        frames = tr.sighting_frame[half]
        assert len(np.unique(tr.actions[frames])) == 40


def test_floor_drift_shows_in_the_motion_residuals_against_heading():
    tr = blind(collect({"noise": "aibo", "effects": {"floor_drift": {"drift_mm_s": [20.0, 0.0]}}}, 9000, seed=4))
    model = EMLearner(EMOptions()).fit([tr]).params
    top = [(s.residual, s.variable) for s in signatures(model, [tr])[:3]]
    assert any(v == "world heading (rad)" and "motion" in r for r, v in top), top


def _diagnose(tmp_path, effects: dict, candidates: str, seed: int = 11, steps: int = 12000) -> dict:
    log = tmp_path / "log.npz"
    save(blind(collect({"noise": "aibo", "effects": effects}, steps, seed=seed)), log)
    out = tmp_path / "diag"
    assert main(["diagnose", str(log), "--out", str(out), "--candidates", candidates, "--jobs", "2"]) == 0
    report = json.loads((out / "report.json").read_text())
    for name in ("model.json", "report.html", "signatures.png", "gap.png"):
        assert (out / name).stat().st_size > 0
    assert "data:image/png;base64," in (out / "report.html").read_text()
    return report
