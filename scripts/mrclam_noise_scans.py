"""Likelihood scans of noises the model lacks, per MRCLAM Dataset 7 robot: the forward likelihood of the sightings
under ``aibo learn``'s whole-log model (defaults) with one form added, the model held (a scan, not a fit).

- **Does the heading's noise in turns persist?** One more state beside the pose, an error of the turn's gain that
  persists as an AR(1) process, b' = exp(-dt / tau) b + N(0, sigma^2 (1 - exp(-2 dt / tau))), each frame turning
  dtheta (1 + b) for the model's dtheta. A short tau is a white noise that grows with the turn
  (``turn_heading_noise``'s form), a long one a slowly wandering gain; the model's own heading noise (a variance
  factor ``c`` on it) may make room for it.
- **Does a robot told to stand still move less than the model says?** Its motion noise's variance times ``k`` on the
  frames whose commanded displacement is zero (the lag included), with the NIS's median (chi-square(2)'s: 1.386).
- **Do the bearings carry a bias per landmark that persists?** One state per landmark added to its bearings, the same
  AR(1) process (sd ``sigma_b`` rad, correlation time ``tau_b``; a long one is a fixed offset per landmark,
  ``landmark_bearing_offset``'s form), the model's bearing noise variance times ``s`` to make room for it.
- **And the sizes (ranges)?** The same per landmark on the size, multiplying it by (1 + b) (``landmark_bias``' form: sd
  ``sigma_r``, correlation time ``tau_r``; a long one is a fixed scale per landmark, ``beacon_height_scale``'s), the
  size noise variance times ``r``.

A sighting more than 30 squared Mahalanobis units off the prediction of the model as fitted (another robot, a
misread barcode) is left out of every row alike.

    python scripts/mrclam_noise_scans.py [DATA] [--robots 1,2,3,4,5] [--png docs/img/mrclam_noise_scans.png]

Prints per robot the gain in log-likelihood over the model as fitted: the best of each grid per correlation time
(every row on stderr), for standing still each k, and the best turn and bearing forms together; ``--png``: the best
gain against the correlation time, per robot, for the turn, the bearings and the sizes. DATA defaults to
../shared/data/mrclam7 (never copied into the repository). The reference NumPy filter, a few seconds per row.
"""

from __future__ import annotations

import sys
from dataclasses import asdict, dataclass, replace
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
from learners.inference.reference import AIBO_ANGLE_MASK, ForwardResult, forward_pass  # noqa: E402
from learners.model.landmark_bias import ar1_step  # noqa: E402

GATE = 30.0  # squared Mahalanobis units: a sighting beyond it under the model as fitted is left out of every row
SIGMAS = (0.05, 0.1, 0.2, 0.4, 0.8)  # the turn gain error's stationary sd (1 = 100% of the turn)
TAUS_S = (0.1, 0.5, 2.0, 8.0)  # its correlation time (s)
HEADING_FACTORS = (1.0, 0.5, 0.25)  # c: the factor on the model's own heading noise variance
STILL_FACTORS = (0.3, 0.1, 0.03)  # k: the factor on the motion noise's variance while told to stand still
BEARING_SIGMAS = (0.003, 0.006, 0.012)  # the bearing bias's stationary sd (rad)
BEARING_TAUS_S = (1.0, 5.0, 20.0, 100.0, 1000.0)  # its correlation time (s)
BEARING_FACTORS = (1.0, 0.5)  # s: the factor on the model's bearing noise variance
SIZE_SIGMAS = (0.005, 0.01, 0.02, 0.05)  # the size bias's stationary sd (relative)
SIZE_TAUS_S = BEARING_TAUS_S  # its correlation time (s)
SIZE_FACTORS = (1.0, 0.5)  # r: the factor on the model's size noise variance


