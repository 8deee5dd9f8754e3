"""Physical-parameter fitting: global search, local refinement, uncertainty.

:func:`fit` is the product's main job::

    from hhra_phys.fit import fit
    res = fit(dataset)                      # H-GWO (pop 100, 200 it.) then IPOPT
    print(res.summary()); res.save("fit.json")

The pipeline: split the record into estimation and validation parts; build a
:class:`~hhra_phys.problem.Problem` (free parameters, bounds, log coordinates,
the initial values of the model's fitted states); run a global optimiser of
:mod:`hhra_phys.optim` over the whole population at once through the compiled
simulator; refine locally with IPOPT or NLopt on the least-squares cost with
exact CasADi derivatives; compute Gauss-Newton confidence intervals; score
estimation and validation data by free-run simulation.

H-GWO's ``lam``. The paper's mutation ``lam*X_alpha + F*(X_r1 - X_r2)`` with
``lam = 0.25`` pulls every mutant toward the coordinate origin (measured in
``docs/benchmarks.md``). The fitting pipeline therefore uses ``lam = 1`` (standard
DE/best/1) by default; ``lam`` is exposed (CLI ``--lam``) and
``experiments/fit_rig.py`` compares the two.

Several fits (multi-start, several records or seeds) go through any
:class:`concurrent.futures.Executor` with :func:`fit_many`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Executor
from functools import partial
from typing import Any

import numpy as np

from hhra_phys._verb import make_callable

# A fit's settings, box widening, accuracy at the fitted values, intervals and the result's
# assembly live in modules of their own (issue 34); their names stay importable from here.
from hhra_phys.assemble import (  # noqa: F401  (re-exported)
    SearchRecord,
    _data_settings,
    _describe,
    _extrapolation_warnings,
    _pooled,
    _record_scores,
    _result,
    _score,
    _settings,
    assemble_result,
)
from hhra_phys.data import Dataset
from hhra_phys.defaults import default_for, registered_default
from hhra_phys.errors import ParameterError
from hhra_phys.fit_accuracy import (  # noqa: F401  (re-exported)
    ACCURACY_REFIT_SHIFT,
    _accuracy_shift,
    _accurate_at_fit,
    _integration,
)
from hhra_phys.fit_intervals import (  # noqa: F401  (re-exported)
    COLOURED_FACTOR,
    Intervals,
    _coloured,
    _edge_warnings,
    _intervals,
    _linear_intervals,
    _profile,
    _slopes,
)
from hhra_phys.fit_options import (  # noqa: F401  (re-exported)
    _IPOPT_KEYS,
    OPTIMIZERS,
    FitOptions,
    _refiner_names,
)
from hhra_phys.interrupt import interruptible, map_stopping
from hhra_phys.model import Model
from hhra_phys.optim import minimize
from hhra_phys.problem import (  # noqa: F401  (default_free, MAX_WIDEN_DECADES re-exported)
    MAX_WIDEN_DECADES,
    Problem,
    as_records,
    default_free,
    record_label,
)
from hhra_phys.refine import STALL_ITER, Stage, refine_ipopt, refine_nlopt
from hhra_phys.result import FitResult
from hhra_phys.widen import (  # noqa: F401  (re-exported)
    EDGE_TOL,
    WIDEN_CLEAR_GAIN,
    WIDEN_MAX_EXCESS,
    WIDEN_MIN_GAIN,
    _cost,
    _cost_and_excess,
    _may_widen,
    _release_gains,
    _report_widening,
    _sides_to_widen,
    _widened_search,
    _widening_notes,
    at_edges,
    fit_and_widen,
    widen_boxes,
    widened_box,
)

__all__ = [
    "FitOptions",
    "MAX_WIDEN_DECADES",
    "at_edges",
    "widened_box",
    "fit_and_widen",
    "widen_boxes",
    "OPTIMIZERS",
    "default_model",
    "fit",
    "fit_many",
    "best_of",
    "fit_problem",
]


def default_model(
    data: Dataset, valve: str | None = None
) -> tuple[Model, dict[str, tuple[float, float]]]:
    """The model (and bounds) :func:`fit` uses for a record when none is given: the
    registered default model (:mod:`hhra_phys.defaults`; the HHRA registers itself, see
    :func:`hhra_phys.models.hhra.defaults.default_model`).

    Parameters
    ----------
    data : Dataset
        The record.
    valve : str, optional
        The HHRA's valve (``"orifice"``, its default, or ``"linear"``); passed to the
        default model only when given.

    Raises
    ------
    ParameterError
        No default model is registered.
    """
    return default_for(data, **({} if valve is None else {"valve": valve}))


def fit(
    data: Dataset | Sequence[Dataset] | None = None,
    model: Model | None = None,
    *,
    options: FitOptions | None = None,
    validation: Dataset | Sequence[Dataset] | None = None,
    problem: Problem | None = None,
    datasheet: Any | None = None,
    callback: Callable[[Any], bool | None] | None = None,
    **settings: Any,
) -> FitResult:
    """Fit a physical model to a record, or to several records at once.

    Parameters
    ----------
    data : Dataset or sequence of Dataset, optional
        The whole record (default: the default model's example record, the HHRA's
        simulated rig, seed 0: :mod:`hhra_phys.defaults`), or a list
        of records fitted jointly (:class:`~hhra_phys.problem.Problem`): shared
        parameters, per-record initial states (``x0_<state>_rec<k>``) and per-record
        parameters, each record split by ``split`` unless ``validation`` is
        given; metrics per record in :attr:`FitResult.records`, pooled in
        :attr:`FitResult.metrics`.
    model : Model, optional
        Model to fit (default: :func:`default_model`, the registered default model of
        :mod:`hhra_phys.defaults`: the HHRA with the orifice
        valve, a pressure output if the data's output is pressure, rescaled to
        sample units for records without a sample time). With the default model
        the records are first converted to its units (mA, deg) where they declare
        others, and implausible ranges are warned about
        (:func:`~hhra_phys.models.hhra.defaults.prepare_record`).
    options : FitOptions, optional
        The fit's settings (default :class:`FitOptions`'s).
    validation : Dataset or sequence of Dataset, optional
        Separate validation record(s) (then ``data`` is all estimation); they have
        their initial state estimated and the first record's per-record parameters.
    datasheet : object, optional
        Known physical symbols for the model's physical view
        (:meth:`Model.physical_view <hhra_phys.model.Model.physical_view>`; for the
        HHRA a :class:`~hhra_phys.models.hhra.physical.PhysicalParameters`); the
        fitted parameters are then also reported as physical symbols. Simulated
        rig data carries its own.
    callback : callable, optional
        Called after every global iteration (see :func:`hhra_phys.optim.minimize`).
    problem : Problem, optional
        A ready problem (then ``model``, ``free`` ... are taken from it; ``data``, split
        by ``split``, gives the validation parts and the description).
    **settings
        Any field of :class:`FitOptions` (``seed=3``, ``pop_size=30``, ...), overriding
        ``options``; validated with it (:meth:`FitOptions.validate`).

    Returns
    -------
    FitResult
        ``status`` is ``"diverged"`` (with a warning) when the fitted model's
        simulation does not stay finite; intervals that cannot be computed are
        ``(nan, nan)`` and listed in ``intervals["undetermined"]``.

    Raises
    ------
    KeyboardInterrupt
        On Ctrl-C anywhere in the search or the refiners (also inside IPOPT and NLopt
        callbacks, see :mod:`hhra_phys.interrupt`): no result.
    """
    _check_model_argument(model)
    opts = FitOptions.of(options, **settings)
    t_start = time.perf_counter()
    if data is None:
        data = _example_record()
    records = as_records(data)
    whole = as_records(validation) if validation is not None and len(validation) else []
    notes: list[str] = []
    if model is None and problem is None:
        records, whole, notes = _prepare_records(records, whole)
    est, val_parts = _split_records(records, whole, opts.split)
    if problem is None:
        problem = _build_problem(est, model, opts)
    return fit_problem(problem, val_parts, whole, opts, datasheet=datasheet,
                       callback=callback, records=records, notes=notes, t_start=t_start)


def _example_record() -> Dataset:
    """The default model's example record, for a fit without data."""
    default = registered_default()
    if default.example is None:
        raise ParameterError(f"no data given and the default model ({default.name}) has no "
                             "example record: pass data")
    return default.example()


