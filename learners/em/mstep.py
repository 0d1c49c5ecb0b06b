"""The M-step: new components from the E-step's statistics (paper section III; docs/em-math.md).

- Action model: the per-frame displacement estimates mu*_i (``action_statistics``: posterior of the
  robot-frame displacement times the previous model, footnote 3) regressed on the command features
  (``ActionModel.regress``: the paper's per-action mean for the table); with ``learn_motion_noise``
  Sigma_A = (sum_i C*_i + sum_i r_i r_i^T) / N, r_i = mu*_i - features_i weights_new.
- Sensor model: weighted least squares of the sizes on the basis functions of distance over the
  smoothed pose beliefs, and the noise variances (``update_sensor_curve``).
- pi: the smoothed first pose of each log.
- Effects: each effect's conditional maximization, in order (ECM), after the base model.
"""

from __future__ import annotations

from concurrent.futures import wait
from dataclasses import replace

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.em import second_thread
from learners.em.options import EMOptions
from learners.inference.augmented import displacement_statistics, sensor_update_augmented
from learners.model.initial import InitialState
from learners.model.model import Model


def _sym(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + A.T)


def _statistics(compiled: bool):
    """(action_statistics, residual_cov, sensor update) of the compiled or the NumPy path."""
    if compiled:
        from learners.inference import kernels as k

        return k.action_statistics_compiled, k.residual_cov_compiled, k.sensor_update_compiled
    from learners.inference.action_stats import action_statistics, residual_cov
    from learners.inference.sensor_stats import update_sensor_curve

    return action_statistics, residual_cov, update_sensor_curve


def maximize(model: Model, batch: Batch, post: Posterior, rng: np.random.Generator, opts: "EMOptions",
             lo: Lowered | None = None) -> Model:
    """The new model (see the module docstring); ``opts.estep`` picks the compiled or NumPy statistics;
    ``lo``: ``model.lower(batch)`` if the caller has it."""
    action_stats, resid_cov, sensor_update = _statistics(opts.estep == "compiled")
    lo = model.lower(batch) if lo is None else lo
    degree = len(model.sensor.coef) - 1
    # the compiled sensor-curve update on the second thread while this one does the action model: the two
    # read the same posterior and write nothing the other reads (the same numbers; module second_thread)
    pending = None
    if opts.estep == "compiled" and post.extra is None and not opts.hold_curve:
        pending = second_thread.submit(sensor_update, lo, batch, post, rng, method=opts.sensor_method,
                                       n_samples=opts.n_samples, degree=degree)
    try:
        action, mu_star = _action_update(model, batch, post, opts, lo, action_stats, resid_cov)
    finally:
        if pending is not None:  # never leave it reading a posterior the caller may overwrite next
            wait([pending])
    if pending is not None:
        coef, sigma_size, sigma_bearing, drange = pending.result()
    elif post.extra is not None:  # the expectations over each sighting's joint belief of (pose, its size state)
        coef, sigma_size, sigma_bearing, drange = sensor_update_augmented(lo, batch, post, degree)
    elif opts.hold_curve:  # a range sensor's curve held at its start (EMOptions.range_curve): NumPy statistics,
        # sigma_size about the held curve (the conditional maximum); a few thousand sightings cost ~1 ms
        from learners.inference.sensor_stats import update_sensor_curve

        coef, sigma_size, sigma_bearing, drange = update_sensor_curve(
            lo, batch, post, rng, method=opts.sensor_method, n_samples=opts.n_samples, degree=degree,
            held=model.sensor.coef)
    else:
        coef, sigma_size, sigma_bearing, drange = sensor_update(
            lo, batch, post, rng, method=opts.sensor_method, n_samples=opts.n_samples, degree=degree)
    if opts.hold_curve:  # with bias states too: the curve stays at its start
        coef = model.sensor.coef
    sensor = replace(model.sensor, coef=coef, sigma_size=sigma_size, sigma_bearing=sigma_bearing,
                     distance_range_mm=(float(drange[0]), float(drange[1])))
    first = batch.pose_start[:-1]
    init = tuple(InitialState(post.mu_gamma[p].copy(), post.cov_gamma[p].copy()) for p in first)
    new = model.with_(action=action, sensor=sensor, init=init)
    for effect in model.effects:
        if effect.name not in opts.frozen:
            new = new.effect(effect.name).maximize(new, batch, post, mu_star)
    return new


def _action_update(model: Model, batch: Batch, post: Posterior, opts: "EMOptions", lo: Lowered, action_stats,
                   resid_cov):
    """(the new action model, mu_star (N, 3)): the displacement statistics regressed on the commands,
    and with ``learn_motion_noise`` the new Sigma_A."""
    commands, scale = model.effective_commands(batch)
    if post.extra is not None:  # an augmented E-step (extra states): its smoothed joint gives the statistics
        if opts.estep == "compiled":
            from learners.inference.kernels.augmented_stats import displacement_statistics_compiled as displacement
        else:
            displacement = displacement_statistics
        mu_star, C_sum = displacement(lo, batch, post, opts.learn_motion_noise)
    else:
        mu_star, C_sum = action_stats(lo, batch, post, opts.learn_motion_noise)
    fused = opts.estep == "compiled" and model.action.discrete and scale is None  # the table's fused twin
    if fused:
        from learners.inference.kernels import table_means_compiled, table_residual_cov_compiled

        weights = table_means_compiled(commands, mu_star, model.action.weights)
    else:
        weights = model.action.regress(commands, mu_star, scale)
    action = model.action.with_values(weights=weights)
    if opts.learn_motion_noise and len(mu_star):
        inv_n = 1.0 / len(mu_star)
        if fused:
            R = table_residual_cov_compiled(commands, mu_star, weights, lo.cov_scale, lo.cov_sd)
        else:
            pred = action.displacements(commands)
            R = resid_cov(mu_star, pred if scale is None else pred * scale, lo.cov_scale, lo.cov_sd)
        action = action.with_values(cov=_sym(C_sum * inv_n + R * inv_n))
    return action, mu_star
