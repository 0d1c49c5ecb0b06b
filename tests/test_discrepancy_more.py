"""The learner twins of ``false_sightings`` and ``wall_contact`` (``learners/model/catalogue_more.py``):
their lowering, and ``aibo diagnose`` naming them in blind logs with every effect of the catalogue
as a candidate (and naming none in logs without effects)."""

from __future__ import annotations

import numpy as np
import pytest

from aibo_gym.collect import collect
from learners.arrays.batch import make_batch
from learners.discrepancy.fitting import ZERO_DOF_NATS
from learners.em.estep import e_step
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.em.predictive import sightings_logdens
from learners.inference.predictive import predictive_logdens
from learners.model.catalogue_more import FalseSightings, WallContact
from learners.model.effects import EFFECT_MODELS
from tests._logs import diagnose, sim_log

ALL = ",".join(sorted(EFFECT_MODELS))


def test_false_sightings_lowering_and_mixture_density():
    tr = sim_log(3000)
    model = EMLearner(EMOptions(max_iter=20)).fit([tr]).params
    batch = make_batch([tr])
    post = e_step(model, batch, "compiled")
    fs = FalseSightings.start(batch)
    with_fs = model.with_effect(fs).effect("false_sightings").maximize(model.with_effect(fs), batch, post, None)
    eff = with_fs.effect("false_sightings")
    assert eff.w.shape == (batch.n_sightings,) and 0 < eff.rate < 0.5
    lo = with_fs.lower(batch)
    np.testing.assert_allclose(lo.size_var_factor, 1 / np.maximum(eff.w, 1e-4))
    np.testing.assert_allclose(lo.bearing_var_factor, 1 / np.maximum(eff.w, 1e-4))
    other = make_batch([sim_log(3000, seed=4)])  # another batch: the responsibilities are not applied
    assert np.all(with_fs.lower(other).bearing_var_factor == 1.0)
    # the density: the mixture of the filter's Gaussian (own noise un-inflated) and the uniform
    idx = np.flatnonzero(batch.used)
    post2 = e_step(with_fs, batch, "compiled")
    plain = predictive_logdens(lo, batch, post2, idx, with_fs.with_effect(eff.predictive()).lower(batch))
    mix = np.logaddexp(np.log1p(-eff.rate) + plain, np.log(eff.rate) + eff.log_u)
    np.testing.assert_allclose(sightings_logdens(with_fs, batch, post2, idx), mix)
    assert post2.loglik == pytest.approx(mix.sum())


def _against_the_plus_x_wall(probability: list[float]):
    """(model fitted on sim_log(3000), its batch, a ``WallContact`` whose first frames touch the +x wall with these
    contact probabilities, heading 0)."""
    from learners.model.catalogue_more import _frame_key

    tr = sim_log(3000)
    model = EMLearner(EMOptions(max_iter=20)).fit([tr]).params
    batch = make_batch([tr])
    contact = np.zeros((batch.n_frames, 2))
    contact[:len(probability), 0] = probability
    return model, batch, WallContact(contact=contact, heading=np.zeros(batch.n_frames), key=_frame_key(batch))


def test_wall_contact_cancels_outward_motion_only():
    model, batch, wc = _against_the_plus_x_wall([1.0] * 5)
    base, lo = model.lower(batch), model.with_effect(wc).lower(batch)
    moved = base.disp[:5, 0] + lo.offset[:5, 0]
    np.testing.assert_allclose(moved, np.minimum(base.disp[:5, 0], 0.0), atol=1e-12)  # outward part removed
    np.testing.assert_array_equal(lo.offset[5:], base.offset[5:])
    assert wc.dof() == 0 and ZERO_DOF_NATS > 0


def test_contact_probability_known_answers():
    """P(|x| > field / 2 - margin) under N(mean, var): 1/2 at the margin's edge, Phi(-1) one sd inside it, Phi(1)
    one sd beyond it; either side of the field; the sd floored."""
    from scipy.stats import norm

    from learners.model.catalogue_more import contact_probability

    field = np.array([5400.0, 3600.0])
    edge = field / 2 - 60.0  # 2640, 1740
    mean = np.array([[edge[0], -edge[1]], [edge[0] - 30.0, 0.0], [-(edge[0] + 30.0), edge[1] + 500.0],
                     [edge[0] - 3.0, 0.0]])
    var = np.array([[900.0, 900.0], [900.0, 900.0], [900.0, 900.0], [1.0, 900.0]])
    p = contact_probability(mean, var, field, 60.0, 10.0)
    np.testing.assert_allclose(p[0], [0.5, 0.5])
    np.testing.assert_allclose(p[1, 0], norm.cdf(-1.0))
    assert p[1, 1] == 0.0  # the field's centre line: 1740 mm from the wall, 58 sd
    np.testing.assert_allclose(p[2], [norm.cdf(1.0), 1.0])
    np.testing.assert_allclose(p[3, 0], norm.cdf(-0.3))  # sd 1 mm floored at 10 mm