def _check_model_argument(model: object) -> None:
    """Refuse a ``model`` that is not a :class:`~hhra_phys.model.Model` (a name such as
    ``"HHRA"``, a class instead of an instance) with the argument named."""
    if model is None or isinstance(model, Model):
        return
    hint = ("pass an instance, e.g. HHRAModel()" if isinstance(model, type) else
            "pass a Model object, e.g. hhra_phys.HHRAModel() or your own Model([...]); "
            "leave it out for the default HHRA")
    raise ParameterError(f"model must be a hhra_phys Model, got {type(model).__name__} "
                         f"{model!r:.60}; {hint}")


def _prepare_records(records: list[Dataset], whole: list[Dataset]
                     ) -> tuple[list[Dataset], list[Dataset], list[str]]:
    """The default model knows its units: convert the records, warn about odd ranges."""
    prepare_record = registered_default().prepare
    if prepare_record is None:
        return records, whole, []
    notes: list[str] = []
    out: tuple[list[Dataset], list[Dataset]] = ([], [])
    for given, prepared in zip((records, whole), out, strict=True):
        for ds in given:
            new, converted, warns = prepare_record(ds)
            prepared.append(new)
            notes += converted + warns
    return out[0], out[1], notes


def _split_records(records: list[Dataset], whole: list[Dataset], split: float
                   ) -> tuple[list[Dataset], list[Dataset | None]]:
    """Each record's estimation part and held-out part (``None``: whole validation records
    are given, or ``split`` is 1)."""
    if whole or split >= 1:
        return records, [None] * len(records)
    pairs = [ds.split(split) for ds in records]
    return [p[0] for p in pairs], [p[1] for p in pairs]


