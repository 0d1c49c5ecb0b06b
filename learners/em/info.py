"""``FitInfo``: what ``EMLearner.fit`` reports besides the model, as a typed record.

Wall-clock timings live apart in ``FitTimings``, so the model file (``learners.model.io.run_record``) leaves
them out by construction: the same inputs and seed write the same bytes. ``FitInfo.to_dict()`` gives the
flat dict the JSON outputs have always held (results.jsonl, report.json, the model file's ``info``): its keys,
order and values are a contract.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class FitTimings:
    """Wall-clock (and CPU) seconds of a fit's parts; None: the part did not run."""

    first_iteration: float = 0.0  #: s, the first EM iteration (carries the one-time numba compile or cache load)
    per_iteration: float = 0.0  #: s, median of the later EM iterations
    alias_search: float | None = None  #: s, the heading-alias search (``learners.em.alias``)
    lag_search: float | None = None  #: s, the actuation-lag search (``learners.em.lag``)
    scoring: float | None = None  #: s, the scoring finish (``learners.em.finish``)
    uncertainty: float | None = None  #: s, the standard errors (wall clock)
    uncertainty_cpu: float | None = None  #: s, the standard errors (CPU time of this process)


@dataclass
class FitInfo:
    """``EMLearner.fit``'s run information. Optional parts are None when they did not run."""

    best_iteration: int  #: 1-based iteration of the returned model
    resumed_from: int  #: iteration the checkpoint resumed from; 0: a fresh start
    options: dict[str, Any]  #: the ``EMOptions`` used, as a dict
    off_field_fraction: float = 0.0  #: share of smoothed poses far outside the field
    undetermined: list[str] = field(default_factory=list)  #: parameters the data did not determine
    iterations_all_starts: int = 0  #: E-steps of the whole fit (winner, screening, searches)
    starts: list[dict] | None = None  #: the screening's record per start (``learners.em.starts``)
    alias_search: dict | None = None
    lag_search: dict | None = None
    scoring: dict | None = None
    standard_errors: dict | None = None
    #: the same from the robust (sandwich) covariance (``learners.em.uncertainty.sandwich``)
    robust_standard_errors: dict | None = None
    information: dict | None = None
    warnings: list[str] = field(default_factory=list)
    #: sightings the first gate, judged under the commands at face value, set aside (``learners.em.support``)
    face_value_gate_pruned: int | None = None
    #: EM's falls (``learners.em.learner.setback_record``): the largest over one EM step and the largest from its best,
    #: {"nats", "iteration", "from_best_nats", "from_best_iteration", "iterations"} (1-based); None: it never fell
    setback: dict | None = None
    #: the refit of a wrong world with spurious sightings (``EMOptions.spurious_refit``): {"off_field_fraction": the
    #: share of smoothed poses off the field of the fit it replaced}; None: no refit
    spurious_refit: dict | None = None
    #: ``EMOptions.range_curve`` "freed": the fit with the curve held that the free curve started from,
    #: {"iterations", "loglik" (nats), "curve" (its coefficients), "pruned"}; None: no such stage
    held_curve_fit: dict | None = None
    #: ``EMOptions.restricted_noise`` (a final fit of ``aibo diagnose``): the motion noise moved to the restricted
    #: likelihood's maximum (``learners.em.restricted.restricted_noise``' record); None: not done
    restricted_noise: dict | None = None
    #: ``EMOptions.restricted_variances`` (a final fit of ``aibo diagnose``): the named effects' variance parameters
    #: moved to the restricted likelihood's maximum (``learners.em.restricted.restricted_step``' record); None: none
    restricted_variances: dict | None = None
    #: the landmarks whose sightings disagree with the map (``learners.em.map_check.MapDisagreement.to_dict`` each; []:
    #: none); None: not checked
    map_check: list[dict] | None = None
    #: ``EMOptions.map_repair``: the fit tried on the logs with the ids of ``map_check``'s pairs that may be swapped
    #: exchanged (``learners.em.map_check.repair_record``: {"exchanged": [[a, b, their sightings], ...], "left_out":
    #: [as given, exchanged], "sightings", "named", "held"}); "held" true: what the fit returned was made on them; None: none
    map_repair: dict | None = None
    #: the stretches of the logs where the fitted model lost track of the robot, every sighting there left out
    #: (``learners.em.map_check.LostStretch.to_dict`` each; []: none); None: not checked
    lost_track: list[dict] | None = None
    #: ``aibo learn``'s check of a range sensor's bearings whose fit looks wrong (``learners.em.bearing_sign.
    #: sign_check``: both fits' log-likelihoods and bearing noise); None: not made (the bearings looked right)
    bearing_sign: dict | None = None
    timings: FitTimings = field(default_factory=FitTimings)

    def to_dict(self, timings: bool = True) -> dict[str, Any]:
        """The flat dict of the JSON outputs (keys ``*_seconds`` for the timings; ``timings=False``: none)."""
        t = self.timings if timings else None
        out: dict[str, Any] = {"best_iteration": self.best_iteration, "resumed_from": self.resumed_from}
        if t:
            out |= {"first_iteration_seconds": t.first_iteration, "seconds_per_iteration": t.per_iteration}
        out |= {"options": self.options, "off_field_fraction": self.off_field_fraction,
                "undetermined": self.undetermined}
        if self.starts:
            out["starts"] = self.starts
        out["iterations_all_starts"] = self.iterations_all_starts
        for name in ("alias_search", "lag_search", "scoring"):
            if getattr(self, name) is not None:
                if t:
                    out[f"{name}_seconds"] = getattr(t, name)
                out[name] = getattr(self, name)
        if self.standard_errors is not None:
            out["standard_errors"] = self.standard_errors
        if self.robust_standard_errors is not None:
            out["robust_standard_errors"] = self.robust_standard_errors
        if self.information is not None:
            out["information"] = self.information
        if t and t.uncertainty is not None:
            out |= {"uncertainty_seconds": t.uncertainty, "uncertainty_cpu_seconds": t.uncertainty_cpu}
        out["warnings"] = self.warnings
        if self.face_value_gate_pruned is not None:
            out["face_value_gate_pruned"] = self.face_value_gate_pruned
        if self.setback is not None:
            out["setback"] = self.setback
        if self.spurious_refit is not None:
            out["spurious_refit"] = self.spurious_refit
        if self.held_curve_fit is not None:
            out["held_curve_fit"] = self.held_curve_fit
        if self.restricted_noise is not None:
            out["restricted_noise"] = self.restricted_noise
        if self.restricted_variances is not None:
            out["restricted_variances"] = self.restricted_variances
        if self.map_check is not None:
            out["map_check"] = self.map_check
        if self.map_repair is not None:
            out["map_repair"] = self.map_repair
        if self.lost_track is not None:
            out["lost_track"] = self.lost_track
        if self.bearing_sign is not None:
            out["bearing_sign"] = self.bearing_sign
        return out

    # Read access by key, as for the other learners' plain ``info`` dicts (``result.info["best_iteration"]``).
    def __getitem__(self, key: str) -> Any:
        return self.to_dict()[key]

    def __contains__(self, key: object) -> bool:
        return key in self.to_dict()

    def get(self, key: str, default: Any = None) -> Any:
        return self.to_dict().get(key, default)