@dataclass(frozen=True)
class Form:
    """What one row adds to the model (the defaults: nothing)."""

    sigma: float = 0.0  # the turn gain state's sd (0: no state)
    tau: float = 1.0  # its correlation time (s)
    c: float = 1.0  # the factor on the heading noise's variance
    k: float = 1.0  # the factor on the motion noise's variance while told to stand still
    sigma_b: float = 0.0  # the bearing bias states' sd (rad; 0: no states)
    tau_b: float = 1.0  # their correlation time (s)
    s: float = 1.0  # the factor on the bearing noise's variance
    sigma_r: float = 0.0  # the size bias states' sd (relative; 0: no states)
    tau_r: float = 1.0  # their correlation time (s)
    r: float = 1.0  # the factor on the size noise's variance

    def label(self) -> str:
        """The fields that differ from the defaults, each state's correlation time with it, e.g. "sigma 0.4, tau 0.1,
        c 0.25"."""
        states = {"tau": self.sigma, "tau_b": self.sigma_b, "tau_r": self.sigma_r}
        return ", ".join(f"{k} {v:g}" for k, v in asdict(self).items() if v != getattr(Form, k) or states.get(k, 0) > 0)


def told_to_stand_still(lo: Lowered) -> np.ndarray:
    """(N,) bool: the frames whose commanded displacement is zero (the lag included)."""
    return np.all(lo.disp == 0.0, axis=1)


def forward_pass_of(lo: Lowered, batch, landmark: np.ndarray, used: np.ndarray, dt: float, form: Form = Form(),
                    gate: float | None = None) -> ForwardResult:
    """The forward filter of the one log of ``batch`` on its sightings ``used`` with ``form`` added; ``landmark``
    (S,): each sighting's landmark (the index of its bearing's and its size's state)."""
    gain = 1 if form.sigma > 0 else 0
    n_landmarks = int(landmark.max()) + 1
    n_b = n_landmarks if form.sigma_b > 0 else 0
    n_r = n_landmarks if form.sigma_r > 0 else 0
    n = 3 + gain + n_b + n_r
    phi_g, q_g = ar1_step(form.sigma, form.tau, dt)
    phi_b, q_b = ar1_step(form.sigma_b, form.tau_b, dt)
    phi_r, q_r = ar1_step(form.sigma_r, form.tau_r, dt)
    trans = np.array([phi_g] * gain + [phi_b] * n_b + [phi_r] * n_r)
    noise = np.diag([q_g] * gain + [q_b] * n_b + [q_r] * n_r)
    sig_a = lo.shaped_cov(slice(0, batch.n_frames)).copy()
    sig_a[:, 2, :] *= np.sqrt(form.c)
    sig_a[:, :, 2] *= np.sqrt(form.c)
    sig_a[told_to_stand_still(lo)] *= form.k

    def motion(i, mean):
        d = lo.disp[i] * np.array([1.0, 1.0, 1.0 + (mean[3] if gain else 0.0)])
        g3, F3, R3 = geometry.motion(mean[:3], d)
        F, Q = np.zeros((n, n)), np.zeros((n, n))
        F[:3, :3], Q[:3, :3] = F3, lo.cov_scale[i] * (R3 @ sig_a[i] @ R3.T)
        F[3:, 3:], Q[3:, 3:] = np.diag(trans), noise
        if gain:
            F[2, 3] = lo.disp[i, 2]
        return np.concatenate([g3 + lo.offset[i], trans * mean[3:]]), F, Q

    def observe(j, mean):
        if not used[j]:
            return None
        h, H3, rd = sighting_model(lo, mean[None, :3], batch.sight_xy[j : j + 1], np.array([j]))
        h, H, R = h[0].copy(), np.zeros((2, n)), np.diag(rd[0] * np.array([form.r, form.s]))
        H[:, :3] = H3[0]
        if n_b:
            b = 3 + gain + landmark[j]
            h[1] += mean[b]
            H[1, b] = 1.0
        if n_r:
            b = 3 + gain + n_b + landmark[j]
            curve = h[0] - lo.size_offset[j]  # size_scale f(d)
            h[0] = curve * (1.0 + mean[b]) + lo.size_offset[j]
            H[0, :3] *= 1.0 + mean[b]
            H[0, b] = curve
        return h, H, R, batch.sight_value[j], AIBO_ANGLE_MASK

    m0, P0 = np.zeros(n), np.zeros((n, n))
    m0[:3], P0[:3, :3] = lo.init_mean[0], lo.init_cov[0]
    P0[3:, 3:] = np.diag([form.sigma**2] * gain + [form.sigma_b**2] * n_b + [form.sigma_r**2] * n_r)
    return forward_pass(m0, P0, batch.sight_start[: batch.n_frames + 1], motion, observe, gate)


