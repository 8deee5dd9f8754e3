"""``minimize``: a SciPy-style driver that runs any of the optimisers through ask/tell."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult

from hhra_phys.errors import ParameterError
from hhra_phys.optim.core import Optimiser, SeedLike, check_int
from hhra_phys.optim.registry import optimiser_class
from hhra_phys.options import with_overrides

__all__ = [
    "IterationState",
    "MinimizeOptions",
    "make_optimiser",
    "minimize",
]


class _FromOptions:
    """Default of :func:`minimize`'s positional settings: the options object's value."""

    def __repr__(self) -> str:
        return "<from options>"


_FROM_OPTIONS: Any = _FromOptions()


@dataclass(frozen=True)
class MinimizeOptions:
    """Settings of a run of :func:`minimize`, validated as a whole.

    Every field is also a keyword of :func:`minimize`, which overrides the options it is
    given (``minimize(f, box, options=MinimizeOptions(pop_size=50), seed=2)``).

    Attributes
    ----------
    method : str
        The optimiser, a key of :data:`~hhra_phys.optim.registry.METHODS` (``"hgwo"``,
        ``"gwo"``, ``"pso"``, ``"de"``).
    pop_size : int
        Population size (at least the method's ``min_pop_size``).
    max_iter : int or None
        Iterations after the initialisation; ``None`` derives it from ``max_nfev``.
    seed : int, numpy.random.Generator, SeedSequence or None
        The same seed reproduces the run exactly.
    vectorized : bool
        Whether ``fun`` evaluates a whole batch in one call.
    method_options : dict, optional
        The method's own settings (``minimize``'s ``options={...}``): ``F``, ``lam``, ``Cr``,
        ``target_vector`` (hgwo); ``F``, ``Cr`` (de); the fields of
        :class:`~hhra_phys.optim.pso.PSOOptions` (pso).
    max_nfev : int, optional
        Evaluation budget; the run stops before a batch that would exceed it.
    target : float, optional
        Stop once the best cost is ``<= target``.
    progress : bool
        Show a tqdm progress bar over iterations.
    record_diversity : bool
        Record the population's diversity per iteration in the history (a small cost per
        iteration that large studies may skip).
    """

    method: str = "hgwo"
    pop_size: int = 30
    max_iter: int | None = 100
    seed: SeedLike = None
    vectorized: bool = False
    method_options: Mapping[str, Any] | None = None
    max_nfev: int | None = None
    target: float | None = None
    progress: bool = False
    record_diversity: bool = True

    def validate(self) -> MinimizeOptions:
        """Check the settings before any evaluation; returns ``self``.

        The values of the method's own options are checked by its class when the run
        starts (:func:`make_optimiser`), still before any evaluation.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        cls = optimiser_class(self.method)
        check_int(self.pop_size, "pop_size", cls.min_pop_size)
        if self.max_iter is None and self.max_nfev is None:
            raise ParameterError("max_iter: give max_iter, max_nfev or both")
        if self.max_iter is not None:
            check_int(self.max_iter, "max_iter", 0)
        if self.max_nfev is not None:
            check_int(self.max_nfev, "max_nfev", 1)
        if self.target is not None and not isinstance(self.target, (int, float, np.number)):
            raise ParameterError(f"target: expected a number, got {self.target!r}")
        if self.method_options is not None and not isinstance(self.method_options, Mapping):
            raise ParameterError(f"options: expected a dict of {cls.method}'s settings, got "
                                 f"{self.method_options!r}")
        unknown = sorted(set(self.method_options or {}) - set(cls.option_names))
        if unknown:
            raise ParameterError(f"options: {unknown} not understood by {cls.method} "
                                 f"(accepted: {list(cls.option_names)})")
        return self

    @classmethod
    def of(cls, options: MinimizeOptions | Mapping[str, Any] | None = None,
           **overrides: Any) -> MinimizeOptions:
        """``options`` with ``overrides`` applied, validated.

        ``options`` may also be a plain dict: the method's own settings (SciPy's
        convention, ``minimize(..., options={"F": 0.5})``), i.e. ``method_options``.

        Raises
        ------
        ParameterError
            An override that is not a setting (with the settings' names), or a bad value.
        """
        if options is None or isinstance(options, MinimizeOptions):
            base = options if options is not None else cls()
        elif isinstance(options, Mapping):
            base = cls(method_options=dict(options))
        else:
            raise ParameterError(f"options: expected a MinimizeOptions or a dict of the "
                                 f"method's settings, got {options!r}")
        return with_overrides(base, overrides, "minimize").validate()


