"""Particle swarm optimisation (global-best PSO with inertia and velocity clamp)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from hhra_phys.errors import ParameterError
from hhra_phys.optim.core import Optimiser, SeedLike, check_float
from hhra_phys.options import with_overrides

__all__ = [
    "PSO",
    "PSOOptions",
]


@dataclass(frozen=True)
class PSOOptions:
    """PSO's own settings, validated as a whole (:class:`PSO`, ``minimize(options=...)``).

    Attributes
    ----------
    w : float
        Constant inertia weight (paper's benchmarks: 0.8). Ignored when ``w_start`` and
        ``w_end`` are given.
    w_start, w_end : float or None
        Linearly decreasing inertia from ``w_start`` (first move) to ``w_end`` (move number
        ``max_iter``); the paper's identification uses 0.9 to 0.1. Give both or neither.
    c1, c2 : float
        Cognitive and social coefficients (paper: 2 and 2), ``>= 0``.
    vmax : float, array of shape (d,) or None
        Velocity clamp per component (positive). The paper's benchmarks use 6 in absolute
        units; the default ``None`` uses 20 % of the box width in each dimension, which
        does not depend on the units of the problem.
    """

    w: float = 0.8
    w_start: float | None = None
    w_end: float | None = None
    c1: float = 2.0
    c2: float = 2.0
    vmax: float | np.ndarray | None = None

    def validate(self) -> PSOOptions:
        """Check every setting; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        check_float(self.w, "w")
        if (self.w_start is None) != (self.w_end is None):
            raise ParameterError("w_start: give both w_start and w_end, or neither")
        for name in ("w_start", "w_end"):
            if getattr(self, name) is not None:
                check_float(getattr(self, name), name)
        check_float(self.c1, "c1", 0.0)
        check_float(self.c2, "c2", 0.0)
        if self.vmax is not None:
            try:
                v = np.asarray(self.vmax, dtype=float)
            except (TypeError, ValueError) as exc:
                raise ParameterError(f"vmax: expected numbers, got {self.vmax!r}") from exc
            if not np.all(np.isfinite(v) & (v > 0)):
                raise ParameterError(f"vmax: must be positive and finite, got {self.vmax!r}")
        return self


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
    options : PSOOptions, optional
        The inertia, coefficients and velocity clamp (default :class:`PSOOptions`'s).
    **settings
        Any field of :class:`PSOOptions` (``w=0.5``, ``w_start=0.9, w_end=0.4``, ``c1``,
        ``c2``, ``vmax``), overriding ``options``; validated with it.
    """

    method = "pso"
    label = "PSO"
    option_names = tuple(f.name for f in fields(PSOOptions))
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
        options: PSOOptions | None = None,
        **settings: Any,
    ) -> None:
        super().__init__(
            bounds, pop_size, max_iter=max_iter, max_nfev=max_nfev, target=target, seed=seed, x0=x0
        )
        opts = with_overrides(options if options is not None else PSOOptions(), settings,
                              "PSO").validate()
        #: The settings the run uses.
        self.options = opts
        self.w = float(opts.w)
        self.w_start = None if opts.w_start is None else float(opts.w_start)
        self.w_end = None if opts.w_end is None else float(opts.w_end)
        self.c1 = float(opts.c1)
        self.c2 = float(opts.c2)
        if opts.vmax is None:
            self.vmax = 0.2 * self.box.width
        else:
            try:
                self.vmax = np.broadcast_to(np.asarray(opts.vmax, dtype=float),
                                            (self.box.dim,)).copy()
            except ValueError as exc:
                raise ParameterError(f"vmax: expected a number or {self.box.dim} numbers, "
                                     f"got {opts.vmax!r}") from exc
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
