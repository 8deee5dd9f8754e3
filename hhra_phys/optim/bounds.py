"""Box bounds: validation and the two ways of bringing a point back inside the box."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hhra_phys.errors import ParameterError

__all__ = [
    "Box",
    "as_points",
]


@dataclass(frozen=True)
class Box:
    """A validated search box ``lower <= x <= upper`` with finite limits.

    Attributes
    ----------
    lower, upper : numpy.ndarray
        Limits, shape ``(d,)``, with ``lower < upper`` everywhere.
    """

    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def from_bounds(cls, bounds: Any, name: str = "bounds") -> Box:
        """Build a box from ``[(lo, hi), ...]``, an ``(d, 2)`` array or ``scipy.optimize.Bounds``.

        Raises
        ------
        ParameterError
            If the shape is wrong, a limit is not finite, or ``lo >= hi`` somewhere.
        """
        if isinstance(bounds, Box):
            return bounds
        if hasattr(bounds, "lb") and hasattr(bounds, "ub"):  # scipy.optimize.Bounds
            lo = np.atleast_1d(np.asarray(bounds.lb, dtype=float))
            hi = np.atleast_1d(np.asarray(bounds.ub, dtype=float))
            lo, hi = np.broadcast_arrays(lo, hi)
        else:
            try:
                arr = np.asarray(bounds, dtype=float)
            except (TypeError, ValueError) as exc:
                raise ParameterError(f"{name}: expected a sequence of (lo, hi) pairs") from exc
            if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
                raise ParameterError(
                    f"{name}: expected a sequence of (lo, hi) pairs, got shape {arr.shape}"
                )
            lo, hi = arr[:, 0], arr[:, 1]
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ParameterError(f"{name}: every limit must be finite")
        bad = np.flatnonzero(lo >= hi)
        if bad.size:
            i = int(bad[0])
            raise ParameterError(
                f"{name}: lower limit must be below upper limit, got ({lo[i]}, {hi[i]}) "
                f"for dimension {i}"
            )
        lo = np.array(lo, dtype=float)
        hi = np.array(hi, dtype=float)
        lo.flags.writeable = False
        hi.flags.writeable = False
        return cls(lo, hi)

    @property
    def dim(self) -> int:
        """Number of dimensions ``d``."""
        return int(self.lower.size)

    @property
    def width(self) -> np.ndarray:
        """``upper - lower``, shape ``(d,)``."""
        return self.upper - self.lower

    def uniform(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` points drawn uniformly in the box, shape ``(n, d)``."""
        return self.lower + rng.random((n, self.dim)) * self.width

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Map points of the unit cube onto the box."""
        return self.lower + u * self.width

    def opposite(self, x: np.ndarray) -> np.ndarray:
        """Opposite points ``lo + hi - x`` (the paper's Definition 1)."""
        return self.lower + self.upper - x

    def clip(self, x: np.ndarray) -> np.ndarray:
        """Components outside the box set to the nearest limit (Mirjalili's GWO and PSO)."""
        return np.clip(x, self.lower, self.upper)

    def redraw(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Components outside the box re-drawn uniformly inside it (the paper's eq. 22).

        Returns a new array; components inside the box are unchanged.
        """
        rows, cols = np.nonzero((x < self.lower) | (x > self.upper))
        if rows.size == 0:
            return x
        x = x.copy()
        x[rows, cols] = self.lower[cols] + rng.random(rows.size) * self.width[cols]
        return x

    def contains(self, x: np.ndarray) -> bool:
        """Whether every point of ``x`` lies inside the closed box."""
        return bool(np.all((x >= self.lower) & (x <= self.upper)))


def as_points(x: Any, dim: int, name: str) -> np.ndarray:
    """Validate ``x`` as ``(k, dim)`` points (a single ``(dim,)`` vector is accepted)."""
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name}: expected an array of points") from exc
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ParameterError(f"{name}: expected shape (k, {dim}), got {np.shape(x)}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name}: every component must be finite")
    return arr