@dataclass
class Scans:
    """The scans of one log: each grid's rows as (form, gain in nats over the model as fitted, the NIS's median),
    the share of frames told to stand still and the model's own NIS median."""

    turn: list[tuple[Form, float, float]]
    still: list[tuple[Form, float, float]]
    bearing: list[tuple[Form, float, float]]
    size: list[tuple[Form, float, float]]
    both: list[tuple[Form, float, float]]  # the best turn row's form with the best bearing row's (empty without one)
    still_share: float
    median: float


def scans(tr, sigmas=SIGMAS, taus_s=TAUS_S, heading_factors=HEADING_FACTORS, still_factors=STILL_FACTORS,
          bearing_sigmas=BEARING_SIGMAS, bearing_taus_s=BEARING_TAUS_S, bearing_factors=BEARING_FACTORS,
          size_sigmas=SIZE_SIGMAS, size_taus_s=SIZE_TAUS_S, size_factors=SIZE_FACTORS) -> Scans:
    """The four scans of one log under learn's model of it (module docstring)."""
    model = EMLearner(EMOptions(uncertainty=False), check_field=False).fit([tr]).params
    batch = make_batch([tr])
    lo = model.lower(batch)
    if lo.extra is not None:
        raise SystemExit("mrclam_noise_scans.py: learn's model holds extra states; these scans support the pose alone")
    landmark = np.asarray(tr.sighting_landmark, dtype=np.int64)
    first = forward_pass_of(lo, batch, landmark, batch.used, tr.dt, gate=GATE)
    used = batch.used & first.applied  # one set of sightings for every row (a gate per row would score others)
    base = forward_pass_of(lo, batch, landmark, used, tr.dt)

    def rows(forms: list[Form]) -> list[tuple[Form, float, float]]:
        out = []
        for form in forms:
            fw = forward_pass_of(lo, batch, landmark, used, tr.dt, form)
            out.append((form, fw.loglik - base.loglik, float(np.median(fw.mahal2[used]))))
            print(f"  {form.label()}: {out[-1][1]:+.1f} nats, NIS median {out[-1][2]:.3f}", file=sys.stderr, flush=True)
        return out

    turn = rows([Form(sigma=s, tau=t, c=c) for s in sigmas for t in taus_s for c in heading_factors])
    bearing = rows([Form(sigma_b=s, tau_b=t, s=f) for s in bearing_sigmas for t in bearing_taus_s
                    for f in bearing_factors])
    both = []
    if turn and bearing:
        t, b = best(turn)[0], best(bearing)[0]
        both = rows([replace(t, sigma_b=b.sigma_b, tau_b=b.tau_b, s=b.s)])
    return Scans(turn, rows([Form(k=k) for k in still_factors]), bearing,
                 rows([Form(sigma_r=s, tau_r=t, r=f) for s in size_sigmas for t in size_taus_s for f in size_factors]),
                 both, float(np.mean(told_to_stand_still(lo))), float(np.median(base.mahal2[used])))


def best(rows: list[tuple[Form, float, float]], key: str | None = None, value: float = 0.0) -> tuple[Form, float, float]:
    """The row of ``rows`` with the largest gain (among those whose form has ``key`` == ``value``, if ``key``)."""
    return max((r for r in rows if key is None or getattr(r[0], key) == value), key=lambda r: r[1])


