"""Standard errors of the learned parameters: the Fisher information of the filter's innovations.

The likelihood EM maximizes is the EKF's: log p(O | theta) = sum over applied sightings j of
log N(v_j; 0, S_j), v_j the innovation (size, bearing) and S_j its predictive covariance
(docs/em-math.md). Its Fisher information is (e.g. Cavanaugh & Shumway 1996)

    I_kl = sum_j  dv_j/dk^T S_j^-1 dv_j/dl  +  1/2 tr(S_j^-1 dS_j/dk S_j^-1 dS_j/dl),

with the derivatives taken through the whole forward filter. They are taken here by forward
differences of the compiled forward pass (``innovations_compiled``), one pass per parameter:
about p passes of ~4 ms on 27,000 frames (p ~ 135 for the paper's model), the derivatives held whole
while they and the passes' own arrays fit in ``MEMORY_BYTES`` and in blocks beyond (``_information``).
Memory, ``aibo learn`` on 1,000,000 frames (509,246 sightings), 3 EM iterations, p = 134, measured
2026-11-25 with ``python scripts/memory_profile.py`` (2 cores, another job running: times +-30%): the
standard errors peak at 899 MiB RSS (was 1,350), below EM's own 924 MiB, ru_maxrss 0.969e9 bytes
(969 B/frame; was 1.415e9), 333 forward passes in 49-51 s (were 426 in 85-94 s). What changed: the
forward pass alone no longer keeps per-pose beliefs and per-frame information (208 MB of scratch),
EM's work arrays are released before (``release_scratch``, 171 MiB), ``_cross`` copies 8,192 sightings at
a time (95 -> 12 MiB), the second pass's output exists only for central differences (19 MiB), and the
budget counts the passes' own arrays. The
covariance of the estimate is I^-1 (Cramer-Rao); it is mapped to the model file's units by the
delta method (the Jacobian of the file's numbers with respect to the packed parameters).

Robust errors beside them (``Uncertainty.robust_standard_errors``, a model file's ``info["robust_standard_errors"]``):
per entry the larger of the Fisher error and the sandwich error of I^-1 J I^-1 (Huber 1967, White 1982), J the
variance of the score, estimated from the same derivatives: each sighting's score is its whitened derivative rows
times ``_score_weights`` (no extra pass), summed over blocks of ``ROBUST_BLOCK_S`` of a log (batch means: scores
correlated over less than a block, as a model's missing correlations make them, still give a consistent J). Where
the model is the data's, J = I and the two agree, to J's sampling error; where it is not, the sandwich follows the
data: Laplace size noise makes sigma's error sqrt(2.5) times the Fisher one (``tests/test_uncertainty.py``). The
larger of the two, not the sandwich alone (Angrist & Pischke 2009, 8.1): a parameter whose score lives in a few
blocks (one of 40 commands) has a sandwich error from a few numbers, often far too small. Measured
(``scripts/se_halves.py``, docs/results.md "Robust standard errors"): between two fits of the same simulated robot
the differences are about 1 of either error; between the two halves of an MRCLAM robot's log they are 1.7-4.8 Fisher
errors and 1.0-2.5 robust ones.

Parameters: every trainable parameter in ``Model.pack`` (velocities, the sensor curve as its
values at fixed distances, log sigmas, the log-Cholesky factor of Sigma_A unless fixed, effects)
and each log's initial pose mean (``init.mean``; the initial covariance is held fixed). Two kinds of
coordinates are left out of the information, and told apart in the report:

- *fixed*: held at their value by the model's construction (``Component.held``: a unicycle's lateral
  weights and its forward speed's omega and |omega| terms, at exactly 0). They are not parameters: not
  differenced, listed as ``fixed``, and a file entry only they move has standard error exactly 0.0 (its
  value is known, not estimated; a consumer dividing by it must expect 0).
- *undetermined*: no sighting depends on them (a command never executed): listed as ``undetermined``,
  their error ``None``; the others' errors are those with these held at their values.

A member of a normalized group (``"logcontrast"``: factors at geometric mean 1, packed as contrasts)
that no sighting depends on (``beacon_height_scale`` of a landmark never sighted) is undetermined
along a direction that is not a coordinate: moving its log-factor moves the others' (the normalization),
and their common factor trades with the sensor curve's, so the information is singular (condition
number ~1e12 before this was handled) along that member's contrast direction combined with the curve.
What the data determine is the seen members' ratios and each one's product with the curve; their
common level, and the curve's, only once the unseen member's factor is held. So, like a command never
executed, that member is held at its value (EM keeps it at its start, 1: ``BeaconHeightScale.maximize``):
it is listed as ``undetermined`` (``effects.beacon_height_scale.scale[3]``), its error is ``None``, and
every other error is the one given it held: the seen factors' and the curve's are then those of the
same model without the unseen landmark (``tests/test_constrained.py``). It is held only when the data
leave it undetermined (the information along its direction, given all the others, is below
``NULL_RATIO`` of its own): with the curve held (``sensor.coef`` fixed) the normalization alone
determines it, and it is reported like any parameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from learners.arrays.batch import Batch
from learners.inference.kernels import innovations_compiled
from learners.model.effects import ConditionalInformation
from learners.model.io import model_to_json
from learners.model.model import Model
from learners.model.parameters import helmert
from learners.model.sensor import curve_nodes

#: 95% quantiles as constants (scipy.stats costs every command ~1 s to import): the standard normal's two-sided, and
#: chi-square with 1 degree of freedom (a profile-likelihood interval is the drop of half of it, in nats)
Z95 = 1.959963984540054
CHI2_1_95 = 3.841458820694124

#: Forward-difference step in the packed units (one unit ~ one noise width: 10 mm/frame, 1 px, ...);
#: a negative step asks for central differences (twice the passes; the tests compare the two).
STEP = 1e-5
#: Initial pose means enter the packed vector divided by these (mm, mm, rad), like InitialState's scale.
INIT_SCALE = np.array([100.0, 100.0, 0.1])
#: Model-file numbers that are not parameters.
NOT_PARAMETERS = {"dt", "distance_range_mm"}
#: The most the standard errors' log-sized arrays may hold (bytes): the whitened derivatives and the passes' own
#: arrays (``_pass_bytes``). 135 coordinates of a 15-minute log take ~70 MB (held whole, float64); a 1,000,000-frame
#: log (509,246 sightings) takes them in blocks (``_information``): 128 MiB counted for the passes, the rest for
#: 38 coordinates in float32 (34 resident, 4 streamed), 332 passes; its standard errors then peak at 899 MiB
#: RSS, EM at 924 MiB (2026-11-25, ``scripts/memory_profile.py``). (Was 384 MiB for the derivatives alone,
#: 1,350 MiB peak.)
MEMORY_BYTES = 512 * 2**20
#: Sightings per float64 chunk of ``_cross`` (its copies: (a + b) x CROSS_CHUNK x 40 bytes, 12 MiB for 38
#: coordinates; 65,536 took 95 MiB).
CROSS_CHUNK = 8192
#: Coordinates streamed past the resident block at a time (``_information``).
STREAM = 4
#: What the passes hold beside the derivatives, counted against ``memory_bytes`` (``_pass_bytes``), bytes: per
#: sighting, the base innovations, their Cholesky factors and the pass's output (104, held) and a pass's differences
#: and ``_columns``' temporaries (112); per frame, a lowered model's displacements (24); central differences add the
#: second pass's output and its copy (80 per sighting). Measured (tracemalloc) at 1,000,000 frames (509,246
#: sightings), model without effects: 126 MiB, 132 MB = 216 x 509,246 + 24 x 1,000,000 to 1%. An effect's lowered
#: arrays are not counted. The robust errors' score weights add 20 (``_Differences.u``, float32; not in that
#: measurement).
PASS_BYTES_PER_SIGHTING = 236
PASS_BYTES_PER_FRAME = 24
CENTRAL_BYTES_PER_SIGHTING = 80
#: A never-sighted member of a normalized group is held (undetermined) when the information along its direction,
#: given every other direction, is below this fraction of the information along it alone: measured 4e-16 for an
#: unseen landmark's height scale (tests/test_constrained.py's log), 0.46 for the same with the sensor curve held.
NULL_RATIO = 1e-8
#: The robust errors' blocks (``block_starts``): seconds of a log per block, at least ``MIN_BLOCKS`` blocks in a
#: batch. Measured with ``scripts/se_halves.py`` (docs/results.md, "Robust standard errors"): on every MRCLAM robot the
#: halves' differences over the robust errors fall as the blocks lengthen (0.5, 2, 5, 10, 20 s) and level off at
#: 10-20 s; the simulated pairs stay at z about 1 for every length.
ROBUST_BLOCK_S = 10.0
MIN_BLOCKS = 30
#: The blocks of the likelihood-ratio test's overstatement (``information_overstatement``, the search's robust
#: likelihood ratio): the robust errors' blocks merged into blocks of this many seconds, at least
#: ``OVERSTATEMENT_MIN_BLOCKS`` of them. An effect's score can follow slower errors than the standard errors' do (a
#: fade's is the residual times the elapsed time): on MRCLAM robot 4's second half the fade's c was 5.0 / 9.6 / 11.0
#: with 10 / 30 / 60 s blocks, and 1.0 at every length on simulated logs with a true fade (docs/results.md, "The
#: search's checks").
OVERSTATEMENT_BLOCK_S = 30.0
OVERSTATEMENT_MIN_BLOCKS = 10


@dataclass
class Uncertainty:
    """Standard errors (model-file keys and units) and the information behind them."""

    standard_errors: dict[str, Any]  # file key -> SE with the file entry's shape; None where undetermined
    names: list[str]  # the free coordinates of the packed vector
    information: np.ndarray  # (p, p) Fisher information over ``names`` (packed units)
    covariance: np.ndarray  # (p, p) its inverse
    min_eigenvalue: float  # smallest eigenvalue of the correlation form of I (1 = orthogonal, 0 = singular)
    condition_number: float  # of the correlation form of I
    weakest: list[str]  # coordinates carrying most of the weakest direction
    undetermined: list[str]  # coordinates no sighting depends on
    newton_decrement: float  # sqrt(g^T I^-1 g): distance to the likelihood's optimum in standard errors
    free: np.ndarray  # (all coordinates,) bool: which coordinates ``names`` are (the others fixed or undetermined)
    score: np.ndarray  # (p,) d loglik / d x over ``names`` (packed units)
    fixed: list[str] = field(default_factory=list)  # coordinates the model holds at their value (``Component.held``)
    held: np.ndarray | None = None  # (all coordinates,) bool: which coordinates ``fixed`` are
    passes: int = 0  # forward passes of the filter spent on the derivatives (one per coordinate, two if central)
    null: np.ndarray | None = None  # (p, r) orthonormal directions over ``names`` held at their values (unseen group members)
    #: file key -> robust SE (the larger of the Fisher and the sandwich one), shaped as ``standard_errors``
    robust_standard_errors: dict[str, Any] = field(default_factory=dict)
    robust_covariance: np.ndarray | None = None  # (p, p) I^-1 J I^-1 over ``names`` (packed units)
    blocks: int = 0  # batch-means blocks behind J
    block_sums: np.ndarray | None = None  # (p, blocks) the score over ``names`` summed over each block
    block_time: np.ndarray | None = None  # (blocks,) s: the time of each block's first sighting in its log
    block_log: np.ndarray | None = None  # (blocks,) the log of each block

    def summary(self) -> dict[str, Any]:
        """The JSON-ready part for a model file's ``info``."""
        return {"method": "Fisher information of the EKF innovations (finite differences)",
                "parameters": len(self.names) - (0 if self.null is None else self.null.shape[1]),
                "min_eigenvalue": self.min_eigenvalue,
                "condition_number": self.condition_number if math.isfinite(self.condition_number) else None,
                "weakest_direction": self.weakest,
                "undetermined": self.undetermined, "fixed": self.fixed, "newton_decrement": self.newton_decrement}


