"""Likelihood scans of two motion noises the model lacks, per MRCLAM Dataset 7 robot: the forward likelihood of the
sightings under ``aibo learn``'s whole-log model (defaults), the model held (a scan, not a fit).

Does the heading's noise in turns persist? The model with one more state beside the pose: an error of the turn's gain
that persists as an AR(1) process, b' = exp(-dt / tau) b + N(0, sigma^2 (1 - exp(-2 dt / tau))), each frame turning
dtheta (1 + b) for the model's dtheta. A short tau is a white noise that grows with the turn (``turn_heading_noise``'s
form), a long one a slowly wandering gain; the model's own heading noise (a variance factor ``c`` on it) may make
room for it. Does a robot told to stand still move less than the model says? Its motion noise times ``k`` on the
frames whose commanded displacement is zero (the lag included), with the NIS's median (chi-square(2)'s: 1.386).

A sighting more than 30 squared Mahalanobis units off the prediction of the model as fitted (another robot, a
misread barcode) is left out of every row alike.

    python scripts/mrclam_motion_scans.py [DATA] [--robots 1,2,3,4,5]

Prints per robot the gain in log-likelihood over the model as fitted: for the turn's gain the best (sigma, c) per
correlation time (every row on stderr), for standing still each k. DATA defaults to ../shared/data/mrclam7 (never
copied into the repository). The reference NumPy filter, a few seconds per row.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import data_folder, mrclam_parser, robots  # noqa: E402

from aibo_core import geometry  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402
from learners.arrays.batch import make_batch  # noqa: E402
from learners.arrays.lowered import Lowered, sighting_model  # noqa: E402
from learners.em.learner import EMLearner  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402
from learners.inference.reference import AIBO_ANGLE_MASK, forward_pass  # noqa: E402

GATE = 30.0  # squared Mahalanobis units: a sighting beyond it under the model without the state is left out of every row
SIGMAS = (0.05, 0.1, 0.2, 0.4, 0.8)  # the gain error's stationary sd (1 = 100% of the turn)
TAUS_S = (0.1, 0.5, 2.0, 8.0)  # its correlation time (s)
HEADING_FACTORS = (1.0, 0.5, 0.25)  # c: the factor on the model's own heading noise variance
STILL_FACTORS = (0.3, 0.1, 0.03)  # k: the factor on the motion noise's variance while told to stand still


def forward_pass_of(lo: Lowered, batch, used: np.ndarray, dt: float, sigma: float = 0.0, tau: float = 1.0,
                    c: float = 1.0, k: float = 1.0, gate: float | None = None):
    """The forward filter of the one log of ``batch`` on its sightings ``used``, with the gain state (sigma 0:
    without it) and the noise factors c (heading) and k (standing still)."""
    n = 4 if sigma > 0 else 3
    phi = float(np.exp(-dt / tau))
    sig_a = lo.shaped_cov(slice(0, batch.n_frames)).copy()
    sig_a[:, 2, :] *= np.sqrt(c)
    sig_a[:, :, 2] *= np.sqrt(c)
    sig_a[np.all(lo.disp == 0.0, axis=1)] *= k

    def motion(i, mean):
        b = mean[3] if n == 4 else 0.0
        d = lo.disp[i] * np.array([1.0, 1.0, 1.0 + b])
        g3, F3, R3 = geometry.motion(mean[:3], d)
        Q3 = lo.cov_scale[i] * (R3 @ sig_a[i] @ R3.T)
        if n == 3:
            return g3 + lo.offset[i], F3, Q3
        F, Q = np.zeros((4, 4)), np.zeros((4, 4))
        F[:3, :3], F[3, 3], F[2, 3] = F3, phi, lo.disp[i, 2]
        Q[:3, :3], Q[3, 3] = Q3, sigma**2 * (1.0 - phi**2)
        return np.concatenate([g3 + lo.offset[i], [phi * b]]), F, Q

    def observe(j, mean):
        if not used[j]:
            return None
        h, H3, rd = sighting_model(lo, mean[None, :3], batch.sight_xy[j : j + 1], np.array([j]))
        H = np.zeros((2, n))
        H[:, :3] = H3[0]
        return h[0], H, np.diag(rd[0]), batch.sight_value[j], AIBO_ANGLE_MASK

    m0, P0 = np.zeros(n), np.zeros((n, n))
    m0[:3], P0[:3, :3] = lo.init_mean[0], lo.init_cov[0]
    if n == 4:
        P0[3, 3] = sigma**2
    return forward_pass(m0, P0, batch.sight_start[: batch.n_frames + 1], motion, observe, gate)


def robot_rows(tr, sigmas=SIGMAS, taus_s=TAUS_S, heading_factors=HEADING_FACTORS, still_factors=STILL_FACTORS
               ) -> tuple[list[tuple[float, float, float, float]], list[tuple[float, float, float]], float, float]:
    """The scans of one log under learn's model of it: (the turn gain's rows: (sigma, tau s, c, gain in nats over the
    model as fitted), standing still's: (k, gain, the NIS's median), the share of frames told to stand still, the
    model's NIS median)."""
    model = EMLearner(EMOptions(uncertainty=False), check_field=False).fit([tr]).params
    batch = make_batch([tr])
    lo = model.lower(batch)
    if lo.extra is not None:
        raise SystemExit("mrclam_motion_scans.py: learn's model holds extra states; these scans support the pose alone")
    first = forward_pass_of(lo, batch, batch.used, tr.dt, gate=GATE)
    used = batch.used & first.applied  # one set of sightings for every row (a gate per row would score others)
    base = forward_pass_of(lo, batch, used, tr.dt)
    turn = [(s, t, c, forward_pass_of(lo, batch, used, tr.dt, s, t, c).loglik - base.loglik)
            for s in sigmas for t in taus_s for c in heading_factors]
    still = []
    for k in still_factors:
        fw = forward_pass_of(lo, batch, used, tr.dt, k=k)
        still.append((k, fw.loglik - base.loglik, float(np.median(fw.mahal2[used]))))
    return turn, still, float(np.mean(np.all(lo.disp == 0.0, axis=1))), float(np.median(base.mahal2[used]))


def main(argv: list[str] | None = None) -> int:
    args = mrclam_parser(__doc__, "").parse_args(argv)
    data = data_folder("mrclam_motion_scans.py", args.data)
    if data is None:
        return 1
    turn_table = ["| robot | " + " | ".join(f"best at tau {t:g} s: nats (sigma, c)" for t in TAUS_S) + " |",
                  "|---|" + "---|" * len(TAUS_S)]
    still_table = ["| robot | frames told to stand still | NIS median | " + " | ".join(
        f"k {k:g}: nats, NIS median" for k in STILL_FACTORS) + " |", "|---|---|---|" + "---|" * len(STILL_FACTORS)]
    for r in robots(args.robots):
        turn, still, share, median = robot_rows(import_robot(data, r))
        for s, t, c, gain in turn:
            print(f"  robot {r}: sigma {s:g}, tau {t:g} s, c {c:g}: {gain:+.1f} nats", file=sys.stderr, flush=True)
        best = [max((row for row in turn if row[1] == t), key=lambda row: row[3]) for t in TAUS_S]
        turn_table.append(f"| {r} | " + " | ".join(f"{b[3]:+.0f} ({b[0]:g}, {b[2]:g})" for b in best) + " |")
        still_table.append(f"| {r} | {share:.1%} | {median:.3f} | "
                           + " | ".join(f"{g:+.0f}, {m:.3f}" for _, g, m in still) + " |")
    print("\n".join(turn_table + [""] + still_table))
    return 0


if __name__ == "__main__":
    sys.exit(main())