def figure(by_robot: dict[int, Scans], path: Path) -> None:
    """Per robot, the best gain of each correlation time (log scale) for the turn's gain, the bearings' and the sizes'
    bias states, side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aibo.figures import save_png

    panels = (("turn", "tau", TAUS_S, "a turn gain error: white (left) or persistent"),
              ("bearing", "tau_b", BEARING_TAUS_S, "a bias per landmark on the bearings"),
              ("size", "tau_r", SIZE_TAUS_S, "a relative bias per landmark on the sizes"))
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=True)
    for ax, (scan, key, taus, title) in zip(axes, panels):
        for r, sc in by_robot.items():
            ax.plot(taus, [best(getattr(sc, scan), key, t)[1] for t in taus], "o-", label=f"robot {r}")
        ax.set_xscale("log")
        ax.set_xlabel("correlation time (s)")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("gain in log-likelihood (nats), best row")
    axes[0].legend(fontsize=8)
    fig.suptitle("MRCLAM Dataset 7: what each form adds to aibo learn's model (held), by how long its error persists",
                 fontsize=10)
    fig.tight_layout()
    save_png(fig, path)  # atomically, its folder made


def main(argv: list[str] | None = None) -> int:
    ap = mrclam_parser(__doc__, "")
    ap.add_argument("--png", default=None, help="write the figure here")
    args = ap.parse_args(argv)
    data = data_folder("mrclam_noise_scans.py", args.data)
    if data is None:
        return 1
    turn = ["| robot | " + " | ".join(f"turn gain, tau {t:g} s: nats (sigma, c)" for t in TAUS_S) + " |",
            "|---|" + "---|" * len(TAUS_S)]
    still = ["| robot | frames told to stand still | NIS median | " + " | ".join(
        f"k {k:g}: nats, NIS median" for k in STILL_FACTORS) + " |", "|---|---|---|" + "---|" * len(STILL_FACTORS)]
    bearing = ["| robot | " + " | ".join(f"bearing bias, tau {t:g} s: nats (sigma mrad, s)" for t in BEARING_TAUS_S)
               + " | NIS median: model / best |", "|---|" + "---|" * (len(BEARING_TAUS_S) + 1)]
    size = ["| robot | " + " | ".join(f"size bias, tau {t:g} s: nats (sigma %, r)" for t in SIZE_TAUS_S) + " |",
            "|---|" + "---|" * len(SIZE_TAUS_S)]
    both = ["| robot | the turn's best | the bearings' best | both together |", "|---|---|---|---|"]
    by_robot = {}
    for r in robots(args.robots):
        print(f"robot {r}", file=sys.stderr, flush=True)
        sc = by_robot[r] = scans(import_robot(data, r))
        turn.append(f"| {r} | " + " | ".join(f"{g:+.0f} ({f.sigma:g}, {f.c:g})"
                                             for f, g, _ in (best(sc.turn, "tau", t) for t in TAUS_S)) + " |")
        still.append(f"| {r} | {sc.still_share:.1%} | {sc.median:.3f} | "
                     + " | ".join(f"{g:+.0f}, {m:.3f}" for _, g, m in sc.still) + " |")
        bearing.append(f"| {r} | " + " | ".join(f"{g:+.0f} ({1e3 * f.sigma_b:g}, {f.s:g})"
                                                for f, g, _ in (best(sc.bearing, "tau_b", t) for t in BEARING_TAUS_S))
                       + f" | {sc.median:.3f} / {best(sc.bearing)[2]:.3f} |")
        size.append(f"| {r} | " + " | ".join(f"{g:+.0f} ({1e2 * f.sigma_r:g}, {f.r:g})"
                                             for f, g, _ in (best(sc.size, "tau_r", t) for t in SIZE_TAUS_S)) + " |")
        if sc.both:
            both.append(f"| {r} | {best(sc.turn)[1]:+.0f} | {best(sc.bearing)[1]:+.0f} | {sc.both[0][1]:+.0f} |")
    print("\n".join(turn + [""] + still + [""] + bearing + [""] + size + [""] + both))
    if args.png:
        figure(by_robot, Path(args.png))
    return 0


if __name__ == "__main__":
    sys.exit(main())
