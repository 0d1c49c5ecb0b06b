"""A start-pose belief from the log itself, for logs that do not say where the robot started.

A simulated log carries its field and simulator config (``meta["config"]["start_pose"]``); a real
robot's log (e.g. one imported from MRCLAM) says nothing, and the default belief (field centre,
100 mm) may be metres off. ``initial_from_sightings`` estimates the first pose from the earliest
range-and-bearing sightings of known landmarks (NumPy only): a grid search over positions around
the landmarks (the heading at each position is the circular mean implied by the bearings), then
Gauss-Newton on (x, y, theta). The robot is taken as still over that short window: the covariance
is the Gauss-Newton one (J^T J)^-1, widened by the window's length, since the learner does not yet
know how fast the robot moves. Measured on the five MRCLAM robots (dt 0.1 s): 0.1-0.9 m and
0.1-0.8 rad from the true first pose, each within about 2 of its stated standard deviations.

A few sightings of landmarks close together can be explained from either side of them: MRCLAM robot 3's training
half (its first sightings in a held-out block) starts with three landmarks 0.35 m apart seen from 2.9 m while the robot
turns, and the window's best pose is their mirror image, 5.4 m off, outside the arena (robust cost 9.2 against 14.4
at Vicon's pose). ``pose_candidates`` therefore returns the window's distinct local minima (at most
``MAX_POSE_CANDIDATES``, ``MIN_SEPARATION_MM`` apart, best first), and the learner keeps the one the whole log agrees
with under the commands' face value (``learners.em.starts.chosen_start_pose``).

``initial_state_for(tr)`` picks the belief for one log:

1. the simulator's start pose when the log's meta says it (``config.start_pose``: a list of three),
   with the default spread: simulated logs behave as before;
2. the default belief when the log has a ``field`` (a simulated log without a fixed start);
3. otherwise the estimate from the sightings (range sensors), or the default when it fails.

``initial_state_candidates(tr)`` gives the same with every candidate of step 3, for the learner to choose from.
"""

from __future__ import annotations

import numpy as np

from aibo_core.geometry import wrap
from aibo_core.trajectory import Trajectory
from learners.model.initial import DEFAULT_INITIAL, InitialState

#: The first window must hold this many sightings of this many distinct landmarks.
MIN_SIGHTINGS, MIN_LANDMARKS = 6, 2
#: Shortest and longest window (s) of early sightings used.
MIN_WINDOW_S, MAX_WINDOW_S = 2.0, 20.0
#: Spreads assumed for the grid cost: relative range error (with a floor, mm) and bearing (rad).
RANGE_REL, RANGE_FLOOR_MM, BEARING_STD = 0.05, 100.0, 0.15
#: Start belief spread: position and heading std at a zero-length window, and their growth per second.
POS_STD_MM, POS_STD_PER_S = 250.0, 100.0
HEADING_STD, HEADING_STD_PER_S, MAX_HEADING_STD = 0.2, 0.2, 1.0
#: Candidates for the first pose (``pose_candidates``): at most this many, their positions at least this far apart (mm).
MAX_POSE_CANDIDATES, MIN_SEPARATION_MM = 3, 1000.0
#: The lowest grid minima examined for them (a flat cost holds many; MRCLAM robot 2's training half: 212 ms for all)
MAX_REFINED = 40


def _window(tr: Trajectory) -> np.ndarray | None:
    """Indices of the earliest sightings: the shortest window (>= MIN_WINDOW_S) from the first frame
    holding MIN_SIGHTINGS of MIN_LANDMARKS distinct landmarks; None when the first MAX_WINDOW_S do not."""
    if tr.n_sightings < MIN_SIGHTINGS:
        return None
    lo_frames = int(np.ceil(MIN_WINDOW_S / tr.dt))
    t = tr.sighting_frame
    for i in range(tr.n_sightings):
        if t[i] * tr.dt > MAX_WINDOW_S:
            return None
        n = max(i + 1, int(np.searchsorted(t, lo_frames, side="right")))
        if n >= MIN_SIGHTINGS and len(np.unique(tr.sighting_landmark[:n])) >= MIN_LANDMARKS:
            return np.arange(n)
    return None


def _cost(xy: np.ndarray, L: np.ndarray, r: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cost (G,), heading (G,)) of candidate positions xy (G, 2): robust (capped) squared residuals."""
    dx = L[None, :, 0] - xy[:, None, 0]
    dy = L[None, :, 1] - xy[:, None, 1]
    d = np.hypot(dx, dy)
    th_each = np.arctan2(dy, dx) - b[None, :]
    th = np.arctan2(np.sin(th_each).sum(axis=1), np.cos(th_each).sum(axis=1))
    sr = np.maximum(RANGE_REL * r, RANGE_FLOOR_MM)
    er = ((d - r[None, :]) / sr[None, :]) ** 2
    eb = (wrap(th_each - th[:, None]) / BEARING_STD) ** 2
    return np.minimum(er, 25.0).sum(axis=1) + np.minimum(eb, 25.0).sum(axis=1), th


def _jacobian(p: np.ndarray, L: np.ndarray, r: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(whitened residuals (2n,), Jacobian (2n, 3)) of ranges and bearings at pose p."""
    sr = np.maximum(RANGE_REL * r, RANGE_FLOOR_MM)
    dx, dy = L[:, 0] - p[0], L[:, 1] - p[1]
    q = dx**2 + dy**2
    d = np.sqrt(q)
    res = np.concatenate([(r - d) / sr, wrap(b - (np.arctan2(dy, dx) - p[2])) / BEARING_STD])
    J = np.concatenate([np.stack([-dx / d, -dy / d, np.zeros_like(d)], axis=1) / sr[:, None],
                        np.stack([dy / q, -dx / q, -np.ones_like(d)], axis=1) / BEARING_STD])
    return res, J


