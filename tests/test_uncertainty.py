"""Standard errors from the Fisher information of the filter's innovations (learners/em/uncertainty.py)."""

from __future__ import annotations

import numpy as np
import pytest

from learners.arrays.lowered import BASIS_INVERSE, BASIS_POWER
from learners.em.uncertainty import file_values, parameter_uncertainty
from learners.model.action import ActionModel
from learners.model.initial import InitialState
from learners.model.model import Model
from learners.model.sensor import SensorModel
from tests._synth import DT, simulate, true_table

SENSOR_ONLY = frozenset({"action.weights", "action.cov", "init.mean"})


def known_poses_case(basis: int, frames: int = 3000):
    """(model at the truth, batch, true poses) with so little motion noise and so sharp a start that
    the poses are known: the sensor fit is then weighted least squares with a textbook answer."""
    rng = np.random.default_rng(5 + basis)
    motion_std = (0.01, 0.01, 1e-5)
    table = true_table(rng)
    batch, lo, poses = simulate(rng, [frames], table, basis=basis, motion_std=motion_std)
    model = Model(ActionModel(table, np.diag(np.square(motion_std)), DT),
                  SensorModel(lo.coef, lo.sigma_size, lo.sigma_bearing, basis={0: "power", 1: "inverse"}[basis]),
                  (InitialState(lo.init_mean[0], np.diag([1e-6, 1e-6, 1e-12])),))
    return model, batch, poses


@pytest.mark.parametrize("basis", [BASIS_POWER, BASIS_INVERSE])
def test_known_poses_give_the_least_squares_standard_errors(basis):
    model, batch, poses = known_poses_case(basis)
    unc = parameter_uncertainty(model, batch, fixed=SENSOR_ONLY)
    d = np.hypot(*(batch.sight_xy - poses[batch.sight_pose, :2]).T)
    x = d if basis == BASIS_POWER else 1.0 / d
    X = np.vander(x, len(model.sensor.coef), increasing=True)
    s_h, s_a, n = model.sensor.sigma_size, model.sensor.sigma_bearing, batch.n_sightings
    want_coef = s_h * np.sqrt(np.diag(np.linalg.inv(X.T @ X)))
    se = unc.standard_errors
    np.testing.assert_allclose(se["sensor_model.coef"], want_coef, rtol=0.01)
    np.testing.assert_allclose(se["sensor_model.sigma_height"], s_h / np.sqrt(2 * n), rtol=0.01)
    np.testing.assert_allclose(se["sensor_model.sigma_angle"], s_a / np.sqrt(2 * n), rtol=0.01)
    assert set(se) == {"sensor_model.coef", "sensor_model.sigma_height", "sensor_model.sigma_angle"}  # fixed: absent
    assert len(unc.names) == len(model.sensor.coef) + 2


def test_forward_and_central_differences_agree_and_shapes_follow_the_file():
    model, batch, _ = known_poses_case(BASIS_POWER, frames=1500)
    model = model.with_(action=model.action.with_values(cov=np.diag([4.0, 4.0, 1e-4])))  # poses now uncertain
    fwd = parameter_uncertainty(model, batch)
    ctr = parameter_uncertainty(model, batch, step=-1e-3)
    values = file_values(model)
    for key, se in fwd.standard_errors.items():
        a = np.array(se, dtype=float)
        assert a.shape == values[key].shape, key
        np.testing.assert_allclose(a, np.array(ctr.standard_errors[key], dtype=float), rtol=0.02, equal_nan=True)
    assert 0 < fwd.min_eigenvalue <= 1 <= fwd.condition_number


def test_a_command_never_executed_is_undetermined():
    model, batch, _ = known_poses_case(BASIS_POWER, frames=1500)
    missing = sorted(set(range(40)) - set(np.unique(batch.actions)))
    assert missing, "the synthetic log executes every command: pick another seed"
    unc = parameter_uncertainty(model, batch, fixed=frozenset({"init.mean"}))
    vel = unc.standard_errors["action_model.velocities"]
    a = missing[0]
    assert vel[a] == [None, None, None]
    assert f"action_model.velocities[{a}][0]" in unc.undetermined
    done = int(np.unique(batch.actions)[0])
    assert all(v is not None and v > 0 for v in vel[done])
    assert np.isfinite(unc.condition_number)


