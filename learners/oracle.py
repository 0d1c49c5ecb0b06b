"""The ``oracle`` learner: the same models estimated from the TRUE poses of simulated logs.

It is the yardstick: what the data allow at best, with no pose uncertainty. It needs logs with
``pose``; the action weights are the regression of the true relative displacements on the command
features (per-command means for the table), the motion covariance is their pooled scatter, and the
sensor curve is the least-squares fit of the size against the true distance, with the residual sigmas.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from aibo_core.geometry import rel_disp, wrap
from aibo_core.trajectory import Trajectory
from learners.arrays.batch import make_batch
from learners.arrays.lowered import fit_polynomial
from learners.base import LearnResult, ProgressFn
from learners.model.initial import InitialState
from learners.model.model import Model, start_model


class OracleLearner:
    name = "oracle"

    def __init__(self, degree: int = 3, basis: str = "power"):
        self.degree = degree
        self.basis = basis

    def fit(self, logs: list[Trajectory], init: Model | None = None, progress: ProgressFn | None = None,
            action_model: str | None = None) -> LearnResult:
        missing = [i for i, tr in enumerate(logs) if tr.pose is None]
        if missing:
            raise ValueError(f"the oracle needs true poses; log #{missing[0] + 1} has no 'pose'")
        batch = make_batch(logs)
        tr0 = logs[0]
        base = init or start_model(batch, tr0.dt, tr0.sensor_kind, len(tr0.attempted) if tr0.discrete else None,
                                   tuple(tr0.control_names or ()), None, self.basis, self.degree)
        disp = np.concatenate([rel_disp(tr.pose[:-1], tr.pose[1:]) for tr in logs])
        disp[:, 2] = wrap(disp[:, 2])  # simulated poses keep theta wrapped
        commands = batch.actions if batch.actions is not None else batch.controls
        action = base.action.with_values(weights=base.action.regress(commands, disp))
        resid = disp - action.displacements(commands)
        action = action.with_values(cov=resid.T @ resid / len(resid))

        d, size, ang_res = [], [], []
        for tr in logs:
            pose = tr.pose[tr.sighting_frame + 1]
            delta = tr.landmarks[tr.sighting_landmark] - pose[:, :2]
            d.append(np.hypot(delta[:, 0], delta[:, 1]))
            size.append(tr.sighting_value[:, 0])
            ang_res.append(wrap(tr.sighting_value[:, 1] - (np.arctan2(delta[:, 1], delta[:, 0]) - pose[:, 2])))
        d, size, ang_res = np.concatenate(d), np.concatenate(size), np.concatenate(ang_res)
        x = d if base.sensor.basis == "power" else 1.0 / d
        sensor = base.sensor.with_degree(self.degree).with_values(coef=fit_polynomial(x, size, np.ones_like(d),
                                                                                      self.degree))
        sensor = replace(sensor, sigma_size=float(np.sqrt(np.mean((sensor.mean(d) - size) ** 2))),
                         sigma_bearing=float(np.sqrt(np.mean(ang_res**2))),
                         distance_range_mm=(float(d.min()), float(d.max())))
        init_states = tuple(InitialState(tr.pose[0].copy(), np.diag([1.0, 1.0, 1e-4])) for tr in logs)
        model = Model(action, sensor, init_states)
        return LearnResult("oracle", model, iterations=1, converged=True, info={"frames": int(len(commands))})
