"""``scripts/mrclam_motion_noise.py``: the twin's motion noise against Vicon (docs/results.md, "The twin's motion noise
against Vicon")."""

from __future__ import annotations

import numpy as np
import pytest

from aibo_core.geometry import wrap
from tests._diffdrive import diff_drive_log
from tests._scripts import load_script
from tests.test_mrclam import DATA, needs_data


def _errors(tr) -> tuple[np.ndarray, np.ndarray]:
    """(range error mm, bearing error rad) of each sighting at the true pose."""
    f, lm = tr.sighting_frame, tr.landmarks[tr.sighting_landmark]
    p = tr.pose[f + 1]
    d = np.hypot(lm[:, 0] - p[:, 0], lm[:, 1] - p[:, 1])
    b = wrap(np.arctan2(lm[:, 1] - p[:, 1], lm[:, 0] - p[:, 0]) - p[:, 2])
    return tr.sighting_value[:, 0] - d, wrap(tr.sighting_value[:, 1] - b)


def _lag1(tr, e: np.ndarray) -> float:
    """Lag-1 autocorrelation of ``e`` between consecutive sightings of the same landmark."""
    pairs = [(e[i], e[j]) for L in np.unique(tr.sighting_landmark)
             for i, j in zip(np.flatnonzero(tr.sighting_landmark == L)[:-1], np.flatnonzero(tr.sighting_landmark == L)[1:])]
    a = np.array(pairs)
    return float(np.corrcoef(a[:, 0], a[:, 1])[0, 1])


def test_whitening_keeps_the_spread_and_removes_the_persistence():
    """A log whose ranges carry a per-landmark bias over seconds (sigma_rel 0.05, tau 6 s): its range errors correlate
    from one sighting of a landmark to the next; made white they do not, with the same spread; the bearings, made
    white too, keep theirs (0.02 rad)."""
    tr = diff_drive_log(300.0, seed=1, range_bias=(0.05, 6.0))
    er, eb = _errors(tr)
    white = load_script("mrclam_motion_noise").whitened(tr, "both", np.random.default_rng(0))
    wr, wb = _errors(white)
    assert white.n_sightings == tr.n_sightings
    assert _lag1(tr, er) > 0.5 and abs(_lag1(white, wr)) < 0.1
    assert np.std(wr) == pytest.approx(np.std(er), rel=0.1)  # beyond the quadratic: a little less than the raw
    assert np.std(wb) == pytest.approx(0.02, rel=0.1) and np.std(eb) == pytest.approx(0.02, rel=0.1)


@pytest.mark.realdata
@needs_data
def test_the_real_robots_model_wanders_more_than_the_robot_but_turns_right():
    """Robot 4, ``aibo learn``'s model of the whole log: over 1 s windows its forward travel's error is 0.36 of its
    sd and the lateral 0.03 (the model's noise 4.0 and 11.1 mm per frame, Vicon's residual 1.2 and 0.7), the
    heading's 0.96; with the sightings' errors made white the lateral noise falls to 4.5 mm per frame and the forward
    ratio rises to 0.86: errors that persist over seconds taken up as motion noise."""
    from aibo_core.mrclam import import_robot

    script = load_script("mrclam_motion_noise")
    tr = import_robot(DATA, 4)
    model = script.learned(tr)
    one, = script.ratios(model, tr, (1.0,))
    assert one[0] < 0.6 and one[1] < 0.2 and 0.8 < one[2] < 1.25, one
    white = script.learned(script.whitened(tr, "both", np.random.default_rng(script.SEED)))
    assert np.sqrt(white.action.cov[1, 1]) < 0.6 * np.sqrt(model.action.cov[1, 1])
    assert script.ratios(white, tr, (1.0,))[0][0] > 1.5 * one[0]
