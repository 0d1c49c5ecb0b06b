"""``scripts/mrclam_motion_scans.py``: likelihood scans of a persistent error of the turn's gain and of a smaller
noise while standing still (docs/results.md, "Where in the turns the heading's noise is"), on logs of the independent
differential-drive generator whose turn errors are known."""

from __future__ import annotations

import pytest

from learners.arrays.batch import make_batch
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.inference.reference import smooth
from tests._diffdrive import diff_drive_log
from tests._scripts import load_script


def test_without_the_state_the_scan_is_the_models_own_filter():
    """Known answer: sigma 0, c 1, k 1 is the reference E-step's forward likelihood, to 1e-9."""
    script = load_script("mrclam_motion_scans")
    tr = diff_drive_log(seconds=60.0, seed=3)
    batch = make_batch([tr])
    lo = EMLearner(EMOptions(uncertainty=False, max_iter=5), check_field=False).fit([tr]).params.lower(batch)
    ours = script.forward_pass_of(lo, batch, batch.used, tr.dt).loglik
    assert ours == pytest.approx(smooth(lo, batch).loglik, abs=1e-9)
    moved = script.forward_pass_of(lo, batch, batch.used, tr.dt, sigma=0.3, tau=2.0, c=0.5, k=0.1).loglik
    assert abs(moved - ours) > 0.1  # the state and the factors reach the filter


@pytest.mark.parametrize("tau_s, persists", [(20.0, True), (0.01, False)])
def test_the_scan_tells_a_persistent_turn_error_from_a_white_one(tau_s, persists):
    """A log whose turns err by a gain that wanders with a correlation time of 20 s is fitted better by the scan's
    8-s state than by its 0.1-s one; a log whose gain error is white (0.01 s), the other way round."""
    script = load_script("mrclam_motion_scans")
    tr = diff_drive_log(seconds=300.0, seed=5, turn_gain=(0.3, tau_s))
    turn, _, _, _ = script.robot_rows(tr, sigmas=(0.1, 0.3), taus_s=(0.1, 8.0), heading_factors=(1.0, 0.25),
                                      still_factors=())
    best = {t: max(g for _, tau, _, g in turn if tau == t) for t in (0.1, 8.0)}
    assert (best[8.0] > best[0.1] + 5.0) if persists else (best[0.1] > best[8.0] + 5.0), best
