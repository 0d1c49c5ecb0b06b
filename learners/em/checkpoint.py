"""Resumable EM: the whole EMState in one ``.npz``, written atomically, tied to its inputs.

A checkpoint carries a fingerprint of the logs, the start model and the options; resuming
with different inputs is refused, so a stale checkpoint can never leak into a new fit.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from aibo_core.atomic import atomic_write
from learners.em.data import Batch
from learners.em.fit import EMState
from learners.em.params import ActionModel, InitialState, Params, SensorModel

FORMAT = "aibo-em-checkpoint/1"


def fingerprint(batch: Batch, start: Params, options_json: str) -> str:
    """SHA-256 over the data, the start parameters and the options."""
    h = hashlib.sha256()
    for a in (batch.actions, batch.obs, batch.beacon_xy, batch.frame_start):
        h.update(np.ascontiguousarray(a).tobytes())
    for k, v in sorted(_params_arrays("p", start).items()):
        h.update(k.encode())
        h.update(np.ascontiguousarray(v).tobytes())
    h.update(options_json.encode())
    return h.hexdigest()


def _params_arrays(prefix: str, p: Params) -> dict[str, np.ndarray]:
    out = {
        f"{prefix}.disp": p.action.disp, f"{prefix}.cov": p.action.cov, f"{prefix}.dt": np.array(p.action.dt),
        f"{prefix}.coef": p.sensor.coef,
        f"{prefix}.sigmas": np.array([p.sensor.sigma_height, p.sensor.sigma_angle]),
        f"{prefix}.range": np.array(p.sensor.distance_range_mm),
        f"{prefix}.init_mean": np.array([s.mean for s in p.init]),
        f"{prefix}.init_cov": np.array([s.cov for s in p.init]),
    }
    return {k: np.asarray(v, float) for k, v in out.items()}


def _params_from(prefix: str, d) -> Params:
    sig = d[f"{prefix}.sigmas"]
    rng = d[f"{prefix}.range"]
    return Params(
        ActionModel(d[f"{prefix}.disp"], d[f"{prefix}.cov"], float(d[f"{prefix}.dt"])),
        SensorModel(d[f"{prefix}.coef"], float(sig[0]), float(sig[1]), (float(rng[0]), float(rng[1]))),
        tuple(InitialState(m, c) for m, c in zip(d[f"{prefix}.init_mean"], d[f"{prefix}.init_cov"])),
    )


def save(path: str | os.PathLike, state: EMState, fp: str) -> None:
    scalars = {
        "format": FORMAT, "fingerprint": fp, "iteration": state.iteration, "best_loglik": state.best_loglik,
        "best_iteration": state.best_iteration, "pruned": state.pruned, "rng_state": state.rng_state,
        "converged": state.converged, "record_iteration": state.record_iteration,
    }
    arrays = {**_params_arrays("cur", state.params), **_params_arrays("best", state.best)}
    arrays["loglik"] = np.asarray(state.loglik, float)
    arrays["seconds"] = np.asarray(state.seconds, float)
    arrays["used"] = state.used
    arrays["scalars"] = np.array(json.dumps(scalars))
    atomic_write(path, lambda f: np.savez(f, **arrays))


def load(path: str | os.PathLike, fp: str) -> EMState | None:
    """The saved state if ``path`` exists and matches ``fp``; None if absent; ValueError if it mismatches."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as d:
            scalars = json.loads(str(d["scalars"]))
            if scalars.get("format") != FORMAT:
                raise ValueError(f"{path}: not an EM checkpoint")
            if scalars["fingerprint"] != fp:
                raise ValueError(f"{path}: checkpoint is for other logs, start model or options "
                                 "(delete it or pass --no-resume)")
            best_ll = float(scalars["best_loglik"])
            return EMState(
                iteration=int(scalars["iteration"]), params=_params_from("cur", d), best=_params_from("best", d),
                best_loglik=best_ll, best_iteration=int(scalars["best_iteration"]),
                loglik=d["loglik"].tolist(), used=d["used"].astype(bool), pruned=int(scalars["pruned"]),
                rng_state=scalars["rng_state"], converged=bool(scalars["converged"]), seconds=d["seconds"].tolist(),
                record_iteration=int(scalars["record_iteration"]),
            )
    except (KeyError, OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: unreadable checkpoint ({exc}); delete it or pass --no-resume") from None
