"""H-GWO: the paper's hybrid of the grey wolf optimiser and a modified differential evolution."""

from __future__ import annotations

from typing import Any

import numpy as np

from hhra_phys.errors import ParameterError
from hhra_phys.optim.core import Optimiser, SeedLike, check_float, distinct_indices
from hhra_phys.optim.de import binomial_crossover
from hhra_phys.optim.gwo import best_distinct, gwo_a, gwo_move, update_leaders

__all__ = [
    "HGWO",
    "tent_map_unit",
]

TARGET_VECTORS = ("moved", "previous")


def tent_map_unit(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    """``n`` points of the unit cube from the tent map (paper eq. 24).

    One chaotic sequence per dimension, ``x_{k+1} = x_k/phi`` if ``x_k < phi`` else
    ``(1 - x_k)/(1 - phi)``, each with its own random start and its own random ``phi``; row
    ``k`` holds the ``k``-th iterates. The paper only says ``phi = rand(0, 1)``. With ``phi``
    near 0 or 1 the map mixes slowly (its Lyapunov exponent tends to 0) and consecutive
    iterates nearly repeat: one ``phi`` shared by all dimensions collapsed about 2 % of
    initial populations to a small cluster (population spread below a third of a uniform
    one's), a ``phi`` per dimension makes that rare (none in 2000 draws in 30 dimensions,
    0.25 % in 2). In floating point the map can also fall onto 0 or 1 and stay there, so an
    iterate that leaves ``(1e-12, 1 - 1e-12)`` is replaced by a fresh uniform draw.
    """
    phi = rng.uniform(1e-3, 1.0 - 1e-3, d)  # keeps both branches' slopes finite
    x = rng.random(d)
    out = np.empty((n, d))
    for k in range(n):
        x = np.where(x < phi, x / phi, (1.0 - x) / (1.0 - phi))
        bad = (x <= 1e-12) | (x >= 1.0 - 1e-12)
        if bad.any():
            x = np.where(bad, rng.random(d), x)
        out[k] = x
    return out


class HGWO(Optimiser):
    """H-GWO (the reference paper, Section 3.4): GWO move followed by a modified DE step.

    Initialisation (Step 2, eq. 27): ``pop_size`` points ``P`` from the tent map
    (:func:`tent_map_unit`) and their opposites ``OP = lo + hi - P`` are evaluated together
    (``2 * pop_size`` evaluations); after removing duplicate points the best ``pop_size`` form
    the pack (if fewer are distinct, the best duplicates fill the gap). ``x0`` points replace
    the first rows of ``P`` before the opposites are formed, so a good warm start survives the
    selection and a bad one is dropped.

    Each iteration, with the leaders alpha, beta, delta (best three distinct points found so
    far):

    1. GWO move (Step 6, :func:`~hhra_phys.optim.gwo.gwo_move`, ``a`` from 2 to 0), clipped into
       the box as in GWO: ``Y_i``.
    2. Mutation (eq. 20): ``V_i = lam * X_alpha + F * (X_r1 - X_r2)`` with ``r1 != r2`` drawn
       from the current pack, both different from the pack's best member (alpha's index).
       ``lam < 1`` pulls every mutant toward ``lam * X_alpha``, i.e. toward the coordinate
       origin; see ``docs/benchmarks.md``.
    3. Binomial crossover (eq. 21) with ``Cr = 0.5 * (1 + rand)`` drawn per wolf and one forced
       component ``j = R`` per wolf, ``R`` drawn over the dimensions (the paper prints
       ``1..NP``, a slip): ``U_ij = V_ij`` if ``r_j <= Cr`` or ``j == R`` else ``Y_ij``.
    4. Components of ``U_i`` outside the box are re-drawn uniformly inside it (eq. 22).
    5. Greedy one-to-one selection (eq. 23): ``U_i`` replaces the target if ``f(U_i) <=
       f(target)``.

    The paper does not say whether the *target vector* of crossover and selection is the wolf
    after its GWO move or before it. Our choice, ``target_vector="moved"`` (default): the target
    is the moved wolf ``Y_i``; crossover mixes ``V_i`` with ``Y_i`` and ``U_i`` competes with
    ``Y_i``, so both are evaluated in one batch of ``2 * pop_size`` points. This reads Step 6's
    ``X(t+1)`` as the current position that Steps 7-9 then refine, keeps GWO's
    non-elitist pack dynamics, and matches the "about twice the evaluations of GWO per
    iteration" the paper's comparison implies. The alternative,
    ``target_vector="previous"``: ``U_i`` competes with the wolf before its move ``X_i(t)``,
    whose cost is already known, so only ``U_i`` is evaluated (``pop_size`` points per
    iteration). In that variant the moved wolf still supplies crossover's non-mutant
    components, since otherwise the GWO move would have no effect at all; the pack is then
    elitist.

    Parameters
    ----------
    bounds, pop_size, max_iter, max_nfev, target, seed, x0
        See :class:`hhra_phys.optim.core.Optimiser`.
    F : float
        Differential weight, paper 0.5 (the paper allows [0.4, 1]; any value in (0, 2] here).
    lam : float
        Weight of alpha in the mutation, paper 0.25, in (0, 1].
    Cr : float or None
        Fixed crossover rate in [0, 1]; ``None`` (default) draws ``0.5 * (1 + rand)`` per wolf.
    target_vector : {"moved", "previous"}
        Which wolf is the target of crossover and selection, see above.
    """

    method = "hgwo"
    label = "H-GWO"
    option_names = ("F", "lam", "Cr", "target_vector")
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
        lam: float = 0.25,
        Cr: float | None = None,
        target_vector: str = "moved",
    ) -> None:
        self.F = check_float(F, "F", 0.0, 2.0)
        self.lam = check_float(lam, "lam", 0.0, 1.0)
        if self.lam == 0.0:
            raise ParameterError("lam: must lie in (0, 1], got 0")
        self.Cr = None if Cr is None else check_float(Cr, "Cr", 0.0, 1.0)
        if target_vector not in TARGET_VECTORS:
            raise ParameterError(
                f"target_vector: expected one of {TARGET_VECTORS}, got {target_vector!r}"
            )
        self.target_vector = target_vector
        # options go first: the base class checks max_nfev against the batch sizes
        super().__init__(
            bounds, pop_size, max_iter=max_iter, max_nfev=max_nfev, target=target, seed=seed, x0=x0
        )
        self.leaders: np.ndarray | None = None
        self.leader_costs: np.ndarray | None = None

    @property
    def init_evals(self) -> int:
        return 2 * self.pop_size

    @property
    def iter_evals(self) -> int:
        return 2 * self.pop_size if self.target_vector == "moved" else self.pop_size

    def _initial_points(self) -> np.ndarray:
        n, d = self.pop_size, self.box.dim
        p = self._inject_x0(self.box.from_unit(tent_map_unit(self.rng, n, d)))
        return np.vstack([p, self.box.opposite(p)])

    def _tell_initial(self, points: np.ndarray, costs: np.ndarray) -> None:
        n = self.pop_size
        pop, cst = best_distinct(points, costs, n)
        if pop.shape[0] < n:  # too few distinct points: fill with the best of the rest
            order = np.argsort(costs, kind="stable")
            extra = order[: n - pop.shape[0]]
            pop = np.vstack([pop, points[extra]])
            cst = np.concatenate([cst, costs[extra]])
        self.population, self.costs = pop, cst
        self.leaders, self.leader_costs = update_leaders(None, None, pop, cst)

    def _propose(self) -> np.ndarray:
        assert self.population is not None and self.leaders is not None
        x = self.population
        n = x.shape[0]
        rng = self.rng
        moved = self.box.clip(gwo_move(x, self.leaders, gwo_a(self.nit, self.max_iter), rng))
        alpha_idx = np.full(n, int(np.argmin(self.costs)))
        r = distinct_indices(rng, n, 2, exclude=alpha_idx)
        mutant = self.lam * self.leaders[0] + self.F * (x[r[:, 0]] - x[r[:, 1]])
        trial = self.box.redraw(binomial_crossover(rng, mutant, moved, self.Cr), rng)
        if self.target_vector == "moved":
            return np.vstack([moved, trial])
        return trial

    def _accept(self, points: np.ndarray, costs: np.ndarray) -> None:
        n = self.pop_size
        if self.target_vector == "moved":
            tgt, tgt_cost = points[:n], costs[:n]
            trial, trial_cost = points[n:], costs[n:]
        else:
            assert self.population is not None and self.costs is not None
            tgt, tgt_cost = self.population, self.costs
            trial, trial_cost = points, costs
        win = trial_cost <= tgt_cost
        self.population = np.where(win[:, None], trial, tgt)
        self.costs = np.where(win, trial_cost, tgt_cost)
        self.leaders, self.leader_costs = update_leaders(
            self.leaders, self.leader_costs, self.population, self.costs
        )
