"""Where a model's one-step innovations on a log depart from their Gaussian: the shape behind the calibrated check's
NIS statistics, for the report's reading of them.

The check compares the normalized innovation squared (NIS, 2-d: size and bearing) of the log with its simulation's
(``learners.discrepancy.statistics``); its "share outside the 95% band" counts both sides of the chi-square(2) band,
NIS below 0.05 (a sighting predicted more closely than the model's noise says) and above 7.38 (an error the noise
does not hold). A larger share can be either: on the MRCLAM Dataset 7 robots under ``aibo diagnose``'s default model
(2026-11-30) 4.7-6.5% of the sightings fell below the band and 4.7-5.2% above it, 2.5% expected on each side
(docs/results.md, "Where the innovations' shape departs"). This module says which side, which measurement (each
component's normalized innovation against its own standard deviation), at which commanded turn rates, and how soon
after their landmark's last sighting (a sighting predicted from the last one more closely than the noise allows: errors
that persist, or a motion noise that varies; a core sharper even after a gap: the noise's shape), so the reading names
what the log does instead of guessing "heavier tails".
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

from aibo_core.trajectory import Trajectory
from learners.arrays.batch import make_batch
from learners.em.estep import e_step, weighed_on
from learners.em.options import DEFAULT_GATE
from learners.em.whiteness import since_last_sighting
from learners.model.model import Model

from .score import NIS_BAND
from .signatures import TURN_RATE, sighting_residuals

#: a Gaussian component's share outside +-1.96 sd, and the median of its |normalized innovation|
OUTSIDE_EXPECTED, MEDIAN_ABS_EXPECTED = 0.05, float(stats.norm.ppf(0.75))
TURN_THIRDS = 3  # the sightings split into this many equal parts by their commanded turn rate
NIS_MEDIAN_EXPECTED = float(stats.chi2.ppf(0.5, 2))  # 2 log 2
#: the closer half's median NIS below this times the further half's: the reading says the errors persist or the
#: motion's noise varies; the further half's below this times 1.386: a core sharper than the Gaussian (``_repeat_text``).
#: Four sampling sd (about 0.05) of the ratio on 5-minute effect-free simulated logs below 1 (measured 0.97-1.06), not
#: fitted to the robots; `WheeledRobot-v0` logs fitted without size biases of 10% 0.76-0.82 (docs/results.md, "What
#: the NIS's core is"; the MRCLAM robots under the defaults' model 0.59-0.85).
PERSIST_RATIO = 0.8
COMPONENTS = ("size", "bearing")
#: the probabilities of the NIS quantiles each half reports (the tails and the core: the band's 2.5% and 97.5% among)
QUANTILE_PROBS = (0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 0.975, 0.99)


def innovation_shape(model: Model, logs: list[Trajectory]) -> dict[str, Any]:
    """The shape of ``model``'s one-step innovations on ``logs`` (the forward filter over every sighting, ungated, and
    the NIS beyond ``DEFAULT_GATE`` left out, as the check's NIS statistics: ``score.score``): the NIS's share below
    and above its 95% band; per component (size, bearing) the share of |normalized innovation| above 1.96 and its median; and the
    share above 1.96 per component in each third of the sightings by commanded turn rate (rad/s). Expected under the
    model: 0.025 on each side of the band, 0.05 and 0.674 per component."""
    batch = make_batch(logs)
    model = weighed_on(model, batch)  # a mixture's weights on these logs, as ``score``
    post = e_step(model, batch, "compiled", None)  # ungated, as ``score.score`` runs it for the check's NIS
    nis = np.asarray(post.mahal2, float)
    kept = batch.used & np.isfinite(nis) & (nis <= DEFAULT_GATE)
    r = sighting_residuals(model, batch.with_used(kept), post)
    lo, hi = NIS_BAND
    z = nis[kept]
    turn = r[TURN_RATE]
    edges = np.quantile(turn, np.linspace(0.0, 1.0, TURN_THIRDS + 1)) if len(turn) else np.zeros(TURN_THIRDS + 1)
    part = np.clip(np.searchsorted(edges, turn, side="right") - 1, 0, TURN_THIRDS - 1)
    out: dict[str, Any] = {
        "sightings": int(kept.sum()),
        "nis_band": [lo, hi],
        "nis_below_band": _share(z < lo),
        "nis_above_band": _share(z > hi),
        "turn_rate_edges_rad_s": [float(e) for e in edges],
    }
    for c in COMPONENTS:
        big = np.abs(r[c]) > 1.96
        out[c] = {"outside_95": _share(big), "median_abs": float(np.median(np.abs(r[c]))) if len(big) else float("nan"),
                  "outside_95_by_turn_rate": [_share(big[part == k]) for k in range(TURN_THIRDS)]}
    return out | by_time_since_last_sighting(nis, kept, since_last_sighting(batch))


def by_time_since_last_sighting(nis: np.ndarray, kept: np.ndarray, since: np.ndarray) -> dict[str, Any]:
    """The NIS of the sightings ``kept`` split at the median time since their landmark's previous sighting
    (``since``, s): {"repeat_split_s": that median, "nis_by_repeat": {"closer": ..., "further": ...}}, each half's
    count, median NIS, shares below and above the band and NIS quantiles at ``QUANTILE_PROBS`` ("quantile_probs";
    the report's quantile plot against the chi-square(2)'s), None where no landmark is seen twice. Expected under
    the model: both halves alike (the median 2 log 2 = 1.386). A noise with heavier tails than the model's lowers
    both medians alike; errors that persist from one sighting of a landmark to the next, or a motion noise that the
    model averages (larger in the turns than between them), lower the closer half's (``_repeat_text``; measured on
    simulated logs, docs/results.md)."""
    lo, hi = NIS_BAND
    gap, kept_nis = since[kept], nis[kept]
    seen = gap[np.isfinite(gap)]  # a landmark's first sighting has no time since: it goes with the further half
    if not len(seen):
        return {"repeat_split_s": None, "nis_by_repeat": None, "quantile_probs": list(QUANTILE_PROBS)}
    split = float(np.median(gap))
    split = split if np.isfinite(split) else float(np.max(seen))
    halves = {}
    for name, part in (("closer", gap <= split), ("further", gap > split)):
        z = kept_nis[part]
        halves[name] = {"sightings": int(part.sum()), "median": float(np.median(z)) if len(z) else float("nan"),
                        "below_band": _share(z < lo), "above_band": _share(z > hi),
                        "quantiles": np.quantile(z, QUANTILE_PROBS).tolist() if len(z) else None}
    return {"repeat_split_s": split, "nis_by_repeat": halves, "quantile_probs": list(QUANTILE_PROBS)}


def _share(mask: np.ndarray) -> float:
    return float(np.mean(mask)) if len(mask) else float("nan")


def shape_text(statistic: str, shape: dict[str, Any]) -> str:
    """A sentence on where the log's innovations depart from the model's Gaussian, for a NIS statistic of the check
    ("" for any other statistic or without a shape)."""
    if not shape or "NIS" not in statistic or not shape.get("sightings"):
        return ""
    pct = lambda x: f"{100 * x:.1f}%"  # noqa: E731
    sides = (f"{pct(shape['nis_below_band'])} of the sightings fall below the model's 95% NIS band (predicted more "
             f"closely than its noise says) and {pct(shape['nis_above_band'])} above it (2.5% each expected)")
    parts = "; ".join(f"the {c}'s normalized innovation is beyond 1.96 on {pct(shape[c]['outside_95'])} "
                      f"({100 * OUTSIDE_EXPECTED:g}% expected), its median |value| {shape[c]['median_abs']:.2f} "
                      f"({MEDIAN_ABS_EXPECTED:.2f})" for c in COMPONENTS)
    edges = shape["turn_rate_edges_rad_s"]
    worst = max(COMPONENTS, key=lambda c: shape[c]["outside_95"])
    thirds = " / ".join(pct(x) for x in shape[worst]["outside_95_by_turn_rate"])
    turns = (f"the {worst}'s beyond 1.96 on {thirds} in the slowest / middle / fastest third of the commanded turn "
             f"rates ({' / '.join(f'{e:.2g}' for e in edges)} rad/s)")
    return f"{sides}; {parts}; {turns}" + _repeat_text(shape)


def _repeat_text(shape: dict[str, Any]) -> str:
    """The clause on the NIS by the time since the landmark's last sighting (``by_time_since_last_sighting``), with
    what the two halves' medians say ("" for a shape without it): the closer half's below ``PERSIST_RATIO`` times the
    further's, errors that persist between sightings or a motion noise that varies; the further half's below
    ``PERSIST_RATIO`` times the Gaussian's, a core sharper than the model's noise even after a gap (the noise's
    shape). Both can hold."""
    halves = shape.get("nis_by_repeat")
    if not halves or not halves["closer"]["sightings"] or not halves["further"]["sightings"]:
        return ""
    near, far = halves["closer"]["median"], halves["further"]["median"]
    text = (f"; the NIS's median {near:.2f} on the sightings within {shape['repeat_split_s']:.2g} s of their "
            f"landmark's last and {far:.2f} on the others ({NIS_MEDIAN_EXPECTED:.2f} expected)")
    says = []
    if near < PERSIST_RATIO * far:
        says.append("a sighting just after another of its landmark is predicted more closely than one after a gap, "
                    "which the model's noise does not allow (errors that persist between sightings: a landmark's "
                    "bias, landmark_bias or landmark_bearing_bias; or a motion noise larger in some stretches than "
                    "the model's average: turn_heading_noise)")
    if far < PERSIST_RATIO * NIS_MEDIAN_EXPECTED:
        says.append("the sightings after a gap too have a sharper core than the model's Gaussian (the noise's shape: "
                    "heavy_tailed_noise)")
    return text + (": " + "; and ".join(says) if says else "")
