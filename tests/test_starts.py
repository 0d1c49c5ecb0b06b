"""Several starts (learners/em/starts.py) and the sensor basis option."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from learners.arrays.posterior import Posterior
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.em.starts import (
    DISAGREE_NATS,
    DISTANCE_SCALES,
    PRUNED_SHARE_WARN,
    disagreement,
    distance_scales,
    gated_score,
    pruned_warning,
    stretched,
)
from learners.metrics import model_errors
from learners.model.model import paper_start
from learners.model.sensor import SensorModel
from tests._logs import sim_log

#: A sensor line implying distances about twice too long: inside the field, but a wrong world.
FAR_LINE = np.array([50.0, -0.004, 0.0, 0.0])


@pytest.mark.parametrize("basis, coef", [("power", [60.0, -0.02, 3e-6, -1e-10]), ("inverse", [5.0, 40000.0, 1e6])])
def test_a_stretched_curve_implies_scaled_distances(basis, coef):
    sensor = SensorModel.start("height_px", basis, len(coef) - 1).with_values(coef=np.array(coef))
    d = np.linspace(1300.0, 4100.0, 7)
    for s in (0.25, 0.5, 2.0):
        np.testing.assert_allclose(stretched(sensor, s).mean(d * s), sensor.mean(d), rtol=1e-12)


def test_distance_scales_start_with_the_given_start_and_are_seeded():
    assert distance_scales(3, 0) == list(DISTANCE_SCALES[:3]) and DISTANCE_SCALES[0] == 1.0
    many = distance_scales(8, 4)
    assert many == distance_scales(8, 4) and many != distance_scales(8, 5)
    assert all(0.1 <= s <= 3.0 for s in many[len(DISTANCE_SCALES):])


def test_disagreement_names_a_given_start_that_lost_or_failed():
    rows = [{"start": 0, "distance_scale": 1.0, "iterations": 30, "loglik": -100.0, "behind_nats": 0.0,
             "chosen": True},
            {"start": 1, "distance_scale": 0.5, "iterations": 30, "loglik": -9000.0, "behind_nats": 8900.0}]
    assert disagreement(rows) == ""  # a stretched start that falls behind is expected
    close = [dict(rows[0], chosen=False, behind_nats=DISAGREE_NATS / 2), dict(rows[1], behind_nats=0.0, chosen=True)]
    assert disagreement(close) == ""  # the given start lost by little: the same optimum
    lost = [dict(rows[0], chosen=False, behind_nats=2 * DISAGREE_NATS), dict(rows[1], behind_nats=0.0, chosen=True)]
    assert "starts disagree: kept start 1" in disagreement(lost) and "200 nats" in disagreement(lost)
    failed = [{"start": 0, "distance_scale": 1.0, "iterations": 0, "error": "failed: boom"}, lost[1]]
    assert "failed: boom" in disagreement(failed)


def test_the_paper_recipe_keeps_one_start_and_the_cubic():
    paper = EMOptions.paper()
    assert paper.starts == 1 and paper.basis == "power" and paper.sensor_degree(paper.sensor_basis()) == 3
    assert EMOptions().sensor_basis("height_px") == "inverse" and EMOptions().sensor_basis("range_mm") == "power"
    assert EMOptions().sensor_basis("height_px", init_basis="power") == "power"  # --init's basis is kept
    assert EMOptions(basis="inverse").sensor_degree("inverse") == 2
    with pytest.raises(ValueError, match="basis"):
        EMOptions(basis="log").validate()


def test_a_cubic_init_is_refitted_in_the_inverse_basis():
    tr = sim_log(6000, seed=3)
    cubic = paper_start([tr]).sensor.with_values(coef=np.polynomial.polynomial.polyfit(
        np.linspace(1275, 4175, 50), 57000 / np.linspace(1275, 4175, 50), 3))
    start = EMLearner(EMOptions(basis="inverse")).start_params([tr], paper_start([tr]).with_(sensor=cubic), None)
    assert start.sensor.basis == "inverse" and len(start.sensor.coef) == 3
    d = np.linspace(1275, 4175, 100)
    assert np.sqrt(np.mean((start.sensor.mean(d) - cubic.mean(d)) ** 2)) < 0.25  # ~ the cubic's misfit to 57000/d


@pytest.mark.slow
def test_a_single_start_settles_in_a_wrong_world_that_several_starts_escape():
    """15 minutes, a sensor start implying distances twice too long: one start converges (converged=True,
    the path inside the field) with ~40% velocity errors; three starts keep the right world and say so."""
    tr = sim_log(27000, seed=1, robot_seed=1)
    bad = paper_start([tr]).with_(sensor=paper_start([tr]).sensor.with_values(coef=FAR_LINE))
    one = EMLearner(EMOptions(starts=1, uncertainty=False)).fit([tr], init=bad)  # passes the off-field check
    assert one.converged and one.info["off_field_fraction"] < 0.05
    assert model_errors(one.params, [tr]).vx_rel > 0.2
    three = EMLearner(EMOptions(starts=3, uncertainty=False)).fit([tr], init=bad)
    err = model_errors(three.params, [tr])
    assert err.vx_rel < 0.02 and err.vy_rel < 0.02 and err.sensor_rms_px < 0.3
    rows = three.info["starts"]
    assert [r["distance_scale"] for r in rows] == list(DISTANCE_SCALES[:3])
    assert rows[0]["behind_nats"] > 1000 and not rows[0].get("chosen")
    assert any(w.startswith("starts disagree") for w in three.info["warnings"])
    assert max(three.loglik) > max(one.loglik) + 1000


def test_learn_with_starts_and_inverse_basis_reports_both(tmp_path, capsys):
    log = tmp_path / "log.npz"
    trajectory.save(sim_log(6000, seed=3), log)
    out = tmp_path / "m.json"
    assert main(["learn", str(log), "--out", str(out), "--starts", "2", "--sensor-basis", "inverse",
                 "--max-iter", "60"]) == 0
    doc = json.loads(out.read_text())
    assert doc["sensor_model"]["basis"] == "inverse" and len(doc["sensor_model"]["coef"]) == 3
    assert [r["start"] for r in doc["info"]["starts"]] == [0, 1]
    assert doc["info"]["options"]["starts"] == 2
    text = capsys.readouterr().out
    assert "2 starts screened" in text and "<- kept" in text and "standard errors" in text


def test_learn_init_with_its_own_converged_model_keeps_the_data(tmp_path, capsys):
    """A converged model as --init: the stretched starts gate away most sightings and, scored only on the
    sightings none of them pruned, won (5 minutes: a wrong world refused by the field check; 15 minutes: 8,408 of
    13,397 sightings pruned, exit 0). Scored on the same sightings, the given start wins and nothing is pruned."""
    log, first, again = tmp_path / "log.npz", tmp_path / "m.json", tmp_path / "again.json"
    tr = sim_log(6000, seed=3)
    trajectory.save(tr, log)
    assert main(["learn", str(log), "--out", str(first)]) == 0
    capsys.readouterr()
    assert main(["learn", str(log), "--init", str(first), "--out", str(again)]) == 0
    doc = json.loads(again.read_text())
    kept = next(r for r in doc["info"]["starts"] if r.get("chosen"))
    assert kept["start"] == 0 and kept["pruned"] <= PRUNED_SHARE_WARN * tr.n_sightings
    assert max(r["pruned"] for r in doc["info"]["starts"]) > 0.1 * tr.n_sightings  # the stretched starts did prune
    assert "outlier gate pruned" not in capsys.readouterr().err


def _posterior(mahal2, loglik):
    return Posterior(*(None,) * 6, loglik=loglik, mahal2=np.asarray(mahal2, float))


def test_gated_score_counts_a_gated_sighting_at_the_gate():
    used = np.ones(4, bool)
    # applied sightings: d2 = 1, 3 with log-normaliser -2 each: loglik = -2 - 0.5 - 2 - 1.5 = -6
    post = _posterior([1.0, 3.0, 80.0, 200.0], -6.0)
    assert gated_score(post, used, 50.0) == pytest.approx(-6.0 + 2 * (-2.0 - 25.0))
    assert gated_score(post, used, None) == -6.0  # no gate: the likelihood itself
    assert gated_score(post, np.array([True, True, False, False]), 50.0) == -6.0  # sightings not compared: ignored


def test_pruned_warning_beyond_the_bounded_share():
    assert pruned_warning(16, 13397) == "" and pruned_warning(0, 0) == ""
    text = pruned_warning(8408, 13397)
    assert "8,408 of 13,397 sightings (63%" in text and f"{PRUNED_SHARE_WARN:.0%}" in text
