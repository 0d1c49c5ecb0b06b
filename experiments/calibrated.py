"""The calibrated simulator: ``AiboBeacons-v0`` built from a fitted model, replaying a measured log's
commands, and the check that compares it with the measured log. A model with
continuous commands (and a range sensor) gets ``WheeledRobot-v0`` instead (:mod:`experiments.calibrated_wheeled`).

The model becomes an env config (:func:`simulator_config`): its velocity table, its per-frame motion
covariance (``slip_cov``), its sensor curve and noise (``sensor_curve``, ``sigma_height``,
``sigma_angle``), its effects through their simulator twins (same names and parameters), and its
start pose. A model without ``wall_contact`` knows no walls, so its simulator has none
(``walls="open"``). The measured log gives what the model does not describe: the landmarks, the
field, the head pan per frame (replayed), and, when the log comes from this simulator, the camera
(field of view, range, detection probability).

The replay is open loop: the commands are the measured ones, but the simulated robot's path
drifts away from the measured one (the policy that chose them steered on what it saw; the
replay cannot). So statistics tied to where the robot goes relative to the walls are left out of
the comparison (``EXCLUDED``); everything else depends on the path only through the data the
model explains.

The check (:func:`predictive_check`) is a parametric bootstrap: ``replicas`` logs are simulated from
the fitted model with the measured commands; each, and the measured log, goes through the same steps
(outliers set aside, refit on its training half warm-started from the model, then every
statistic of :mod:`learners.discrepancy.statistics`); the measured value of a statistic is compared
with the replicas' spread as z = (measured - mean) / sd. Where the model is right, the measured log
looks like one more replica. A statistic disagrees when the measured value is outside the replicas'
prediction interval at level 1 - ``FAMILY_ALPHA`` / K (K statistics, Bonferroni; Student t with
R - 1 dof, widened by sqrt(1 + 1/R)): a model that is right shows no disagreement in 95% of checks, where each
statistic's spread over the replicas is near Gaussian (a residual signature's strength is (-log10 p)^(1/3) for that:
:mod:`learners.discrepancy.statistics`). Measured on 100 effect-free 5-minute logs (``scripts/check_null.py``,
docs/results.md "The calibrated check on effect-free logs"): the whole log's fit disagreed on 3 (16 replicas; none on
two statistics); the search's base model, a fit of the training half, on more, where that fit sat in a local optimum of
EM, which the replicas, refitted warm from the model that made them, do not repeat.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from scipy import stats

from aibo_core.actions import N_ACTIONS
from aibo_core.atomic import finite_json
from aibo_core.trajectory import Trajectory
from aibo_core.workers import process_pool
from experiments.calibrated_wheeled import image_frames, needs_path, wheeled_config
from learners.discrepancy.search import drop_outliers
from learners.discrepancy.split import training_log
from learners.discrepancy.statistics import check_statistics
from learners.em.learner import EMLearner
from learners.em.options import COMPARABLE_IMPROVEMENT, EMOptions
from learners.model.model import Model

#: Camera and body settings taken from a log made by this simulator (``meta["config"]``).
SIMULATOR_KEYS = ("fov", "range_mm", "detect_prob", "pan_amplitude", "pan_period", "focal_px", "beacon_height_mm")
EXCLUDED = ("distance to walls",)  # statistics naming these: the open-loop replay cannot reproduce them
FAMILY_ALPHA = 0.05  # chance that a right model shows any disagreement in one check
#: The fewest replicas whose spread can reject a statistic (fewer: the threshold is infinite, nothing
#: disagrees whatever the data); ``aibo diagnose --replicas`` refuses 1 and 2.
MIN_REPLICAS = 3
#: The replicas of a check by default (``aibo diagnose --replicas``). With the signatures' strengths as (-log10 p)^(1/3)
#: the family's false alarms stay at 4.3-5.2% whatever the number (4, 8, 16 or 24; 30 effect-free models of three
#: generators, one replica checked against others: docs/results.md, "The calibrated check on effect-free logs"), and
#: more replicas lower the threshold (|z| 5.54 with 8, 4.08 with 16), so the check sees weaker effects: with 8 the cube
#: root left two catalogue effects below it (``tests/test_check_sees_effects.py``), with 16 none. The check of a
#: 15-minute MRCLAM log then takes 8-10 s on 2 cores (4-5 s with 8).
REPLICAS = 16
#: The replicas' refit: a warm-started polish, as the search's fits of the measured log are (one start, no alias
#: search: from the generating model there is no heading alias to escape, and it took 0.8 of a replica's 1.8 s on a
#: 10-minute log; no lag search, no standard errors).
REFIT = EMOptions(starts=1, max_iter=60, patience=10, min_improvement=COMPARABLE_IMPROVEMENT, uncertainty=False,
                  lag_search=False, alias_search=False)
FIELD_MARGIN_MM = 1000.0  # a log without a field: the landmarks' bounding box grown by this


def simulator_env(model: Model) -> str:
    """The env id of ``model``'s simulator: ``WheeledRobot-v0`` for continuous commands, else ``AiboBeacons-v0``."""
    return "AiboBeacons-v0" if model.action.discrete else "WheeledRobot-v0"


