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

from aibo_core.atomic import save_npz
from aibo_core.npzfile import FileFormatError, read_npz
from learners.arrays.batch import Batch
from learners.em.fit import EMState
from learners.model.initial import InitialState
from learners.model.io import model_from_json, model_to_json
from learners.model.model import Model

FORMAT = "aibo-em-checkpoint/2"


def _model_text(model: Model) -> str:
    """The model's structure and values as JSON text (the exact arrays are stored beside it)."""
    return json.dumps({"format": "aibo-model/1", **model_to_json(model)}, sort_keys=True)


def _arrays(prefix: str, model: Model) -> dict[str, np.ndarray]:
    """Every parameter array, bit for bit (the JSON text keeps the structure; velocities = weights / dt
    would not round-trip exactly)."""
    out = {f"{prefix}.{c}.{p}": v for c, comp in model.components() for p, v in comp.values().items()}
    out[f"{prefix}.init_mean"] = np.array([s.mean for s in model.init])
    out[f"{prefix}.init_cov"] = np.array([s.cov for s in model.init])
    return out


def _restore(prefix: str, d: dict[str, np.ndarray], source: str) -> Model:
    model = model_from_json(json.loads(str(d[prefix])), source)
    for cname, comp in model.components():
        values = {p: (float(d[f"{prefix}.{cname}.{p}"]) if d[f"{prefix}.{cname}.{p}"].shape == ()
                      else d[f"{prefix}.{cname}.{p}"]) for p in comp.PARAMS}
        new = comp.with_values(**values)
        model = model.with_effect(new) if cname.startswith("effects.") else model.with_(**{cname: new})
    init = tuple(InitialState(m, c) for m, c in zip(d[f"{prefix}.init_mean"], d[f"{prefix}.init_cov"]))
    return model.with_(init=init)


def fingerprint(batch: Batch, start: Model, options_json: str) -> str:
    """SHA-256 over the data, the start model and the options."""
    h = hashlib.sha256()
    for a in (batch.frame_start, batch.actions, batch.controls, batch.sight_start, batch.sight_landmark,
              batch.sight_value, batch.landmarks, batch.sight_time):  # sight_time last: None for most logs
        if a is not None:
            h.update(np.ascontiguousarray(a).tobytes())
    h.update(_model_text(start).encode())
    h.update(options_json.encode())
    return h.hexdigest()


def save(path: str | os.PathLike, state: EMState, fp: str) -> None:
    scalars = {
        "format": FORMAT, "fingerprint": fp, "iteration": state.iteration, "best_loglik": state.best_loglik,
        "best_iteration": state.best_iteration, "pruned": state.pruned, "rng_state": state.rng_state,
        "converged": state.converged, "record_iteration": state.record_iteration, "starts": state.starts,
        "polishes": state.polishes, "setbacks": state.setbacks,
        "step_ref": state.step_ref, "angle_noise": state.angle_noise,
    }
    arrays = {"cur": np.array(_model_text(state.params)), "best": np.array(_model_text(state.best)),
              **_arrays("cur", state.params), **_arrays("best", state.best)}
    arrays["loglik"] = np.asarray(state.loglik, float)
    arrays["seconds"] = np.asarray(state.seconds, float)
    arrays["used"] = state.used
    arrays["scalars"] = np.array(json.dumps(scalars))
    save_npz(path, arrays)


def load(path: str | os.PathLike, fp: str) -> EMState | None:
    """The saved state if ``path`` exists and matches ``fp``; None if absent; ValueError if it mismatches."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        d = read_npz(path)
        scalars = json.loads(str(d["scalars"]))
        if scalars.get("format") != FORMAT:
            raise ValueError(f"{path}: not an EM checkpoint")
        if scalars["fingerprint"] != fp:
            raise ValueError(f"{path}: checkpoint is for other logs, start model or options "
                             "(delete it or pass --no-resume)")
        best_ll = float(scalars["best_loglik"])
        return EMState(
            iteration=int(scalars["iteration"]), params=_restore("cur", d, str(path)),
            best=_restore("best", d, str(path)),
            best_loglik=best_ll, best_iteration=int(scalars["best_iteration"]),
            loglik=d["loglik"].tolist(), used=d["used"].astype(bool), pruned=int(scalars["pruned"]),
            rng_state=scalars["rng_state"], converged=bool(scalars["converged"]), seconds=d["seconds"].tolist(),
            record_iteration=int(scalars["record_iteration"]), starts=list(scalars.get("starts", [])),
            polishes=int(scalars.get("polishes", 0)), setbacks=list(scalars.get("setbacks", [])),
            step_ref=scalars.get("step_ref"), angle_noise=scalars.get("angle_noise"),
        )
    except (FileFormatError, KeyError, TypeError, OSError, json.JSONDecodeError, ValueError) as exc:
        if str(exc).startswith(f"{path}: checkpoint is for other"):
            raise
        raise ValueError(f"{path}: broken checkpoint ({str(exc)[:200]}); pass --no-resume to start over") from None
