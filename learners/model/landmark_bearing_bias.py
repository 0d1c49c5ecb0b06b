"""``landmark_bearing_bias``: each landmark's bearing carries a slowly varying bias of its own (rad), the bearings'
counterpart of ``landmark_bias`` (learner twin of ``aibo_gym.catalogue.LandmarkBearingBias``; same name and parameter
names, a contract).

    bearing_j = wrap(atan2(dy, dx) - theta + bearing_offset_j + c_l(t_j)) + e,   l = the landmark of sighting j,

c_l a first-order Gauss-Markov process per landmark, independent across landmarks, with stationary standard deviation
``sigma_rad`` (rad) and correlation time ``tau_s`` (s): per frame of dt seconds c' = phi c + N(0, sigma_rad^2 (1 -
phi^2)), phi = exp(-dt / tau_s). A fixed offset per landmark is ``landmark_bearing_offset``; this is an error that
changes from one pass to the next (a marker seen against a different background, a barcode's visible centre moving
with the viewing angle, a camera's distortion over the part of the image the landmark crosses).

Why: on the five MRCLAM robots the likelihood of the sightings under ``aibo learn``'s whole-log models gains 209-486
nats from such states at correlation times of 20-100 s and sd 3-6 mrad, against 202-423 for fixed offsets and 111-315
at 1 s (``scripts/mrclam_noise_scans.py``, docs/results.md, "The bearings' bias states, scanned").

How the model carries it: as ``landmark_bias`` does (the same allocation of states, ``slot_schedule``; the same AR(1)
M-step and likelihood polish), each sighting's state added to its predicted bearing (``ExtraStates.bearing_slot``).
With both effects the states of the sizes come first (``LOWER_ORDER``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.model.effects import EffectModel, register_effect
from learners.model.landmark_bias import lower_ar1, maximize_ar1, polish_ar1
from learners.model.parameters import Param

if TYPE_CHECKING:
    from learners.model.model import Model

#: warm_start's grid: sigma_rad as multiples of the sensor's bearing noise, and tau_s (s). The MRCLAM scans' best rows
#: were at 0.3-0.6 of the bearing noise and 20-100 s.
WARM_GRID = ((0.25, 0.5, 1.0), (3.0, 10.0, 30.0, 100.0))


#: s: the shortest correlation time of a bearing bias that is named. On effect-free ``paper-sim`` logs (0.5 rad bearings)
#: the search with this candidate named it on 2 of 50, at 0.10 rad x 1.89 s and 0.10 x 1.83 s (seeds 1000 and 1048,
#: 5 minutes, 2026-11-30: the linearized filter's errors with bearings that coarse, over a landmark's consecutive
#: sightings); where the biases are real the fits are far above it: at 20 s simulated (``aibo``, 29 named of 50 logs)
#: 9.5-74 s, on the five MRCLAM robots 11-653 s (docs/results.md, "Bearing bias states"). ``landmark_bias``' sizes
#: keep 1 s.
MIN_PLAUSIBLE_TAU_S = 5.0


@register_effect
@dataclass(frozen=True)
class LandmarkBearingBias(EffectModel):
    """A per-landmark bearing bias (rad), a first-order Gauss-Markov process (module docstring). Residual signature: the
    bearing residuals of one landmark correlated over seconds, which shows as "bearing vs landmark"."""

    sigma_rad: float  # stationary standard deviation of c (rad)
    tau_s: float  # correlation time (s)

    name: ClassVar[str] = "landmark_bearing_bias"
    #: the calibrated check's statistics that read it (a bias that persists over a landmark's consecutive sightings; the
    #: likelihood gain of bearing states, which sees it where the heading takes it up: ``score_tests.BEARING_BIAS``), and
    #: the one where its pass-to-pass means show
    SIGNATURE: ClassVar[str] = "bearing-innovation autocorrelation"
    ALSO_SIGNATURES: ClassVar[tuple[str, ...]] = ("bearing (sigma) vs landmark", "gain of bearing states per landmark")
    PARAMS: ClassVar[dict[str, Param]] = {
        "sigma_rad": Param("rad", "log", low=0.0, high=0.5, shape=()),
        "tau_s": Param("s", "log", low=1e-3, high=1e6, shape=()),
    }
    #: a medium strength on the ``aibo`` preset (bearing noise 0.0267 rad); on MRCLAM 3-6 mrad at 20-100 s
    EXAMPLE: ClassVar[dict[str, Any]] = {"sigma_rad": 0.02, "tau_s": 20.0}
    VARIANCE_PARAMS: ClassVar[tuple[str, ...]] = ("sigma_rad", "tau_s")  # the states' covariance (REML's step)
    STARTS_OFF: ClassVar[bool] = False  # at sigma_rad 0 EM could not move it (as landmark_bias)
    #: after ``landmark_bias`` (order 0): the size states first, then the bearing states (``landmark_bias._columns``)
    LOWER_ORDER: ClassVar[int] = 1
    #: Tried only when asked for (``--candidates``): it explains the real robots' "bearing vs landmark", but on the
    #: halves they were not fitted to it costs the forward speed (MRCLAM robot 5: +30% / +13% against Vicon added
    #: alone to learn's model, first / second half; within 3% of learn's on 8 of 10 halves against the defaults' 9)
    #: (docs/results.md, "Bearing bias states").
    DEFAULT_CANDIDATE: ClassVar[bool] = False

    @classmethod
    def start(cls, batch: Batch) -> "LandmarkBearingBias":
        """A weak bias to start EM from (at sigma_rad = 0 EM could not move it)."""
        return cls(0.005, 20.0)

    def warm_start(self, model: "Model", batch: Batch, loglik: Callable[["Model"], float]) -> "LandmarkBearingBias":
        """The most likely point of ``WARM_GRID`` (forward passes, the rest of ``model`` fixed), as ``landmark_bias``."""
        noise = model.sensor.sigma_bearing
        return max((LandmarkBearingBias(f * noise, t) for f in WARM_GRID[0] for t in WARM_GRID[1]),
                   key=lambda e: loglik(model.with_effect(e)))

    def polish(self, model: "Model", batch: Batch, loglik: Callable[["Model"], float]) -> "LandmarkBearingBias":
        """(sigma_rad, tau_s) maximizing the likelihood itself, the rest held (``LandmarkBias.polish``)."""
        return polish_ar1(self, model, loglik, sigma_name="sigma_rad")

    def implausible(self) -> str:
        """A bearing 'bias' that loses its correlation within ``MIN_PLAUSIBLE_TAU_S`` is no per-landmark bias: what
        the linearized filter leaves of a coarse bearing sensor's noise over a landmark's few consecutive sightings."""
        if self.tau_s < MIN_PLAUSIBLE_TAU_S:
            return (f"tau_s {self.tau_s:.2f} s is no per-landmark bias (below {MIN_PLAUSIBLE_TAU_S:.0f} s): the bearing "
                    "noise's own correlation over a landmark's consecutive sightings (the linearized filter's)")
        return ""

    def ridge_possible(self) -> bool:
        """Below ``MIN_PLAUSIBLE_TAU_S`` the states take the sightings' own noise: the model's limit, not a ridge."""
        return self.tau_s >= MIN_PLAUSIBLE_TAU_S

    def lower(self, lo: Lowered, batch: Batch) -> None:
        lower_ar1(lo, batch, self.sigma_rad, self.tau_s, kind="bearing")

    def maximize(self, model: "Model", batch: Batch, post: Posterior, mu_star: np.ndarray) -> "Model":
        """sigma_rad, tau_s maximizing the expected log density of the states (``landmark_bias.maximize_ar1``)."""
        fitted = maximize_ar1(batch, post, kind="bearing") if self.sigma_rad > 0.0 else None  # none: no states
        return model if fitted is None else model.with_effect(LandmarkBearingBias(*fitted))
