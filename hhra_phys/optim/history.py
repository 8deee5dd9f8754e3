"""What an optimiser records per iteration, and the NOI definition computed from it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "History",
    "noi",
]

#: Relative tolerance of the NOI definition (0.1 %).
NOI_RTOL = 1e-3


def noi(best: np.ndarray, rtol: float = NOI_RTOL, atol: float = 0.0) -> int:
    """Number of iterations (NOI) to reach the run's final best cost.

    The paper reports NOI without defining it. Here NOI is the first iteration ``t`` whose
    best-so-far cost is within 0.1 % of the run's final best:
    ``|best[t] - best[-1]| <= rtol * |best[-1]| + atol``, with ``rtol = 1e-3`` and ``atol = 0``.
    Iteration 0 is the initial population. With ``atol = 0`` a run whose final best is exactly
    zero has NOI equal to the first iteration that reached zero.

    Parameters
    ----------
    best : numpy.ndarray
        Best-so-far cost per iteration (non-increasing), index 0 = initial population.
    rtol, atol : float
        Relative and absolute tolerance.

    Returns
    -------
    int
        The NOI, or ``-1`` if ``best`` is empty or its final value is not finite.
    """
    best = np.asarray(best, dtype=float)
    if best.size == 0 or not np.isfinite(best[-1]):
        return -1
    final = best[-1]
    close = np.abs(best - final) <= rtol * abs(final) + atol
    return int(np.argmax(close))


@dataclass
class History:
    """Per-iteration record of a run; index 0 is the initial population.

    Attributes
    ----------
    best : list of float
        Best cost found so far, at the end of each iteration.
    nfev : list of int
        Cumulative objective evaluations at the end of each iteration.
    x_best : list of numpy.ndarray
        Best point found so far, at the end of each iteration.
    diversity : list of float
        Population spread: mean over dimensions of the population's standard deviation divided
        by the box width (0 = collapsed onto one point, about 0.29 for a uniform population).
        Empty when the optimiser's ``record_diversity`` is off.
    """

    best: list[float] = field(default_factory=list)
    nfev: list[int] = field(default_factory=list)
    x_best: list[np.ndarray] = field(default_factory=list)
    diversity: list[float] = field(default_factory=list)

    def append(
        self, best: float, nfev: int, x_best: np.ndarray, diversity: float | None = None
    ) -> None:
        """Record one iteration (``diversity=None``: not recorded)."""
        self.best.append(float(best))
        self.nfev.append(int(nfev))
        self.x_best.append(np.array(x_best, copy=True))
        if diversity is not None:
            self.diversity.append(float(diversity))

    @property
    def evals_per_iteration(self) -> np.ndarray:
        """Objective evaluations spent in each iteration (index 0 = initialisation)."""
        return np.diff(np.asarray(self.nfev, dtype=int), prepend=0)

    def as_arrays(self) -> dict[str, np.ndarray]:
        """The record as numpy arrays (``x_best`` has shape ``(nit + 1, d)``)."""
        return {
            "best": np.asarray(self.best, dtype=float),
            "nfev": np.asarray(self.nfev, dtype=int),
            "x_best": np.asarray(self.x_best, dtype=float),
            "diversity": np.asarray(self.diversity, dtype=float),
        }

    def noi(self, rtol: float = NOI_RTOL, atol: float = 0.0) -> int:
        """NOI of this run, see :func:`noi`."""
        return noi(np.asarray(self.best, dtype=float), rtol=rtol, atol=atol)

    def __len__(self) -> int:
        return len(self.best)
