"""The sensor model: size measurement ~ N(f(d), sigma_size^2), bearing ~ N(true bearing, sigma_bearing^2).

d is the distance (mm) from the robot to the landmark; the size is what the log's ``sensor_kind``
declares: a pinhole height in px (``height_px``, the paper's Aibo) or a range in mm (``range_mm``).
f is a linear combination of basis functions of d (``basis``):

=============  ================================  ===============================================
basis          f(d)                              use
=============  ================================  ===============================================
``power``      sum_k coef[k] d^k                 the paper's cubic (degree 3); range = d is
                                                 coef = [0, 1]
``inverse``    sum_k coef[k] d^-k                a pinhole height is c1 / d exactly
=============  ================================  ===============================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from learners.arrays.lowered import BASIS_INVERSE, BASIS_POWER, curve, fit_polynomial
from learners.model.parameters import Component, Param

BASES = {"power": BASIS_POWER, "inverse": BASIS_INVERSE}
SIZE_UNITS = {"height_px": "px", "range_mm": "mm"}
#: Distances (mm) at which the curve is represented for acceleration: Chebyshev nodes of the paper's
#: recognition range. Constants, so that a resumed fit extrapolates exactly as an unbroken one.
NODE_RANGE_MM = (1275.0, 4175.0)


def curve_nodes(m: int) -> np.ndarray:
    """m Chebyshev nodes (mm) over NODE_RANGE_MM."""
    c, h = (NODE_RANGE_MM[0] + NODE_RANGE_MM[1]) / 2, (NODE_RANGE_MM[1] - NODE_RANGE_MM[0]) / 2
    return c + h * np.cos(np.pi * (np.arange(m) + 0.5) / m)


@dataclass(frozen=True)
class SensorModel(Component):
    """f(d) in a basis of distance, Gaussian size and bearing noise (module docstring)."""

    coef: np.ndarray  # (m,) coefficients of f in ``basis``
    sigma_size: float  # px or mm, as ``kind`` declares
    sigma_bearing: float  # rad
    distance_range_mm: tuple[float, float] = NODE_RANGE_MM  # distances the data covered
    basis: str = "power"
    kind: str = "height_px"

    PARAMS: ClassVar[dict[str, Param]] = {
        "coef": Param("size per basis function", "curve"),
        "sigma_size": Param("px or mm", "log"),
        "sigma_bearing": Param("rad", "log"),
    }

    def __post_init__(self) -> None:
        if self.basis not in BASES:
            raise ValueError(f"unknown sensor basis {self.basis!r} (valid choices: {', '.join(BASES)})")
        if self.kind not in SIZE_UNITS:
            raise ValueError(f"unknown sensor kind {self.kind!r} (valid choices: {', '.join(SIZE_UNITS)})")

    @property
    def basis_id(self) -> int:
        return BASES[self.basis]

    @property
    def unit(self) -> str:
        return SIZE_UNITS[self.kind]

    def mean(self, distances_mm) -> np.ndarray:
        """Mean size measurement (px or mm, as the log declared) at distances (mm) (public API).

        The curve is learned from the distances in ``distance_range_mm``; outside it, it is an
        extrapolation of the fitted basis (a polynomial may bend away): check a distance against that
        range before trusting the value there."""
        return curve(self.basis_id, self.coef, distances_mm)[0]

    def dmean(self, distances_mm) -> np.ndarray:
        """d mean / d distance (px/mm or mm/mm)."""
        return curve(self.basis_id, self.coef, distances_mm)[1]

    def std(self, distances_mm) -> np.ndarray:
        """(N, 2) standard deviations [size (px or mm), bearing rad] at distances (mm) (public API)."""
        d = np.atleast_1d(np.asarray(distances_mm, dtype=float))
        return np.tile([self.sigma_size, self.sigma_bearing], (len(d), 1))

    def pack_curve(self, coef: np.ndarray) -> np.ndarray:
        """The curve as its values at Chebyshev nodes (px or mm): one unit = one pixel (or mm)."""
        return curve(self.basis_id, coef, curve_nodes(len(coef)))[0]

    def unpack_curve(self, values: np.ndarray, old: np.ndarray) -> np.ndarray:
        """Coefficients of the curve through ``values`` at the nodes (inverse of ``pack_curve``)."""
        nodes = curve_nodes(len(old))
        if self.basis == "power":
            return fit_polynomial(nodes, values, np.ones(len(nodes)), len(old) - 1)
        x = 1.0 / nodes
        return np.linalg.solve(np.vander(x, len(old), increasing=True), values)

    @staticmethod
    def start(kind: str, basis: str = "power", degree: int = 3) -> "SensorModel":
        """The start model suited to the sensor kind, as degree + 1 coefficients (trailing zeros).

        Heights: the paper's very poor line 40 - 0.005 d px (``power``; in ``inverse``, the curve
        12.5 + 30000 / d through the same values at 1.5 m and 4 m), sigma 10 px, 0.2 rad: its implied
        distances fit the field (docs/results.md). Ranges: range = d (``power``), sigma 100 mm, 0.2 rad.
        """
        lines = {("height_px", "power"): [40.0, -0.005], ("height_px", "inverse"): [12.5, 30000.0],
                 ("range_mm", "power"): [0.0, 1.0], ("range_mm", "inverse"): [3000.0, 0.0]}
        coef = np.zeros(max(degree + 1, 2))
        coef[:2] = lines[(kind, basis)]
        return SensorModel(coef, 10.0 if kind == "height_px" else 100.0, 0.2, NODE_RANGE_MM, basis, kind)

    def in_basis(self, basis: str, degree: int) -> "SensorModel":
        """The same model with its curve in ``basis`` with degree + 1 coefficients: unchanged (zeros
        appended, ``with_degree``) in its own basis; otherwise the least-squares fit of the curve over
        its distance range (e.g. a cubic ``--init`` for an ``inverse`` fit)."""
        if basis == self.basis:
            return self.with_degree(degree)
        d = np.linspace(*self.distance_range_mm, 200)
        x = d if basis == "power" else 1.0 / d
        coef = fit_polynomial(x, self.mean(d), np.ones(len(d)), degree)
        return SensorModel(coef, self.sigma_size, self.sigma_bearing, self.distance_range_mm, basis, self.kind)

    def with_degree(self, degree: int) -> "SensorModel":
        """The same curve with degree + 1 coefficients (zeros appended; refuses to drop non-zero ones)."""
        coef = np.zeros(degree + 1)
        n = min(len(self.coef), degree + 1)
        if np.any(self.coef[n:] != 0):
            raise ValueError(f"sensor curve has {len(self.coef)} coefficients, more than degree {degree} allows")
        coef[:n] = self.coef[:n]
        return self.with_values(coef=coef)