def simulator_config(model: Model, log: Trajectory | None = None, index: int = 0,
                     path: np.ndarray | None = None) -> dict[str, Any]:
    """The env config of a simulator built from ``model`` (module docstring; for continuous commands,
    ``WheeledRobot-v0``'s: :mod:`experiments.calibrated_wheeled`); ``log`` (the measured one, the
    ``index``-th of the fit) gives landmarks, field and camera; ``path`` (continuous commands): where the camera's
    detection is measured when the log has no true poses. ValueError (one line) when the simulator cannot represent
    the model."""
    act, sen = model.action, model.sensor
    if not act.discrete:
        return wheeled_config(model, log, index, path)
    if not act.discrete or act.weights.shape[0] != N_ACTIONS:
        raise ValueError(f"the simulator walks {N_ACTIONS} discrete commands; this model's action model is "
                         f"'{act.feature_map}' with {act.weights.shape[0]} rows")
    if sen.kind != "height_px":
        raise ValueError(f"the simulator's camera reports heights in px; this model's sensor is '{sen.kind}'")
    walls = "clamp" if model.effect("wall_contact") is not None else "open"
    cfg: dict[str, Any] = {
        "dt": act.dt, "velocities": act.velocities.tolist(), "slip_cov": act.cov.tolist(), "big_slip_prob": 0.0,
        "sensor_curve": {"basis": sen.basis, "coef": [float(c) for c in sen.coef]},
        "sigma_height": float(sen.sigma_size), "sigma_angle": float(sen.sigma_bearing),
        "effects": {e.name: e.to_json()["parameters"] for e in model.effects}, "walls": walls,
    }
    if log is not None:
        made_here = log.meta.get("config") if isinstance(log.meta.get("config"), dict) else {}
        cfg.update({k: made_here[k] for k in SIMULATOR_KEYS if k in made_here})
        cfg["beacons"] = log.landmarks.tolist()
        cfg["field"] = (log.field if log.field is not None else _bounding_field(log.landmarks)).tolist()
        cfg["max_steps"] = int(log.n_frames)
    start = model.init[min(index, len(model.init) - 1)].mean
    half = np.asarray(cfg.get("field", (5400.0, 3600.0)), float) / 2
    cfg["start_pose"] = [*np.clip(start[:2], -half, half).tolist(), float(start[2])]
    return cfg


def _bounding_field(landmarks: np.ndarray) -> np.ndarray:
    return 2.0 * (np.abs(landmarks).max(axis=0) + FIELD_MARGIN_MM)


def replay_log(model: Model, log: Trajectory, seed: int, index: int = 0, path: np.ndarray | None = None,
               steer: bool = False) -> Trajectory:
    """``log``'s commands (and head pan, or for continuous commands its image frames) replayed in the
    simulator of ``model``: a log of the same length, as the model says the robot would have made it.
    ``path`` (continuous commands only; ``smoothed_paths``): where the camera's detection is measured when the log
    has no true poses, and with ``steer`` the path the replay's commands are steered along
    (``aibo_gym.collect_wheeled.replay_wheeled``; commands ``TRACKED_CONTROLS`` only, the others open loop)."""
    from aibo_gym.collect import replay
    from aibo_gym.collect_wheeled import TRACKED_CONTROLS, replay_wheeled

    cfg = simulator_config(model, log, index, path=path)
    reference = path if steer and tuple(log.control_names or ()) == TRACKED_CONTROLS else None
    src = str(log.meta.get("source", log.meta.get("generator", "")))
    if not model.action.discrete:
        if log.controls is None:
            raise ValueError("replay: the log has no continuous commands ('controls') for this model to replay")
        return replay_wheeled(cfg, log.controls, seed, images=image_frames(log), source=src, reference=reference)
    if log.actions is None:
        raise ValueError("replay: the log has no discrete commands ('actions') to replay")
    return replay(cfg, log.actions, seed, head_pan=log.head_pan, source=src)


