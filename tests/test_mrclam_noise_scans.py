"""``scripts/mrclam_noise_scans.py``: likelihood scans of a persistent error of the turn's gain, of a smaller noise
while standing still and of bearing and size biases per landmark (docs/results.md, "Where in the turns the heading's noise
is"), on logs of the independent differential-drive generator whose errors are known."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from aibo_core.mrclam import import_robot
from learners.arrays.batch import make_batch
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.inference.reference import smooth
from tests._diffdrive import diff_drive_log
from tests._scripts import load_script
from tests.test_mrclam import DATA, needs_data

NO_TURN = dict(sigmas=(), still_factors=(), size_sigmas=())
NO_BEARING = dict(bearing_sigmas=(), still_factors=(), size_sigmas=())


def test_without_a_form_the_scan_is_the_models_own_filter():
    """Known answer: the form that adds nothing is the reference E-step's forward likelihood, to 1e-9; each form's
    parameters reach the filter."""
    script = load_script("mrclam_noise_scans")
    tr = diff_drive_log(seconds=60.0, seed=3)
    batch = make_batch([tr])
    lo = EMLearner(EMOptions(uncertainty=False, max_iter=5), check_field=False).fit([tr]).params.lower(batch)
    landmark = np.asarray(tr.sighting_landmark)
    ours = script.forward_pass_of(lo, batch, landmark, batch.used, tr.dt).loglik
    assert ours == pytest.approx(smooth(lo, batch).loglik, abs=1e-9)
    for form in (script.Form(sigma=0.3, tau=2.0), script.Form(c=0.5), script.Form(sigma_b=0.01, tau_b=10.0),
                 script.Form(s=0.5), script.Form(sigma_r=0.05, tau_r=10.0), script.Form(r=0.5)):
        assert abs(script.forward_pass_of(lo, batch, landmark, batch.used, tr.dt, form).loglik - ours) > 0.1, form
    still = replace(lo, disp=np.where(np.arange(len(lo.disp))[:, None] < 200, 0.0, lo.disp))  # 10 s standing still
    at_rest = script.forward_pass_of(still, batch, landmark, batch.used, tr.dt).loglik
    assert abs(script.forward_pass_of(still, batch, landmark, batch.used, tr.dt, script.Form(k=0.1)).loglik
               - at_rest) > 0.1


@pytest.mark.parametrize("tau_s, persists", [(20.0, True), (0.01, False)])
def test_the_scan_tells_a_persistent_turn_error_from_a_white_one(tau_s, persists):
    """A log whose turns err by a gain that wanders with a correlation time of 20 s is fitted better by the scan's
    8-s state than by its 0.1-s one (by 330-400 nats on seeds 5 and 6); a log whose gain error is white (0.01 s), the
    other way round (by 33-46)."""
    script = load_script("mrclam_noise_scans")
    tr = diff_drive_log(seconds=300.0, seed=5, turn_gain=(0.3, tau_s))
    turn = script.scans(tr, taus_s=(0.1, 8.0), sigmas=(0.1, 0.3), heading_factors=(1.0, 0.25), **NO_BEARING).turn
    best = {t: script.best(turn, "tau", t)[1] for t in (0.1, 8.0)}
    assert (best[8.0] > best[0.1] + 5.0) if persists else (best[0.1] > best[8.0] + 5.0), best


@pytest.mark.parametrize("bias, gains", [((0.02, 30.0), True), (None, False)])
def test_the_scan_finds_bearing_biases_per_landmark_where_the_log_has_them(bias, gains):
    """A log whose bearings carry a bias per landmark (sd 20 mrad, 30 s) gains far more from the scan's bearing states
    than an effect-free one, whose best row gains a few nats at most."""
    script = load_script("mrclam_noise_scans")
    tr = diff_drive_log(seconds=300.0, seed=5, bearing_bias=bias)
    bearing = script.scans(tr, bearing_sigmas=(0.005, 0.02), bearing_taus_s=(30.0,), bearing_factors=(1.0, 0.5),
                           **NO_TURN).bearing
    top = max(g for _, g, _ in bearing)
    assert top > 100.0 if gains else top < 10.0, top


@pytest.mark.parametrize("bias, gains", [((0.05, 30.0), True), (None, False)])
def test_the_scan_finds_range_biases_per_landmark_where_the_log_has_them(bias, gains):
    """A log whose ranges carry a relative bias per landmark (sd 5%, 30 s) gains far more from the scan's size states
    than an effect-free one, whose best row gains a few nats at most."""
    script = load_script("mrclam_noise_scans")
    tr = diff_drive_log(seconds=300.0, seed=5, range_bias=bias)
    size = script.scans(tr, size_sigmas=(0.02, 0.05), size_taus_s=(30.0,), size_factors=(1.0,), sigmas=(),
                        still_factors=(), bearing_sigmas=()).size
    top = max(g for _, g, _ in size)
    assert top > 100.0 if gains else top < 10.0, top


def test_both_forms_together_are_the_best_turn_and_bearing_rows_joined():
    """The last table's row: the best turn row's form with the best bearing row's, scored once more."""
    script = load_script("mrclam_noise_scans")
    sc = script.scans(diff_drive_log(seconds=60.0, seed=3), sigmas=(0.1, 0.3), taus_s=(0.1,), heading_factors=(1.0,),
                      still_factors=(), bearing_sigmas=(0.01,), bearing_taus_s=(10.0,), bearing_factors=(1.0,),
                      size_sigmas=())
    t = max(sc.turn, key=lambda row: row[1])[0]
    assert sc.both[0][0] == script.Form(sigma=t.sigma, tau=0.1, sigma_b=0.01, tau_b=10.0)
    assert sc.both[0][1] != sc.turn[0][1] and sc.both[0][1] != sc.bearing[0][1]
    assert sc.both[0][0].label() == f"sigma {t.sigma:g}, tau 0.1, sigma_b 0.01, tau_b 10"


def test_the_figure_is_written(tmp_path):
    """``--png``'s figure: one PNG with the three scans' panels (looked at: docs/img/mrclam_noise_scans.png)."""
    script = load_script("mrclam_noise_scans")
    sc = script.scans(diff_drive_log(seconds=60.0, seed=3), sigmas=(0.3,), heading_factors=(1.0,), still_factors=(),
                      bearing_sigmas=(0.01,), bearing_factors=(1.0,), size_sigmas=(0.02,), size_factors=(1.0,))
    script.figure({1: sc}, tmp_path / "scans.png")
    assert (tmp_path / "scans.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.realdata
@needs_data
def test_robot_1s_sightings_want_the_turn_noise_white_and_the_bearing_biases_persistent():
    """MRCLAM robot 1 (2026-11-30, docs/results.md): at sigma 0.4 of the turn and the heading noise x 0.25, a white turn
    gain error (0.1 s) is worth more than one that persists 8 s; at 6 mrad and the bearing noise x 0.5, bearing biases
    that persist 20 s are worth more than ones that last 1 s (each by more than 100 nats)."""
    script = load_script("mrclam_noise_scans")
    sc = script.scans(import_robot(DATA, 1), sigmas=(0.4,), taus_s=(0.1, 8.0), heading_factors=(0.25,),
                      still_factors=(), bearing_sigmas=(0.006,), bearing_taus_s=(1.0, 20.0), bearing_factors=(0.5,),
                      size_sigmas=())
    turn = {f.tau: g for f, g, _ in sc.turn}
    bearing = {f.tau_b: g for f, g, _ in sc.bearing}
    assert turn[0.1] > turn[8.0] + 100.0 and bearing[20.0] > bearing[1.0] + 100.0, (turn, bearing)