@pytest.mark.slow
def test_standard_errors_match_the_spread_over_simulated_logs():
    """8 independent 10-minute logs of one robot, EM from the true velocities (so every fit is in the
    right basin): the pooled standard errors of the velocities match the spread of the estimates
    (the Monte Carlo study in docs/results.md does the same with 15-minute logs from the paper's start).
    vtheta's Fisher SE is ~15% optimistic on logs this short (each command held ~2-3 times)."""
    from aibo_gym.collect import collect
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions
    from learners.model.model import paper_start

    est, se = [], []
    for i in range(8):
        tr = collect({"noise": "paper-sim", "robot_seed": 3, "max_steps": 18000}, steps=18000, seed=900 + i)
        start = paper_start([tr])
        truth = np.array(tr.truth["velocities"])
        start = start.with_(action=start.action.with_values(weights=truth * tr.dt))
        res = EMLearner(EMOptions(starts=1, patience=20)).fit([tr], init=start)
        est.append(res.params.action.velocities)
        se.append(np.array(res.info["standard_errors"]["action_model.velocities"], dtype=float))
    est, se = np.array(est), np.array(se)
    ratio = np.sqrt(np.mean(se**2, axis=(0, 1))) / np.sqrt(np.mean(est.std(axis=0, ddof=1) ** 2, axis=0))
    assert np.all(np.abs(ratio[:2] - 1) < 0.15) and 0.7 < ratio[2] < 1.15, ratio