# ---------------------------------------------------------------------------------------------- coordinates
def _coordinate_names(model: Model, fixed: frozenset[str]) -> list[str]:
    """One name per entry of ``pack(fixed)`` followed by the initial pose means."""
    names: list[str] = []
    for cname, pname, n in model.packed_layout(fixed):
        key = f"{cname}.{pname}"
        if key == "action.weights":
            label = "velocities" if model.action.discrete else "weights"
            names += [f"action_model.{label}[{i // 3}][{i % 3}]" for i in range(n)]
        elif key == "sensor.coef":
            names += [f"sensor_model.curve_at_{d:.0f}mm" for d in curve_nodes(n)]
        elif key == "sensor.sigma_size":
            names.append("sensor_model.sigma_height" if model.sensor.kind == "height_px" else "sensor_model.sigma_range_mm")
        elif key == "sensor.sigma_bearing":
            names.append("sensor_model.sigma_angle")
        elif key == "action.cov":
            names += [f"action_model.motion_cov.logchol[{i}]" for i in range(n)]
        elif (param := dict(model.components())[cname].PARAMS[pname]).group:  # Helmert contrasts (of the logs)
            names += [f"{key}.{'log_' if param.transform == 'logcontrast' else ''}contrast[{i}]" for i in range(n)]
        else:
            names += [f"{key}[{i}]" for i in range(n)]
    for k in range(_n_init(model, fixed)):
        names += [f"initial_state.{k}.mean[{i}]" for i in range(3)]
    return names


