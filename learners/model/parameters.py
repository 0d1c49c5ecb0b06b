"""Parameters as small containers with properties (in the spirit of dynamax's ``ParameterProperties``).

A model component is a frozen dataclass; ``PARAMS`` declares which of its fields are parameters
and their properties, so that acceleration (packing), checkpoints, the model file, printing and
comparison are generic loops over components:

- ``unit``: printed and documented unit (e.g. ``"mm/s"``);
- ``transform``: how the parameter is mapped to the unconstrained, scaled vector SQUAREM
  extrapolates: ``"scaled"`` (value / scale), ``"log"`` (positive), ``"logchol"`` (symmetric
  positive definite: log-Cholesky), ``"logcontrast"`` (a normalized group: K positive factors at
  geometric mean 1, packed as the K - 1 orthonormal contrasts of their logs, ``helmert``),
  ``"contrast"`` (an additive normalized group: K numbers summing to 0, packed as their K - 1
  orthonormal contrasts divided by ``scale``), or a
  component's own (``pack_<name>`` / ``unpack_<name>``);
- ``scale``: the typical size of one unit of the parameter (a "noise width");
- ``trainable``: estimated by EM (False: kept fixed);
- ``order``: noise covariances (order 1) are packed after the curves (order 0);
- ``low``, ``high``: the domain, inclusive bounds on every entry (a ``"log"`` parameter is also > 0),
  and ``shape``: ``()`` a number, ``(n,)`` n numbers, ``(-1,)`` a list of any length, None unchecked;
  a model file's values outside them are refused (``Param.domain_error``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, ClassVar

import numpy as np


@dataclass(frozen=True)
class Param:
    """Properties of one parameter array of a component."""

    unit: str
    transform: str = "scaled"
    scale: float | tuple[float, ...] = 1.0
    trainable: bool = True
    order: int = 0  # packing order: parameters are packed by (order, component, declaration)
    low: float = -math.inf
    high: float = math.inf
    shape: tuple[int, ...] | None = None

    @property
    def group(self) -> bool:
        """Whether the parameter is a normalized group (``"logcontrast"``: geometric mean 1; ``"contrast"``: sum 0)."""
        return self.transform in GROUP_TRANSFORMS

    @property
    def constraints(self) -> int:
        """Constraints among the entries that the transform removes (a normalized group: 1, its geometric
        mean or its sum): the packed vector has that many fewer entries, and a likelihood-ratio test that
        many fewer degrees of freedom."""
        return 1 if self.group else 0

    def packed_size(self, value: np.ndarray) -> int:
        """Number of entries ``value`` takes in the packed vector."""
        if self.transform == "logchol":
            return 6
        return max(np.size(value) - self.constraints, 0)

    def domain_error(self, value: np.ndarray) -> str:
        """What is wrong with ``value`` (finite floats) for this parameter's shape and domain; "" if nothing."""
        if self.shape is not None and (value.ndim != len(self.shape) or any(
                n not in (-1, m) for n, m in zip(self.shape, value.shape))):
            want = "a number" if self.shape == () else "a list of numbers" if self.shape == (-1,) else \
                f"a list of {self.shape[0]} numbers"
            return f"expected {want}, got shape {value.shape}"
        if self.transform in ("log", "logcontrast") and np.any(value <= 0):
            return f"must be > 0, got {value.min():g}"
        if np.any(value < self.low) or np.any(value > self.high):
            bad = value[(value < self.low) | (value > self.high)].ravel()[0]
            return f"must be in [{self.low:g}, {self.high:g}] ({self.unit or 'no unit'}), got {bad:g}"
        return ""


#: The transforms of a normalized group (``Param.group``): packed as contrasts, one number fewer.
GROUP_TRANSFORMS = ("logcontrast", "contrast")


#: Largest magnitude of any number a model file may hold: no quantity of a model comes near it, and
#: larger ones overflow the learner's squares and products (1e300).
MAX_ABS = 1e15