def test_wall_contact_cancels_its_probability_of_the_outward_motion():
    """A contact probability p cancels p of the outward motion; those frames are blocked."""
    p = np.array([0.3, 0.3, 0.3, 0.7, 0.7, 0.7])
    model, batch, wc = _against_the_plus_x_wall(list(p))
    base, lo = model.lower(batch), model.with_effect(wc).lower(batch)
    d = base.disp[:6, 0]
    np.testing.assert_allclose(d + lo.offset[:6, 0], np.where(d > 0, (1 - p) * d, d), atol=1e-12)
    np.testing.assert_array_equal(lo.blocked[:6], d > 0)
    assert not lo.blocked[6:].any()


def test_wall_contact_reads_probabilities_off_the_smoothed_path():
    """The M-step's contacts are the end poses' contact probabilities (0 below ``MIN_PROBABILITY``), signed by
    the wall's side."""
    from learners.model.catalogue_more import contact_probability

    tr = collect({"noise": "aibo"}, 1800, seed=11, policy_params={"margin_mm": -800.0})
    model = EMLearner(EMOptions(max_iter=10)).fit([tr]).params
    batch = make_batch([tr])
    post = e_step(model, batch, "compiled")
    end = post.mu_gamma[batch.frame_to_pose + 1]
    wc = model.with_effect(WallContact()).effect("wall_contact").maximize(model.with_effect(WallContact()), batch,
                                                                        post, None).effect("wall_contact")
    prob = contact_probability(end[:, :2], np.diagonal(post.cov_gamma[batch.frame_to_pose + 1], axis1=1,
                                                       axis2=2)[:, :2], np.asarray(batch.field), 60.0, 10.0)
    expect = np.sign(end[:, :2]) * np.where(prob < WallContact.MIN_PROBABILITY, 0.0, prob)
    np.testing.assert_array_equal(wc.contact, expect)
    soft = (np.abs(wc.contact) > 0) & (np.abs(wc.contact) < 0.99)
    assert wc.n_contacts() > 0 and soft.any()  # some frames neither surely free nor surely against a wall


def test_a_wall_stops_a_floor_drift_whichever_was_named_first():
    """``wall_contact`` lowers after every effect that moves the robot (``LOWER_ORDER``): named before a drift, the
    drift pushed through the walls in the model. The drift's M-step leaves the blocked frames out."""
    from learners.model.catalogue import FloorDrift

    model, batch, wc = _against_the_plus_x_wall([1.0] * 5)
    drift = FloorDrift(np.array([30.0, 0.0]))  # outwards, +x
    first, second = model.with_effect(wc).with_effect(drift), model.with_effect(drift).with_effect(wc)
    lo1, lo2 = first.lower(batch), second.lower(batch)
    np.testing.assert_array_equal(lo1.offset, lo2.offset)
    base = model.lower(batch)
    assert np.all(base.disp[:5, 0] + lo1.offset[:5, 0] <= 1e-12)  # nothing moves through the +x wall
    blocked = lo1.blocked
    assert blocked is not None and blocked[:5].all() and not blocked[5:].any()
    # the drift's M-step: the same estimate when the blocked frames' displacements are anything at all
    post = e_step(first, batch, "compiled")
    mu = np.array(base.disp)  # any displacement estimate will do
    est = first.effect("floor_drift").maximize(first, batch, post, mu).effect("floor_drift").drift_mm_s
    mu[:5] += 500.0
    moved = first.effect("floor_drift").maximize(first, batch, post, mu).effect("floor_drift").drift_mm_s
    np.testing.assert_allclose(moved, est, atol=1e-9)


#: What may say that a diagnosed model is wrong (``aibo diagnose``'s warnings): a wrong world, EM falling from the model
#: it returns (``learners.em.learner.setback_warnings``), an estimate the final fit moved, a fit beaten elsewhere.
MAY_BE_WRONG = ("a wrong world?", "EM's likelihood fell by", "moved it outside its interval", "is not the likelihood's maximum")