def held_coordinates(model: Model, fixed: frozenset[str]) -> np.ndarray:
    """(all coordinates of ``packed``,) bool: those the model holds at their value by construction
    (``Model.packed_held``; never an initial pose)."""
    return np.concatenate([model.packed_held(fixed), np.zeros(3 * _n_init(model, fixed), dtype=bool)])


def _n_init(model: Model, fixed: frozenset[str]) -> int:
    """Number of initial pose means among the coordinates (none if ``init.mean`` is fixed)."""
    return 0 if "init.mean" in fixed else len(model.init)


def packed(model: Model, fixed: frozenset[str]) -> np.ndarray:
    """The coordinates the information is over: ``model.pack(fixed)``, then each log's initial pose mean
    divided by INIT_SCALE (unless ``init.mean`` is fixed)."""
    means = [s.mean / INIT_SCALE for s in model.init[: _n_init(model, fixed)]]
    return np.concatenate([model.pack(fixed), *means])


def unpacked(model: Model, x: np.ndarray, fixed: frozenset[str]) -> Model:
    """Inverse of ``packed``: ``model`` with every coordinate read from ``x``."""
    n = len(x) - 3 * _n_init(model, fixed)
    new = model.unpack(x[:n], fixed)
    init = list(new.init)
    for k in range(_n_init(model, fixed)):
        init[k] = replace(init[k], mean=x[n + 3 * k: n + 3 * k + 3] * INIT_SCALE)
    return new.with_(init=tuple(init))


def file_values(model: Model) -> dict[str, np.ndarray]:
    """The model file's parameter numbers by dotted key (``action_model.velocities``, ``sensor_model.coef``,
    ``effects.<name>.<parameter>``, ``initial_state.<k>.mean``), in the file's units."""
    doc = model_to_json(model)
    out = {}
    for section in ("action_model", "sensor_model"):
        for key, value in doc[section].items():
            if key not in NOT_PARAMETERS and not isinstance(value, str) and key != "control_names":
                out[f"{section}.{key}"] = np.asarray(value, dtype=float)
    for e in doc["effects"]:
        out.update({f"effects.{e['name']}.{k}": np.asarray(v, dtype=float) for k, v in e["parameters"].items()})
    for k, s in enumerate(doc["initial_state"]):
        out[f"initial_state.{k}.mean"] = np.asarray(s["mean"], dtype=float)
    return out


