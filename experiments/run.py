"""One run of an experiment: a :class:`RunSpec` -> a result record (a JSON-able dict).

``run(spec, out_dir)`` simulates ``minutes`` of the env config under the policy spec (seed
``seed``), learns with EM, scores the model against the log's truth and on a held-out log of the
same robot, and keeps the log and the model in ``out_dir/runs/<id>/`` (paths in the record are
relative to ``out_dir``). The same spec gives the same record, whatever the process or backend,
except ``timing`` (wall-clock seconds). The record file ``runs/<id>/record.json`` is written last
and atomically: its presence means the run is complete.
"""

from __future__ import annotations

import hashlib
import json
import re
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from aibo_core import trajectory
from aibo_core.atomic import write_json
from learners.em.learner import MAX_OFF_FIELD

FPS = 30.0
HOLDOUT_SEED_OFFSET = 10_000  # the held-out log of seed s is collected with seed s + this
HOLDOUT_POLICY = {"name": "random-balanced", "params": {"localizer": "ekf"}}


@dataclass
class RunSpec:
    """What one run does. ``env``: env config overrides (``aibo_gym.config``); ``policy``: a policy
    spec; ``minutes`` of robot time (30 frames/s); ``seed``: the env's and the policy's seed;
    ``learner``: ``EMOptions`` overrides (its ``seed`` defaults to ``seed``); ``holdout_minutes``:
    length of the held-out log (random-balanced on the onboard EKF, seed + 10000; 0: none);
    ``tag``: a free label kept in the record."""

    policy: Any
    minutes: float
    seed: int
    env: dict[str, Any] = field(default_factory=dict)
    learner: dict[str, Any] = field(default_factory=dict)
    holdout_minutes: float = 5.0
    tag: str = ""

    def normalized(self) -> "RunSpec":
        from aibo_gym.policies import validate_policy

        return RunSpec(validate_policy(self.policy), float(self.minutes), int(self.seed), dict(self.env),
                       dict(self.learner), float(self.holdout_minutes), str(self.tag))

    def to_json(self) -> dict[str, Any]:
        return asdict(self.normalized())

    @property
    def steps(self) -> int:
        return max(1, int(round(self.minutes * 60 * FPS)))

    @property
    def run_id(self) -> str:
        """A file-name-safe id: the policy label, minutes, seed and a hash of the whole spec."""
        from aibo_gym.policies import policy_label

        text = json.dumps(self.to_json(), sort_keys=True)
        digest = hashlib.sha1(text.encode()).hexdigest()[:8]
        label = re.sub(r"[^A-Za-z0-9_.-]+", "-", policy_label(self.policy))
        return f"{label}_{self.minutes:g}min_s{self.seed}_{digest}"


def spec_from_json(d: dict[str, Any]) -> RunSpec:
    return RunSpec(**d)


def em_options(spec: RunSpec):
    from learners.em.options import EMOptions

    return EMOptions(**{"seed": spec.seed, **spec.learner})


def run(spec: RunSpec, out_dir: str | Path) -> dict[str, Any]:
    """Do the run of ``spec`` (see the module docstring); return its record."""
    from experiments.loop import fit_em, heldout_loglik, log_stats, score, simulate
    from learners.model import io as model_io

    spec = spec.normalized()
    out_dir = Path(out_dir)
    rel = Path("runs") / spec.run_id
    folder = out_dir / rel
    folder.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    tr = simulate(spec.env, spec.steps, spec.seed, spec.policy)
    trajectory.save(tr, folder / "log.npz")
    t1 = time.perf_counter()
    # a fit that leaves the field is kept and flagged (``diverged``), not raised: it is a result of the data
    res = fit_em([tr], em_options(spec), check_field=False)
    model_io.save_result(res, folder / "model.json")
    t2 = time.perf_counter()
    err = score(res.params, [tr])
    held = None
    if spec.holdout_minutes > 0:
        hold = simulate(spec.env, max(1, int(round(spec.holdout_minutes * 60 * FPS))),
                        spec.seed + HOLDOUT_SEED_OFFSET, HOLDOUT_POLICY)
        held = heldout_loglik(res.params, hold)
    t3 = time.perf_counter()
    from aibo_gym.policies import policy_label

    record = {
        "id": spec.run_id, "policy": policy_label(spec.policy), "minutes": spec.minutes, "seed": spec.seed,
        "robot_seed": tr.meta["config"]["robot_seed"],
        "vx_rel": err["vx_rel"], "vy_rel": err["vy_rel"], "vth_rel": err["vtheta_rel"],
        "sensor_rms_px": err["sensor_rms_px"],
        "vel_rel_mean": (err["vx_rel"] + err["vy_rel"] + err["vtheta_rel"]) / 3,
        "vx_rms": err["vx_rms"], "vy_rms": err["vy_rms"], "vth_rms": err["vtheta_rms"],
        "sigma_height_rel": err["sigma_height_rel"], "sigma_angle_rel": err["sigma_angle_rel"],
        "heldout_loglik": held, "train_loglik_per_sighting": float(max(res.loglik)) / max(tr.n_sightings, 1),
        "iterations": res.iterations, "converged": bool(res.converged), "pruned": int(res.pruned_observations),
        "undetermined": len(res.info.get("undetermined", [])),
        # the spectrum of the information matrix at the estimate (learners/em/uncertainty.py): a policy can
        # be informative in total and still leave parameters confounded
        "info_min_eigenvalue": res.info.get("information", {}).get("min_eigenvalue"),
        "info_condition_number": res.info.get("information", {}).get("condition_number"),
        "off_field_fraction": float(res.info.get("off_field_fraction", 0.0)),
        "diverged": bool(res.info.get("off_field_fraction", 0.0) > MAX_OFF_FIELD),
        **log_stats(tr),
        "log": str(rel / "log.npz"), "model": str(rel / "model.json"),
        "spec": spec.to_json(),
        "timing": {"collect_s": t1 - t0, "learn_s": t2 - t1, "score_s": t3 - t2, "total_s": t3 - t0},
    }
    write_json(folder / "record.json", record)  # NaN -> null: always valid JSON
    return record


def run_json(spec_json: dict[str, Any], out_dir: str) -> dict[str, Any]:
    """``run`` on a spec given as JSON (what the executors send to workers)."""
    return run(spec_from_json(spec_json), out_dir)


#: Keys every record.json holds (a record without one is refused, not resumed).
REQUIRED_KEYS = ("id", "policy", "minutes", "seed", "vx_rel", "vy_rel", "vth_rel", "sensor_rms_px", "log", "model",
                 "spec", "timing")


def load_record(out_dir: str | Path, spec: RunSpec) -> dict[str, Any] | None:
    """The record of a completed run of ``spec`` in ``out_dir``, or None (missing, unreadable or another
    spec). A record of this spec that is not an object with every ``REQUIRED_KEYS`` raises a ValueError
    (one line naming the file and the key)."""
    path = Path(out_dir) / "runs" / spec.run_id / "record.json"
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(rec, dict):
        raise ValueError(f"{path}: not a JSON object but {type(rec).__name__} (delete the file to redo the run)")
    if rec.get("spec") != spec.to_json():
        return None
    missing = [k for k in REQUIRED_KEYS if k not in rec]
    if missing:
        raise ValueError(f"{path}: no key {missing[0]!r} (delete the file to redo the run)")
    return rec
