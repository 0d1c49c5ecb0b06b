"""Issue 18, "none of the above": an effect outside the catalogue (a sloped floor: the walking speed depends on the
heading, ``experiments.outside_catalogue``) is reported unexplained by the search's final check
(``learners.model.probes``), with its signature, and not forced onto a catalogue name; effect-free logs report
nothing. The sloped floor is a simulator effect no learner twin was written for (data our catalogue did not shape).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from aibo_core.trajectory import blind
from aibo_gym.collect import collect
from experiments.outside_catalogue import SlopedFloor, registered
from learners.arrays.batch import make_batch
from learners.discrepancy.search import search
from learners.em.estep import e_step
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.model.effects import EFFECT_MODELS
from learners.model.probes import PROBES, SpeedVsHeading
from tests._logs import diagnose, sim_log

FIVE_MINUTES = 9000  # frames
ALL = ",".join(sorted(EFFECT_MODELS))
DOWNHILL = 0.5  # rad


def _sloped(seed: int, grade: float = 0.15):
    with registered(SlopedFloor):
        return collect({"noise": "aibo", "effects": {"sloped_floor": {"grade": grade, "downhill_rad": DOWNHILL}}},
                       FIVE_MINUTES, seed=seed)


def test_probes_are_never_candidates_and_are_neutral_at_zero():
    assert not set(PROBES) & set(EFFECT_MODELS)
    tr = sim_log(3000)
    model = EMLearner(EMOptions(max_iter=5, starts=1, alias_search=False, lag_search=False)).fit([tr]).params
    batch = make_batch([tr])
    probe = SpeedVsHeading.around(e_step(model, batch, "compiled"), batch)
    assert probe.basis.shape == (batch.n_frames, 2)
    np.testing.assert_allclose(np.hypot(*probe.basis.T), 1.0)  # (cos, sin) of a heading
    assert model.with_effect(probe).effective_commands(batch)[1] is None  # coef 0: no factor at all
    tilted = probe.with_values(coef=np.array([0.2, 0.0]))
    scale = model.with_effect(tilted).effective_commands(batch)[1]
    np.testing.assert_allclose(scale[:, 0], 1.0 + 0.2 * probe.basis[:, 0])  # forward and lateral scaled,
    np.testing.assert_allclose(scale[:, 1], scale[:, 0])
    np.testing.assert_allclose(scale[:, 2], 1.0)  # the turn not
    other = make_batch([sim_log(3001)])  # another log's frames: the probe does nothing there
    assert tilted.disp_scale(other) is None


def test_a_sloped_floor_is_reported_none_of_the_above_through_aibo_diagnose(tmp_path):
    report = diagnose(tmp_path, _sloped(4000), ALL)
    assert report["effects"] == []  # no catalogue name forced on it
    (u,) = [u for u in report["unexplained"] if u.get("probe")]
    assert u["effect"] == "none of the above" and u["probe"] == "speed_vs_heading"
    assert u["gain_heldout"] > 0 and u["p_value"] < 1e-6
    c0, c1 = u["parameters"]["coef"]
    # truth 0.15 (cos 0.5, sin 0.5) = (0.132, 0.072): measured (0.106, 0.052), the grade attenuated (the headings are
    # read off the smoothed path and the speed model absorbs part of it) but the downhill direction right
    assert abs(np.arctan2(c1, c0) - DOWNHILL) < 0.3 and 0.06 < np.hypot(c0, c1) < 0.2
    # the signature: the smoothed forward speed over the model's rises with the probe's factor (measured: -0.6% to
    # +0.8% over factors -0.11 to +0.12, attenuated: one frame's smoothed displacement stays near the prediction).
    # Its p-value allows for the frames' serial correlation (``equal_means``): 0.0014 (the F-test's was below 1e-6)
    sig = u["signature"]
    assert sig["p_value"] < 0.01 and np.polyfit(sig["centers"], sig["means"], 1)[0] > 0.03
    page = (tmp_path / "diag" / "report.html").read_text()
    assert "Verdict: <b>none of the above</b>" in page and "world heading" in page
    json.dumps(report)


@pytest.mark.parametrize("preset,seed", [("aibo", 1000), ("paper-sim", 1001)])
def test_an_effect_free_log_reports_nothing_unexplained(preset, seed):
    tr = blind(collect({"noise": preset}, FIVE_MINUTES, seed=seed))
    found = search([tr], [], EMOptions(), jobs=2, progress=lambda s: None)  # no candidates: the final check alone
    assert {c.name for c in found["probes"]} == set(PROBES)
    assert not any(c.significant for c in found["probes"]), [(c.name, c.gain_train, c.p_value) for c in found["probes"]]