# ---------------------------------------------------------------------------------------------- information
def _whiten(S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cholesky factor C (S = C C^T) of each 2x2 [S00, S01, S11]: (c00, c10, c11)."""
    c00 = np.sqrt(S[:, 0])
    c10 = S[:, 1] / c00
    return c00, c10, np.sqrt(S[:, 2] - c10 * c10)


def _solve(c, a0: np.ndarray, a1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C^-1 (a0, a1) for lower-triangular C = (c00, c10, c11)."""
    w0 = a0 / c[0]
    return w0, (a1 - c[1] * w0) / c[2]


def _score_weights(v: np.ndarray, c) -> np.ndarray:
    """(n, 5) weights u with one sighting's score d log N(v; 0, S) / dk = (its ``_columns`` row for k) . u: with the
    whitened innovation e = C^-1 v, the score is -(C^-1 dv) . e + 1/2 (e^T A e - tr A), A = C^-1 dS C^-T, so u =
    (-e0, -e1, (e0^2 - 1) / sqrt(2), e0 e1, (e1^2 - 1) / sqrt(2)) against the rows' (w0, w1, a00 / sqrt(2), a01,
    a11 / sqrt(2))."""
    e0, e1 = _solve(c, v[:, 0], v[:, 1])
    h = math.sqrt(0.5)
    return np.stack([-e0, -e1, h * (e0 * e0 - 1.0), e0 * e1, h * (e1 * e1 - 1.0)], axis=1)


def block_starts(batch: Batch, rows: np.ndarray) -> np.ndarray:
    """Start indices (into ``rows``, the applied sightings in time order) of the blocks of the robust covariance
    (``parameter_uncertainty``): the sightings of each ``block_seconds(batch)`` of a log."""
    if not len(rows):
        return np.zeros(0, dtype=int)
    return _bin_starts(batch.sight_log[rows], batch.frame_time[batch.sight_frame[rows]], block_seconds(batch))


def _bin_starts(logs: np.ndarray, times: np.ndarray, length: float) -> np.ndarray:
    """Start indices of the runs of consecutive entries (in time order, ``times`` s) in one ``length``-second bin of one
    log (``logs``): the blocks of ``block_starts`` and of ``merged_blocks``."""
    key = logs.astype(np.int64) * 10**9 + np.floor(times / length).astype(np.int64)
    return np.flatnonzero(np.r_[True, key[1:] != key[:-1]])


def block_seconds(batch: Batch) -> float:
    """The blocks' length (s): ``ROBUST_BLOCK_S``, shorter on a batch of less than ``MIN_BLOCKS`` of them."""
    return min(ROBUST_BLOCK_S, batch.n_frames * batch.dt / MIN_BLOCKS)


def _columns(dv: np.ndarray, dS: np.ndarray, c, out: np.ndarray | None = None) -> np.ndarray:
    """(n, 5) rows whose Gram sum is the information: C^-1 dv and 1/sqrt(2) C^-1 dS C^-T (symmetric,
    off-diagonal counted twice); written into ``out`` ((n, 5), float64 or float32: rounded once) when given."""
    w0, w1 = _solve(c, dv[:, 0], dv[:, 1])
    n0, n1 = _solve(c, dS[:, 0], dS[:, 1])  # first column of C^-1 dS
    m0, m1 = _solve(c, dS[:, 1], dS[:, 2])  # second column
    a00, a01 = _solve(c, n0, m0)  # C^-1 (C^-1 dS)^T: rows of the whitened matrix
    _, a11 = _solve(c, n1, m1)
    h = math.sqrt(0.5)
    return np.stack([w0, w1, h * a00, a01, h * a11], axis=1, out=out)


class _Perturber:
    """Models with one packed coordinate moved: only the block holding it is unpacked again (the
    sensor curve's unpacking is a least-squares fit; doing all of them per coordinate cost ~1 s)."""

    def __init__(self, model: Model, x0: np.ndarray, fixed: frozenset[str]):
        self.model, self.x0, self.fixed = model, x0, fixed
        self.blocks: list[tuple[str, str, int, int]] = []  # (component, parameter, start, stop)
        at = 0
        for cname, pname, n in model.packed_layout(fixed):
            self.blocks.append((cname, pname, at, at + n))
            at += n
        self.blocks += [("init", str(k), at + 3 * k, at + 3 * k + 3) for k in range(_n_init(model, fixed))]

    def moved(self, k: int, delta: float) -> Model:
        cname, pname, a, b = next(blk for blk in self.blocks if blk[2] <= k < blk[3])
        x = self.x0[a:b].copy()
        x[k - a] += delta
        m = self.model
        if cname == "init":
            i = int(pname)
            init = list(m.init)
            init[i] = replace(init[i], mean=x * INIT_SCALE)
            return m.with_(init=tuple(init))
        comp = dict(m.components())[cname]
        value, _ = comp.unpack_param(pname, x)
        new = comp.with_values(**{pname: value})
        return m.with_effect(new) if cname.startswith("effects.") else replace(m, **{cname: new})


class _Differences:
    """One coordinate's whitened derivative rows (n, 5) and score by differences of step ``step`` (one
    number or one per coordinate; > 0: forward, one pass per coordinate; < 0: central, two)."""

    def __init__(self, model: Model, batch: Batch, x0: np.ndarray, fixed: frozenset[str], rows: np.ndarray,
                 step: float | np.ndarray):
        self.batch, self.rows = batch, rows
        self.ll0, innov0 = innovations_compiled(model.lower(batch), batch)
        self.base = innov0[rows]
        self.c = _whiten(self.base[:, 2:])
        self.u = _score_weights(self.base[:, :2], self.c).astype(np.float32)  # block sums need no more
        self.starts = block_starts(batch, rows)
        self.plus = innov0  # the passes' output (S, 5), reused; a second one only for central differences
        self.steps = np.broadcast_to(np.asarray(step, dtype=float), x0.shape)
        self.minus = np.empty_like(innov0) if np.any(self.steps < 0) else None
        self.perturb = _Perturber(model, x0, fixed)

    def __call__(self, k: int, out: np.ndarray | None = None) -> tuple[np.ndarray, float]:
        """(coordinate k's (n, 5) whitened derivative rows, written into ``out`` when given, score)."""
        h, rows, batch = abs(float(self.steps[k])), self.rows, self.batch
        llp, _ = innovations_compiled(self.perturb.moved(k, h).lower(batch), batch, out=self.plus)
        d = self.plus[rows]
        if self.steps[k] < 0:
            llm, _ = innovations_compiled(self.perturb.moved(k, -h).lower(batch), batch, out=self.minus)
            d -= self.minus[rows]
            span = 2 * h
        else:
            d -= self.base
            llm, span = self.ll0, h
        d[:, 1] = np.angle(np.exp(1j * d[:, 1]))  # bearings: wrapped difference
        d /= span
        return _columns(d[:, :2], d[:, 2:], self.c, out), (llp - llm) / span

    def block_time(self) -> np.ndarray:
        """(blocks,) s: the time of each block's first sighting."""
        return self.batch.frame_time[self.batch.sight_frame[self.rows[self.starts]]]

    def block_scores(self, cols: np.ndarray) -> np.ndarray:
        """(blocks,) a coordinate's score summed over each block of consecutive sightings (``block_starts``), from its
        whitened derivative rows ``cols`` (n, 5): per sighting, the rows times ``_score_weights``."""
        return np.add.reduceat(np.einsum("nf,nf->n", cols, self.u, dtype=float), self.starts)


def _information(diff: _Differences, coords: np.ndarray,
                 memory_bytes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(I (p, p) = the Gram sum of the whitened derivatives G (p, n, 5), score (p,), the score's block sums (p,
    blocks): ``_Differences.block_scores``) over the coordinates ``coords`` (p of them: indices into the packed vector).

    ``memory_bytes`` bounds what the derivatives take beside the passes' own arrays (``_pass_bytes``). G is
    held whole (float64) when it fits: p forward passes. A longer log holds one block of s coordinates
    (float32) and streams every later coordinate past it STREAM at a time (float32; products summed in
    float64 by ``_cross``): block i's own passes run once, each later coordinate's once per earlier block,
    p + sum over blocks of (p - the block's end) passes in all. (Was: two blocks of s/2 in memory, block j
    run max(j, 1) times: 425 passes for p = 134 with 38 coordinates in memory at 1,000,000 frames, 332 now;
    the differences themselves carry ~1e-5 relative error, far above float32's rounding.)"""
    n, p = len(diff.rows), len(coords)
    score, blocks = np.empty(p), np.empty((p, len(diff.starts)))
    budget = memory_bytes - _pass_bytes(diff)
    if p * n * 5 * 8 <= budget:
        G = np.empty((p, n, 5))
        for k in range(p):
            _, score[k] = diff(int(coords[k]), out=G[k])
            blocks[k] = diff.block_scores(G[k])
        return _gram(G), score, blocks
    per = n * 5 * 4 + CROSS_CHUNK * 5 * 8  # one coordinate's float32 rows and its float64 chunk in ``_cross``
    q = min(STREAM, max(1, p - 1))
    size = max(1, min(p, budget // per - q))
    A, B = np.empty((size, n, 5), np.float32), np.empty((q if size < p else 0, n, 5), np.float32)
    info = np.empty((p, p))
    for a in range(0, p, size):
        block = np.arange(a, min(a + size, p))
        for r, k in enumerate(block):
            _, score[k] = diff(int(coords[k]), out=A[r])
            blocks[k] = diff.block_scores(A[r])
        Ab = A[: len(block)]
        info[np.ix_(block, block)] = _cross(Ab, Ab)
        for c in range(block[-1] + 1, p, q):
            group = np.arange(c, min(c + q, p))
            for r, k in enumerate(group):
                _, score[k] = diff(int(coords[k]), out=B[r])
            info[np.ix_(block, group)] = _cross(Ab, B[: len(group)])
            info[np.ix_(group, block)] = info[np.ix_(block, group)].T
    return info, score, blocks


def _pass_bytes(diff: _Differences) -> int:
    """Bytes the forward passes take beside the derivatives, counted against ``memory_bytes``:
    PASS_BYTES_PER_SIGHTING (+ CENTRAL_BYTES_PER_SIGHTING) per sighting of the batch, PASS_BYTES_PER_FRAME per frame."""
    per_sighting = PASS_BYTES_PER_SIGHTING + (CENTRAL_BYTES_PER_SIGHTING if diff.minus is not None else 0)
    return per_sighting * diff.batch.n_sightings + PASS_BYTES_PER_FRAME * diff.batch.n_frames


def _gram(G: np.ndarray) -> np.ndarray:
    """The sum over sightings and rows of G G^T: (p, p)."""
    flat = G.reshape(len(G), -1)
    return flat @ flat.T


def _cross(A: np.ndarray, B: np.ndarray, chunk: int = CROSS_CHUNK) -> np.ndarray:
    """The sum over sightings and rows of A B^T for float32 (a, n, 5) and (b, n, 5), summed in float64
    ``chunk`` sightings at a time: (a, b)."""
    out = np.zeros((len(A), len(B)))
    for s in range(0, A.shape[1], chunk):
        a = A[:, s : s + chunk].astype(np.float64).reshape(len(A), -1)
        b = B[:, s : s + chunk].astype(np.float64).reshape(len(B), -1)
        out += a @ b.T
    return out


# ---------------------------------------------------------------------------------------------- errors
def _file_jacobian(model: Model, x0: np.ndarray, fixed: frozenset[str], step: float = 1e-6) -> dict[str, np.ndarray]:
    """d file_values / dx (key -> (entries, p)) by central differences (no E-step: cheap)."""
    cols: dict[str, list[np.ndarray]] = {}
    perturb = _Perturber(model, x0, fixed)
    for k in range(len(x0)):
        plus = file_values(perturb.moved(k, step))
        minus = file_values(perturb.moved(k, -step))
        for key in plus:
            cols.setdefault(key, []).append(np.ravel(plus[key] - minus[key]) / (2 * step))
    return {key: np.stack(c, axis=1) for key, c in cols.items()}


def _errors(jac: dict[str, np.ndarray], shapes: dict[str, tuple], free: np.ndarray, held: np.ndarray,
            cov: np.ndarray, null: np.ndarray, floor: np.ndarray | None = None) -> dict[str, Any]:
    """SE per file key (nested lists like the file; None for entries depending on an undetermined
    coordinate, neither ``free`` nor ``held``, and for entries moved along the held directions ``null``
    (over the free coordinates) and along no other: an unseen group member's own factor; 0.0 for entries
    only ``held`` coordinates move: fixed by the model); keys no coordinate moves (fixed parameters) are
    left out. ``floor``: a second covariance, each entry's error then the larger of the two (the robust errors)."""
    out = {}
    undetermined = ~free & ~held
    for key, J in jac.items():
        moved = np.abs(J) > 1e-12 * max(1.0, float(np.abs(J).max(initial=0.0)))
        if not moved.any():
            continue
        Jf = J[:, free]
        var = np.einsum("ik,kl,il->i", Jf, cov, Jf)
        if floor is not None:
            var = np.maximum(var, np.einsum("ik,kl,il->i", Jf, floor, Jf))
        se = np.sqrt(np.maximum(var, 0.0))
        silent = np.zeros(len(J), dtype=bool)
        if null.shape[1]:
            along = Jf @ null
            silent = np.linalg.norm(Jf - along @ null.T, axis=1) <= 1e-6 * np.linalg.norm(along, axis=1)
        se_list = [None if moved[i, undetermined].any() or silent[i] else float(se[i]) for i in range(len(se))]
        out[key] = np.array(se_list, dtype=object).reshape(shapes[key]).tolist() if shapes[key] else se_list[0]
    return out


def _spectrum(info: np.ndarray, names: list[str], basis: np.ndarray | None = None,
              diag: np.ndarray | None = None) -> tuple[float, float, list[str]]:
    """(smallest eigenvalue, condition number) of the correlation form D^-1/2 I D^-1/2, and the
    names carrying most (>= 10% of the squared weight) of its weakest direction. ``basis``: when ``info``
    is over its columns (directions over ``names``), not over the names' coordinates (``diag``: the
    information of each of these, for their correlation scale)."""
    d = 1.0 / np.sqrt(np.diag(info))
    w, V = np.linalg.eigh(info * np.outer(d, d))
    lo = max(float(w[0]), 0.0)
    if basis is None:
        v = V[:, 0] ** 2
    else:
        v = (basis @ (V[:, 0] * d)) ** 2 * diag
        v = v / v.sum()
    weakest = [names[i] for i in np.argsort(-v)[:5] if v[i] >= 0.1]
    return lo, float(w[-1] / lo) if lo > 0 else math.inf, weakest


def _silent_members(diff: _Differences, model: Model) -> list[tuple[int, int, str, list[int]]]:
    """Per normalized group (a ``"logcontrast"`` or ``"contrast"`` block a:b of the packed coordinates): (a, b, its dotted
    name, the members no applied sighting depends on), as the component reports them for this batch
    (``EffectModel.undetermined``, which ``learners.em.support.check_support`` lists too: a landmark never
    sighted), so that this report and the fit's warning say the same."""
    out = []
    comps = dict(model.components())
    for cname, pname, a, b in diff.perturb.blocks:
        if cname == "init" or not comps[cname].PARAMS[pname].group:
            continue
        entries = getattr(comps[cname], "undetermined", lambda batch: [])(diff.batch)
        silent = [int(e[len(pname) + 1 : -1]) for e in entries if e.startswith(pname + "[")]
        out.append((a, b, f"{cname}.{pname}", silent))
    return out


def _null_directions(groups: list[tuple[int, int, str, list[int]]], free: np.ndarray,
                     info: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """((p, r) orthonormal directions over the free coordinates to hold, the names of the members held): per
    group of ``_silent_members`` with unseen members (and every coordinate free), the contrast directions that
    move their log-factors (their rows of the Helmert basis), held when the data leave them undetermined: the
    information along them given every other direction (a Schur complement) below ``NULL_RATIO`` of their own."""
    index = np.cumsum(free) - 1  # coordinate -> position among the free ones
    p = int(free.sum())
    cols, names = [], []
    for a, b, key, silent in groups:
        if not silent or not free[a:b].all():
            continue
        _, sv, vt = np.linalg.svd(helmert(b - a + 1)[silent])
        r = int(np.sum(sv > 1e-9 * sv.max()))
        dirs = np.zeros((p, r))
        dirs[index[a:b], :] = vt[:r].T
        Q = np.linalg.svd(dirs, full_matrices=True)[0]
        D, T = Q[:, :r], Q[:, r:]
        IT = info @ T
        own = D.T @ info @ D
        schur = own - (D.T @ IT) @ np.linalg.pinv(T.T @ IT, hermitian=True) @ (IT.T @ D)
        s = 1.0 / np.sqrt(np.diag(own))
        if np.linalg.eigvalsh(schur * np.outer(s, s))[-1] < NULL_RATIO:
            cols.append(D)
            names += [f"{key}[{u}]" for u in silent]
    if not cols:
        return np.zeros((p, 0)), []
    return np.linalg.svd(np.concatenate(cols, axis=1), full_matrices=False)[0], names


def parameter_uncertainty(model: Model, batch: Batch, fixed: frozenset[str] = frozenset(),
                          step: float | np.ndarray = STEP, memory_bytes: int = MEMORY_BYTES) -> Uncertainty:
    """Standard errors of every learned parameter of ``model`` (usually EM's estimate) on ``batch``
    (the fit's sightings, pruned ones excluded), from the Fisher information of the EKF innovations
    (module docstring). ``step``: the difference step in packed units, one number or one per coordinate
    of ``packed`` (negative: central differences). ``fixed``: dotted parameter names held fixed (e.g. ``action.cov`` when the motion
    noise is not learned; ``init.mean``: the initial poses). ``memory_bytes``: the most the derivatives and the
    passes' own arrays may hold (bytes; ``_information``). The coordinates the model itself holds
    (``held_coordinates``) are not differenced: reported as ``fixed`` (module docstring). The image angle's expectation
    is taken with the model's bearing noise held (``Batch.angle_noise``), as EM takes it: through it the sizes would
    otherwise speak of the bearing noise (MRCLAM robot 5's sigma_angle error 2e-5 rad instead of 9e-5)."""
    batch = batch.holding_angle_noise(model.sensor.sigma_bearing)
    x0 = packed(model, fixed)
    names = _coordinate_names(model, fixed)
    rows = np.flatnonzero(batch.used)
    held = held_coordinates(model, fixed)
    coords = np.flatnonzero(~held)
    steps = np.broadcast_to(np.asarray(step, dtype=float), x0.shape)
    diff = _Differences(model, batch, x0, fixed, rows, step)
    info_c, score_c, blocks_c = _information(diff, coords, memory_bytes)
    info_all, score = np.zeros((len(x0), len(x0))), np.zeros(len(x0))
    info_all[np.ix_(coords, coords)], score[coords] = info_c, score_c
    passes = int(np.sum(np.where(steps[coords] < 0, 2, 1)))
    diag = np.diag(info_all)
    free = ~held & (diag > 1e-12 * diag.max())
    info = info_all[np.ix_(free, free)]
    free_names = [n for n, f in zip(names, free) if f]
    groups = _silent_members(diff, model)
    null, unseen = _null_directions(groups, free, info)
    if null.shape[1]:  # held along ``null``: the information over the other directions T (orthonormal)
        T = np.linalg.svd(null, full_matrices=True)[0][:, null.shape[1] :]
        reduced = T.T @ info @ T
        lo, cond, weakest = _spectrum(reduced, free_names, T, np.diag(info))
        cov = T @ (np.linalg.pinv(reduced, hermitian=True) if cond > 1e14 else np.linalg.inv(reduced)) @ T.T
    else:
        lo, cond, weakest = _spectrum(info, free_names)
        cov = np.linalg.pinv(info, hermitian=True) if cond > 1e14 else np.linalg.inv(info)
    cov = 0.5 * (cov + cov.T)
    g = score[free]
    newton = float(np.sqrt(max(g @ cov @ g, 0.0)))
    shapes = {k: v.shape for k, v in file_values(model).items()}
    jac = _file_jacobian(model, x0, fixed)
    errors = _errors(jac, shapes, free, held, cov, null)
    block_sums = np.zeros((len(x0), blocks_c.shape[1]))
    block_sums[coords] = blocks_c
    robust = sandwich(cov, block_sums[free])
    return Uncertainty(errors, free_names, info, cov, lo, cond, weakest,
                       [n for n, f, h in zip(names, free, held) if not f and not h] + unseen, newton, free, g,
                       fixed=[n for n, h in zip(names, held) if h], held=held, passes=passes, null=null,
                       robust_standard_errors=_errors(jac, shapes, free, held, robust, null, floor=cov),
                       robust_covariance=robust,
                       blocks=blocks_c.shape[1], block_sums=block_sums[free], block_time=diff.block_time(),
                       block_log=batch.sight_log[rows[diff.starts]])


def information_overstatement(unc: Uncertainty, prefix: str, block_s: float | None = None) -> float:
    """How many times the Fisher information overstates what the data carry about the coordinates whose names start
    with ``prefix`` (e.g. ``"effects.velocity_fade."``): c = tr(V_F^-1 V_R) / d over their block of the Fisher
    covariance V_F = I^-1 and the sandwich V_R = I^-1 J I^-1 (the mean of the d eigenvalues of V_F^-1 V_R: Satorra &
    Bentler 1994's scaling of a likelihood-ratio statistic, which under a model that is not the data's is the sum of
    those eigenvalues times independent chi-square(1)s; Kent 1982). At least 1, as the robust errors are at least the
    Fisher ones (``ROBUST_BLOCK_S``); 1 when no coordinate matches or there is no sandwich. ``block_s``: J from the
    robust errors' blocks merged into blocks of that many seconds (``merged_blocks``); None: the robust errors' own."""
    idx = [i for i, n in enumerate(unc.names) if n.startswith(prefix)]
    if not idx or unc.robust_covariance is None:
        return 1.0
    fisher = unc.covariance[np.ix_(idx, idx)]
    if block_s is None or unc.block_sums is None:
        robust = unc.robust_covariance[np.ix_(idx, idx)]
    else:
        robust = sandwich(unc.covariance, merged_blocks(unc, block_s))[np.ix_(idx, idx)]
    rank = np.linalg.matrix_rank(fisher, hermitian=True)
    if rank == 0:
        return 1.0
    c = float(np.trace(np.linalg.pinv(fisher, hermitian=True) @ robust)) / rank
    return max(1.0, c) if math.isfinite(c) else 1.0


def merged_blocks(unc: Uncertainty, block_s: float) -> np.ndarray:
    """(p, m) ``unc``'s block sums of the score merged into blocks of ``block_s`` seconds of each log (shorter when
    the logs hold fewer than ``OVERSTATEMENT_MIN_BLOCKS`` of them, never shorter than the blocks merged)."""
    t, logs = unc.block_time, unc.block_log
    span = sum(float(np.ptp(t[logs == k])) for k in np.unique(logs))
    length = min(block_s, span / OVERSTATEMENT_MIN_BLOCKS)
    if length <= 0:
        return unc.block_sums
    return np.add.reduceat(unc.block_sums, _bin_starts(logs, t, length), axis=1)


def sandwich(cov: np.ndarray, block_sums: np.ndarray) -> np.ndarray:
    """The robust covariance I^-1 J I^-1 (Huber 1967; White 1982): ``cov`` = I^-1 (p, p), J the variance of the score
    estimated by batch means, sum over blocks of (B_b - mean B)(B_b - mean B)^T x m / (m - 1), ``block_sums`` (p, m)
    the score summed over each block of consecutive sightings. It equals I^-1 in expectation when the model is the
    data's (J = I) and stays the estimate's sampling covariance when it is not: noise that is not Gaussian (the
    variances' errors then follow the noise's kurtosis, not 2 sigma^4), or an EKF's linearization far from linear."""
    m = block_sums.shape[1]
    c = block_sums - block_sums.mean(axis=1, keepdims=True)
    J = (c @ c.T) * (m / max(m - 1, 1))
    out = cov @ J @ cov
    return 0.5 * (out + out.T)


def conditional_errors(info: ConditionalInformation, batch: Batch) -> tuple[dict[str, float], dict[str, float]]:
    """(standard errors, robust standard errors) of an effect's parameters from its own likelihood with the filter held
    (``EffectModel.conditional_information``), by parameter name; {} where the information does not determine them.
    The robust ones are the larger of the observed information's and the sandwich's, the scores summed over the blocks
    of ``block_starts`` (the rule of the EKF's robust errors): neighbouring sightings share the predicted pose's error,
    so their scores are correlated, and the observed information overstates what the log holds (``heavy_tailed_noise``'s
    scale: docs/results.md, "A scale mixture of the noise")."""
    k = len(info.names)
    se = np.sqrt(np.maximum(np.diag(info.cov)[:k], 0.0))
    if not (np.all(np.isfinite(se)) and np.all(se > 0)):
        return {}, {}
    sums = np.add.reduceat(info.scores, block_starts(batch, info.rows), axis=0).T if len(info.rows) else None
    robust = se if sums is None else np.maximum(se, np.sqrt(np.maximum(np.diag(sandwich(info.cov, sums))[:k], 0.0)))
    return dict(zip(info.names, se.tolist())), dict(zip(info.names, robust.tolist()))


def fill_conditional_errors(model: Model, batch: Batch, se: dict[str, Any], robust: dict[str, Any]) -> list[str]:
    """Fill ``se`` and ``robust`` (file key -> standard error), in place, for the effects' parameters the EKF's
    information leaves undetermined (a mixture's rate or scale: the filter's innovations do not depend on them), from
    each effect's own likelihood with the filter held (``EffectModel.conditional_information``,
    ``conditional_errors``); returns the file keys filled."""
    from learners.em.estep import e_step

    missing = {e.name: [p for p in e.PARAMS if se.get(f"effects.{e.name}.{p}") is None] for e in model.effects}
    missing = {n: ps for n, ps in missing.items() if ps}
    if not missing:
        return []
    post = e_step(model, batch, "compiled")
    filled = []
    for name, params in missing.items():
        info = model.effect(name).conditional_information(model, batch, post)
        errors, robust_errors = conditional_errors(info, batch) if info is not None else ({}, {})
        for p in (p for p in params if p in errors):
            key = f"effects.{name}.{p}"
            se[key], filled = errors[p], filled + [key]
            if p in robust_errors:
                robust[key] = robust_errors[p]
    return filled
