"""The ``oracle`` learner: the same models estimated from the TRUE poses of simulated logs.

It is the yardstick: what the data allow at best, with no pose uncertainty. It needs logs
with ``pose``; velocities are per-action means of the true relative displacements, the
motion covariance is their pooled scatter, and the sensor model is the cubic fit of
height against true distance with the residual sigmas.
"""

from __future__ import annotations

import numpy as np

from aibo_core.trajectory import Trajectory
from learners.base import LearnResult, ProgressFn
from aibo_core.geometry import rel_disp, wrap
from learners.em.params import N_ACTIONS, ActionModel, InitialState, Params, SensorModel
from learners.em.sensor_mstep import fit_polynomial


class OracleLearner:
    name = "oracle"

    def __init__(self, degree: int = 3):
        self.degree = degree

    def fit(self, logs: list[Trajectory], init: Params | None = None, progress: ProgressFn | None = None) -> LearnResult:
        missing = [i for i, tr in enumerate(logs) if tr.pose is None]
        if missing:
            raise ValueError(f"the oracle needs true poses; log #{missing[0] + 1} has no 'pose'")
        dt = logs[0].dt
        disp = np.concatenate([rel_disp(tr.pose[:-1], tr.pose[1:]) for tr in logs])
        disp[:, 2] = wrap(disp[:, 2])  # simulated poses keep theta wrapped
        actions = np.concatenate([tr.actions for tr in logs])
        mean = np.zeros((N_ACTIONS, 3))
        if init is not None:
            mean[:] = init.action.disp
        for a in np.unique(actions):
            mean[a] = disp[actions == a].mean(axis=0)
        resid = disp - mean[actions]
        cov = resid.T @ resid / len(resid)

        d, h, ang_res = [], [], []
        for tr in logs:
            pose = tr.pose[tr.sighting_frame + 1]
            delta = tr.landmarks[tr.sighting_landmark] - pose[:, :2]
            d.append(np.hypot(delta[:, 0], delta[:, 1]))
            h.append(tr.sighting_value[:, 0])
            ang_res.append(wrap(tr.sighting_value[:, 1] - (np.arctan2(delta[:, 1], delta[:, 0]) - pose[:, 2])))
        d, h, ang_res = np.concatenate(d), np.concatenate(h), np.concatenate(ang_res)
        coef = fit_polynomial(d, h, np.ones_like(d), self.degree)
        sh = float(np.sqrt(np.mean((np.polynomial.polynomial.polyval(d, coef) - h) ** 2)))
        sa = float(np.sqrt(np.mean(ang_res**2)))
        sensor = SensorModel(coef, sh, sa, (float(d.min()), float(d.max())))
        init_states = tuple(InitialState(tr.pose[0].copy(), np.diag([1.0, 1.0, 1e-4])) for tr in logs)
        params = Params(ActionModel(mean, cov, dt), sensor, init_states)
        return LearnResult("oracle", params, iterations=1, converged=True, info={"frames": int(len(actions))})
