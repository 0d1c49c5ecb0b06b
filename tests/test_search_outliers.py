"""The sightings the search sets aside as outliers (``learners.discrepancy.search.base_and_outliers``): judged by a base
model that may have stopped in a poorer world, they are judged again by ``aibo learn``'s model of the whole log."""

from __future__ import annotations

import numpy as np
import pytest

from aibo_core.trajectory import blind
from aibo_gym.collect import collect
from learners.discrepancy.search import base_and_outliers, base_fits, outliers
from learners.em.options import EMOptions


def test_a_base_fit_in_a_poorer_world_does_not_set_good_sightings_aside():
    """An effect-free 5-minute ``aibo`` log (seed 6045): the base fit from the paper's start on the training half gates
    out 1,245 of its 4,776 sightings (1,273 with an AMD EPYC's BLAS kernels: the count the report states is read back,
    not fixed); ``aibo learn``'s model of the whole log none. The search's base is then the fit from that model:
    nothing set aside, and more likely on the sightings neither gates out (by 706 nats; 206 on the EPYC)."""
    tr = blind(collect({"noise": "aibo", "effects": {}}, 9000, seed=6045))
    opts = EMOptions().comparable()
    first, _ = base_fits([tr], opts)
    gated = int(outliers(first, [tr]).sum())
    assert gated > 1000
    said: list[str] = []
    base, refit, (kept,), n = base_and_outliers([tr], opts, progress=said.append)
    assert n == 0 and kept.n_sightings == tr.n_sightings and refit is None
    assert [e.name for e in base.effects] == [e.name for e in first.effects]  # learn's structure is not taken
    assert len(said) == 1 and said[0].startswith(f"  the base fit gated out {gated} sightings") and "kept" in said[0]


def test_a_base_that_gates_out_few_is_kept_as_it_is():
    """Where the base fit gates out at most 1% (here none), nothing else is fitted: the base and the logs are
    ``base_fits``' own, and nothing is said."""
    tr = blind(collect({"noise": "aibo", "effects": {}}, 9000, seed=6000))
    opts = EMOptions().comparable()
    first, _ = base_fits([tr], opts)
    said: list[str] = []
    base, _, (kept,), n = base_and_outliers([tr], opts, progress=said.append)
    assert said == [] and n == int(outliers(first, [tr]).sum()) <= 0.01 * tr.n_sightings
    np.testing.assert_array_equal(np.asarray(base.action.weights), np.asarray(first.action.weights))


@pytest.mark.slow
def test_the_sightings_set_aside_on_a_log_with_spurious_ones_are_the_spurious_ones_and_the_report_says_so():
    """A blind 5-minute ``aibo`` log with 2% spurious sightings (seed 2002: 105 of 4,991): the base fit from the paper's
    start ends in a wrong world and gates out 119; the base the search keeps gates out 101, every one of them spurious.
    No model of the search sees them, ``false_sightings`` included (it gained nothing on this log), so the report
    says how many were set aside and what would leave them (``aibo.commands.diagnose.outlier_warning``)."""
    from aibo.commands.diagnose import outlier_warning, set_aside

    truth = collect({"noise": "aibo", "effects": {"false_sightings": {"rate": 0.02}}}, 9000, seed=2002)
    tr = blind(truth)
    base, _, (kept,), n = base_and_outliers([tr], EMOptions().comparable(), progress=lambda s: None)
    spurious = np.zeros(tr.n_sightings, bool)
    spurious[truth.meta["truth"]["spurious_sightings"]] = True
    bad = outliers(base, [tr])
    assert n == bad.sum() == tr.n_sightings - kept.n_sightings
    assert (bad & spurious).sum() >= 95 and (bad & ~spurious).sum() <= 2
    report = {"outliers": set_aside({"outliers": {"set_aside": n, "sightings": tr.n_sightings}}), "effects": [],
              "candidates": [{"name": "false_sightings"}]}
    assert report["outliers"]["share"] == n / tr.n_sightings > 0.01
    (warning,) = outlier_warning(report)
    assert warning.startswith(f"{n} of {tr.n_sightings} sightings (2.0%) were set aside as gross errors")
    assert warning.endswith("the search tried it on the sightings kept, where it had none of these to explain")


def test_the_outlier_warning_names_what_the_report_holds():
    """No warning at or below ``OUTLIER_SHARE``; above it, the reading follows what the search did with
    ``false_sightings``: named, tried and not named, or not among the candidates."""
    from aibo.commands.diagnose import outlier_warning, set_aside
    from learners.discrepancy.search import OUTLIER_SHARE

    def report(n: int, named: list[str], tried: list[str]) -> dict:
        return {"outliers": set_aside({"outliers": {"set_aside": n, "sightings": 1000}}),
                "effects": [{"name": x} for x in named], "candidates": [{"name": x} for x in tried]}

    assert outlier_warning(report(int(OUTLIER_SHARE * 1000), [], ["false_sightings"])) == []
    assert outlier_warning(report(0, [], [])) == [] and set_aside({"outliers": {"set_aside": 0, "sightings": 0}})["share"] == 0.0
    (named,) = outlier_warning(report(30, ["false_sightings"], ["false_sightings"]))
    assert named.startswith("30 of 1000 sightings (3.0%)") and "false_sightings, named" in named
    (absent,) = outlier_warning(report(30, [], ["actuation_lag"]))
    assert absent.endswith("(false_sightings, not among the candidates) would leave them")
    assert "Mahalanobis^2 > 50 under the search's base model, which on 100 effect-free simulated logs set aside at most" in absent
