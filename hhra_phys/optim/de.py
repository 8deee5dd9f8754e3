"""Differential evolution, DE/rand/1/bin (Storn & Price 1997), with the paper's settings."""

from __future__ import annotations

from typing import Any

import numpy as np

from hhra_phys.optim.core import Optimiser, SeedLike, check_float, distinct_indices

__all__ = [
    "DE",
    "binomial_crossover",
]


def binomial_crossover(
    rng: np.random.Generator, mutant: np.ndarray, target: np.ndarray, cr: float | None
) -> np.ndarray:
    """Binomial crossover with one forced component per row (paper eq. 21).

    Component ``j`` of row ``i`` comes from ``mutant`` if ``rand <= Cr`` or ``j == R_i``
    (``R_i`` uniform over the dimensions), else from ``target``. ``cr=None`` draws
    ``Cr = 0.5 * (1 + rand)`` per row (the paper's setting).
    """
    n, d = target.shape
    u = rng.random((n, d + 2))  # one draw for all: d per component, then Cr, then R
    rate = 0.5 * (1.0 + u[:, d : d + 1]) if cr is None else cr
    take = u[:, :d] <= rate
    take[np.arange(n), (u[:, d + 1] * d).astype(np.intp)] = True
    return np.where(take, mutant, target)


class DE(Optimiser):
    """DE/rand/1/bin with greedy one-to-one selection.

    Per member ``i``: mutant ``V_i = X_r1 + F * (X_r2 - X_r3)`` with ``r1, r2, r3`` distinct and
    different from ``i``; binomial crossover with ``Cr = 0.5 * (1 + rand)`` drawn per member and
    one forced component; out-of-box components re-drawn uniformly (the same rule as H-GWO,
    the paper's eq. 22); the trial replaces ``X_i`` if its cost is ``<=``. The initial
    population is uniform in the box (``x0`` points replace its first rows). Costs ``pop_size``
    evaluations at initialisation and per iteration (generation).

    Parameters
    ----------
    bounds, pop_size, max_iter, max_nfev, target, seed, x0
        See :class:`hhra_phys.optim.core.Optimiser`.
    F : float
        Differential weight (paper: 0.5), in [0, 2].
    Cr : float or None
        Fixed crossover rate in [0, 1]; ``None`` (default) draws ``0.5 * (1 + rand)`` per member.
    """

    method = "de"
    label = "DE"
    option_names = ("F", "Cr")
    min_pop_size = 4

    def __init__(
        self,
        bounds: Any,
        pop_size: int = 30,
        *,
        max_iter: int | None = 100,
        max_nfev: int | None = None,
        target: float | None = None,
        seed: SeedLike = None,
        x0: Any = None,
        F: float = 0.5,
        Cr: float | None = None,
    ) -> None:
        self.F = check_float(F, "F", 0.0, 2.0)
        self.Cr = None if Cr is None else check_float(Cr, "Cr", 0.0, 1.0)
        super().__init__(
            bounds, pop_size, max_iter=max_iter, max_nfev=max_nfev, target=target, seed=seed, x0=x0
        )

    def _initial_points(self) -> np.ndarray:
        return self._inject_x0(self.box.uniform(self.rng, self.pop_size))

    def _tell_initial(self, points: np.ndarray, costs: np.ndarray) -> None:
        self.population, self.costs = points, costs

    def _propose(self) -> np.ndarray:
        assert self.population is not None
        x = self.population
        n = x.shape[0]
        r = distinct_indices(self.rng, n, 3, exclude=np.arange(n))
        mutant = x[r[:, 0]] + self.F * (x[r[:, 1]] - x[r[:, 2]])
        trial = binomial_crossover(self.rng, mutant, x, self.Cr)
        return self.box.redraw(trial, self.rng)

    def _accept(self, points: np.ndarray, costs: np.ndarray) -> None:
        assert self.population is not None and self.costs is not None
        win = costs <= self.costs
        self.population = np.where(win[:, None], points, self.population)
        self.costs = np.where(win, costs, self.costs)
