"""The log file every learner reads: ``aibo-trajectory/1`` (a NumPy ``.npz``).

This module is the contract between robots (simulated or real) and learners.
It depends on NumPy only, so learners can read logs without the simulator.

Keys (T frames, B beacons):

===========  ===============  ==================================================
key          shape, type      meaning
===========  ===============  ==================================================
format       str              ``"aibo-trajectory/1"``
dt           float            seconds per frame (> 0)
actions      (T,) int         action executed during frame t (pose t -> t+1)
obs          (T, 2) float     sighting at the end of frame t: [height px,
                              angle rad]; NaN row when none
beacon       (T,) int         index into ``beacons`` of the beacon seen, -1 none
head_pan     (T,) float       head pan (rad, relative to the body), end of t
beacons      (B, 2) float     beacon positions, mm
field        (2,) float       field length and width, mm
attempted    (40, 3) float    attempted normalized velocities per action
pose         (T+1, 3) float   optional: true pose (x mm, y mm, theta rad)
meta         str              optional JSON: generator, seed, config, truth
===========  ===============  ==================================================
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "aibo-trajectory/1"
N_ACTIONS = 40
REQUIRED = ("format", "dt", "actions", "obs", "beacon", "head_pan", "beacons", "field", "attempted")
OPTIONAL = ("pose", "meta")


class TrajectoryError(ValueError):
    """A log file that does not follow aibo-trajectory/1. The message names file and field."""


@dataclass
class Trajectory:
    """One log: T frames of actions and sightings (see the module docstring for units)."""

    dt: float
    actions: np.ndarray
    obs: np.ndarray
    beacon: np.ndarray
    head_pan: np.ndarray
    beacons: np.ndarray
    field: np.ndarray
    attempted: np.ndarray
    pose: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.actions.shape[0])

    @property
    def truth(self) -> dict[str, Any] | None:
        """Ground truth of a simulated log (``meta["truth"]``), or None for real/blind logs."""
        return self.meta.get("truth")

    def validate(self, source: str = "<trajectory>") -> "Trajectory":
        """Check shapes, dtypes and ranges; raise TrajectoryError naming ``source`` and the field."""
        _validate(self, source)
        return self


def _fail(source: str, key: str, what: str) -> None:
    raise TrajectoryError(f"{source}: field '{key}': {what}")


def _check_float(source: str, key: str, a: np.ndarray, shape: tuple, allow_nan: bool = False) -> None:
    if a.dtype.kind not in "fiu":
        _fail(source, key, f"expected numbers, got dtype {a.dtype}")
    if a.shape != shape:
        _fail(source, key, f"expected shape {shape}, got {a.shape}")
    bad = np.isinf(a) if allow_nan else ~np.isfinite(a)
    if np.any(bad):
        idx = np.argwhere(bad)[0].tolist()
        _fail(source, key, f"{'infinite' if allow_nan else 'non-finite'} value at index {idx}")


def _check_int(source: str, key: str, a: np.ndarray, shape: tuple, lo: int, hi: int) -> None:
    if a.dtype.kind not in "iu":
        _fail(source, key, f"expected integers, got dtype {a.dtype}")
    if a.shape != shape:
        _fail(source, key, f"expected shape {shape}, got {a.shape}")
    out = (a < lo) | (a > hi)
    if np.any(out):
        i = int(np.argmax(out))
        _fail(source, key, f"value {int(a[i])} at index {i} outside {lo}..{hi}")


def _validate(tr: Trajectory, source: str) -> None:
    if not (np.isfinite(tr.dt) and tr.dt > 0):
        _fail(source, "dt", f"must be a positive number of seconds, got {tr.dt}")
    if tr.actions.ndim != 1:
        _fail(source, "actions", f"expected shape (T,), got {tr.actions.shape}")
    T = tr.actions.shape[0]
    if T < 1:
        _fail(source, "actions", "log has no frames")
    _check_int(source, "actions", tr.actions, (T,), 0, N_ACTIONS - 1)
    if tr.beacons.ndim != 2 or tr.beacons.shape[1] != 2:
        _fail(source, "beacons", f"expected shape (B, 2), got {tr.beacons.shape}")
    B = tr.beacons.shape[0]
    _check_float(source, "beacons", tr.beacons, (B, 2))
    if B < 1:
        _fail(source, "beacons", "needs at least one beacon")
    _check_int(source, "beacon", tr.beacon, (T,), -1, B - 1)
    _check_float(source, "obs", tr.obs, (T, 2), allow_nan=True)
    seen = tr.beacon >= 0
    nan_rows = np.isnan(tr.obs).any(axis=1)
    mismatch = seen == nan_rows
    if np.any(mismatch):
        i = int(np.argmax(mismatch))
        what = "NaN sighting for a seen beacon" if seen[i] else "a sighting where beacon is -1"
        _fail(source, "obs", f"row {i}: {what} (obs must be NaN exactly where beacon == -1)")
    _check_float(source, "head_pan", tr.head_pan, (T,))
    _check_float(source, "field", tr.field, (2,))
    if np.any(tr.field <= 0):
        _fail(source, "field", f"length and width must be positive, got {tr.field.tolist()}")
    _check_float(source, "attempted", tr.attempted, (N_ACTIONS, 3))
    if tr.pose is not None:
        _check_float(source, "pose", tr.pose, (T + 1, 3))


def _as_str(source: str, key: str, value: np.ndarray) -> str:
    if value.dtype.kind not in "US" or value.shape != ():
        _fail(source, key, f"expected a string, got dtype {value.dtype} shape {value.shape}")
    return str(value)


def load(path: str | os.PathLike) -> Trajectory:
    """Read and validate an aibo-trajectory/1 file. Raises TrajectoryError on any problem."""
    source = str(path)
    try:
        with open(path, "rb") as f:
            if f.read(4) != b"PK\x03\x04":
                raise TrajectoryError(f"{source}: not an .npz file (no zip signature)")
        npz = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise TrajectoryError(f"{source}: file not found") from None
    except IsADirectoryError:
        raise TrajectoryError(f"{source}: is a folder, not a log file") from None
    except TrajectoryError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise TrajectoryError(f"{source}: not a readable .npz file ({exc})") from None
    with npz:
        keys = set(npz.files)
        for key in REQUIRED:
            if key not in keys:
                _fail(source, key, "missing")
        unknown = keys - set(REQUIRED) - set(OPTIONAL)
        if unknown:
            _fail(source, sorted(unknown)[0], f"unknown key (allowed: {', '.join(REQUIRED + OPTIONAL)})")
        try:
            data = {k: npz[k] for k in keys}
        except ValueError as exc:  # object arrays need pickle, which we refuse
            raise TrajectoryError(f"{source}: cannot read arrays ({exc})") from None
    fmt = _as_str(source, "format", data["format"])
    if fmt != FORMAT:
        _fail(source, "format", f"expected '{FORMAT}', got '{fmt}'")
    dt = data["dt"]
    if dt.shape != () or dt.dtype.kind not in "fiu":
        _fail(source, "dt", f"expected a scalar number, got dtype {dt.dtype} shape {dt.shape}")
    meta: dict[str, Any] = {}
    if "meta" in data:
        text = _as_str(source, "meta", data["meta"])
        try:
            meta = json.loads(text)
        except json.JSONDecodeError as exc:
            _fail(source, "meta", f"not valid JSON ({exc.msg} at char {exc.pos})")
        if not isinstance(meta, dict):
            _fail(source, "meta", "must be a JSON object")
    tr = Trajectory(
        dt=float(dt),
        actions=data["actions"],
        obs=data["obs"],
        beacon=data["beacon"],
        head_pan=data["head_pan"],
        beacons=data["beacons"],
        field=data["field"],
        attempted=data["attempted"],
        pose=data.get("pose"),
        meta=meta,
    )
    tr.validate(source)
    tr.actions = tr.actions.astype(np.int64)
    tr.beacon = tr.beacon.astype(np.int64)
    for name in ("obs", "head_pan", "beacons", "field", "attempted"):
        setattr(tr, name, getattr(tr, name).astype(np.float64))
    if tr.pose is not None:
        tr.pose = tr.pose.astype(np.float64)
    return tr


def blind(tr: Trajectory) -> Trajectory:
    """The same log as a real robot would have it: no ``pose`` and no ``truth`` in meta."""
    meta = {k: v for k, v in tr.meta.items() if k != "truth"}
    return Trajectory(tr.dt, tr.actions, tr.obs, tr.beacon, tr.head_pan, tr.beacons, tr.field, tr.attempted, None, meta)


def save(tr: Trajectory, path: str | os.PathLike) -> None:
    """Validate and write ``tr`` atomically: a failed write leaves any existing file untouched."""
    path = Path(path)
    tr.validate(str(path))
    arrays: dict[str, Any] = {
        "format": np.array(FORMAT),
        "dt": np.array(float(tr.dt)),
        "actions": np.asarray(tr.actions, dtype=np.int64),
        "obs": np.asarray(tr.obs, dtype=np.float64),
        "beacon": np.asarray(tr.beacon, dtype=np.int64),
        "head_pan": np.asarray(tr.head_pan, dtype=np.float64),
        "beacons": np.asarray(tr.beacons, dtype=np.float64),
        "field": np.asarray(tr.field, dtype=np.float64),
        "attempted": np.asarray(tr.attempted, dtype=np.float64),
    }
    if tr.pose is not None:
        arrays["pose"] = np.asarray(tr.pose, dtype=np.float64)
    if tr.meta:
        arrays["meta"] = np.array(json.dumps(tr.meta, sort_keys=True))
    atomic_write(path, lambda f: _write_npz(f, arrays))


def _write_npz(f, arrays: dict[str, np.ndarray]) -> None:
    """Like ``np.savez_compressed`` but with fixed zip timestamps: same content, same bytes."""
    with zipfile.ZipFile(f, mode="w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key, value in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)


def atomic_write(path: str | os.PathLike, write) -> None:
    """Call ``write(fileobj)`` on a temp file beside ``path`` and rename it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file its usual mode
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
