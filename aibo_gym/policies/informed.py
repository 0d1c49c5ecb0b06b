"""``informed``: greedy in the expected information about the action and sensor models.

Every ``hold_s`` seconds, for each command whose predicted path (nominal velocities, from the
onboard EKF estimate) keeps ``margin_mm`` inside the field, it predicts the sightings of holding
it (the head-pan schedule, field of view, range and detection probability of the camera:
:meth:`OnboardTracker.expected_sightings`) and scores

    log(1 + E_a / (prior_sightings + S_a))  +  coverage_weight * new_a

E_a: expected sightings during the hold; S_a: sightings gathered so far while holding command a
(the data that determine its velocity; the log is the diminishing return of more of them, as the
log-determinant of a growing information matrix); new_a: coverage cells (command x distance bin
x bearing bin) not yet visited that the predicted sightings would visit (the sensor curve over
distances, each command seen from several geometries). The highest score wins (ties at random).
Only onboard information is used.
"""

from __future__ import annotations

import math

import numpy as np

from .base import HoldPolicy, register_policy
from .onboard import N_BEARING_BINS, N_DIST_BINS


@register_policy
class InformedPolicy(HoldPolicy):
    name = "informed"
    defaults = {"hold_s": 5.0, "margin_mm": 300.0, "prior_sightings": 30.0, "coverage_weight": 0.05,
                "path_points": 30.0}

    def scores(self) -> tuple[np.ndarray, np.ndarray]:
        """(candidates, their scores)."""
        tr = self.tracker
        points = max(2, int(self.params["path_points"]))
        xy, heading = tr.predict_holds(self.hold_s, points)
        cand = self.candidates(xy)
        expected, seen = tr.expected_sightings(xy[cand], heading[cand], self.hold_s)
        score = np.log1p(expected / (self.params["prior_sightings"] + tr.seen[cand]))
        w = self.params["coverage_weight"]
        if w:
            span = tr.rmax - tr.rmin
            for i, a in enumerate(cand):
                d, b = seen[i, :, 0], seen[i, :, 1]
                ok = np.isfinite(d)
                if not ok.any():
                    continue
                db = np.clip(((d[ok] - tr.rmin) / span * N_DIST_BINS).astype(int), 0, N_DIST_BINS - 1)
                bb = np.clip(((b[ok] + math.pi) / (2 * math.pi) * N_BEARING_BINS).astype(int), 0, N_BEARING_BINS - 1)
                cells = np.unique((a * N_DIST_BINS + db) * N_BEARING_BINS + bb)
                score[i] += w * np.count_nonzero(~tr.cells[cells])
        return cand, score

    def choose(self) -> int:
        cand, score = self.scores()
        best = cand[score >= score.max() - 1e-12]
        return int(self.rng.choice(best))