@dataclass
class Check:
    """The measured statistics against the calibrated simulation's (``replicas`` rows)."""

    names: list[str]
    measured: np.ndarray  # (K,)
    replicas: np.ndarray  # (R, K); NaN where a replica lacks a statistic
    failed: list[str] = field(default_factory=list)  # replicas that could not be simulated or fitted

    @property
    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """(K,) mean and (K,) sample sd of the replicas' statistics (NaN where fewer than 2 replicas have one)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # too few replicas: NaN, said by the caller
            return np.nanmean(self.replicas, axis=0), np.nanstd(self.replicas, axis=0, ddof=1)

    @property
    def z(self) -> np.ndarray:
        """(K,) (measured - replica mean) / replica sd; 0 where the replicas agree exactly with the data."""
        mean, sd = self.moments
        diff = self.measured - mean
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(sd > 0, diff / sd, np.where(diff == 0, 0.0, np.sign(diff) * np.inf))
        return np.where(np.isfinite(self.measured), z, np.nan)

    @property
    def threshold(self) -> float:
        """|z| above which a statistic disagrees (module docstring); inf with fewer than ``MIN_REPLICAS``."""
        r, k = len(self.replicas), max(len(self.names), 1)
        if r < MIN_REPLICAS:
            return math.inf
        return float(stats.t.ppf(1.0 - FAMILY_ALPHA / (2 * k), r - 1) * math.sqrt(1.0 + 1.0 / r))

    def disagreements(self) -> list[tuple[str, float]]:
        """(statistic, z) with |z| > ``threshold``, the largest first."""
        z, limit = self.z, self.threshold
        idx = [k for k in np.argsort(-np.abs(np.nan_to_num(z))) if abs(z[k]) > limit]
        return [(self.names[k], float(z[k])) for k in idx]

    def as_dict(self) -> dict[str, Any]:
        z = self.z
        mean, sd = self.moments
        rows = [{"statistic": n, "measured": m, "simulated_mean": a, "simulated_sd": s, "z": q}
                for n, m, a, s, q in zip(self.names, self.measured, mean, sd, z)]
        return finite_json({"replicas": int(len(self.replicas)), "disagree_z": self.threshold, "statistics": rows,
                            "disagreements": [{"statistic": n, "z": q} for n, q in self.disagreements()],
                            "failed_replicas": self.failed})


def replica_statistics(model: Model, logs: list[Trajectory], seed: int, paths: list[np.ndarray | None] | None = None,
                       steer: bool = False) -> dict[str, float]:
    """One replica: every log replayed in ``model``'s simulator (``paths``: one smoothed path or None per log, and
    ``steer``, as ``replay_log`` takes them), then the measured logs' treatment (outliers set aside, refit on the
    training half from ``model``, statistics on the whole)."""
    paths = paths or [None] * len(logs)
    sims = [replay_log(model, tr, seed + 7919 * i, index=i, path=paths[i], steer=steer) for i, tr in enumerate(logs)]
    sims, _ = drop_outliers(model, sims)
    return _compared(check_statistics(training_refit(model, sims), sims))


def camera_paths(model: Model, logs: list[Trajectory]) -> list[np.ndarray | None]:
    """Per log, the path its camera is measured at in ``model``'s simulator: ``model``'s smoothed path where the camera
    is measured and the log has no true poses (``calibrated_wheeled.needs_path``), else None (true poses, a camera
    from the log's own config, or a discrete model's simulator, whose camera is its config's). Smoothed only when
    one is needed."""
    if model.action.discrete or not any(needs_path(tr) for tr in logs):
        return [None] * len(logs)
    paths = smoothed_paths(model, logs)
    return [p if needs_path(tr) else None for tr, p in zip(logs, paths)]


def smoothed_paths(model: Model, logs: list[Trajectory]) -> list[np.ndarray] | None:
    """``model``'s smoothed path of each of ``logs`` ((T + 1, 3) poses [x mm, y mm, theta rad]), for a model of
    continuous commands (None for a discrete one, whose simulator takes the camera from its config). What a replica's
    camera is measured at when a log has no true poses (a real robot's without Vicon: otherwise its simulator would
    detect with the env's default probability), and what a tracking replica steers along. Why steer: a replay of the
    measured commands open loop drifts metres away over minutes (the measured robot steered on its pose; the replay
    cannot), and the sightings' statistics then compare a robot in the arena with one outside it (MRCLAM: every
    robot's "sightings per frame" disagreed at z +2.5 to +4.9, docs/results.md, "The twin's replays follow the robot's
    path")."""
    from learners.scoring import smoothed_poses

    if model.action.discrete:
        return None
    return smoothed_poses(model, logs)[0]


def training_refit(model: Model, logs: list[Trajectory]) -> Model:
    """``model`` refitted on the training halves of ``logs`` from itself (``REFIT``): what the check's statistics are
    computed with, for the measured logs and each replica alike."""
    return EMLearner(REFIT, check_field=False).fit([training_log(tr) for tr in logs], init=model).params


def _compared(stats: dict[str, float]) -> dict[str, float]:
    return {k: v for k, v in stats.items() if not any(x in k for x in EXCLUDED)}


def _replica_job(args: tuple) -> dict[str, float] | str:
    try:
        return replica_statistics(*args)
    except (FloatingPointError, np.linalg.LinAlgError, ValueError, RuntimeError) as err:
        return f"replica seed {args[2]}: {str(err).splitlines()[0]}"


def predictive_check(model: Model, logs: list[Trajectory], replicas: int = REPLICAS, seed: int = 0, jobs: int = 1,
                     progress: Callable[[str], None] | None = None, tracking: bool = False) -> Check:
    """The measured ``logs`` (outliers already set aside; ``model`` a fit of them, of the whole logs or of their
    training halves) against ``replicas`` simulations from ``model`` with the same commands (module docstring): the
    measured logs go through what each replica goes through, a refit on their training halves from ``model`` and then
    the statistics. Before 2026-11-28 the measured statistics were ``model``'s own, which holds only for a fit of the
    training halves: for the whole logs' fit that ``aibo diagnose`` writes (the twin a user drives) its held-out
    statistics would be in-sample. Measured on MRCLAM robot 2 (the twin's recipe, docs/results.md): the final fit's
    model, its own statistics, 2 disagreements; refitted as the replicas are, 4, those the report gave for the
    search's training-half model.

    ``tracking``: the replicas steered along ``model``'s smoothed paths (``smoothed_paths``) instead of open loop.
    Not the default: on the five MRCLAM robots' diagnosed models it brought "sightings per frame" into the replicas'
    spread on four, and the statistics disagreeing summed to 41 against 39 open loop (worse on robots 2 and 5: the
    tracked replicas' narrower spread shows the twin's motion noise; docs/results.md, "The twin's replays follow the
    robot's path")."""
    simulator_config(model, logs[0])  # refuse early, in one line, what the simulator cannot represent
    measured = _compared(check_statistics(training_refit(model, logs), logs))
    paths = smoothed_paths(model, logs) if tracking else camera_paths(model, logs)
    args = [(model, logs, 1_000_003 * (seed + 1) + r, paths, tracking) for r in range(replicas)]
    if jobs > 1:
        with process_pool(jobs) as pool:
            results = list(pool.map(_replica_job, args))
    else:
        results = [_replica_job(a) for a in args]
    done = [r for r in results if isinstance(r, dict)]
    failed = [r for r in results if isinstance(r, str)]
    names = list(measured)
    table = np.array([[r.get(n, np.nan) for n in names] for r in done]).reshape(len(done), len(names))
    check = Check(names, np.array([measured[n] for n in names]), table, failed)
    if progress is not None:
        worst = check.disagreements()[:3]
        progress(f"calibrated simulator: {len(done)} replicas ({len(failed)} failed); "
                 + (", ".join(f"{n} z = {z:+.1f}" for n, z in worst) if worst else "no statistic disagrees"))
    return check