def test_a_log_too_long_for_the_memory_takes_the_coordinates_in_blocks_with_the_same_information(monkeypatch):
    """A resident block of 7 coordinates with every later coordinate streamed past it (float32 storage, each
    later coordinate's pass run again per earlier block) gives the information of the whole float64 derivative
    array, and only the blocked run holds float32 blocks."""
    import learners.em.uncertainty as unc_mod

    model, batch, _ = known_poses_case(BASIS_POWER, frames=1500)
    model = model.with_(action=model.action.with_values(cov=np.diag([4.0, 4.0, 1e-4])))
    whole = parameter_uncertainty(model, batch)
    calls, cross = [], []
    real_call, real_cross = unc_mod._Differences.__call__, unc_mod._cross
    monkeypatch.setattr(unc_mod._Differences, "__call__",
                        lambda self, k, out=None: (calls.append(k), real_call(self, k, out))[1])
    monkeypatch.setattr(unc_mod, "_cross", lambda a, b, chunk=997: (cross.append(a.dtype), real_cross(a, b, chunk))[1])
    n = int(batch.used.sum())
    pass_bytes = unc_mod.PASS_BYTES_PER_SIGHTING * batch.n_sightings + unc_mod.PASS_BYTES_PER_FRAME * batch.n_frames
    per = n * 5 * 4 + unc_mod.CROSS_CHUNK * 5 * 8
    blocked = parameter_uncertainty(model, batch, memory_bytes=pass_bytes + (7 + unc_mod.STREAM) * per)
    p = len(whole.free)
    blocks = -(-p // 7)
    # each block's own passes once, every later coordinate once per earlier block: p + sum of (p - block end)
    assert len(calls) == p + sum(p - min(7 * (j + 1), p) for j in range(blocks))
    assert blocks >= 4  # several later blocks, so a coordinate run again is counted
    assert cross and set(cross) == {np.dtype(np.float32)}
    np.testing.assert_array_equal(blocked.free, whole.free)
    np.testing.assert_allclose(blocked.information, whole.information, rtol=1e-5, atol=1e-6 * np.abs(whole.information).max())
    np.testing.assert_allclose(blocked.score, whole.score, rtol=1e-12)
    for key, se in whole.standard_errors.items():
        np.testing.assert_allclose(np.array(blocked.standard_errors[key], dtype=float), np.array(se, dtype=float),
                                   rtol=1e-4, equal_nan=True)


def _with_laplace_sizes(model, batch, poses, seed: int):
    """``batch`` with its sizes' noise drawn again from a Laplace distribution of the model's variance (kurtosis 6,
    a Gaussian's 3): the model's noise then has the right width but the wrong shape."""
    from dataclasses import replace

    d = np.hypot(*(batch.sight_xy - poses[batch.sight_pose, :2]).T)
    z = batch.sight_value.copy()
    rng = np.random.default_rng(seed)
    z[:, 0] = model.sensor.mean(d) + rng.laplace(0.0, model.sensor.sigma_size / np.sqrt(2.0), batch.n_sightings)
    return replace(batch, sight_value=z)


def test_the_robust_covariance_follows_the_noise_kurtosis_the_fisher_one_cannot_see():
    """Known answer: with the poses known, sigma's estimate is sqrt(mean r^2), whose variance is (mu4 - sigma^4) /
    (4 sigma^2 n): sigma^2 / (2 n) for Gaussian noise (the Fisher information's), 5 sigma^2 / (4 n) for Laplace noise
    of the same variance, a standard error sqrt(2.5) = 1.58 times the Fisher one. The robust errors find that ratio
    on the Laplace sizes and about 1 on the Gaussian log; the bearings (Gaussian in both) keep theirs."""
    model, batch, poses = known_poses_case(BASIS_POWER, frames=12000)
    ratio = {}
    for name, b in (("gauss", batch), ("laplace", _with_laplace_sizes(model, batch, poses, seed=0))):
        unc = parameter_uncertainty(model, b, fixed=SENSOR_ONLY)
        assert unc.blocks == 40  # 400 s of log in blocks of ROBUST_BLOCK_S = 10 s
        ratio[name] = {k: np.asarray(unc.robust_standard_errors[k], float) / np.asarray(unc.standard_errors[k], float)
                       for k in ("sensor_model.sigma_height", "sensor_model.sigma_angle")}
    assert 1.0 <= ratio["gauss"]["sensor_model.sigma_height"] < 1.15  # the larger of the two: never below 1
    assert 1.0 <= ratio["gauss"]["sensor_model.sigma_angle"] < 1.15
    assert 1.25 < ratio["laplace"]["sensor_model.sigma_height"] < 1.9, ratio  # 1.36-1.42 on seeds 0-3
    np.testing.assert_allclose(ratio["laplace"]["sensor_model.sigma_angle"], ratio["gauss"]["sensor_model.sigma_angle"],
                               rtol=1e-3)  # the poses move a little with the sizes


def test_the_scores_block_sums_add_up_to_the_score():
    """The per-sighting scores behind the robust covariance (``_score_weights``) are the likelihood's: their block
    sums add up to the score the forward differences of the log-likelihood give."""
    from learners.em.uncertainty import _Differences, _information, packed

    model, batch, _ = known_poses_case(BASIS_POWER, frames=1500)
    model = model.with_(sensor=model.sensor.with_values(sigma_size=0.9))  # off the optimum: a score to match
    diff = _Differences(model, batch, packed(model, SENSOR_ONLY), SENSOR_ONLY, np.flatnonzero(batch.used), -1e-4)
    coords = np.arange(len(packed(model, SENSOR_ONLY)))
    _, score, blocks = _information(diff, coords, 2**30)
    np.testing.assert_allclose(blocks.sum(axis=1), score, rtol=1e-4, atol=1e-3 * np.abs(score).max())


def test_the_informations_overstatement_is_the_mean_eigenvalue_of_fisher_inverse_times_sandwich():
    """Over a block with Fisher covariance diag(1, 4) and sandwich diag(2, 12) the ratios are 2 and 3: c = 2.5,
    whatever the other coordinates; rotated (a correlated block) the same; never below 1; 1 for no coordinate."""
    from types import SimpleNamespace

    from learners.em.uncertainty import information_overstatement

    F = np.diag([1.0, 4.0, 9.0])
    R = np.diag([2.0, 12.0, 3.0])
    unc = SimpleNamespace(names=["effects.e.a", "effects.e.b", "action.weights[0]"], covariance=F, robust_covariance=R)
    assert information_overstatement(unc, "effects.e.") == pytest.approx(2.5)
    th = 0.3
    Q = np.eye(3)
    Q[:2, :2] = [[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]
    rot = SimpleNamespace(names=unc.names, covariance=Q @ F @ Q.T, robust_covariance=Q @ R @ Q.T)
    assert information_overstatement(rot, "effects.e.") == pytest.approx(2.5)
    assert information_overstatement(unc, "action.") == pytest.approx(1.0)  # 3 / 9 < 1: floored
    assert information_overstatement(unc, "sensor.") == 1.0


def test_the_overstatement_over_longer_blocks_sees_a_drift_the_short_blocks_miss():
    """One coordinate whose 400 blocks of 10 s each carry information 1 (Fisher covariance 1/400). Block sums that are
    independent N(0, 1): c about 1 over the 10 s blocks and over 30 s ones. An AR(1) of unit variance and lag-1
    correlation 0.9 (a drift much slower than a block): each 10 s block's sum has the variance the information says
    (c = 1), but three of them together have (3 + 2 (2 x 0.9 + 0.81)) / 3 = 2.74 times it, which the merged blocks see
    (2.4 on this series)."""
    from types import SimpleNamespace

    from learners.em.uncertainty import information_overstatement, merged_blocks, sandwich

    rng = np.random.default_rng(0)
    m = 400
    t = 10.0 * np.arange(m)

    def unc_of(sums: np.ndarray) -> SimpleNamespace:
        cov = np.array([[1.0 / m]])
        return SimpleNamespace(names=["effects.e.a"], covariance=cov, robust_covariance=sandwich(cov, sums[None]),
                               block_sums=sums[None], block_time=t, block_log=np.zeros(m, int))

    white = unc_of(rng.normal(size=m))
    assert merged_blocks(white, 30.0).shape == (1, 134)  # blocks [0, 30), [30, 60), ... of the 3,990 s
    np.testing.assert_allclose(merged_blocks(white, 30.0)[0, :3], [white.block_sums[0, 3 * k: 3 * k + 3].sum()
                                                                   for k in range(3)])
    assert information_overstatement(white, "effects.e.") == pytest.approx(1.0, abs=0.2)
    assert information_overstatement(white, "effects.e.", 30.0) == pytest.approx(1.0, abs=0.3)
    x = np.zeros(m)
    for k in range(1, m):
        x[k] = 0.9 * x[k - 1] + np.sqrt(1 - 0.81) * rng.normal()
    drift = unc_of(x)
    short, long_ = information_overstatement(drift, "effects.e."), information_overstatement(drift, "effects.e.", 30.0)
    assert short == pytest.approx(1.0, abs=0.2) and long_ == pytest.approx(2.74, abs=0.6), (short, long_)


def test_the_conditional_errors_robust_form_sees_sightings_that_share_an_error():
    """An effect's own likelihood (``conditional_errors``): a mean of unit-variance scores, the observed information
    n (se 1 / sqrt(n)). Independent scores: the robust error is the observed information's (the larger of the two, the
    sandwich's about equal). Each value shared by 4 neighbouring sightings (inside one 10 s block): the sum's variance
    is 4 n, so the robust error is twice the observed information's (1.95 on this series)."""
    from types import SimpleNamespace

    from learners.em.uncertainty import conditional_errors
    from learners.model.effects import ConditionalInformation

    rng = np.random.default_rng(3)
    n = 12_000  # one sighting per frame of 0.1 s: 120 blocks of 10 s, 100 sightings each
    batch = SimpleNamespace(n_frames=n, dt=0.1, frame_time=0.1 * np.arange(n), sight_frame=np.arange(n),
                            sight_log=np.zeros(n, int))

    def errors(scores: np.ndarray) -> tuple[float, float]:
        info = ConditionalInformation(("mean",), np.array([[1.0 / n]]), scores[:, None], np.arange(n))
        se, robust = conditional_errors(info, batch)
        return se["mean"], robust["mean"]

    se, robust = errors(rng.normal(size=n))
    assert se == pytest.approx(1 / np.sqrt(n)) and robust / se == pytest.approx(1.0, abs=0.15)
    se, robust = errors(np.repeat(rng.normal(size=n // 4), 4))
    assert robust / se == pytest.approx(2.0, abs=0.3), robust / se