def as_numbers(value: Any) -> np.ndarray:
    """``value`` (a JSON number or nested lists of numbers) as a float array; ValueError saying what is
    wrong for anything else: strings, booleans, null, NaN/inf, magnitudes above ``MAX_ABS``, ragged lists."""
    def check(v: Any) -> None:
        if isinstance(v, list):
            for x in v:
                check(x)
        elif isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"expected numbers, got {v!r:.40}")
    check(value)
    try:
        arr = np.asarray(value, dtype=float)
    except (ValueError, OverflowError):
        raise ValueError("expected numbers in lists of equal length") from None
    if not np.all(np.isfinite(arr)):
        raise ValueError("non-finite value")
    if np.any(np.abs(arr) > MAX_ABS):
        raise ValueError(f"{np.abs(arr).max():g} is larger than {MAX_ABS:g} in magnitude")
    return arr


#: Largest |log| a ``"log"`` parameter (or a log-Cholesky diagonal) unpacks from: an extrapolated step
#: (SQUAREM) beyond it is clipped, so the value stays within [1 / MAX_ABS, MAX_ABS] and ``exp`` never
#: overflows (it did, as a RuntimeWarning "overflow encountered in exp" reaching the user).
LOG_MAX = math.log(MAX_ABS)


def safe_exp(x: np.ndarray) -> np.ndarray:
    """exp(x) with x clipped to [-LOG_MAX, LOG_MAX] (NaN stays NaN): finite, positive, no warning."""
    return np.exp(np.clip(x, -LOG_MAX, LOG_MAX))


def chol_vec(cov: np.ndarray) -> np.ndarray:
    """Log-Cholesky vector of a 3x3 SPD matrix: log of the diagonal, then the lower triangle."""
    L = np.linalg.cholesky(cov)
    return np.array([np.log(L[0, 0]), np.log(L[1, 1]), np.log(L[2, 2]), L[1, 0], L[2, 0], L[2, 1]])


def chol_mat(v: np.ndarray) -> np.ndarray:
    """Inverse of ``chol_vec``."""
    L = np.diag(safe_exp(v[:3]))
    L[1, 0], L[2, 0], L[2, 1] = v[3], v[4], v[5]
    return L @ L.T


def helmert(k: int) -> np.ndarray:
    """(k, k - 1) orthonormal basis of the contrasts of k numbers (columns orthogonal to the ones vector):
    the Helmert basis, column j = (1, ..., 1, -j, 0, ..., 0) / sqrt(j (j + 1)) with j ones. H^T H = I and
    H H^T = I - 11^T / k: the projection that removes the mean."""
    H = np.zeros((k, max(k - 1, 0)))
    for j in range(1, k):
        H[:j, j - 1] = 1.0
        H[j, j - 1] = -float(j)
        H[:, j - 1] /= math.sqrt(j * (j + 1))
    return H


def pack_logcontrast(value: np.ndarray) -> np.ndarray:
    """K positive factors as the K - 1 orthonormal contrasts of their logs, H^T log(value): their
    geometric mean (the direction a normalization removes) is not in the vector."""
    logs = np.log(np.ravel(value))
    return helmert(len(logs)).T @ logs


def unpack_logcontrast(x: np.ndarray, old: np.ndarray) -> np.ndarray:
    """Inverse of ``pack_logcontrast``: the factors exp(H x) times the geometric mean of ``old`` (1 for a
    normalized group, kept exactly: a model whose group is not normalized keeps its common factor)."""
    logs = np.log(np.ravel(old))
    mean = float(np.mean(logs)) if len(logs) else 0.0
    return safe_exp(mean + helmert(len(logs)) @ x).reshape(np.shape(old))


def pack_contrast(value: np.ndarray, scale: float) -> np.ndarray:
    """K numbers as their K - 1 orthonormal contrasts in units of ``scale``, H^T value / scale: their mean
    (the direction a sum-zero normalization removes) is not in the vector."""
    v = np.ravel(value)
    return helmert(len(v)).T @ v / scale