@pytest.mark.slow
def test_a_base_in_a_wrong_world_is_refitted_and_the_rate_of_spurious_sightings_holds_the_logs_own_share(tmp_path):
    """8% false sightings on a 5-minute ``aibo`` log (seed 12): the base fit from the paper's start ends in a wrong
    world (all its smoothed poses off the field); refitted with spurious sightings in the model it finds the field,
    and ``false_sightings``, tried from that refit, is named first and alone (its rivals that gained in round 1
    among the candidates), with no warning that the fit may be wrong. Its interval holds the share of spurious
    sightings this log holds (counted: the simulator's real sightings are the same without the effect, its own
    stream): 0.089 here, a 2.4-sigma draw of the rate 0.08. Measured 2026-11-28 (all candidates): 0.0900 [0.0820,
    0.0980]; before the refit the search named it from the wrong world at 0.129 [0.126, 0.232] and warned."""
    config = {"noise": "aibo", "effects": {"false_sightings": {"rate": 0.08}}}
    log = collect(config, 9000, seed=12)
    real = collect({"noise": "aibo", "effects": {"false_sightings": {"rate": 0.0}}}, 9000, seed=12).n_sightings
    share = 1.0 - real / log.n_sightings
    report = diagnose(tmp_path, log, "false_sightings,heavy_tailed_noise,landmark_bias,beacon_height_scale")
    assert report["base_refit"]["off_field_fraction"] > 0.5
    assert [e["name"] for e in report["effects"]] == ["false_sightings"], report["effects"]
    assert not [w for w in report["warnings"] if any(m in w for m in MAY_BE_WRONG)], report["warnings"]
    low, high = report["effects"][0]["intervals"]["rate"]["interval_95"]
    assert low <= share <= high and high - low < 0.03, (share, low, high)
    # a mixture's rate has no Fisher error on the training half (its final interval is the conditional one): nothing
    # is kept beside the value it was named at, and "moved since named" compares with the interval alone
    assert report["effects"][0]["se_when_named"] == {} and report["effects"][0]["warnings"] == []
    assert report["gap_after"] < report["gap_before"] - 1.0  # nats per sighting: 3.66 -> 0.75 measured


def test_responsibilities_are_kept_in_a_process_with_another_hash_seed(tmp_path):
    """An effect's per-sighting state (``false_sightings``' responsibilities) is keyed to its batch by a digest that
    every process computes alike: pickled to a worker that does not share this interpreter's hash salt (a spawned
    worker, another run), the model still applies it. With keys from ``hash()`` of the bytes it did not."""
    import os
    import pickle
    import subprocess
    import sys

    tr = sim_log(3000)
    model = EMLearner(EMOptions(max_iter=5, uncertainty=False)).fit([tr]).params
    batch = make_batch([tr])
    fs = FalseSightings.start(batch)
    model = model.with_effect(fs).effect("false_sightings").maximize(model.with_effect(fs), batch,
                                                                      e_step(model, batch, "compiled"), None)
    here = model.lower(batch).size_var_factor
    assert np.any(here != 1.0)
    (tmp_path / "state.pkl").write_bytes(pickle.dumps((model, batch)))
    code = ("import pickle, sys, numpy as np; m, b = pickle.load(open(sys.argv[1], 'rb')); "
            "np.save(sys.argv[2], m.lower(b).size_var_factor)")
    for seed in ("1", "2"):
        subprocess.run([sys.executable, "-c", code, str(tmp_path / "state.pkl"), str(tmp_path / "there.npy")],
                       check=True, env={**os.environ, "PYTHONHASHSEED": seed})
        np.testing.assert_array_equal(np.load(tmp_path / "there.npy"), here)


@pytest.mark.slow
def test_diagnose_names_wall_contact(tmp_path):
    """A policy that lets its paths leave the field by 800 mm: ~11% of the frames against a wall."""
    tr = collect({"noise": "aibo"}, 18000, seed=11, policy_params={"margin_mm": -800.0})
    report = diagnose(tmp_path, tr, ALL)
    assert report["effect"] == "wall_contact", report["effects"]
    assert report["gap_after"] < report["gap_before"]


