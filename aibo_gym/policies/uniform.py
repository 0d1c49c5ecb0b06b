"""``uniform``: every ``hold_s`` a command drawn uniformly among those whose predicted path keeps
``margin_mm`` inside the field (by the onboard estimate); no balancing of command use."""

from __future__ import annotations

from .base import HoldPolicy, register_policy

PATH_POINTS = 25


@register_policy
class UniformPolicy(HoldPolicy):
    name = "uniform"
    defaults = {"hold_s": 5.0, "margin_mm": 300.0}

    def choose(self) -> int:
        xy, _ = self.tracker.predict_holds(self.hold_s, PATH_POINTS)
        return int(self.rng.choice(self.candidates(xy)))
