"""Every knob of the EM fit (``EMOptions``) and the defaults behind them, in one module that imports nothing of
the fit: the loop (``fit``), its acceleration (``accel``), the M-step (``mstep``) and every caller read the
options from here (issue 21: this ended an import cycle between ``fit``, ``accel`` and ``mstep``)."""

from __future__ import annotations

from dataclasses import dataclass, replace

#: First-iteration outlier gate on the innovation's Mahalanobis^2 (2 dof: p = 1.4e-11). Not the
#: chi-square 0.999 quantile (13.8): with the paper's very poor start that prunes ~12% of honest
#: sightings and biases sigma_angle by ~20% (README, "Options").
DEFAULT_GATE = 50.0
#: Sensor curve degree per basis when ``EMOptions.degree`` is None: the paper's cubic in d; c0 + c1/d + c2/d^2.
DEFAULT_DEGREE = {"power": 3, "inverse": 2}
#: The sensor basis of a fresh start when ``EMOptions.basis`` is None, per sensor kind: a pinhole height
#: is c1/d (README, "EM at the information bound"); a range is d.
DEFAULT_BASIS = {"height_px": "inverse", "range_mm": "power"}
#: What EM does with a range sensor's curve (``EMOptions.range_curve``).
RANGE_CURVES = ("held", "free", "freed")
#: The switch to the scoring finish (``EMOptions.switch_gain``) looks at the best likelihood's gain over
#: this many iterations, and not before this many E-steps (the screening's included).
SWITCH_WINDOW = 10
COMPARABLE_IMPROVEMENT = 0.1  # nats: the stop rule's record margin in fits that are compared (``comparable``)
#: The default stop rule (min_improvement nats, patience iterations) of a base model; a model with effects fitted
#: with it resolves to the strict rule (``learners.em.learner.fit_options``).
EARLY_STOP = (1.0, 10)
STRICT_PATIENCE = 50  # iterations: the paper's patience, kept by fits whose likelihoods are compared
SWITCH_MIN_ITER = 60