@pytest.mark.slow
def test_a_drift_that_pushes_into_the_walls_is_named_with_them(tmp_path):
    """The drift + walls pair of ``scripts/diagnose_power.py`` (a drift of [15, -10] mm/s into a corner, blind
    10-minute log): both named, the drift within the single-effect tolerance (5 mm/s). With contacts 0/1 by the
    smoothed mean, this seed's drift gained 18.9 nats in training, -8.3 held out, and was not named (named on 5 of
    10 seeds; 9 of 10 with the contact probabilities)."""
    tr = collect({"noise": "aibo", "effects": {"floor_drift": {"drift_mm_s": [15.0, -10.0]}}}, 18000, seed=5004,
                 policy_params={"margin_mm": -800.0})
    report = diagnose(tmp_path, tr, ALL)
    named = {e["name"]: e["parameters"] for e in report["effects"]}
    assert set(named) == {"wall_contact", "floor_drift"}, named
    np.testing.assert_allclose(named["floor_drift"]["drift_mm_s"], [15.0, -10.0], atol=5.0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3011, 3022])
def test_walls_are_not_reported_as_a_speed_that_depends_on_the_heading(tmp_path, seed):
    """Effect-free logs that meet the walls: a robot pushing a wall moves slower towards it, which a speed that
    depends on the heading mimics. Seed 3011: the probe is tested given the wall nuisance (``checks.GivenNuisance``)
    and is not reported (it was, p = 0.004). Seed 3022: after a base escape from ``wall_contact``'s fit, the repeated
    round fits it from its own fit too (``try_candidate``'s ``previous``); from the escape alone it kept no contact,
    nothing was named and the walls came out as a speed that depends on the heading."""
    tr = collect({"noise": "aibo"}, 9000, seed=seed, policy_params={"margin_mm": -800.0})
    report = diagnose(tmp_path, tr, ALL)
    assert {e["name"] for e in report["effects"]} <= {"wall_contact"}, report["effects"]
    assert not [u for u in report["unexplained"] if "probe" in u], report["unexplained"]


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12])
def test_no_effect_names_none_with_every_candidate(tmp_path, seed):
    """The default policy keeps 300 mm from the walls: no frame against a wall, nothing to name."""
    report = diagnose(tmp_path, collect({"noise": "aibo"}, 18000, seed=seed), ALL)
    assert report["effect"] == "none" and report["effects"] == [], report["effects"]


