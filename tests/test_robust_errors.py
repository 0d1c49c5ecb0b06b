"""Robust standard errors against the differences between two fits of the same robot (``scripts/se_halves.py``;
``learners.em.uncertainty``): about 1 of either error between two simulated runs, and the robust ones, not the
Fisher ones, about the size of the differences between the two halves of a real robot's log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests._logs import MRCLAM_DATA as DATA
from tests._scripts import load_script

ROOT = Path(__file__).resolve().parents[1]


def _script():
    return load_script("se_halves")


def _rms(z: dict[str, list[float]]) -> float:
    return float(np.sqrt(np.mean(np.square(np.concatenate([np.asarray(v, float) for v in z.values()])))))


def test_two_simulated_runs_differ_by_about_their_errors(tmp_path):
    """Two 5-minute wheeled logs (seeds 9400, 9401), ``aibo learn`` on each: the differences of the motion, sensor and
    range-shrink entries over their combined errors have an RMS about 1 with either kind of error (0.95-1.25 per
    family, ``docs/results.md``), and the robust errors are never below the Fisher ones."""
    se_halves = _script()
    docs = [se_halves.fitted(se_halves.simulated("wheeled", 9400 + k), tmp_path / f"w{k}.npz") for k in (0, 1)]
    z = se_halves.z_scores(*docs)
    assert 0.6 < _rms(z["fisher"]) < 1.5 and 0.6 < _rms(z["robust"]) < 1.5, z
    for doc in docs:
        for key, se in doc["info"]["standard_errors"].items():
            a = np.array(np.ravel(np.array(se, dtype=object)), dtype=float)
            b = np.array(np.ravel(np.array(doc["info"]["robust_standard_errors"][key], dtype=object)), dtype=float)
            ok = np.isfinite(a) & np.isfinite(b)
            assert np.all(b[ok] >= a[ok]), key


@pytest.mark.realdata
@pytest.mark.skipif(not (DATA / "Robot5_Odometry.dat").is_file(),
                    reason=f"MRCLAM Dataset 7 not found at {DATA} (see README, 'Real robot logs (MRCLAM)')")
def test_on_a_real_robot_the_robust_errors_are_the_size_of_its_halves_differences(tmp_path):
    """MRCLAM robot 5, ``aibo learn`` on each half of its log: the halves differ by 3.5 Fisher errors (RMS over the
    motion, sensor and shrink entries) and by 1.3 robust ones (docs/results.md, "Robust standard errors"; robot 2,
    4.6 and 1.4 with the range curve held, is at 1.9 and 0.9 with it freed, the default)."""
    se_halves = _script()
    docs = [se_halves.fitted(half, tmp_path / f"h{k}.npz") for k, half in enumerate(se_halves.halves(DATA, 5))]
    z = se_halves.z_scores(*docs)
    fisher, robust = _rms(z["fisher"]), _rms(z["robust"])
    assert fisher > 3.0 and robust < 2.0 and robust < 0.5 * fisher, (fisher, robust)