@dataclass
class EMOptions:
    """Every knob of the EM fit. Defaults follow the measured evidence (README, "Options");
    ``EMOptions.paper()`` is the paper's recipe as written."""

    max_iter: int = 3000
    # The stop rule (a deviation from the paper, issue 19): stop after ``patience`` iterations without a new best
    # likelihood that beats the old by ``min_improvement`` nats; paper: 50 iterations, any amount (``paper()``).
    # EM's late iterations climb a ridge of the EKF likelihood that moves no velocity: on 10 + 10 fifteen-minute logs
    # (paper-sim, aibo; ``scripts/monte_carlo.py --variants slow screen30 default``, docs/results.md) 1 nat and 10
    # iterations (with starts screened 15 iterations) gave the same velocity errors (vx 1.48 vs 1.45%, vy 1.25 vs
    # 1.26%, vtheta 0.78 vs 0.78% on paper-sim; 1.34 / 1.52 / 0.73 vs 1.33 / 1.56 / 0.73% on aibo), a sensor curve
    # 0.005-0.011 px worse, in 123-136 instead of 345-396 E-steps. Fits whose likelihoods are compared with each
    # other (the discrepancy search, the lag profile, the calibrated check's refits) keep converging to 0.1 nats, and
    # so does a model with effects fitted with these defaults (EARLY_STOP; EM moves an effect's parameters slowly).
    patience: int = 10
    gate: float | None = DEFAULT_GATE  # first-iteration Mahalanobis^2 gate; None disables pruning
    sensor_method: str = "cubature"  # paper: "sample" (one draw per sighting); deterministic: "cubature"
    n_samples: int = 1  # paper: one sample per frame (method "sample")
    basis: str | None = None  # sensor curve basis: "power" (paper) or "inverse"; None: --init's, else DEFAULT_BASIS
    degree: int | None = None  # sensor curve degree; None: DEFAULT_DEGREE of the basis (paper: cubic)
    learn_motion_noise: bool = True  # paper: fixed Sigma_A (10 mm, 10 mm, 0.1 rad)
    estep: str = "compiled"  # "compiled" (numba) or "numpy" (the per-step reference)
    accel: str = "squarem"  # paper: "none"; "squarem": extrapolated EM with a monotone safeguard
    min_improvement: float = 1.0  # a new best must beat the old by this (nats); paper: any amount (see patience)
    starts: int = 3  # starts screened, the most likely continued (``learners.em.starts``); paper: 1
    screen_iter: int = 15  # EM iterations each start runs before the most likely is chosen (was 30: the same errors)
    alias_search: bool = True  # search heading aliases after the fit (``learners.em.alias``); paper: off
    # continuous commands: after the fit, profile an actuation lag and keep it when significant (``learners.em.lag``)
    lag_search: bool = True
    uncertainty: bool = True  # standard errors from the Fisher information (``learners.em.uncertainty``)
    # after EM: "none" (EM's own stop, as the paper) or "scoring": EM stops early and Fisher scoring climbs to
    # the likelihood's maximum (``learners.em.finish``; off by default: README, "EM at the information bound")
    finish: str = "none"
    switch_gain: float = 1.0  # with the finish, EM stops once SWITCH_WINDOW iterations gained less (nats)
    seed: int = 0
    frozen: tuple[str, ...] = ()  # effects held at their values (profile likelihood), by name
    # once EM has converged: each free effect's ``polish`` (a direct maximization of the likelihood over its own
    # parameters, the rest held: ECME's conditional step) and EM resumed from it, at most ``fit.POLISH_ROUNDS`` times.
    # Off by default (the search's fits, ``aibo learn``); on in ``aibo diagnose``'s final fit, whose values the report
    # states (``learners.discrepancy.final``; evidence: docs/results.md, calibration)
    polish: bool = False
    # a range sensor (range_mm): "held" keeps its curve at the start's (range = distance: the sensor reports metres)
    # and screens no stretched starts; "free": EM fits the cubic as for a height (the paper); "freed": from a start
    # that stands still (the paper's), the fit with the curve held, then the curve freed from that fit's world (a warm
    # start's curve is free: its world is found). Default "freed" (deviation from the paper: from the paper's start the
    # free curve ended in wrong worlds on MRCLAM robots 3 and 4, docs/results.md "Why robots 3 and 4 ..."; held, the
    # robots' ranges read 2-5% longer than the curve; freed from the held fit, the forward speed on the unseen halves
    # summed 55.1 -> 52.5 mm/s for learn and 54.5 -> 51.7 for diagnose's model: "The range curve freed by default")
    range_curve: str = "freed"
    # a range sensor (range_mm) from the paper's start: the range's shrink away from the image centre (the effect
    # ``off_center_shrink``, k from 0) fitted with the rest. A range computed from a landmark's apparent size is the
    # depth along the camera's axis (d cos(phi)), not the distance; held at the distance, EM read the range's sweep
    # across the image on arcs as forward motion (MRCLAM robot 5's whole-log forward error 0.69x the face value's;
    # with it 0.36-0.47x on all five robots: docs/results.md, "A range is depth"). Paper: off (a camera's heights).
    range_shrink: bool = True
    # continuous (v, omega) commands with a range sensor, from a start that stands still (the paper's): the
    # first-iteration outlier gate is judged once, under the commands' face value, and every start sees the same
    # sightings (``learners.em.learner.face_value_gate``); a warm start (one that moves) is gated at itself
    # (``learners.em.learner.stands_still``)
    face_value_gate: bool = True
    # a fit from the paper's start that ends in a wrong world is fitted again from the same start with a share of
    # spurious sightings (``false_sightings``) in the model from the first iteration: with 8-10% of them on 5-minute
    # ``aibo`` logs the fit without them put 54-99% of the smoothed poses off the field, the refit found the field and
    # the rate (docs/results.md, "Spurious sightings: the refit of a wrong world"). Paper: off (the wrong world is an
    # error).
    spurious_refit: bool = True
    # continuous (v, omega) commands with a range sensor, from the paper's start (range_curve "freed"): the held-curve
    # fit made a second time from the commands' face value (``learners.em.learner.face_value_start``) and kept where it
    # is more than ``FACE_START_MARGIN_NATS`` (5) more likely on the same sightings. From the paper's start alone EM
    # settled in a wrong world on MRCLAM Dataset 6's robot 1 (first half: the turn rate's error 1.5 times the face
    # value's on the other half; docs/results.md, "A second start at the face value"). Paper: off (one start).
    face_value_start: bool = True
    # where the fit finds a landmark whose sightings fit another's map position (``learners.em.map_check``: their ids
    # swapped, or maybe: ``swaps``, ``suspects``), it is made again from the start on the logs with the pair's ids
    # exchanged (``map_check.repaired``) and that fit kept where it explains them better (``exchange_holds``); other
    # disagreements are warned of only. MRCLAM Dataset 1 holds such a pair on every robot (docs/results.md,
    # "Landmarks where the map does not put them"). Paper: off (the map as given).
    map_repair: bool = True
    hold_curve: bool = False  # internal: the curve held at its start (range_curve "held"; a final fit's first stage)
    # ``aibo diagnose``'s final fit (``learners.discrepancy.final.fit_from``; EM itself does not read it): once converged,
    # the motion noise's position block moved to the restricted likelihood's maximum (``learners.em.restricted``) and
    # held there for the rest of the fit and its intervals. Off by default (the paper and every measured default keep
    # maximum likelihood): on 50 five-minute `aibo` logs of a 12 mm/s floor drift it took the position noise's sd from
    # 1.27 to 2.8 mm per frame (truth 3) and the drift's intervals from 82% to 87% coverage along it (`paper-sim`: 88% to
    # 92%); on MRCLAM robot 5 it changed nothing (docs/results.md, "The motion noise at the likelihood's maximum")
    restricted_noise: bool = False
    # ``aibo diagnose``'s final fit (``learners.discrepancy.final.diagnosed``; EM itself does not read it): the named
    # effects' variance parameters (``EffectModel.VARIANCE_PARAMS``: a bias process's sd and correlation time) moved
    # from the likelihood's maximum towards the restricted likelihood's by a Newton step, shortened where the
    # likelihood falls faster than its information says (``learners.em.restricted.restricted_step``), their intervals
    # with them. Measured on 50 five-minute `aibo` logs of ``landmark_bias`` (0.05, 8 s): sigma_rel's intervals hold
    # the truth on 90% (maximum likelihood: 80%), its bias +0.12 standard errors (-0.90); on 50 `paper-sim` logs 86%
    # (91%), +0.92 (+0.19), where the states' own upward bias is no longer cancelled by the velocities' share
    # (docs/results.md, "A bias process's sd by restricted likelihood"). Paper: no effects, nothing to step.
    restricted_variances: bool = True

    def comparable(self) -> "EMOptions":
        """These options with the stop rule of fits whose likelihoods are compared with each other (a likelihood-ratio
        test, a profile): a new best must beat the old by 0.1 nats, patience at least 50 (before the search caps
        it), starts screened 30 iterations: the defaults before issue 19's early stop, kept where nats are compared."""
        # and on the logs as given: a fit that repaired its logs (``map_repair``) would be compared on other sightings
        return replace(self, min_improvement=min(self.min_improvement, COMPARABLE_IMPROVEMENT),
                       patience=max(self.patience, STRICT_PATIENCE), screen_iter=max(self.screen_iter, 30),
                       map_repair=False)

    @classmethod
    def paper(cls, **overrides) -> "EMOptions":
        """The paper's recipe: fixed motion noise, one sample per sighting, plain EM, strict stop rule."""
        base = dict(sensor_method="sample", learn_motion_noise=False, accel="none", min_improvement=0.0,
                    patience=STRICT_PATIENCE,
                    basis="power", degree=3, starts=1, alias_search=False, lag_search=False, range_curve="free",
                    range_shrink=False, face_value_gate=False, spurious_refit=False, face_value_start=False,
                    map_repair=False)
        return cls(**{**base, **overrides})

    def validate(self) -> "EMOptions":
        if self.sensor_method not in ("sample", "cubature"):
            raise ValueError(f"sensor_method must be 'sample' or 'cubature', got {self.sensor_method!r}")
        if self.accel not in ("none", "squarem"):
            raise ValueError(f"accel must be 'none' or 'squarem', got {self.accel!r}")
        if self.estep not in ("compiled", "numpy"):
            raise ValueError(f"estep must be 'compiled' or 'numpy', got {self.estep!r}")
        if self.finish not in ("none", "scoring"):
            raise ValueError(f"finish must be 'none' or 'scoring', got {self.finish!r}")
        if self.range_curve not in RANGE_CURVES:
            raise ValueError(f"range_curve must be one of {', '.join(RANGE_CURVES)}, got {self.range_curve!r}")
        if self.basis is not None and self.basis not in DEFAULT_DEGREE:
            raise ValueError(f"basis must be 'power' or 'inverse', got {self.basis!r}")
        for name in ("max_iter", "patience", "n_samples", "degree", "starts", "screen_iter"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        return self

    def sensor_basis(self, kind: str = "height_px", init_basis: str | None = None) -> str:
        """The basis of the fit: the option, else the start model's (``init_basis``), else DEFAULT_BASIS
        of the sensor ``kind``."""
        return self.basis or init_basis or DEFAULT_BASIS[kind]

    def sensor_degree(self, basis: str) -> int:
        """The curve's degree: the option, else DEFAULT_DEGREE of ``basis``."""
        return self.degree if self.degree is not None else DEFAULT_DEGREE[basis]
