"""Synthetic logs for the inference tests, built directly as (Batch, Lowered) with no env package.

``simulate`` draws true poses from the lowered motion model (per-frame disp, offset, cov scale) and
sightings from the lowered sensor model (per-sighting size scale/offset/variance factor, bearing
offset, the curve in either basis), any number per frame; ``case`` builds named, deterministic
test cases covering the brief: several logs of different lengths (including 1 and 0 frames), gaps
without sightings, frames with several sightings, bearings near +-pi, headings winding several
turns, gross outliers, non-zero offsets, cov scales and per-sighting effects, the inverse-distance
basis, and the plain one-hot table + cubic model.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.lowered import BASIS_INVERSE, BASIS_POWER, Lowered

DT = 1.0 / 30.0
N_ACTIONS = 40
LANDMARKS = np.array([[-2900.0, -2000.0], [0.0, -2000.0], [2900.0, -2000.0],
                      [-2900.0, 2000.0], [0.0, 2000.0], [2900.0, 2000.0]])  # fmt: skip
GATE = 13.8


def wrap(a):
    return a - 2 * np.pi * np.ceil((a - np.pi) / (2 * np.pi))


def rot3(th):
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pinhole_coef(basis: int, degree: int = 3) -> np.ndarray:
    """Curve coefficients close to size = 57000 / d (px) in the given basis."""
    d = np.linspace(900.0, 5500.0, 200)
    x = d if basis == BASIS_POWER else 1.0 / d
    return np.polynomial.polynomial.polyfit(x, 57000.0 / d, degree)


def true_table(rng) -> np.ndarray:
    """(40, 3) per-frame displacements: up to ~22 mm/frame forward, 8 sideways, -0.05..0.15 rad/frame."""
    d = np.zeros((N_ACTIONS, 3))
    d[:, 0] = rng.uniform(-12.0, 22.0, N_ACTIONS)
    d[:, 1] = rng.uniform(-8.0, 8.0, N_ACTIONS)
    d[:, 2] = rng.uniform(-0.05, 0.15, N_ACTIONS)  # biased: the heading winds several turns
    d[0] = 0.0
    return d


def simulate(rng, lengths, table, *, effects=False, basis=BASIS_POWER, max_per_frame=1, gaps=None, outliers=0,
             behind=0.1, seg=30, sigma=(0.8, 0.03), motion_std=(2.0, 2.0, 0.01)):
    """(batch, lowered_true, true poses (P, 3)) for logs of the given lengths.

    ``effects``: random per-frame offsets / cov scales, per-component noise factors (``cov_sd``: a fixed pattern, no
    random draw) and per-sighting size scale / offset /
    variance factor / bearing offset (else the plain model). ``max_per_frame``: each frame has
    0..max_per_frame sightings (70 % of frames at least one). ``gaps[k]``: frame ranges of log k
    without sightings. ``outliers``: sightings made gross outliers per log.
    """
    coef = pinhole_coef(basis)
    n_tot = int(sum(lengths))
    frame_start = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    actions = np.empty(n_tot, np.int64)
    poses, starts = [], []
    counts = np.zeros(n_tot, np.int64)
    s_lm, s_val = [], []
    offset = np.zeros((n_tot, 3))
    scale = np.ones(n_tot)
    sd = np.ones((n_tot, 3))
    if effects:
        offset = rng.normal(0.0, [1.5, 1.5, 0.004], (n_tot, 3))
        scale = rng.uniform(0.5, 2.0, n_tot)
        t = np.arange(n_tot)
        sd = np.stack([1.2 + 0.5 * np.sin(t / 7.0), 0.8 + 0.3 * np.cos(t / 5.0), 1.3 + 0.7 * np.sin(t / 11.0)], axis=1)
    sc_list, so_list, vf_list, bo_list = [], [], [], []
    for k, n in enumerate(lengths):
        f0 = frame_start[k]
        pose = np.array([rng.uniform(-800, 800), rng.uniform(-500, 500), rng.uniform(-np.pi, np.pi)])
        starts.append(pose.copy())
        poses.append(pose.copy())
        a = 0
        gap_mask = np.zeros(n, bool)
        for g0, g1 in (gaps[k] if gaps else ()):
            gap_mask[g0:g1] = True
        for j in range(n):
            i = f0 + j
            if j % seg == 0:  # among random candidates, the action keeping the robot nearest the centre
                cand = rng.integers(0, N_ACTIONS, 8)
                best, best_d = cand[0], np.inf
                for c in cand:
                    p = pose.copy()
                    for _ in range(seg):
                        p = p + rot3(p[2]) @ table[c]
                    dd = abs(p[0]) / 2200 + abs(p[1]) / 1400
                    if dd < best_d:
                        best, best_d = c, dd
                a = int(best)
            actions[i] = a
            noise = rng.normal(0.0, motion_std) * math.sqrt(scale[i]) * sd[i]
            pose = pose + rot3(pose[2]) @ (table[a] + noise) + offset[i]
            poses[-1] = np.vstack([poses[-1], pose])
            if gap_mask[j] or rng.random() >= 0.7:
                continue
            m = int(rng.integers(1, max_per_frame + 1))
            counts[i] = m
            for _ in range(m):
                if rng.random() < behind:  # the landmark most nearly behind the robot: bearing near +-pi
                    brg = wrap(np.arctan2(LANDMARKS[:, 1] - pose[1], LANDMARKS[:, 0] - pose[0]) - pose[2])
                    b = int(np.argmax(np.abs(brg)))
                else:
                    b = int(rng.integers(0, len(LANDMARKS)))
                sc, so, vf, bo = 1.0, 0.0, 1.0, 0.0
                if effects:
                    sc, so, vf, bo = rng.uniform(0.8, 1.25), rng.normal(0, 2.0), rng.uniform(0.5, 3.0), rng.normal(0, 0.05)
                dx, dy = LANDMARKS[b] - pose[:2]
                d = math.hypot(dx, dy)
                x = d if basis == BASIS_POWER else 1.0 / d
                size = sc * np.polynomial.polynomial.polyval(x, coef) + so + rng.normal(0, sigma[0] * math.sqrt(vf))
                brg = wrap(math.atan2(dy, dx) - pose[2] + bo + rng.normal(0, sigma[1]))
                s_lm.append(b)
                s_val.append((size, brg))
                sc_list.append(sc), so_list.append(so), vf_list.append(vf), bo_list.append(bo)
    s_val = np.array(s_val, float).reshape(-1, 2)
    sight_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    # outliers: per log, among its sightings
    for k in range(len(lengths)):
        a0, a1 = sight_start[frame_start[k]], sight_start[frame_start[k + 1]]
        m = min(outliers, a1 - a0)
        if m:
            bad = rng.choice(np.arange(a0, a1), m, replace=False)
            s_val[bad, 0] += rng.choice([-1, 1], m) * rng.uniform(20, 40, m)
            s_val[bad[::2], 1] = wrap(s_val[bad[::2], 1] + rng.uniform(1.5, 3.0, len(bad[::2])))
    s_lm = np.array(s_lm, np.int64)
    S = len(s_lm)
    batch = Batch(frame_start=frame_start, dt=DT, actions=actions, controls=None, sight_start=sight_start,
                  sight_landmark=s_lm, sight_xy=np.ascontiguousarray(LANDMARKS[s_lm].reshape(-1, 2)),
                  sight_value=s_val, used=np.ones(S, bool), landmarks=LANDMARKS.copy())  # fmt: skip
    lo = Lowered(
        disp=table[actions].copy(), offset=offset, cov=np.diag(np.square(motion_std)), cov_scale=scale, cov_sd=sd,
        basis=basis,
        coef=coef, sigma_size=sigma[0], sigma_bearing=sigma[1], size_scale=np.array(sc_list, float),
        size_offset=np.array(so_list, float), size_var_factor=np.array(vf_list, float),
        bearing_offset=np.array(bo_list, float), init_mean=np.array(starts).reshape(-1, 3),
        init_cov=np.broadcast_to(np.diag([100.0**2, 100.0**2, 0.1**2]), (len(lengths), 3, 3)).copy(),
    )
    return batch, lo, np.vstack(poses)


def perturbed(rng, lo: Lowered, batch: Batch, *, zero_disp=False, learned_cov=False) -> Lowered:
    """A model near the truth (the one inference runs with): perturbed disp, curve and start beliefs
    (log k's start heading offset by 2 pi k), a larger motion noise."""
    n_act = N_ACTIONS
    table = lo.disp  # per frame
    if zero_disp:
        disp = np.zeros_like(table)
    else:
        # perturb per action (so that frames of one action share a prior, like the table)
        pert_a = 1 + 0.05 * rng.standard_normal((n_act, 3))
        add_a = 0.3 * rng.standard_normal((n_act, 3)) * [1, 1, 0.01]
        disp = table * pert_a[batch.actions] + add_a[batch.actions]
    cov = np.diag([10.0**2, 10.0**2, 0.1**2])
    if learned_cov:
        A = rng.standard_normal((3, 3)) * [3.0, 3.0, 0.01]
        cov = np.diag([4.0, 4.0, 1e-4]) + A @ A.T
    L = len(lo.init_mean)
    init_mean = lo.init_mean + rng.normal(0, [50.0, 50.0, 0.05], (L, 3)) + np.outer(np.arange(L), [0, 0, 2 * np.pi])
    return Lowered(
        disp=np.ascontiguousarray(disp), offset=lo.offset.copy(), cov=cov, cov_scale=lo.cov_scale.copy(),
        cov_sd=lo.cov_sd.copy(),
        basis=lo.basis, coef=lo.coef * (1 + 0.002 * rng.standard_normal(len(lo.coef))), sigma_size=1.0,
        sigma_bearing=0.04, size_scale=lo.size_scale.copy(), size_offset=lo.size_offset.copy(),
        size_var_factor=lo.size_var_factor.copy(), bearing_offset=lo.bearing_offset.copy(),
        init_mean=init_mean, init_cov=lo.init_cov.copy(),
    )


CASES = ["multi", "zero_actions", "learned_cov", "several", "effects", "inverse"]


@lru_cache(maxsize=None)
def case(name: str):
    """(lowered model to run, batch, true poses) for a named case; deterministic. Do not mutate."""
    rng = np.random.default_rng(sum(map(ord, name)))
    table = true_table(rng)
    if name == "multi":  # one-hot table + cubic, one sighting per frame: three logs, long gaps, outliers
        batch, lo, pose = simulate(rng, [900, 350, 1300], table, gaps=[[(100, 400)], [], [(200, 450), (800, 1100)]],
                                   outliers=4)  # fmt: skip
        return perturbed(rng, lo, batch), batch, pose
    if name == "zero_actions":  # the paper's start: all displacements zero
        batch, lo, pose = simulate(rng, [700, 500], table, gaps=[[(50, 300)], [(0, 120)]], outliers=3)
        return perturbed(rng, lo, batch, zero_disp=True), batch, pose
    if name == "learned_cov":  # non-diagonal Sigma_A; logs of 1 and 0 frames; a log without sightings
        batch, lo, pose = simulate(rng, [800, 1, 0, 40], table, gaps=[[(300, 650)], [], [], [(0, 40)]], outliers=4)
        return perturbed(rng, lo, batch, learned_cov=True), batch, pose
    if name == "several":  # up to 3 sightings per frame
        batch, lo, pose = simulate(rng, [600, 450], table, max_per_frame=3, gaps=[[(100, 250)], []], outliers=5)
        return perturbed(rng, lo, batch, learned_cov=True), batch, pose
    if name == "effects":  # offsets, cov scales, per-sighting effects, several sightings per frame
        batch, lo, pose = simulate(rng, [700, 300], table, effects=True, max_per_frame=3, gaps=[[(200, 330)], []],
                                   outliers=4)  # fmt: skip
        return perturbed(rng, lo, batch, learned_cov=True), batch, pose
    if name == "inverse":  # the inverse-distance basis, with effects
        batch, lo, pose = simulate(rng, [500, 400], table, effects=True, basis=BASIS_INVERSE, max_per_frame=2,
                                   outliers=3)  # fmt: skip
        return perturbed(rng, lo, batch), batch, pose
    raise KeyError(name)