def _refine(p: np.ndarray, L: np.ndarray, r: np.ndarray, b: np.ndarray, iters: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on (x, y, theta) from p: (pose, covariance (J^T J)^-1)."""
    for _ in range(iters):
        res, J = _jacobian(p, L, r, b)
        step = np.linalg.lstsq(J, res, rcond=None)[0]
        p = p + step
        if np.abs(step[:2]).max() < 1.0 and abs(step[2]) < 1e-4:
            break
    _, J = _jacobian(p, L, r, b)
    return np.array([p[0], p[1], wrap(p[2])]), np.linalg.pinv(J.T @ J)


def _local_minima(cost: np.ndarray) -> np.ndarray:
    """Flat indices of the grid cells (cost shaped (nx, ny)) no higher than any of their 8 neighbours, lowest first."""
    padded = np.pad(cost, 1, constant_values=np.inf)
    nx, ny = cost.shape
    lowest = np.ones(cost.shape, bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                lowest &= cost <= padded[1 + dx:1 + dx + nx, 1 + dy:1 + dy + ny]
    idx = np.flatnonzero(lowest)
    return idx[np.argsort(cost.ravel()[idx], kind="stable")]


def pose_candidates(tr: Trajectory, grid_mm: float = 100.0,
                    most: int | None = None) -> list[InitialState]:
    """The first pose's candidates from the earliest sightings (range sensors only; module docstring): the grid's
    local minima of the robust cost, each refined by Gauss-Newton, at least ``MIN_SEPARATION_MM`` apart, best first,
    at most ``most`` (default ``MAX_POSE_CANDIDATES``); [] when the log does not allow it."""
    most = MAX_POSE_CANDIDATES if most is None else most
    if tr.sensor_kind != "range_mm":
        return []
    idx = _window(tr)
    if idx is None:
        return []
    L = tr.landmarks[tr.sighting_landmark[idx]]
    r, b = tr.sighting_value[idx, 0], tr.sighting_value[idx, 1]
    reach = float(r.max()) * 1.1 + grid_mm
    lo, hi = L.min(axis=0) - reach, L.max(axis=0) + reach
    gx, gy = np.arange(lo[0], hi[0], grid_mm), np.arange(lo[1], hi[1], grid_mm)
    xy = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
    parts = [_cost(chunk, L, r, b) for chunk in np.array_split(xy, max(1, len(xy) // 20000))]
    cost, th = np.concatenate([c for c, _ in parts]), np.concatenate([t for _, t in parts])
    w = float(tr.sighting_frame[idx[-1]] + 1) * tr.dt  # seconds from the start to the window's end
    pos = POS_STD_MM + POS_STD_PER_S * w
    head = min(HEADING_STD + HEADING_STD_PER_S * w, MAX_HEADING_STD)
    out: list[InitialState] = []
    for i in _local_minima(cost.reshape(len(gx), len(gy)))[:MAX_REFINED]:
        if len(out) == most:
            break
        if any(np.hypot(*(xy[i] - c.mean[:2])) < MIN_SEPARATION_MM for c in out):
            continue  # in a basin already found (a flat valley holds many grid minima): no refinement
        p, cov = _refine(np.array([xy[i, 0], xy[i, 1], th[i]]), L, r, b)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(cov))):
            continue
        if all(np.hypot(*(p[:2] - c.mean[:2])) >= MIN_SEPARATION_MM for c in out):
            out.append(InitialState(p, 0.5 * (cov + cov.T) + np.diag([pos**2, pos**2, head**2])))
    return out


def initial_from_sightings(tr: Trajectory, grid_mm: float = 100.0) -> InitialState | None:
    """The first pose estimated from the earliest sightings (range sensors only; module docstring): the best of
    ``pose_candidates``, or None when the log does not allow it."""
    found = pose_candidates(tr, grid_mm, most=1)
    return found[0] if found else None


def initial_state_candidates(tr: Trajectory) -> list[InitialState]:
    """The start beliefs for one log, best first (module docstring): the simulator's start, the default, or the
    sightings' ``pose_candidates`` (the default when there are none)."""
    start = (tr.meta.get("config") or {}).get("start_pose") if isinstance(tr.meta.get("config"), dict) else None
    if isinstance(start, (list, tuple)) and len(start) == 3:
        return [InitialState(np.asarray(start, float), DEFAULT_INITIAL.cov.copy())]
    if tr.field is not None:
        return [DEFAULT_INITIAL]
    return pose_candidates(tr) or [DEFAULT_INITIAL]


def initial_state_for(tr: Trajectory) -> InitialState:
    """The start belief for one log (module docstring: simulator start, default, or estimated): the first of
    ``initial_state_candidates``."""
    return initial_state_candidates(tr)[0]