def unpack_contrast(x: np.ndarray, old: np.ndarray, scale: float) -> np.ndarray:
    """Inverse of ``pack_contrast``: H x scale plus the mean of ``old`` (0 for a normalized group, kept
    exactly)."""
    v = np.ravel(old)
    mean = float(np.mean(v)) if len(v) else 0.0
    return (mean + helmert(len(v)) @ x * scale).reshape(np.shape(old))


class Component:
    """Base of every model component: generic access to the declared parameters."""

    PARAMS: ClassVar[dict[str, Param]] = {}

    def values(self) -> dict[str, np.ndarray]:
        """Every declared parameter as a float array."""
        return {name: np.asarray(getattr(self, name), dtype=float) for name in self.PARAMS}

    def with_values(self, **values: Any):
        """A copy with some parameters replaced (arrays keep their shape)."""
        return replace(self, **values)

    def config(self) -> dict[str, Any]:
        """The non-parameter fields (structure: feature map, basis, units, ...)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name not in self.PARAMS}

    def pack_param(self, name: str) -> np.ndarray:
        """Parameter ``name`` in the unconstrained, scaled space SQUAREM extrapolates (1-d)."""
        p = self.PARAMS[name]
        value = np.asarray(getattr(self, name), dtype=float)
        own = getattr(self, f"pack_{p.transform}", None)
        if own is not None:
            return np.ravel(own(value))
        if p.transform == "log":
            return np.log(np.ravel(value))
        if p.transform == "logcontrast":
            return pack_logcontrast(value)
        if p.transform == "contrast":
            return pack_contrast(value, float(p.scale))
        if p.transform == "logchol":
            return chol_vec(value)
        return np.ravel(value / np.asarray(p.scale, dtype=float))

    def unpack_param(self, name: str, x: np.ndarray) -> tuple[Any, int]:
        """(value of parameter ``name`` read from the start of ``x``, number of entries used)."""
        p = self.PARAMS[name]
        old = np.asarray(getattr(self, name), dtype=float)
        n = p.packed_size(old)
        chunk = x[:n]
        own = getattr(self, f"unpack_{p.transform}", None)
        if own is not None:
            value = own(chunk, old)
        elif p.transform == "log":
            value = safe_exp(chunk).reshape(old.shape)
        elif p.transform == "logcontrast":
            value = unpack_logcontrast(chunk, old)
        elif p.transform == "contrast":
            value = unpack_contrast(chunk, old, float(p.scale))
        elif p.transform == "logchol":
            value = chol_mat(chunk)
        else:
            value = chunk.reshape(old.shape) * np.asarray(p.scale, dtype=float)
        if p.transform in ("scaled", "log"):
            # an extrapolated step (SQUAREM) may leave the domain (a distance_dependent_noise exponent of -0.56
            # came out of one and was named, in a model file that could not be loaded): projected back onto it
            value = np.clip(value, p.low, p.high)
        return (float(value) if old.shape == () else value), n

    def held(self, name: str) -> np.ndarray:
        """(entries of ``pack_param(name)``,) bool: the packed entries of parameter ``name`` the component holds at
        their value by construction (a unicycle's lateral weights, at exactly 0): packed like the others, but no
        parameters: the M-step never moves them, and the standard errors (``learners.em.uncertainty``) report them
        as ``fixed``, error 0. None by default."""
        return np.zeros(len(self.pack_param(name)), dtype=bool)

    def describe(self) -> list[str]:
        """Lines ``name = value unit`` for printing."""
        lines = []
        for name, p in self.PARAMS.items():
            v = np.asarray(getattr(self, name), dtype=float)
            text = f"{float(v):.6g}" if v.shape == () else np.array2string(v, precision=4, max_line_width=100)
            lines.append(f"{name} = {text} {p.unit}".rstrip())
        return lines
