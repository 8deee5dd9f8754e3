"""Grey wolf optimiser (Mirjalili, Mirjalili & Lewis 2014), as used by the paper."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from hhra_phys.optim.core import Optimiser, SeedLike

__all__ = [
    "GWO",
    "gwo_move",
    "gwo_a",
]


@functools.cache
def _strictly_upper(m: int) -> np.ndarray:
    return np.triu(np.ones((m, m), dtype=bool), 1)


def best_distinct(points: np.ndarray, costs: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` lowest-cost distinct rows of ``points`` (fewer if there are fewer distinct).

    Sorting is stable, so among equal costs the earlier row wins; of equal rows the
    lowest-cost one is kept.
    """
    order = np.argsort(costs, kind="stable")
    cand = points[order[:k]]
    if ((cand[:, None, :] == cand[None, :, :]).all(axis=2)).sum() == cand.shape[0]:
        return cand, costs[order[:k]]  # the usual case: the k best are already distinct
    m = min(order.size, k + 4)  # duplicates are rare: look a little past k first
    while True:
        cand = points[order[:m]]
        same = (cand[:, None, :] == cand[None, :, :]).all(axis=2)
        dup = (same & _strictly_upper(m)).any(axis=0)  # equal to a better-ranked candidate
        keep = order[:m][~dup][:k]
        if keep.size == k or m == order.size:
            return points[keep], costs[keep]
        m = order.size


def update_leaders(
    leaders: np.ndarray | None,
    leader_costs: np.ndarray | None,
    points: np.ndarray,
    costs: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Alpha, beta and delta: the three best distinct points found so far.

    Mirjalili's reference code keeps the leaders' scores across iterations, so a leader is only
    replaced by a better point; it does not demote an old alpha to beta when a new alpha
    appears. Here the leaders are simply the three best distinct points seen so far (the usual
    correction of that quirk). With fewer than three distinct points the last one is repeated.
    """
    if leaders is not None and leader_costs is not None:
        if costs.min() >= leader_costs[-1]:
            return leaders, leader_costs  # nothing new beats delta: the usual case late in a run
        points = np.vstack([leaders, points])
        costs = np.concatenate([leader_costs, costs])
    pts, cst = best_distinct(points, costs, 3)
    if pts.shape[0] < 3:
        pad = 3 - pts.shape[0]
        pts = np.vstack([pts, np.repeat(pts[-1:], pad, axis=0)])
        cst = np.concatenate([cst, np.repeat(cst[-1:], pad)])
    return pts, cst


def gwo_move(
    wolves: np.ndarray, leaders: np.ndarray, a: float, rng: np.random.Generator
) -> np.ndarray:
    """Move every wolf toward the three leaders (paper eqs. 16-19).

    ``X_L = L - A * |C * L - X|`` with ``A = 2a*r1 - a`` and ``C = 2*r2`` drawn per wolf, leader
    and component; the new position is the mean of the three ``X_L``. The result is not
    bounded.
    """
    n, d = wolves.shape
    r = rng.random((2, 3, n, d))
    # in place on the random draws: this is the inner loop of every GWO-type run
    step = r[0]
    step *= 2.0 * a
    step -= a  # A
    dist = r[1]
    dist *= 2.0  # C
    dist *= leaders[:, None, :]
    dist -= wolves
    np.abs(dist, out=dist)  # D = |C*L - X|
    step *= dist
    # mean over the leaders of L - A*D
    return (leaders.sum(axis=0) - step.sum(axis=0)) / 3.0


def gwo_a(t: int, horizon: int) -> float:
    """Distance control ``a(t) = 2 - 2t/MaxIter`` for the move of iteration ``t + 1``."""
    return 2.0 - 2.0 * t / max(horizon, 1)


class GWO(Optimiser):
    """Original grey wolf optimiser: ``a`` from 2 to 0, three leaders, no greedy selection.

    Each iteration moves every wolf with :func:`gwo_move`, clips the result into the box (as
    Mirjalili's reference code does) and evaluates it; the moved pack replaces the old one
    unconditionally. The leaders persist across iterations (best three distinct points seen so
    far). ``a`` falls linearly from 2 (first move) toward 0 over ``max_iter`` moves. Costs
    ``pop_size`` evaluations at initialisation and per iteration.

    The initial pack is uniform in the box; ``x0`` points replace its first rows.

    Parameters
    ----------
    bounds, pop_size, max_iter, max_nfev, target, seed, x0
        See :class:`hhra_phys.optim.core.Optimiser`.
    """

    method = "gwo"
    label = "GWO"
    option_names = ()
    min_pop_size = 3

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
    ) -> None:
        super().__init__(
            bounds, pop_size, max_iter=max_iter, max_nfev=max_nfev, target=target, seed=seed, x0=x0
        )
        self.leaders: np.ndarray | None = None
        self.leader_costs: np.ndarray | None = None

    def _initial_points(self) -> np.ndarray:
        return self._inject_x0(self.box.uniform(self.rng, self.pop_size))

    def _tell_initial(self, points: np.ndarray, costs: np.ndarray) -> None:
        self.population, self.costs = points, costs
        self.leaders, self.leader_costs = update_leaders(None, None, points, costs)

    def _propose(self) -> np.ndarray:
        assert self.population is not None and self.leaders is not None
        a = gwo_a(self.nit, self.max_iter)
        return self.box.clip(gwo_move(self.population, self.leaders, a, self.rng))

    def _accept(self, points: np.ndarray, costs: np.ndarray) -> None:
        self.population, self.costs = points, costs
        self.leaders, self.leader_costs = update_leaders(
            self.leaders, self.leader_costs, points, costs
        )
