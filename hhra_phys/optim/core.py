"""The ask/tell core shared by every population optimiser (PINTS style).

A run is a sequence of batches. ``ask()`` hands out a whole batch as an ``(m, d)`` array and
``tell(costs)`` takes its ``m`` costs back. The first batch is the initialisation (iteration 0 of
the history); every later batch is one iteration. Evaluating a batch is the caller's business,
which is what lets the same optimiser drive a vectorised simulator, a process pool or a cluster.

Conventions every optimiser follows:

* every point handed out lies inside the box (each method says how it brings points back);
* a non-finite cost (NaN, +inf, -inf) counts as the worst possible cost (+inf), it never raises;
* ``x_best``/``f_best`` are the best point ever evaluated (ties keep the earlier point);
* stopping: ``max_iter`` iterations after the initialisation, a ``target`` cost reached, or an
  evaluation budget ``max_nfev`` that the next batch would exceed (so ``nfev <= max_nfev``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np

from hhra_phys.errors import ParameterError
from hhra_phys.optim.bounds import Box, as_points
from hhra_phys.optim.history import History

__all__ = [
    "Optimiser",
]

SeedLike = int | np.random.Generator | np.random.SeedSequence | None


def check_int(value: Any, name: str, minimum: int) -> int:
    """Return ``value`` as an int ``>= minimum`` or raise :class:`ParameterError`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ParameterError(f"{name}: expected an integer, got {value!r}")
    if value < minimum:
        raise ParameterError(f"{name}: must be >= {minimum}, got {value}")
    return int(value)


def check_float(
    value: Any, name: str, low: float | None = None, high: float | None = None
) -> float:
    """Return ``value`` as a finite float in ``[low, high]`` or raise :class:`ParameterError`."""
    try:
        out = float(value)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name}: expected a number, got {value!r}") from exc
    if not np.isfinite(out):
        raise ParameterError(f"{name}: must be finite, got {value!r}")
    if (low is not None and out < low) or (high is not None and out > high):
        raise ParameterError(f"{name}: must lie in [{low}, {high}], got {out}")
    return out


def distinct_indices(
    rng: np.random.Generator, n: int, k: int, exclude: np.ndarray | None = None
) -> np.ndarray:
    """For each of ``n`` rows, ``k`` distinct random indices in ``range(n)``.

    ``exclude`` (shape ``(n,)`` or ``(n, j)``) lists indices a row must not use. Drawing random
    keys and sorting them gives uniformly random distinct picks without a Python loop.
    """
    keys = rng.random((n, n))
    if exclude is not None:
        ex = np.asarray(exclude).reshape(n, -1)
        keys[np.arange(n)[:, None], ex] = np.inf
    return np.argsort(keys, axis=1)[:, :k]