@pytest.mark.slow
def test_an_aibo_trajectory_1_log_of_another_head_camera_and_start(tmp_path):
    """A /1 file (the old layout: one sighting per frame) of a robot with another head scan (0.8 rad
    every 2 s), a wider camera, another start and noise, and no simulator config in its meta: the
    hidden beacon heights are named, and the calibrated simulator replays that log's own head pan."""
    import json

    from aibo.cli import main
    from tests._logs import frame_view

    scale = [1.08, 0.94, 1.04, 0.95]
    tr = collect({"pan_period": 2.0, "pan_amplitude": 0.8, "fov": 1.4, "start_pose": [300.0, -200.0, 0.3],
                  "sigma_height": 1.2, "sigma_angle": 0.04, "effects": {"beacon_height_scale": {"scale": scale}}},
                 18000, seed=5)
    obs, beacon = frame_view(tr)
    log = tmp_path / "other.npz"
    np.savez_compressed(log, format=np.array("aibo-trajectory/1"), dt=np.array(tr.dt), actions=tr.actions, obs=obs,
                        beacon=beacon, head_pan=tr.head_pan, beacons=tr.landmarks, field=tr.field,
                        attempted=tr.attempted, meta=np.array(json.dumps({"generator": "another simulator"})))
    out = tmp_path / "diag"
    assert main(["diagnose", str(log), "--out", str(out), "--candidates", "beacon_height_scale,floor_drift,velocity_fade",
                 "--replicas", "4"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["effect"] == "beacon_height_scale" and report["gap_after"] < report["gap_before"]
    geo = np.exp(np.mean(np.log(scale)))
    np.testing.assert_allclose(report["parameters"]["scale"], np.array(scale) / geo, atol=0.015)
    assert report["calibrated_simulation"]["before"]["replicas"] == 4


def test_a_false_sightings_rate_of_a_few_outliers_is_negligible_not_an_effect():
    assert "negligible: the rate 0.0001 means 0.9 spurious sightings in 9000" in FalseSightings(1e-4).negligible(9000)
    assert FalseSightings(0.05).negligible(9000) == "" and FalseSightings(1e-3).negligible(9000) == ""
    assert all(cls(**{k: 0.0 for k in cls.PARAMS}).negligible(100) == "" for name, cls in EFFECT_MODELS.items()
               if name not in ("false_sightings", "heavy_tailed_noise", "beacon_height_scale", "landmark_bearing_offset"))


def test_a_bearing_offset_that_a_turned_model_explains_as_well_is_not_named():
    """The effect-free log where ``angle_bias`` was named (paper-sim noise, walls met, seed 3007: 0.0086 rad,
    +9.1 nats, p = 2e-5): the same model without it, its start heading and velocities turned by the offset
    (``AngleBias.equivalent``), scores the same, so the search reports it not identifiable instead."""
    from aibo_core.trajectory import blind
    from learners.discrepancy.search import search

    tr = blind(collect({"noise": "paper-sim", "effects": {}}, 9000, seed=3007, policy_params={"margin_mm": -800.0}))
    found = search([tr], ["angle_bias"], EMOptions(), jobs=1, progress=lambda s: None)
    assert found["named"] == []
    # the turned model, 9 nats above the null, is the better base: the round is repeated from it
    (escape,) = found["escapes"]
    (c,) = escape["candidates"]
    assert escape["from"] == "angle_bias" and escape["nats"] > 5.0
    assert c["p_value"] < 1e-3 and not c["identifiable"] and "explains the sightings as well" in c["note"], c
    assert found["rounds"][0][0].gain_train < 1.0  # from the turned model, the offset gains nothing


def test_a_gain_that_the_base_keeps_without_the_effect_is_not_the_effects():
    """The effect-free log where ``actuation_lag`` was named (paper-sim noise, seed 1005, 5 min: 0.1 s, +28.7 nats,
    p = 4e-14): EM from the paper's start stopped at a poor optimum of the base model, and the lag's fit left it.
    Refitted without the lag, that fit keeps the whole gain: the lag is not named, and the better base becomes the
    current model (``learners.discrepancy.checks.GivenItsOwnBase``). Where EM from the paper's start is left at
    the poor optimum depends on the CPU's rounding (on an AMD EPYC it found the better base itself): the lag is
    never named, and when a candidate's fit finds the better base, the round is repeated from it."""
    from aibo_core.trajectory import blind
    from learners.discrepancy.search import search

    said = []
    tr = blind(collect({"noise": "paper-sim", "effects": {}}, 9000, seed=1005))
    found = search([tr], ["actuation_lag"], EMOptions(), jobs=1, progress=said.append)
    assert found["named"] == [], [c.as_dict() for c in found["rounds"][-1]]
    repeated = any("better than the null: the round is repeated" in s for s in said)
    assert repeated == bool(found["escapes"]), said



def test_distance_noise_m_step_takes_the_squared_size_residuals_expectation_under_the_smoothed_pose():
    """``DistanceDependentNoise.maximize``'s sigma_size is the weighted mean of each sighting's EXPECTED squared size
    residual under its smoothed pose (the mean over the 6 cubature points, as the sensor M-step's): with the pose's
    covariance shrunk to nothing it is the residual at the smoothed mean, computed here by hand; with the covariance it
    is larger (the pose's spread adds about f'(d)^2 var(d))."""
    from dataclasses import replace as dc_replace

    from learners.model.catalogue import REFERENCE_DISTANCE_MM, DistanceDependentNoise, implied_distance

    tr = sim_log(3000, noise="aibo")
    noise = DistanceDependentNoise(exponent=0.5)
    model = EMLearner(EMOptions(max_iter=10, lag_search=False)).fit([tr]).params.with_effect(noise)
    batch = make_batch([tr])
    post = e_step(model, batch, "compiled")
    sharp = dc_replace(post, cov_gamma=post.cov_gamma * 1e-12)
    at_mean = noise.maximize(model, batch, sharp, None)
    spread = noise.maximize(model, batch, post, None)
    # by hand, at the smoothed means, for the exponent the step chose
    lo = model.lower(batch)
    idx = np.flatnonzero(batch.used)
    pose = post.mu_gamma[batch.sight_pose[idx]]
    d = np.hypot(*(batch.sight_xy[idx] - pose[:, :2]).T)
    r2 = (batch.sight_value[idx, 0] - lo.size_offset[idx] - model.sensor.mean(d) * lo.size_scale[idx]) ** 2
    e = at_mean.effect("distance_dependent_noise").exponent
    v = (implied_distance(lo, batch)[idx] / REFERENCE_DISTANCE_MM) ** (2 * e)
    assert at_mean.sensor.sigma_size == pytest.approx(np.sqrt(np.mean(r2 / v)), rel=1e-6)
    assert spread.sensor.sigma_size > at_mean.sensor.sigma_size * 1.01
