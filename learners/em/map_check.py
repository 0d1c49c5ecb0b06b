"""Landmarks whose sightings disagree with the map: a map position that is wrong, or two landmarks whose ids are
swapped (in the map's rows or in the table that turns a detector's ids into landmarks).

A fitted model's smoothed poses say where the robot was. A landmark whose sightings that model mostly leaves out
(beyond its outlier gate, every sighting of the logs judged: more than ``LEFT_OUT_SHARE``) is looked at through the
bearings of the sightings left out alone, so that neither the range curve nor the size model enters: where their
median bearing error at the landmark's map position is small (``AGREES_RAD``) they were left out for their sizes or
their noise, not the map; where it is large, the map disagrees. Where they fit another landmark's map position, its id
is the likely error (of several positions in one direction, the one nearest the point their rays cross at), and two
landmarks whose sightings each fit the other's position (or one's the other's, the other named too with its sightings
at no landmark's position) are a swapped pair; otherwise that point (``triangulate``) says where the landmark is.
``EMOptions.map_repair`` fits again on the logs with the ids exchanged of each swapped pair and of each pair that may
be one (``suspects``: a landmark at another's position that is not named, its sightings absorbed by a world the wrong
map bent), and keeps that fit where it explains the logs better (``exchange_holds``: at least ``MIN_SIGHTINGS`` fewer
sightings left out, and neither landmark named by its own check). The other findings are warned of only: a fit in a
world the wrong map bent can leave out a right landmark's sightings too (MRCLAM Dataset 1, robot 1's first half: two
landmarks near the swapped one named as moved when the first gate's pruning counted as left out), and a moved landmark
has no id to exchange.

Measured (``scripts/mrclam_without_truth.py``, ``aibo learn`` with its defaults; docs/results.md, "Landmarks where the
map does not put them"): MRCLAM Dataset 1 (a run never used to build anything here; its files as kept in GitHub
curow/multi-robot-localization) sees landmarks 5 and 11 (subjects 11 and 17) where its map puts the other on every
robot: robot 1's fit left out 462 of 546 and 230 of 230 of their sightings, whose bearings miss their own map
positions by 2.6 and 1.8 rad (median) and fit each other's within 0.025 and 0.028 rad; repaired (robot 4's first half
as a suspect pair), all 15 fits of Dataset 1 (whole logs and halves) are the fits with the map corrected by hand,
number for number. On the ten whole logs of Datasets 6 and 7 and the 36 fits of Datasets 2-4 it names no landmark.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from aibo_core.geometry import wrap
from aibo_core.trajectory import Trajectory
from learners.arrays.batch import Batch, make_batch
from learners.model.model import Model

#: Fewest sightings of a landmark for a verdict on it.
MIN_SIGHTINGS = 20
#: A landmark is looked at again when the fit left out more than this share of its sightings.
LEFT_OUT_SHARE = 0.5
#: The median |bearing error| (rad) of the sightings left out, against a map position, at or below which they are
#: sightings of a landmark there (its own: they were left out for another reason, not the map's).
AGREES_RAD = 0.1
#: ``triangulate``: rays further than this many times the median distance from the point are dropped, twice.
TRIM = 3.0
#: ``lost_track``: a sighting is where the fit lost track when, of the sightings within this many seconds of it (its
#: own log's, at least ``LOST_MIN_SIGHTINGS``), the fit applied fewer than ``LOST_SHARE``.
LOST_WINDOW_S = 5.0
LOST_MIN_SIGHTINGS = 5
LOST_SHARE = 0.5


@dataclass(frozen=True)
class MapDisagreement:
    """One landmark whose sightings the map does not explain (indices into the log's ``landmarks``, 0-based)."""

    landmark: int
    sightings: int
    left_out: int  # of them, not applied by the fit
    map_xy: tuple[float, float]  # mm
    bearing_error_rad: float  # the median |bearing error| of those left out, at the map position
    at_landmark: int | None  # the other landmark whose map position explains their bearings (AGREES_RAD), if any
    at_bearing_error_rad: float | None  # ... their median |bearing error| there
    swapped: bool  # that landmark's sightings left out are in turn at this one's map position (``check``)
    seen_xy: tuple[float, float] | None  # mm: where their bearings put it (``triangulate``), None: nowhere determined
    seen_sd_mm: float | None  # that point's standard error along its worst direction (mm)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class LostStretch:
    """A stretch of a log where the fit applied almost none of the sightings (``lost_track``): its smoothed path is
    wrong there, so nothing it says about the map there is evidence."""

    log: int
    from_s: float  # s since the log's start: its first sighting
    to_s: float  # ... its last
    sightings: int
    left_out: int

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Judgement:
    """A fitted model's view of the logs' sightings (``judged``)."""

    found: list[MapDisagreement]  # ``check``
    left_out: int  # sightings it did not apply (pruned, or beyond the gate)
    lost: list[LostStretch]  # ``lost_track``


def triangulate(origins: np.ndarray, angles: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(the point (mm) nearest, in the least-squares sense, to the rays from ``origins`` (n, 2) mm in directions
    ``angles`` (n,) rad, rays far from it dropped twice (``TRIM``); its standard error along its worst direction, mm,
    from the rays' scatter about it); None where the rays do not cross at usable angles (all nearly parallel) or the
    point lies behind most of them."""
    dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    keep = np.ones(len(origins), bool)
    for _ in range(3):
        u = dirs[keep]
        proj = np.eye(2)[None] - u[:, :, None] * u[:, None, :]  # I - u u^T per ray
        A, b = proj.sum(axis=0), np.einsum("nij,nj->i", proj, origins[keep])
        if keep.sum() < 3 or np.linalg.eigvalsh(A)[0] < 1e-3 * keep.sum():  # directions within about 2 degrees
            return None
        point = np.linalg.solve(A, b)
        rel = point - origins
        dist = np.abs(rel[:, 0] * dirs[:, 1] - rel[:, 1] * dirs[:, 0])  # each ray's perpendicular distance
        used, keep = keep, dist <= TRIM * max(float(np.median(dist[keep])), 1.0)
    ahead = np.einsum("ni,ni->n", point - origins[used], dirs[used]) > 0
    if ahead.mean() <= 0.5:
        return None
    scatter = float(np.sum(dist[used] ** 2) / max(int(used.sum()) - 2, 1))
    return point, float(np.sqrt(scatter * np.linalg.eigvalsh(np.linalg.inv(A))[-1]))


def bearing_errors(origins: np.ndarray, angles: np.ndarray, places: np.ndarray) -> np.ndarray:
    """(B,) the median |bearing error| (rad) of rays from ``origins`` (n, 2) in directions ``angles`` (n,) at each of
    ``places`` (B, 2) mm."""
    want = np.arctan2(places[:, None, 1] - origins[None, :, 1], places[:, None, 0] - origins[None, :, 0])
    return np.median(np.abs(wrap(angles[None] - want)), axis=1)


def where_seen(pose: np.ndarray, world: np.ndarray, rays: np.ndarray, landmarks: np.ndarray,
               own: int) -> tuple[np.ndarray, int | None, tuple[np.ndarray, float] | None]:
    """For the sightings ``rays`` ((S,) bool) of landmark ``own``: (the median |bearing error| at every landmark's map
    position, (B,) rad; the other landmark whose position they fit (``AGREES_RAD``), the nearest to the point their
    rays cross at where there is one, since bearings alone cannot tell apart two positions in one direction; that
    point, ``triangulate``)."""
    err = bearing_errors(pose[rays, :2], world[rays], landmarks)
    seen = triangulate(pose[rays, :2], world[rays])
    fit = [k for k in range(len(landmarks)) if k != own and err[k] <= AGREES_RAD]
    if not fit:
        return err, None, seen
    if seen is None:
        return err, min(fit, key=lambda k: err[k]), None
    return err, min(fit, key=lambda k: float(np.hypot(*(landmarks[k] - seen[0])))), seen


def lost_sightings(batch: Batch, applied: np.ndarray) -> np.ndarray:
    """(S,) bool: the sightings of ``batch`` where the fit lost track, of the sightings within ``LOST_WINDOW_S`` of
    each (its own log's, at least ``LOST_MIN_SIGHTINGS``) fewer than ``LOST_SHARE`` applied (``applied`` (S,)). A
    filter whose heading or position went wrong (a turn, a slip or a push its motion model does not predict, with no
    sighting to correct it) gates out every sighting after it until it is found again: MRCLAM Dataset 9, robot 4's
    second half, 9 s of turning unseen and then 143 of 144 sightings over 58 s left out."""
    key = batch.sight_log * 1e9 + batch.frame_time[batch.sight_frame]  # s, logs kept apart; non-decreasing
    done = np.concatenate([[0], np.cumsum(applied)])
    lo = np.searchsorted(key, key - LOST_WINDOW_S, "left")
    hi = np.searchsorted(key, key + LOST_WINDOW_S, "right")
    near = hi - lo
    return (near >= LOST_MIN_SIGHTINGS) & (done[hi] - done[lo] < LOST_SHARE * near)


def lost_track(batch: Batch, applied: np.ndarray) -> list[LostStretch]:
    """The stretches of ``lost_sightings`` (runs of them, in each log's time order) that left out at least
    ``MIN_SIGHTINGS`` / 2 sightings."""
    lost = lost_sightings(batch, applied)
    time = batch.frame_time[batch.sight_frame]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], lost.astype(np.int8), [0]])))
    out = []
    for a, b in zip(edges[::2], edges[1::2]):  # runs [a, b) of lost sightings
        logs = batch.sight_log[a:b]
        for k in np.unique(logs):  # a run that crosses from one log to the next is two stretches
            idx = np.arange(a, b)[logs == k]
            left = int(np.count_nonzero(~applied[idx]))
            if left >= MIN_SIGHTINGS / 2:
                out.append(LostStretch(int(k), float(time[idx[0]]), float(time[idx[-1]]), len(idx), left))
    return out


def lost_warning(lost: list[LostStretch]) -> list[str]:
    """The line that says where the fit lost track (``lost_track``), if anywhere."""
    if not lost:
        return []
    span = sum(st.to_s - st.from_s for st in lost)
    left, sightings = sum(st.left_out for st in lost), sum(st.sightings for st in lost)
    longest = max(lost, key=lambda st: st.to_s - st.from_s)
    where = f" of log {longest.log}" if any(st.log for st in lost) else ""
    return [f"the fit lost track of the robot in {len(lost)} stretch(es), {span:,.0f} s in all (the longest "
            f"{longest.from_s:,.0f}-{longest.to_s:,.0f} s{where}): it left out {left:,d} of the {sightings:,d} sightings "
            f"there (model.json: info[\"lost_track\"]): its smoothed path is wrong there, after a turn, slip or push "
            "the motion model does not predict with no sighting to correct it, and so is what is read from it there "
            "(the map check names no landmark from those sightings)"]


def check(batch: Batch, poses: np.ndarray, applied: np.ndarray) -> list[MapDisagreement]:
    """The landmarks whose sightings disagree with the map (module docstring): ``poses`` (P, 3) the fit's smoothed
    poses [x mm, y mm, theta rad], ``applied`` (S,) which sightings of ``batch`` the fit applied. A landmark whose
    sightings left out fit no other landmark's position is named (as moved) only where most of them were made where
    the fit kept track (``lost_sightings``): where it lost track its path, not the map, is wrong."""
    pose = poses[batch.sight_pose]
    world = pose[:, 2] + batch.sight_value[:, 1]  # the bearing is the body's (a head's pan included)
    lost = lost_sightings(batch, applied)
    found = []
    for lm in range(len(batch.landmarks)):
        mine = batch.sight_landmark == lm
        left = mine & ~applied  # those that agree with the map were applied: the others say where it is
        n, out = int(mine.sum()), int(left.sum())
        if n < MIN_SIGHTINGS or out <= LEFT_OUT_SHARE * n:
            continue
        err, at, seen = where_seen(pose, world, left, batch.landmarks, lm)
        if err[lm] <= AGREES_RAD:  # at its map position after all: left out for its sizes, or its noise
            continue
        if at is None and np.count_nonzero(left & lost) >= out / 2:  # the path lost there, not the map
            continue
        swapped = False
        if at is not None:  # a swap: the other's sightings left out (at least half of MIN_SIGHTINGS) are at this one
            theirs = (batch.sight_landmark == at) & ~applied
            if theirs.sum() >= MIN_SIGHTINGS / 2:
                their_err, their_at, _ = where_seen(pose, world, theirs, batch.landmarks, at)
                swapped = bool(their_at == lm and their_err[at] > AGREES_RAD)
        found.append(MapDisagreement(lm, n, out, tuple(map(float, batch.landmarks[lm])), float(err[lm]), at,
                                     None if at is None else float(err[at]), swapped,
                                     None if seen is None else tuple(map(float, seen[0])),
                                     None if seen is None else seen[1]))
    # where the other landmark is named too and its sightings fit no landmark's position (a world the wrong map bent:
    # MRCLAM Dataset 1's robot 4, 3,269 sightings), its being named at all is the other half of the swap's evidence
    named = {d.landmark: d for d in found}
    return [replace(d, swapped=True) if (not d.swapped and d.at_landmark in named
                                         and named[d.at_landmark].at_landmark is None) else d for d in found]


def swaps(found: list[MapDisagreement]) -> list[list[int]]:
    """The swapped pairs of ``found``, [[a, b], ...] with a < b, each once; a landmark in two pairs (the check cannot
    tell which) in none."""
    pairs = {tuple(sorted((d.landmark, d.at_landmark))) for d in found if d.swapped}
    count: dict[int, int] = {}
    for p in pairs:
        for lm in p:
            count[lm] = count.get(lm, 0) + 1
    return [list(p) for p in sorted(pairs) if count[p[0]] == count[p[1]] == 1]


def map_warnings(found: list[MapDisagreement]) -> list[str]:
    """One warning per landmark of ``found`` (a swapped pair: one for both)."""
    out, said = [], set()
    by_landmark = {d.landmark: d for d in found}
    for d in found:
        if d.landmark in said:
            continue
        head = (f"the map and the sightings disagree: the fit left out {d.left_out:,d} of {d.sightings:,d} sightings of "
                f"landmark {d.landmark} (map ({d.map_xy[0]:,.0f}, {d.map_xy[1]:,.0f}) mm), whose bearings miss its map "
                f"position by {d.bearing_error_rad:.2f} rad (median)")
        if d.swapped:
            other = by_landmark.get(d.at_landmark)
            said.add(d.at_landmark)
            theirs = "" if other is None else f" ({other.left_out:,d} of {other.sightings:,d} left out)"
            where = ("no landmark's position" if other is not None and other.at_landmark is None
                     else f"landmark {d.landmark}'s")
            out.append(f"{head} and fit landmark {d.at_landmark}'s ({d.at_bearing_error_rad:.3f} rad), while landmark "
                       f"{d.at_landmark}'s{theirs} left out fit {where}: their ids look swapped (the map's rows or the "
                       "table of detector ids); correct the map and fit again")
        elif d.at_landmark is not None:
            out.append(f"{head} and fit landmark {d.at_landmark}'s ({d.at_bearing_error_rad:.3f} rad): its id may be "
                       "wrong; correct the map and fit again")
        else:
            if d.seen_xy is None:  # no point where their rays cross: sightings of other things under its id
                out.append(f"{head}; their bearings cross at no one point: they may be of other landmarks under its id "
                           "(misread ids, reflections) rather than of a landmark the map misplaces; check the "
                           "detector's ids and the map, and fit again")
            else:
                out.append(f"{head}; they put it at ({d.seen_xy[0]:,.0f}, {d.seen_xy[1]:,.0f}) mm (+-"
                           f"{2 * d.seen_sd_mm:,.0f} mm): its map position may be wrong (or it was moved); correct the "
                           "map and fit again")
        said.add(d.landmark)
    return out


def suspects(found: list[MapDisagreement]) -> list[list[int]]:
    """The pairs of ``found`` that may be swapped but that ``swaps`` cannot vouch for: a landmark whose sightings fit
    another's map position while that other is not named (its sightings absorbed by a world the wrong map bent:
    MRCLAM Dataset 1, robot 4's first half), [[a, b], ...] with a < b, disjoint from each other and from ``swaps``;
    the refit on their exchange decides (``exchange_holds``)."""
    named = {d.landmark for d in found}
    taken = {lm for pair in swaps(found) for lm in pair}
    out: list[list[int]] = []
    for d in found:
        pair = sorted((d.landmark, d.at_landmark)) if d.at_landmark is not None else None
        if pair and not d.swapped and d.at_landmark not in named and not taken & set(pair):
            out.append(pair)
            taken |= set(pair)
    return sorted(out)


def exchanges(found: list[MapDisagreement]) -> list[list[list[int]]]:
    """The exchanges of ids to try, in order (each a list of pairs): every pair of ``found`` that is or may be swapped
    (``swaps``, ``suspects``); where some are suspects only, then the pairs ``check`` vouches for alone (a wrong suspect
    would sink their exchange with it)."""
    sure, maybe = swaps(found), suspects(found)
    return ([sorted(sure + maybe)] if sure or maybe else []) + ([sure] if sure and maybe else [])


def judged(model: Model, batch: Batch, gate: float) -> Judgement:
    """``batch``'s sightings under ``model``: its smoothed poses, the sightings not used (pruned) or beyond ``gate``
    (Mahalanobis^2) not applied; ``check`` and ``lost_track`` of them."""
    from learners.em.estep import e_step

    post = e_step(model, batch, "compiled", gate)
    applied = batch.used & ~(post.mahal2 > gate)
    return Judgement(check(batch, post.mu_gamma, applied), int(np.count_nonzero(~applied)), lost_track(batch, applied))


def named_among(pairs: list[list[int]], found: list[MapDisagreement]) -> list[int]:
    """The landmarks of ``pairs`` that ``found`` names, in order."""
    exchanged = {lm for pair in pairs for lm in pair}
    return sorted(d.landmark for d in found if d.landmark in exchanged)


def exchange_holds(left_out_before: int, after: Judgement, pairs: list[list[int]]) -> bool:
    """Whether the fit on the logs with ``pairs`` exchanged (``after``: ``judged`` by it) explains them better than the
    fit on the logs as given (which left out ``left_out_before`` sightings): at least ``MIN_SIGHTINGS`` fewer left out,
    and none of the exchanged landmarks named by its own check. A wrong exchange moves the right landmark's sightings
    to a map position where they are not: its refit leaves them out and names it."""
    return after.left_out + MIN_SIGHTINGS <= left_out_before and not named_among(pairs, after.found)


def tried_exchanges(logs: list[Trajectory], tries: list[list[list[int]]], left_out: int, gate: float,
                    fit: Callable[[list[Trajectory]], tuple[Any, Model]]) -> tuple[list[dict], Any, list[Trajectory]]:
    """Each exchange of ``tries`` (``exchanges``) in order, until one holds: ``fit(the logs exchanged)`` -> (its
    result, its model), the model ``judged`` at ``gate`` on them against ``left_out`` (the fit on ``logs`` as given).
    (every tried exchange's ``repair_record``; the result and the logs of the one that held, else None and ``logs``)."""
    records = []
    for pairs in tries:
        fixed = repaired(logs, pairs)
        result, model = fit(fixed)
        records.append(repair_record(logs, pairs, left_out, judged(model, make_batch(fixed), gate)))
        if records[-1]["held"]:
            return records, result, fixed
    return records, None, logs


def repaired(logs: list[Trajectory], pairs: list[list[int]]) -> list[Trajectory]:
    """``logs`` with the ids of each pair of ``pairs`` (``swaps``) exchanged in every sighting."""
    out = []
    for tr in logs:
        ids = tr.sighting_landmark.copy()
        for a, b in pairs:
            ids[tr.sighting_landmark == a], ids[tr.sighting_landmark == b] = b, a
        out.append(replace(tr, sighting_landmark=ids))
    return out


def repair_record(logs: list[Trajectory], pairs: list[list[int]], before: int, after: Judgement) -> dict:
    """``FitInfo.map_repair``: {"exchanged": [[a, b, their sightings], ...], "left_out": [of the sightings, by the fit
    on the logs as given (``before``), by the fit on the exchange (``after``: ``judged`` by it)], "sightings": of the
    logs, "named": the exchanged landmarks that fit's own check names, "held": ``exchange_holds``, so the fit on the
    exchange is the one returned}."""
    seen = np.concatenate([tr.sighting_landmark for tr in logs])
    return {"exchanged": [[a, b, int(np.isin(seen, [a, b]).sum())] for a, b in pairs],
            "left_out": [int(before), after.left_out], "sightings": int(len(seen)),
            "named": named_among(pairs, after.found), "held": exchange_holds(before, after, pairs)}


def repair_text(record: dict) -> str:
    """What was repaired (``FitInfo.map_repair``), e.g. "landmarks 5 and 11's ids exchanged in their 776 sightings"."""
    return ", ".join(f"landmarks {a} and {b}'s ids exchanged in their {n:,d} sightings" for a, b, n in record["exchanged"])


def left_out_text(record: dict) -> str:
    """E.g. "it leaves out 2 of 1,533 sightings, the fit on the map as given 228" (``repair_record``)."""
    (before, after), n = record["left_out"], record["sightings"]
    return f"it leaves out {after:,d} of {n:,d} sightings, the fit on the map as given {before:,d}"


def repair_warning(record: dict) -> str:
    """The line that says what the fit was made on, or that the exchange was tried and did not hold
    (``FitInfo.map_repair``)."""
    if not record["held"]:
        named = ("; its own map check names landmark(s) " + ", ".join(map(str, record["named"]))
                 if record["named"] else "")
        return (f"a fit with {repair_text(record)} was tried and explains the log(s) no better "
                f"({left_out_text(record)}{named}): the fit on the map as given is kept")
    return (f"the model was fitted again on the log(s) with {repair_text(record)} ({left_out_text(record)}; "
            "--no-map-repair fits the map as given): correct the map and these lines go")