def _build_problem(est: list[Dataset], model: Model | None, opts: FitOptions) -> Problem:
    """The fit's problem on the estimation parts.

    Without a model, the default model's automatic boxes of the records (the widest of
    each) join the default boxes; the user's explicit ``bounds`` are kept as given,
    default boxes may be widened.
    """
    defaults = dict(opts.default_bounds or {})
    if model is None:
        model, auto = default_model(est[0])
        for ds in est[1:]:
            for name, (lo, hi) in default_model(ds)[1].items():
                old = auto.get(name, (lo, hi))
                auto[name] = (min(old[0], lo), max(old[1], hi))
        defaults = {**auto, **defaults}
    return Problem(model, est, cost=opts.cost, free=opts.free,  # type: ignore[arg-type]
                   fixed=opts.fixed, bounds=opts.bounds, default_bounds=defaults or None,
                   initial_state=opts.initial_state,  # type: ignore[arg-type]
                   start=opts.start, allow_outside_box=opts.allow_outside_box,
                   per_record=opts.per_record)


def fit_problem(
    problem: Problem,
    validation: Sequence[Dataset | None] = (),
    whole: Sequence[Dataset] = (),
    options: FitOptions | None = None,
    *,
    datasheet: Any | None = None,
    callback: Callable[[Any], bool | None] | None = None,
    records: Sequence[Dataset] | None = None,
    notes: Sequence[str] = (),
    t_start: float | None = None,
) -> FitResult:
    """Fit a ready problem: search, refiners, box widening, accuracy check, the result.

    What :func:`fit` runs after building the problem, and the diagnosis loop's fits.

    Parameters
    ----------
    problem : Problem
    validation : sequence of (Dataset or None)
        Each record's held-out part, scored with that record's own values (empty or
        ``None`` entries: none).
    whole : sequence of Dataset
        Whole validation records (initial state estimated on each, the first record's
        per-record values).
    options : FitOptions, optional
        The search's settings (the problem's own settings are the problem's).
    datasheet, callback
        As for :func:`fit`.
    records : sequence of Dataset, optional
        The records as given (before any split), for the result's description (default:
        the problem's).
    notes : sequence of str
        Warnings about the records to add to the result's.
    t_start : float, optional
        ``time.perf_counter()`` at the start of the fit (default: now).
    """
    opts = options if options is not None else FitOptions()
    t_start = time.perf_counter() if t_start is None else t_start
    parts = list(validation) or [None] * len(problem.records)
    if len(parts) != len(problem.records):
        raise ParameterError(f"{len(parts)} validation parts for {len(problem.records)} "
                             "records (one per record, None for none)")
    search = partial(_search_and_refine, optimizer=opts.optimizer, refine=opts.refine,
                     pop_size=opts.pop_size, max_iter=opts.max_iter, seed=opts.seed,
                     lam=opts.lam, options=opts.optimizer_options,
                     refine_options=opts.refine_options, start=opts.start,
                     seed_population=opts.seed_population, progress=opts.progress,
                     callback=callback)
    with interruptible():
        problem, z, stages, history, widened = fit_and_widen(problem, search, opts.widen_bounds)
        problem, z = _accurate_at_fit(problem, z, stages, opts.refine, opts.refine_options)
    result = _result(problem, z, (stages, history), (parts, list(whole)), opts, datasheet,
                     list(records) if records is not None else problem.datasets, t_start)
    _report_widening(result, widened, problem)
    result.warnings.extend(notes)
    return result