@dataclass(frozen=True)
class IterationState:
    """What a callback sees after each iteration (``nit = 0`` is the initialisation).

    Attributes
    ----------
    nit : int
        Iterations completed after the initialisation.
    nfev : int
        Objective evaluations so far.
    x : numpy.ndarray
        Best point found so far.
    fun : float
        Its cost.
    diversity : float
        Population spread (see :class:`hhra_phys.optim.history.History`).
    elapsed : float
        Seconds since the run started.
    """

    nit: int
    nfev: int
    x: np.ndarray
    fun: float
    diversity: float
    elapsed: float


def make_optimiser(
    method: str,
    bounds: Any,
    pop_size: int = 30,
    *,
    max_iter: int | None = 100,
    max_nfev: int | None = None,
    target: float | None = None,
    seed: SeedLike = None,
    x0: Any = None,
    options: Mapping[str, Any] | None = None,
) -> Optimiser:
    """Build the ask/tell optimiser of ``method`` (see :func:`minimize` for the arguments)."""
    cls = optimiser_class(method)
    opts = dict(options or {})
    unknown = sorted(set(opts) - set(cls.option_names))
    if unknown:
        raise ParameterError(
            f"options: {unknown} not understood by {cls.method} "
            f"(accepted: {list(cls.option_names)})"
        )
    return cls(
        bounds,
        pop_size,
        max_iter=max_iter,
        max_nfev=max_nfev,
        target=target,
        seed=seed,
        x0=x0,
        **opts,
    )


def _as_costs(values: Any) -> np.ndarray:
    """Costs as a float array. ``None`` becomes NaN (a failed evaluation, so the worst cost);
    anything else that is not a number is the caller's error."""
    try:
        return np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"fun: must return numbers (costs), got {values!r:.80}") from exc


def _evaluator(
    fun: Callable[..., Any], vectorized: bool, executor: Executor | None
) -> Callable[[np.ndarray], np.ndarray]:
    """A function mapping an ``(m, d)`` batch to its ``m`` costs."""
    if vectorized:

        def evaluate(points: np.ndarray) -> np.ndarray:
            out = _as_costs(fun(points))
            if out.ndim == 2 and out.shape[1] == 1:
                out = out[:, 0]
            if out.shape != (points.shape[0],):
                raise ParameterError(
                    f"fun: with vectorized=True it must map ({points.shape[0]}, d) points to "
                    f"({points.shape[0]},) costs, got shape {out.shape}"
                )
            return out

    elif executor is not None:

        def evaluate(points: np.ndarray) -> np.ndarray:
            return _as_costs(list(executor.map(fun, points)))

    else:

        def evaluate(points: np.ndarray) -> np.ndarray:
            return _as_costs([fun(p) for p in points])

    return evaluate


