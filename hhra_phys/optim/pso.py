"""Particle swarm optimisation (global-best PSO with inertia and velocity clamp)."""

from __future__ import annotations

from typing import Any

import numpy as np

from hhra_phys.errors import ParameterError
from hhra_phys.optim.core import Optimiser, SeedLike, check_float

__all__ = [
    "PSO",
]


class PSO(Optimiser):
    """Global-best PSO with constant or linearly decreasing inertia, as in Mirjalili's code.

    ``v = w*v + c1*r1*(pbest - x) + c2*r2*(gbest - x)``, each velocity component clamped to
    ``[-vmax, vmax]``, then ``x = x + v`` clipped into the box. Particles start uniform in the
    box (``x0`` points replace the first rows) with zero velocity. Costs ``pop_size``
    evaluations at initialisation and per iteration.

    Parameters
    ----------
    bounds, pop_size, max_iter, max_nfev, target, seed, x0
        See :class:`hhra_phys.optim.core.Optimiser`.
    w : float
        Constant inertia weight (paper's benchmarks: 0.8). Ignored when ``w_start`` and
        ``w_end`` are given.
    w_start, w_end : float or None
        Linearly decreasing inertia from ``w_start`` (first move) to ``w_end`` (move number
        ``max_iter``); the paper's identification uses 0.9 to 0.1. Give both or neither.
    c1, c2 : float
        Cognitive and social coefficients (paper: 2 and 2).
    vmax : float, array of shape (d,) or None
        Velocity clamp per component. The paper's benchmarks use 6 in absolute units; the
        default ``None`` uses 20 % of the box width in each dimension, which does not depend on
        the units of the problem.
    """

    method = "pso"
    option_names = ("w", "w_start", "w_end", "c1", "c2", "vmax")
    min_pop_size = 2

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
        w: float = 0.8,
        w_start: float | None = None,
        w_end: float | None = None,
        c1: float = 2.0,
        c2: float = 2.0,
        vmax: float | np.ndarray | None = None,
    ) -> None:
        super().__init__(
            bounds, pop_size, max_iter=max_iter, max_nfev=max_nfev, target=target, seed=seed, x0=x0
        )
        self.w = check_float(w, "w")
        if (w_start is None) != (w_end is None):
            raise ParameterError("w_start: give both w_start and w_end, or neither")
        self.w_start = None if w_start is None else check_float(w_start, "w_start")
        self.w_end = None if w_end is None else check_float(w_end, "w_end")
        self.c1 = check_float(c1, "c1", 0.0)
        self.c2 = check_float(c2, "c2", 0.0)
        if vmax is None:
            self.vmax = 0.2 * self.box.width
        else:
            v = np.broadcast_to(np.asarray(vmax, dtype=float), (self.box.dim,)).copy()
            if not np.all(np.isfinite(v) & (v > 0)):
                raise ParameterError(f"vmax: must be positive and finite, got {vmax!r}")
            self.vmax = v
        self.velocity = np.zeros((self.pop_size, self.box.dim))
        self.pbest: np.ndarray | None = None
        self.pbest_costs: np.ndarray | None = None

    def inertia(self, t: int) -> float:
        """Inertia weight of move number ``t + 1`` (``t`` = iterations done)."""
        if self.w_start is None or self.w_end is None:
            return self.w
        frac = t / max(self.max_iter - 1, 1)
        return self.w_start + (self.w_end - self.w_start) * min(frac, 1.0)

    def _initial_points(self) -> np.ndarray:
        return self._inject_x0(self.box.uniform(self.rng, self.pop_size))

    def _tell_initial(self, points: np.ndarray, costs: np.ndarray) -> None:
        self.population, self.costs = points, costs
        self.pbest, self.pbest_costs = points.copy(), costs.copy()

    def _propose(self) -> np.ndarray:
        assert self.population is not None and self.pbest is not None and self.x_best is not None
        x = self.population
        r = self.rng.random((2,) + x.shape)
        v = (
            self.inertia(self.nit) * self.velocity
            + self.c1 * r[0] * (self.pbest - x)
            + self.c2 * r[1] * (self.x_best - x)
        )
        self.velocity = np.clip(v, -self.vmax, self.vmax)
        return self.box.clip(x + self.velocity)

    def _accept(self, points: np.ndarray, costs: np.ndarray) -> None:
        assert self.pbest is not None and self.pbest_costs is not None
        self.population, self.costs = points, costs
        better = costs < self.pbest_costs
        self.pbest = np.where(better[:, None], points, self.pbest)
        self.pbest_costs = np.where(better, costs, self.pbest_costs)