def _search_and_refine(
    problem: Any,
    optimizer: str,
    refine: str | Sequence[str] | None,
    pop_size: int,
    max_iter: int,
    seed: int | None,
    lam: float,
    options: Mapping[str, Any] | None,
    refine_options: Mapping[str, Any] | None,
    start: Mapping[str, float] | None,
    seed_population: bool | None,
    progress: bool,
    callback: Callable[[Any], bool | None] | None,
    z_start: np.ndarray | None = None,
    label: str = "",
    global_search: bool = True,
) -> tuple[np.ndarray, list[Stage], list[float]]:
    """Global search then refiners on a problem (one record or stacked); (z, stages, history).

    ``z_start`` (a refit after widening a box) starts there, with it in the first
    population; ``label`` is appended to the stage names; ``global_search=False`` runs
    the refiners alone from ``z_start`` (a widening round's check, :func:`_widened_search`).
    """
    stages: list[Stage] = []
    history: list[float] = []
    warm = bool(start) if seed_population is None else seed_population
    if z_start is None:
        z_start = problem.to_z(problem.start_values())
    else:
        warm = True
    z = z_start
    if optimizer != "none" and global_search:
        t0 = time.perf_counter()
        opts = dict(options or {})
        if optimizer == "hgwo":
            opts.setdefault("lam", lam)
        bz = problem.bounds_z()
        x0 = np.clip(z_start, bz[:, 0], bz[:, 1])[None, :] if warm else None
        res = minimize(problem, bz, method=optimizer, pop_size=pop_size, max_iter=max_iter,
                       seed=seed, vectorized=True, options=opts, x0=x0, progress=progress,
                       callback=callback)
        first = float(res.history.best[0]) if len(res.history.best) else float("nan")
        history = [float(v) for v in res.history.best]
        z = np.asarray(res.x, dtype=float)
        stages.append(Stage(optimizer + label, z, first, float(res.fun), int(res.nfev),
                            time.perf_counter() - t0,
                            {"nit": int(res.nit), "noi": _int_or_none(res.noi),
                             "cost": problem.cost, "options": opts}))
    ropts = dict(refine_options or {})
    if not global_search:
        # A check of a prediction, from an optimum: IPOPT stops where its iterate stalls.
        ropts.setdefault("stall_iter", STALL_ITER)
    for name in _refiner_names(refine):
        if name == "ipopt":
            st = refine_ipopt(problem, z, **{k: v for k, v in ropts.items() if k in _IPOPT_KEYS})
        else:
            keys = ("max_eval", "xtol_rel", "ftol_rel")
            st = refine_nlopt(problem, z, algorithm=name.split(":", 1)[1],
                              **{k: v for k, v in ropts.items() if k in keys})
        st.name += label
        stages.append(st)
        z = st.z
    return z, stages, history


def _int_or_none(x: Any) -> int | None:
    try:
        return None if x is None else int(x)
    except (TypeError, ValueError):
        return None


def _fit_one(kwargs: dict[str, Any]) -> FitResult:
    return fit(**kwargs)


def fit_many(
    datasets: Iterable[Dataset | None] | None = None,
    seeds: Iterable[int] | None = None,
    executor: Executor | None = None,
    **kwargs: Any,
) -> list[FitResult]:
    """Run several fits: batch over records and/or multi-start over seeds.

    Parameters
    ----------
    datasets : iterable of Dataset, optional
        Records to fit (default: one, the ``data`` keyword or the simulated rig).
    seeds : iterable of int, optional
        Seeds of the global search; with several seeds and one record this is a
        multi-start (see :func:`best_of`).
    executor : concurrent.futures.Executor, optional
        Where the fits run (a ``ProcessPoolExecutor`` locally, a Dask
        ``Client.get_executor()`` on a cluster); default: one after another here. On
        Ctrl-C its queued fits are cancelled and its worker processes ended
        (:func:`hhra_phys.interrupt.stop_workers`; a process pool cannot be used again).
    **kwargs
        Passed to :func:`fit`.

    Returns
    -------
    list of FitResult
        In the order of ``datasets`` x ``seeds``.
    """
    data_list = list(datasets) if datasets is not None else [kwargs.pop("data", None)]
    seed_list = list(seeds) if seeds is not None else [kwargs.pop("seed", 0)]
    jobs = [dict(kwargs, data=d, seed=s) for d in data_list for s in seed_list]
    if executor is None:
        return [_fit_one(j) for j in jobs]
    return list(map_stopping(executor, _fit_one, jobs))


def best_of(results: Sequence[FitResult]) -> FitResult:
    """The result with the lowest final least-squares cost (estimation RMSE)."""
    if not results:
        raise ParameterError("best_of needs at least one result")
    return min(results, key=lambda r: r.metrics["est"].get("rmse", np.inf))


make_callable(__name__, "hhra_phys.fit:fit")  # hhra_phys.fit(...) is fit(...) (hhra_phys._verb)