class Optimiser(ABC):
    """Base class of the population optimisers: ask/tell protocol, stopping and history.

    Parameters
    ----------
    bounds : sequence of (float, float), (d, 2) array or scipy.optimize.Bounds
        Finite box, ``lo < hi`` in every dimension.
    pop_size : int
        Population size ``n``.
    max_iter : int or None
        Iterations after the initialisation. ``None`` derives it from ``max_nfev`` (the number
        of whole iterations that fit in the budget), which also sets the horizon of
        time-dependent schedules (GWO's ``a``, PSO's decreasing inertia).
    max_nfev : int or None
        Evaluation budget; the run stops before a batch that would exceed it.
    target : float or None
        Stop as soon as the best cost is ``<= target``.
    seed : int, numpy.random.Generator, SeedSequence or None
        Source of randomness; the same seed reproduces a run exactly.
    x0 : array of shape (k, d) or (d,), optional
        Points injected into the first population, ``k <= pop_size``; each method documents how.
    """

    #: Name used by :func:`hhra_phys.optim.minimize`.
    method: ClassVar[str] = ""
    #: Display name (tables, plots, reports).
    label: ClassVar[str] = ""
    #: Method-specific options accepted in ``minimize(..., options=...)``.
    option_names: ClassVar[tuple[str, ...]] = ()
    #: Smallest population the method can work with.
    min_pop_size: ClassVar[int] = 1
    #: Whether :attr:`history` records the population's diversity (costs a little per iteration).
    record_diversity: bool = True

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
        self.box = Box.from_bounds(bounds)
        self.pop_size = check_int(pop_size, "pop_size", self.min_pop_size)
        try:
            self.rng = np.random.default_rng(seed)
        except (TypeError, ValueError) as exc:
            msg = f"seed: expected an int, a Generator or None, got {seed!r}"
            raise ParameterError(msg) from exc
        self.x0 = None if x0 is None else as_points(x0, self.box.dim, "x0")
        if self.x0 is not None:
            if self.x0.shape[0] > self.pop_size:
                raise ParameterError(
                    f"x0: at most pop_size={self.pop_size} points, got {self.x0.shape[0]}"
                )
            if not self.box.contains(self.x0):
                raise ParameterError("x0: every point must lie inside the bounds")
        self.target = None if target is None else float(target)
        if max_nfev is not None:
            max_nfev = check_int(max_nfev, "max_nfev", 1)
            if max_nfev < self.init_evals:
                raise ParameterError(
                    f"max_nfev: the initialisation of {self.method} alone needs "
                    f"{self.init_evals} evaluations, got max_nfev={max_nfev}"
                )
        if max_iter is None:
            if max_nfev is None:
                raise ParameterError("max_iter: give max_iter, max_nfev or both")
            max_iter = (max_nfev - self.init_evals) // self.iter_evals
        self.max_iter = check_int(max_iter, "max_iter", 0)
        self.max_nfev = max_nfev

        self.nit = 0
        self.nfev = 0
        self.x_best: np.ndarray | None = None
        self.f_best = np.inf
        self.history = History()
        self.population: np.ndarray | None = None
        self.costs: np.ndarray | None = None
        self._pending: np.ndarray | None = None
        self._initialised = False

    # -- what each method provides -------------------------------------------------------
    @property
    def init_evals(self) -> int:
        """Evaluations spent by the initialisation batch."""
        return self.pop_size

    @property
    def iter_evals(self) -> int:
        """Evaluations spent by each later iteration."""
        return self.pop_size

    @abstractmethod
    def _initial_points(self) -> np.ndarray:
        """First batch, inside the box, with ``x0`` injected."""

    @abstractmethod
    def _tell_initial(self, points: np.ndarray, costs: np.ndarray) -> None:
        """Set ``population``/``costs`` (and method state) from the first batch."""

    @abstractmethod
    def _propose(self) -> np.ndarray:
        """Batch of iteration ``self.nit + 1``, inside the box."""

    @abstractmethod
    def _accept(self, points: np.ndarray, costs: np.ndarray) -> None:
        """Update ``population``/``costs`` from an iteration's batch."""

    # -- the protocol ------------------------------------------------------------------------
    def ask(self) -> np.ndarray:
        """Points to evaluate next, shape ``(m, d)``.

        Asking again before :meth:`tell` returns the same points.

        Raises
        ------
        RuntimeError
            If the run has already stopped (see :attr:`stop_reason`).
        """
        if self._pending is None:
            reason = self.stop_reason
            if reason is not None:
                raise RuntimeError(f"{self.method}: the run has stopped ({reason})")
            pts = self._propose() if self._initialised else self._initial_points()
            self._pending = pts
        return self._pending.copy()

    def tell(self, costs: Any) -> None:
        """Report the costs of the points of the last :meth:`ask`.

        Parameters
        ----------
        costs : array_like of shape (m,)
            One cost per point, in the order asked. Non-finite costs count as ``+inf``.

        Raises
        ------
        ParameterError
            If the number of costs does not match the number of points asked.
        RuntimeError
            If there is no pending :meth:`ask`.
        """
        if self._pending is None:
            raise RuntimeError(f"{self.method}: tell() called without a pending ask()")
        pts = self._pending
        try:
            arr = np.asarray(costs, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ParameterError("costs: expected an array of numbers") from exc
        if arr.ndim == 2 and arr.shape[1] == 1:
            arr = arr[:, 0]
        if arr.shape != (pts.shape[0],):
            raise ParameterError(
                f"costs: expected shape ({pts.shape[0]},) for the points asked, got {arr.shape}"
            )
        arr = np.where(np.isfinite(arr), arr, np.inf)
        self._pending = None
        self.nfev += pts.shape[0]
        i = int(np.argmin(arr))
        if self.x_best is None or arr[i] < self.f_best:
            self.x_best = pts[i].copy()
            self.f_best = float(arr[i])
        if self._initialised:
            self._accept(pts, arr)
            self.nit += 1
        else:
            self._tell_initial(pts, arr)
            self._initialised = True
        div = self.diversity if self.record_diversity else None
        self.history.append(self.f_best, self.nfev, self.x_best, div)

    # -- state -----------------------------------------------------------------------------
    @property
    def diversity(self) -> float:
        """Mean over dimensions of the population's std divided by the box width."""
        if self.population is None:
            return float("nan")
        c = self.population - self.population.mean(axis=0)
        std = np.sqrt(np.einsum("ij,ij->j", c, c) / c.shape[0])  # np.std, without its overhead
        return float(np.mean(std / self.box.width))

    @property
    def stop_reason(self) -> str | None:
        """Why the run is over, or ``None`` while it goes on."""
        if self.target is not None and self.f_best <= self.target:
            return f"target {self.target:g} reached"
        if self._initialised and self.nit >= self.max_iter:
            return f"max_iter={self.max_iter} iterations reached"
        if self.max_nfev is not None:
            nxt = self.iter_evals if self._initialised else self.init_evals
            if self.nfev + nxt > self.max_nfev:
                return f"max_nfev={self.max_nfev} reached (next batch needs {nxt})"
        return None

    @property
    def done(self) -> bool:
        """Whether the run has stopped."""
        return self.stop_reason is not None

    def _inject_x0(self, pop: np.ndarray) -> np.ndarray:
        """Replace the first ``k`` rows of ``pop`` by the ``x0`` points."""
        if self.x0 is not None:
            pop[: self.x0.shape[0]] = self.x0
        return pop