def minimize(
    fun: Callable[..., Any],
    bounds: Any,
    method: str = _FROM_OPTIONS,
    pop_size: int = _FROM_OPTIONS,
    max_iter: int | None = _FROM_OPTIONS,
    seed: SeedLike = _FROM_OPTIONS,
    vectorized: bool = _FROM_OPTIONS,
    *,
    options: MinimizeOptions | Mapping[str, Any] | None = None,
    x0: Any = None,
    callback: Callable[[IterationState], bool | None] | None = None,
    executor: Executor | None = None,
    **settings: Any,
) -> OptimizeResult:
    """Minimise ``fun`` over a box with a population optimiser.

    Parameters
    ----------
    fun : callable
        With ``vectorized=True``: ``fun(X)`` takes an ``(m, d)`` array and returns ``m`` costs.
        Otherwise ``fun(x)`` takes one ``(d,)`` vector and returns a float. Non-finite costs
        count as the worst possible cost.
    bounds : sequence of (float, float), (d, 2) array or scipy.optimize.Bounds
        Finite box with ``lo < hi``. Every point evaluated lies inside it.
    method, pop_size, max_iter, seed, vectorized
        The common settings (fields of :class:`MinimizeOptions`), given here they override
        ``options``; defaults ``"hgwo"``, 30, 100, ``None``, ``False``. ``method`` is a key
        of :data:`~hhra_phys.optim.registry.METHODS`: :class:`~hhra_phys.optim.hgwo.HGWO`,
        :class:`~hhra_phys.optim.gwo.GWO`, :class:`~hhra_phys.optim.pso.PSO`,
        :class:`~hhra_phys.optim.de.DE`.
    options : MinimizeOptions or dict, optional
        The run's settings; a plain dict holds only the method's own settings (SciPy's
        convention): ``F``, ``lam``, ``Cr``, ``target_vector`` (hgwo); ``F``, ``Cr`` (de);
        ``w``, ``w_start``, ``w_end``, ``c1``, ``c2``, ``vmax`` (pso).
    x0 : array of shape (k, d) or (d,), optional
        Points injected into the first population (warm start), each method documents how:
        GWO, PSO and DE put them in place of the first ``k`` random members; H-GWO puts them
        in place of the first ``k`` tent-map points, so they compete (with their opposites) in
        the opposition-based selection and survive only if among the best ``pop_size``.
    callback : callable, optional
        ``callback(state)`` after the initialisation and after every iteration, with an
        :class:`IterationState`; returning ``True`` stops the run.
    executor : concurrent.futures.Executor, optional
        With ``vectorized=False``, the batch's points are evaluated through ``executor.map``
        (a process pool, a Dask ``Client.get_executor()`` ...). Ignored with
        ``vectorized=True``, where the whole batch goes to ``fun`` in one call.
    **settings
        Any other field of :class:`MinimizeOptions`: ``max_nfev``, ``target``, ``progress``,
        ``record_diversity``, ``method_options``; overriding ``options``.

    Returns
    -------
    scipy.optimize.OptimizeResult
        ``x``, ``fun`` (best point and cost), ``nit`` (iterations after the initialisation),
        ``nfev``, ``history`` (:class:`~hhra_phys.optim.history.History`), ``noi`` (first
        iteration within 0.1 % of the final best, see :func:`~hhra_phys.optim.history.noi`),
        ``success``, ``status``, ``message``, ``method``, ``population`` and ``population_costs``
        (the final population) and ``seconds`` (wall time).

    Raises
    ------
    ParameterError
        On an unknown method or option, bad bounds, ``pop_size``, ``x0`` or budget, or a
        vectorised ``fun`` returning the wrong shape.
    """
    given = {name: value for name, value in (("method", method), ("pop_size", pop_size),
                                             ("max_iter", max_iter), ("seed", seed),
                                             ("vectorized", vectorized))
             if value is not _FROM_OPTIONS}
    opts = MinimizeOptions.of(options, **given, **settings)
    opt = make_optimiser(
        opts.method,
        bounds,
        opts.pop_size,
        max_iter=opts.max_iter,
        max_nfev=opts.max_nfev,
        target=opts.target,
        seed=opts.seed,
        x0=x0,
        options=opts.method_options,
    )
    opt.record_diversity = opts.record_diversity
    evaluate = _evaluator(fun, opts.vectorized, executor)
    bar = None
    if opts.progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=opt.max_iter, desc=opt.method, unit="it")
    start = time.perf_counter()
    stopped_by_callback = False
    try:
        while not opt.done:
            points = opt.ask()
            opt.tell(evaluate(points))
            if bar is not None and opt.nit > 0:
                bar.update(1)
                bar.set_postfix(best=f"{opt.f_best:.6g}", refresh=False)
            if callback is not None:
                state = IterationState(
                    nit=opt.nit,
                    nfev=opt.nfev,
                    x=np.array(opt.x_best, copy=True),
                    fun=opt.f_best,
                    diversity=opt.diversity,
                    elapsed=time.perf_counter() - start,
                )
                if callback(state) is True:
                    stopped_by_callback = True
                    break
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - start
    if stopped_by_callback:
        message, status = "stopped by the callback", 1
    else:
        message = opt.stop_reason or ""
        status = 0
    finite = bool(np.isfinite(opt.f_best))
    return OptimizeResult(
        x=np.array(opt.x_best, copy=True),
        fun=opt.f_best,
        nit=opt.nit,
        nfev=opt.nfev,
        history=opt.history,
        noi=opt.history.noi(),
        success=finite,
        status=status if finite else 2,
        message=message if finite else f"{message}; no finite cost was found",
        method=opt.method,
        population=np.array(opt.population, copy=True),
        population_costs=np.array(opt.costs, copy=True),
        seconds=seconds,
    )
