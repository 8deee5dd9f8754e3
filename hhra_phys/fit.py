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
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from hhra_phys._verb import make_callable
from hhra_phys.data import Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.interrupt import interruptible, map_stopping
from hhra_phys.likelihood import profile_intervals
from hhra_phys.metrics import score
from hhra_phys.model import Model
from hhra_phys.multi import pooled_score
from hhra_phys.noise import coloured_covariance, interval_factor
from hhra_phys.optim import minimize
from hhra_phys.optim.registry import METHODS
from hhra_phys.options import with_overrides
from hhra_phys.parameters import split_record_name
from hhra_phys.problem import (  # noqa: F401  (default_free, MAX_WIDEN_DECADES re-exported)
    MAX_WIDEN_DECADES,
    Problem,
    as_records,
    default_free,
    record_label,
)
from hhra_phys.refine import (
    STALL_ITER,
    CompiledLeastSquares,
    Stage,
    refine_ipopt,
    refine_nlopt,
)
from hhra_phys.result import (
    FitResult,
    derived_estimates,
    physical_covariance,
    uncertainty,
    weak_directions,
)
from hhra_phys.simulate import MAX_ACCURACY_SUBSTEPS

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

#: Global searches of a fit: the registered optimisers (:mod:`hhra_phys.optim.registry`) and
#: ``"none"`` (the refiners alone).
OPTIMIZERS: tuple[str, ...] = (*METHODS, "none")


def default_model(
    data: Dataset, valve: str = "orifice"
) -> tuple[Model, dict[str, tuple[float, float]]]:
    """The model (and bounds) :func:`fit` uses for a record when none is given: the HHRA.

    See :func:`hhra_phys.models.hhra.defaults.default_model`.
    """
    from hhra_phys.models.hhra.defaults import default_model as hhra_default

    return hhra_default(data, valve=valve)


def _refiner_names(refine: str | Sequence[str] | None) -> list[str]:
    if refine is None:
        return []
    names = [refine] if isinstance(refine, str) else list(refine)
    out = []
    for name in names:
        low = name.lower()
        if low == "none":
            continue
        if low == "nlopt":
            low = "nlopt:LD_LBFGS"
        if not (low == "ipopt" or low.startswith("nlopt:")):
            raise ParameterError(
                f"refine must be 'ipopt', 'nlopt', 'nlopt:ALGORITHM' or 'none', got {name!r}"
            )
        out.append(low)
    return out


@dataclass(frozen=True)
class FitOptions:
    """Settings of a fit (:func:`fit`), validated as a whole.

    Every field is also a keyword of :func:`fit`, which overrides the options it is given
    (``fit(ds, options=FitOptions(pop_size=30), seed=2)``).

    Attributes
    ----------
    optimizer : {"hgwo", "gwo", "pso", "de", "none"}
        Global search (``"none"``: start the refiners from the nominal values or
        ``start``).
    refine : str or list of str or None
        ``"ipopt"`` (default), ``"nlopt"`` (``LD_LBFGS`` with the CasADi gradient),
        ``"nlopt:ALGORITHM"`` (e.g. ``"nlopt:LN_BOBYQA"``), a list of them run in
        turn, or ``"none"``.
    free, fixed, bounds, cost, initial_state
        See :class:`~hhra_phys.problem.Problem` (default free set: every parameter
        but the model's ``held`` ones, for the HHRA ``g_spring`` and ``g_load``; the
        initial values of the model's fitted states, the HHRA's angle, are fitted).
    split : float
        Fraction of the record used for estimation; the rest is validation.
    pop_size, max_iter : int
        Global search population and iterations (paper: 100 and 200).
    seed : int or None
        Seed of the global search.
    lam : float
        H-GWO's mutation factor (module docstring); ignored by other methods.
    optimizer_options : dict, optional
        Further optimiser options (``F``, ``w``, ...).
    refine_options : dict, optional
        Keyword arguments for the refiners (``hessian``, ``shooting``, ``max_iter``,
        ``stall_iter``, ``max_eval`` ...), applied to those that accept them.
    start : dict, optional
        Starting values (physical units) for the global search's first population
        and for ``optimizer="none"``.
    progress : bool
        Show a progress bar during the global search.
    seed_population : bool, optional
        Put the start values (``start``, or those of ``problem``) into the global
        search's first population (warm start). Default: when ``start`` is given.
    intervals : {"linear", "profile"}
        95 % intervals from the Gauss-Newton covariance at the optimum (fast), or
        profile-likelihood intervals (:mod:`hhra_phys.likelihood`; a few seconds more,
        better founded along curved, weakly determined directions).
    per_record : sequence of str, optional
        With several records: free model parameters estimated once per record
        (default: those the model's parts declare, such as a sensor offset).
    default_bounds : dict, optional
        ``{name: (lower, upper)}`` replacing the model's default boxes (e.g. the wider
        boxes of a record in sample units); unlike ``bounds`` they may be widened.
    widen_bounds : bool
        When a log-scaled free group ends at the edge of its default box (the model's,
        or ``default_bounds``) and moving it out lowers the sum of squares, widen that
        side by a decade (at most :data:`MAX_WIDEN_DECADES`, fewer when a refit does not
        lower the cost) and refit (:func:`widen_boxes`); the result's warnings and
        ``settings["widened"]`` say so. The same for one record, several records and a
        given ``problem`` (whose ``bounds`` are its explicit ones); groups with explicit
        ``bounds`` are never widened.
    allow_outside_box : bool
        Accept ``fixed`` values outside their parameter's box (checked by
        :class:`~hhra_phys.problem.Problem`; the CLI's ``--allow-outside-box``).

    """

    optimizer: str = "hgwo"
    refine: str | tuple[str, ...] | None = "ipopt"
    free: tuple[str, ...] | None = None
    fixed: Mapping[str, float] | None = None
    bounds: Mapping[str, tuple[float, float]] | None = None
    split: float = 0.5
    cost: str = "itae"
    initial_state: str = "fit"
    pop_size: int = 100
    max_iter: int = 200
    seed: int | None = 0
    lam: float = 1.0
    optimizer_options: Mapping[str, Any] | None = None
    refine_options: Mapping[str, Any] | None = None
    start: Mapping[str, float] | None = None
    progress: bool = False
    seed_population: bool | None = None
    intervals: str = "linear"
    per_record: tuple[str, ...] | None = None
    default_bounds: Mapping[str, tuple[float, float]] | None = None
    widen_bounds: bool = True
    allow_outside_box: bool = False

    def validate(self) -> FitOptions:
        """Check the settings a fit checks before any work; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        if self.intervals not in ("linear", "profile"):
            raise ParameterError(f"intervals must be 'linear' or 'profile', got "
                                 f"{self.intervals!r}")
        if self.optimizer not in OPTIMIZERS:
            raise ParameterError(f"optimizer must be one of {', '.join(OPTIMIZERS)}, got "
                                 f"{self.optimizer!r}")
        if not 0 < self.split <= 1:
            raise ParameterError(f"split must be in (0, 1], got {self.split}")
        from hhra_phys.options import MAX_ITERATIONS, MAX_POPULATION

        for name, most in (("pop_size", MAX_POPULATION), ("max_iter", MAX_ITERATIONS)):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0):
                raise ParameterError(f"{name} must be an integer >= 0, got {v!r}")
            if v > most:
                raise ParameterError(f"{name} must be at most {most:,} (see "
                                     f"hhra_phys.options), got {v:,}")
        return self

    @classmethod
    def of(cls, options: FitOptions | None = None, **overrides: Any) -> FitOptions:
        """``options`` (default: the defaults) with ``overrides`` applied, validated.

        Raises
        ------
        ParameterError
            An override that is not a setting (with the settings' names), or a bad value.
        """
        return with_overrides(options if options is not None else cls(), overrides, "fit",
                              ("free", "per_record", "refine")).validate()


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
        The whole record (default: the built-in simulated rig, seed 0), or a list
        of records fitted jointly (:class:`~hhra_phys.problem.Problem`): shared
        parameters, per-record initial states (``x0_<state>_rec<k>``) and per-record
        parameters, each record split by ``split`` unless ``validation`` is
        given; metrics per record in :attr:`FitResult.records`, pooled in
        :attr:`FitResult.metrics`.
    model : Model, optional
        Model to fit (default: :func:`default_model`: the HHRA with the orifice
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
        from hhra_phys.models.hhra.rig import simulate_rig

        data = simulate_rig(seed=0)
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
    """The default HHRA knows its units: convert the records, warn about odd ranges."""
    from hhra_phys.models.hhra.defaults import prepare_record

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


def fit_and_widen(
    problem: Any,
    search: Callable[..., tuple[np.ndarray, list[Stage], list[float]]],
    widen: bool = True,
) -> tuple[Any, np.ndarray, list[Stage], list[float], list[dict[str, Any]]]:
    """Search and refine ``problem``, then widen default boxes a group ends at and refit.

    The one place every fit (one record, a given problem, several records) runs its
    search and the box widening of :func:`widen_boxes`.

    Parameters
    ----------
    problem : Problem
    search : callable
        ``search(problem, z_start=None, label="") -> (z, stages, history)``
        (:func:`_search_and_refine` with the fit's settings).
    widen : bool
        Widen default boxes (``False``: one search, as given).

    Returns
    -------
    problem, z, stages, history, widened
        The (possibly widened) problem, the optimum in its coordinates, the stages and
        best-cost history of all searches, and the widened box sides (the problem's own
        widenings for start values first).
    """
    z, stages, history = search(problem)
    widened: list[dict[str, Any]] = list(getattr(problem, "widened", []))
    if widen:
        problem, z, more = widen_boxes(problem, z, search, stages, history)
        widened += more
    return problem, z, stages, history, widened


def _report_widening(result: FitResult, widened: list[dict[str, Any]], problem: Any) -> None:
    """Put the widened sides and the fixed-value notes into the result."""
    if widened:
        result.settings["widened"] = widened
        result.warnings.extend(_widening_notes(widened))
    result.warnings.extend(getattr(problem, "notes", []))


def _widening_notes(widened: list[dict[str, Any]]) -> list[str]:
    """One sentence per widened box side, from the rounds of :func:`widen_boxes`."""
    sides: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for w in widened:
        sides.setdefault((w["name"], w["side"], w.get("reason", "fit")), []).append(w)
    notes = []
    for (name, side, _), rounds in sides.items():
        first, last = rounds[0], rounds[-1]
        n = sum(int(w.get("decades", 1)) for w in rounds)
        if first.get("reason") == "start":
            notes.append(f"{name}'s start value lies beyond the {side} edge of its default box "
                         f"[{first['from'][0]:.4g}, {first['from'][1]:.4g}]; that side was "
                         f"widened by {n} decade{'s' if n > 1 else ''} to [{last['to'][0]:.4g}, "
                         f"{last['to'][1]:.4g}]")
            continue
        text = (f"{name} ended at the {side} edge of its default box [{first['from'][0]:.4g}, "
                f"{first['from'][1]:.4g}]; that side was widened by {n} decade"
                f"{'s' if n > 1 else ''} to [{last['to'][0]:.4g}, {last['to'][1]:.4g}] and the "
                "fit repeated")
        if last.get("searched", True) is False and last.get("gain", 1.0) >= WIDEN_MIN_GAIN:
            text += (f" locally (the refit gained {100 * last['gain']:.2g} %, less than "
                     "predicted: not worth a search of the wider box)")
        elif last.get("gain", 1.0) < WIDEN_MIN_GAIN:
            text += (f", which lowered the sum of squares by only {100 * last['gain']:.2g} %: "
                     f"the data do not determine {name} beyond the old edge (it is negligible "
                     "or unobservable there), so widening stopped")
        notes.append(text)
    return notes


#: Distance to a box edge (fraction of the box in fitting coordinates) that counts as "at it".
EDGE_TOL = 1e-4
#: Relative fall of the least-squares cost below which a widened box did not help: the
#: group sits at its edge because the data do not see it there (a leakage of zero), not
#: because the truth lies beyond, and further decades would only cost refits.
WIDEN_MIN_GAIN = 1e-3
#: Largest share of the sum of squares above the residual's noise level at which boxes
#: are widened (0.5: RMSE up to sqrt(2) times the noise). A model that lacks an effect
#: leaves a residual far above the noise and pushes groups to their edges to make up for
#: it; a wider box there buys a few per cent and distorts the groups the effect should
#: explain (the diagnosis loop then chose the wrong effect). Measured (docs/fitting.md):
#: 0.04-0.13 for the heavily damped rig whose group lies beyond its box, 0.86-0.93 for base
#: fits lacking a sharp friction, 0.53-0.99 for the loop's candidate fits there.
WIDEN_MAX_EXCESS = 0.5
#: Predicted relative fall of the sum of squares (Gauss-Newton, :func:`_release_gains`) from
#: letting one group out of its box above which the box is widened whatever the residual's
#: excess over the noise: a group its box holds that far from the optimum is held by the
#: guess, not pushed there by missing physics (a base fit lacking a sharp friction gained
#: 1-2 % from its widened groups, docs/fitting.md). The loop's candidates need it: a found
#: effect whose coefficient stops at a guessed bound (a gravity load at a third of its true
#: size) leaves a residual far above the noise, and without the widening a stand-in follows.
WIDEN_CLEAR_GAIN = 0.1
#: Intervals at least this much too narrow under the residual's noise colour are
#: recomputed with the noise model (:func:`hhra_phys.noise.coloured_covariance`) and
#: warned about (:func:`hhra_phys.noise.interval_factor`).
COLOURED_FACTOR = 2.0


def at_edges(problem: Any, z: np.ndarray, tol: float = EDGE_TOL) -> list[tuple[int, str]]:
    """Free parameters (index, ``"lower"``/``"upper"``) whose coordinate ends at its box edge.

    Parameters
    ----------
    problem : Problem
    z : ndarray, shape (n_free,)
        Fitting coordinates.
    tol : float
        Distance to an edge, as a fraction of the box width, that counts as at it.
    """
    bz = problem.bounds_z()
    span = bz[:, 1] - bz[:, 0]
    out = []
    for i in range(problem.n_free):
        lo, hi = z[i] - bz[i, 0], bz[i, 1] - z[i]
        if min(lo, hi) <= tol * span[i]:
            out.append((i, "lower" if lo <= hi else "upper"))
    return out


def widened_box(par: Any, side: str) -> tuple[float, float] | None:
    """``par``'s box with one side widened once, or None when that side cannot move.

    A log-scaled (positive) parameter's side moves a decade; a signed (linear) one's
    moves ten times as far from zero; a side at zero, or on the other side of it, is a
    sign (physics), not a guessed size, and stays (None).
    """
    lo, hi = float(par.lower), float(par.upper)
    if par.scale == "log":
        return (lo / 10, hi) if side == "lower" else (lo, hi * 10)
    if side == "lower" and lo < 0:
        return 10 * lo, hi
    if side == "upper" and hi > 0:
        return lo, 10 * hi
    return None


def _cost(problem: Any, z: np.ndarray) -> float:
    """Least-squares cost ``0.5 sum r^2`` at ``z`` (``inf`` where the simulation fails)."""
    r = problem.simulate_values(problem.from_z(np.asarray(z, dtype=float))) - problem.y
    total = float(r @ r)
    return 0.5 * total if np.isfinite(total) else np.inf


def _cost_and_excess(problem: Any, z: np.ndarray) -> tuple[float, float]:
    """Least-squares cost ``0.5 sum r^2`` at ``z`` and the share of ``sum r^2`` above the noise.

    The noise is the residual's own (:func:`hhra_phys.noise.noise_level`: the part not
    coherent with the input and the simulated output); one simulation.
    """
    from hhra_phys.noise import noise_level

    yhat = problem.simulate_values(problem.from_z(np.asarray(z, dtype=float)))
    r = yhat - problem.y
    total = float(r @ r)
    if not np.isfinite(total):
        return np.inf, 1.0
    if total <= 0:
        return 0.0, 0.0
    u = getattr(getattr(problem, "data", None), "u", None)
    inputs = (u, yhat) if u is not None and np.shape(u) == r.shape else None
    return 0.5 * total, max(0.0, 1.0 - r.size * noise_level(r, inputs) ** 2 / total)


def _release_gains(problem: Any, z: np.ndarray, edges: list[tuple[int, str]]) -> list[float]:
    """Predicted relative fall of the sum of squares from letting each edge group out.

    One Gauss-Newton model of the least-squares cost at ``z`` (the exact residual
    Jacobian, as for the intervals): for each edge coordinate, the step over all free
    coordinates with that one released and the other edge ones held, against the step
    with all of them held. A group at an edge because the data do not see it there (a
    negligible effect's coefficient) gains nothing, nor does one the step would move
    back inside; widening its box would only cost a refit. Moving one coordinate alone
    is no test: a group correlated with others (damping with leakage) only pays off when
    they follow it.
    """
    r, J = CompiledLeastSquares(problem)(z)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
        return [0.0] * len(edges)
    total = float(r @ r)
    held = {i for i, _ in edges}

    def rest(cols: list[int]) -> tuple[float, np.ndarray]:
        dz, *_ = np.linalg.lstsq(J[:, cols], -r, rcond=1e-10)
        e = r + J[:, cols] @ dz
        return float(e @ e), dz

    base, _ = rest([j for j in range(problem.n_free) if j not in held])
    gains = []
    for i, side in edges:
        cols = [j for j in range(problem.n_free) if j not in held or j == i]
        ssr, dz = rest(cols)
        outward = dz[cols.index(i)] * (1.0 if side == "upper" else -1.0) > 0
        gains.append((base - ssr) / total if outward and total > 0 else 0.0)
    return gains


def widen_boxes(
    problem: Any,
    z: np.ndarray,
    search: Callable[..., tuple[np.ndarray, list[Stage], list[float]]],
    stages: list[Stage],
    history: list[float],
) -> tuple[Any, np.ndarray, list[dict[str, Any]]]:
    """Widen default boxes whose edge a free parameter ends at, and refit.

    The rule of every fit path (:func:`fit_and_widen`; the loop's base, candidate and
    backward refits are such fits): only default boxes (the model's, an effect's or
    ``default_bounds``, :attr:`Problem.default_boxes
    <hhra_phys.problem.Problem.default_boxes>`) of model parameters are widened, never the
    user's explicit bounds or initial states; a log-scaled (positive) parameter by one
    decade on that side per round, a signed (linear) one by moving that side ten times as
    far from zero (a side at zero is a sign and stays), at most :data:`MAX_WIDEN_DECADES`
    beyond the default box. A side is widened where moving the parameter out of its box
    lowers the sum of squares by at least :data:`WIDEN_MIN_GAIN` (predicted by a
    Gauss-Newton step, :func:`_release_gains`) while the residual is mostly noise (at most
    :data:`WIDEN_MAX_EXCESS` of the sum of squares above its noise level), and by at least
    :data:`WIDEN_CLEAR_GAIN` otherwise (with the model lacking something the edge is
    usually a symptom of it; a release that pays that much is the box's doing). Each
    round refines from the previous optimum first and searches the widened box globally
    only when that refit bears the prediction out (:func:`_widened_search`); rounds stop
    once a refit lowers the least-squares cost by less than :data:`WIDEN_MIN_GAIN`
    (relative), or a round's prediction was not borne out. A global refit starts with the
    previous optimum in its population, so it cannot end worse.

    Parameters
    ----------
    problem : Problem
    z : ndarray, shape (n_free,)
        The optimum of the first search, in fitting coordinates.
    search : callable
        As for :func:`fit_and_widen`.
    stages, history : list
        Extended in place with the refits' stages and histories.

    Returns
    -------
    problem, z, widened
        The widened problem (``problem`` itself if nothing was widened), its optimum and
        one dict per widened side and round: ``name``, ``side``, ``round``, ``from``,
        ``to`` (the box in physical units), ``gain`` (the refit's relative fall of the
        least-squares cost) and ``searched: False`` where only the refiners ran (the
        predicted gain was not borne out).
    """

    origin = getattr(problem, "default_boxes", {})
    widened: list[dict[str, Any]] = []
    edges = at_edges(problem, z)
    if not edges:
        return problem, z, widened  # the common case: no simulation, no Jacobian
    cost, excess = _cost_and_excess(problem, z)
    for round_ in range(1, MAX_WIDEN_DECADES + 1):
        if not np.isfinite(cost) or not edges:
            break  # a diverged fit is not at an edge for a reason a wider box would fix
        if excess is None:
            excess = _cost_and_excess(problem, z)[1]
        need = WIDEN_MIN_GAIN if excess <= WIDEN_MAX_EXCESS else WIDEN_CLEAR_GAIN
        box, changes = _sides_to_widen(problem, edges, _release_gains(problem, z, edges),
                                       origin, need, round_)
        if not changes:
            break
        values = problem.from_z(z)
        problem = problem.with_boxes({n: tuple(b) for n, b in box.items()})
        z, new_cost, confirmed = _widened_search(problem, problem.to_z(values), search,
                                                 f" (widened {round_})", cost, need,
                                                 stages, history)
        excess = None  # the next round's (a noise-level estimate: only if there is one)
        gain = (cost - new_cost) / cost if cost > 0 else 0.0
        for c in changes:
            c["gain"] = float(gain)
            if not confirmed:
                c["searched"] = False
        widened.extend(changes)
        cost = new_cost
        edges = at_edges(problem, z)
        if gain < WIDEN_MIN_GAIN or not confirmed:
            break
    return problem, z, widened


def _widened_search(problem: Any, z0: np.ndarray,
                    search: Callable[..., tuple[np.ndarray, list[Stage], list[float]]],
                    label: str, cost: float, need: float, stages: list[Stage],
                    history: list[float]) -> tuple[np.ndarray, float, bool]:
    """One widening round's refit of the widened ``problem`` from ``z0``: ``(z, cost, searched)``.

    The refiners alone first (``search(..., global_search=False)``), from the previous
    optimum: they reach whatever the release of the edge groups gains near it. The global
    search runs again only when that local gain is at least ``need``, the gain the
    Gauss-Newton prediction had to promise for the side to be widened: a prediction the
    local refit does not bear out (a model lacking an effect, whose residual is far from
    the Gauss-Newton model's linear reach) is not worth a search of the whole box
    (measured: a base fit lacking a dead zone, predicted >= 10 %, refitted 0.02 %, at
    the cost of a full H-GWO search). With no refiner the search runs as before. The
    better of the two optima is kept, so a confirmed round ends no worse than the
    search alone.
    """
    z_loc, more, _ = search(problem, z_start=z0, label=label, global_search=False)
    stages.extend(more)
    loc_cost = _cost(problem, z_loc) if more else np.inf
    if more and not (cost > 0 and (cost - loc_cost) / cost >= need):
        return z_loc, loc_cost, False
    z, more, hist = search(problem, z_start=z0, label=label)
    stages.extend(more)
    history.extend(hist)
    new_cost = _cost(problem, z)
    if loc_cost < new_cost:
        return z_loc, loc_cost, True
    return z, new_cost, True


def _sides_to_widen(problem: Any, edges: list[tuple[int, str]], gains: list[float],
                    origin: Mapping[str, tuple[float, float]], need: float, round_: int,
                    ) -> tuple[dict[str, list[float]], list[dict[str, Any]]]:
    """The boxes of one round of :func:`widen_boxes` and one record per widened side.

    A side is widened when its parameter's box is a default one (``origin``), the side
    is not a sign (at or across zero), it is less than :data:`MAX_WIDEN_DECADES` beyond
    the default box, and letting the parameter out pays at least ``need`` (the
    predicted relative fall of the sum of squares, ``gains``).
    """
    box: dict[str, list[float]] = {}
    changes: list[dict[str, Any]] = []
    for (i, side), predicted in zip(edges, gains, strict=True):
        par = problem.free_params[i]
        name = split_record_name(par.name)[0]
        if name not in origin or name in box or not _may_widen(par, side, origin[name]):
            continue
        # Model error, not a group beyond its box, unless the release clearly pays:
        # then the edge warning stays.
        new = widened_box(par, side) if predicted >= need else None
        if new is None:
            continue
        box[name] = list(new)
        changes.append({"name": name, "side": side, "round": round_,
                        "from": [par.lower, par.upper], "to": list(new)})
    return box, changes


def _may_widen(par: Any, side: str, first_box: tuple[float, float]) -> bool:
    """Whether ``side`` of ``par``'s box may move: not a sign, not yet at the widening limit."""
    k = 0 if side == "lower" else 1
    edge, first = [par.lower, par.upper][k], first_box[k]
    # A signed parameter's side at zero is a sign (physics), not a guessed size.
    if edge == 0 or first == 0 or edge * first < 0:
        return False
    return bool(abs(np.log10(edge / first)) < MAX_WIDEN_DECADES - 0.5)


#: The ``refine_options`` :func:`~hhra_phys.refine.refine_ipopt` takes (the fit's IPOPT
#: stages, the accuracy check's included).
_IPOPT_KEYS = ("hessian", "shooting", "segments", "max_iter", "tol", "verbose", "stall_iter",
               "stall_step")


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


def _integration(problem: Problem, z: np.ndarray) -> dict[str, Any]:
    """The simulator's accuracy choice and its error estimate at the fitted values ``z``."""
    if not problem.sim.accuracy or problem.sim.accuracy.get("error_estimate") is None:
        # Substeps given (or inherited, as the loop's candidates keep the base fit's):
        # no estimate here, which would cost a few seconds for a stiff candidate.
        return {"method": problem.sim.method, "substeps": problem.sim.substeps,
                "error_estimate": None,
                "note": str(problem.sim.accuracy.get("reason", "substeps given, not chosen "
                                                               "for accuracy"))}
    info = dict(problem.sim.accuracy)
    v = problem.from_z(z)
    try:
        info["error_at_fit"] = problem.sim.integration_error(
            problem.u, problem.full(v), x0=problem.initial_states(v)[0])
    except Exception as exc:  # noqa: BLE001 - a diverged fit has no estimate
        info["error_at_fit"] = float("nan")
        info["error_note"] = str(exc)
    return info


def _accurate_at_fit(problem: Problem, z: np.ndarray, stages: list[Stage], refine: Any,
                     refine_options: Mapping[str, Any] | None) -> tuple[Problem, np.ndarray]:
    """Refine again with finer substeps if the fitted values need them for accuracy.

    The substeps were chosen at the start values (:meth:`Problem.__init__`); when the
    error estimate at the fitted values exceeds the tolerance, the problem gets the
    simulator :meth:`~hhra_phys.simulate.Simulator.accurate` gives there (up to
    :data:`~hhra_phys.simulate.MAX_ACCURACY_SUBSTEPS` in its finest run, four times the
    search's) and IPOPT (when it is among the refiners) refines once more from ``z``.
    """
    acc = problem.sim.accuracy
    tol = float(acc.get("tolerance", np.inf)) if acc else np.inf
    if (not np.isfinite(tol) or acc.get("error_estimate") is None
            or "ipopt" not in _refiner_names(refine)):
        return problem, z
    v = problem.from_z(z)
    x0 = problem.initial_states(v)[0]
    sim = problem.sim.accurate(problem.u, problem.full(v), tol, x0=x0,
                               finest=MAX_ACCURACY_SUBSTEPS)
    if sim is problem.sim or sim.substeps <= problem.sim.substeps:
        return problem, z
    new = problem.with_simulator(sim)
    shift = _accuracy_shift(problem, new, z)
    sim.accuracy["refit_shift"] = shift
    if shift < ACCURACY_REFIT_SHIFT:
        return new, z
    ropts = dict(refine_options or {})
    st = refine_ipopt(new, z, **{k: val for k, val in ropts.items() if k in _IPOPT_KEYS})
    st.name += f" (accuracy: {sim.method} x {sim.substeps})"
    stages.append(st)
    return new, st.z


#: Predicted move of the optimum under finer substeps, in the fit's own uncertainty
#: (:func:`_accuracy_shift`), below which the accuracy rule's refit is not run: the
#: finer simulator is kept (intervals, scores and later stages use it) at the values
#: found. 0.1 is a move of about a third of a standard deviation in the worst direction.
ACCURACY_REFIT_SHIFT = 0.1


def _accuracy_shift(coarse: Problem, fine: Problem, z: np.ndarray) -> float:
    """How far the optimum at ``z`` moves when ``coarse``'s simulator gives way to ``fine``'s
    (finer substeps), in the fit's own uncertainty: ``|P_J e|^2 / s^2``.

    ``e`` is the change of the residual at ``z`` between the two simulators (their
    integration error there), ``P_J`` the projection on the columns of the finer
    residual's Jacobian ``J``, ``s^2 = |r|^2 / (N - n_free)`` the residual variance:
    ``P_J e`` is what the Gauss-Newton step of the parameters can follow of the change,
    so the ratio is the squared move of the optimum in the metric of its confidence
    ellipsoid (at most ``|e|^2 / s^2``). Why: the integration error matters only as far
    as it is coherent with the parameters' directions and only against the residual the
    model leaves. A fit at the noise level moves by several standard deviations (the
    refit is needed); a model lacking an effect, whose residual is many times the noise,
    moves by a small fraction of one (measured: a base fit lacking a dead zone, whose
    refit took 3634 IPOPT evaluations for a relative gain below 1e-8). ``inf`` when it
    cannot be computed (the refit then runs, as before).
    """
    r_c, _ = CompiledLeastSquares(coarse)(z)
    r, J = CompiledLeastSquares(fine)(z)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J)) and np.all(np.isfinite(r_c))):
        return np.inf
    var = float(r @ r) / max(r.size - fine.n_free, 1)
    if var <= 0:
        return np.inf
    e = r - r_c
    coef, *_ = np.linalg.lstsq(J, e, rcond=1e-10)
    pe = J @ coef
    return float(pe @ pe) / var


def _int_or_none(x: Any) -> int | None:
    try:
        return None if x is None else int(x)
    except (TypeError, ValueError):
        return None


@dataclass
class Intervals:
    """The uncertainty of a fit at its optimum (:func:`_intervals`).

    Attributes
    ----------
    ci95 : dict of str to (float, float)
        95 % interval of each free parameter, physical units.
    std : dict of str to float
        Standard deviation in fitting coordinates.
    correlation : ndarray, shape (n_free, n_free)
    covariance : ndarray, shape (n_free, n_free)
        Linearised covariance in physical units (the delta method's input).
    warnings : list of str
    info : dict
        :attr:`~hhra_phys.result.FitResult.intervals` (method, undetermined, weak
        directions, coloured noise, ``at_edge``: free parameters at a box edge by side).
    """

    ci95: dict[str, tuple[float, float]]
    std: dict[str, float]
    correlation: np.ndarray
    covariance: np.ndarray
    warnings: list[str]
    info: dict[str, Any]


@dataclass
class SearchRecord:
    """How a fit's optimum was found: its stages, the global search's history, its seed."""

    stages: list[Stage]
    history: list[float]
    seed: int | None


def _intervals(problem: Any, z: np.ndarray, intervals: str) -> Intervals:
    """95 % intervals, standard deviations, correlation, covariance, warnings and
    interval info at ``z``.

    For any number of records (intervals from all records together).
    """
    # Uncertainty from the exact residual Jacobian at the optimum.
    r, J = CompiledLeastSquares(problem)(z)
    cov, corr, warnings = uncertainty(J, r, problem.free_names)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    ci95, std = _linear_intervals(problem, z, sd)
    info: dict[str, Any] = {"method": "linear"}
    diverged = not (np.all(np.isfinite(r)) and np.all(np.isfinite(J)))
    if intervals == "profile" and diverged:
        warnings.append("profile intervals skipped: the fit diverged")
    elif intervals == "profile":
        info = _profile(problem, z, ci95, warnings)
    undetermined = [n for i, n in enumerate(problem.free_names) if not np.isfinite(sd[i])]
    if undetermined:
        info["undetermined"] = undetermined
    if not diverged:
        cov = _coloured(problem, z, (J, r, cov), ci95, std, warnings, info)
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    weak = weak_directions(J, list(problem.free_names))
    if weak:
        # Which parameters trade off, and why their intervals are missing.
        info["weak_directions"] = weak
        info["reasons"] = {
            name: next(d["reason"] for d in weak if name in d["params"])
            for name in undetermined if any(name in d["params"] for d in weak)}
    edges = _edge_warnings(problem, z, sd, warnings)
    if edges:
        info["at_edge"] = edges
    return Intervals(ci95, std, corr, physical_covariance(cov, _slopes(problem, z)),
                     warnings, info)


def _linear_intervals(problem: Any, z: np.ndarray, sd: np.ndarray
                      ) -> tuple[dict[str, tuple[float, float]], dict[str, float]]:
    """``z +- 1.96 sd`` mapped to physical units (NaN where ``sd`` is not finite)."""
    ci95: dict[str, tuple[float, float]] = {}
    std: dict[str, float] = {}
    for i, name in enumerate(problem.free_names):
        if not np.isfinite(sd[i]):
            ci95[name] = (float("nan"), float("nan"))
        else:
            lo, hi = problem.from_z(z - 1.96 * sd)[i], problem.from_z(z + 1.96 * sd)[i]
            ci95[name] = (float(min(lo, hi)), float(max(lo, hi)))
        std[name] = float(sd[i])
    return ci95, std


def _slopes(problem: Any, z: np.ndarray) -> np.ndarray:
    """``d theta_i / d z_i`` at ``z``: ``ln(10) theta`` for log-scaled parameters, the
    scale (the map at ``z = 1``, exact as it is linear) for the others."""
    log = np.array([p.scale == "log" for p in problem.free_params], dtype=bool)
    return np.where(log, np.log(10.0) * problem.from_z(z), problem.from_z(np.ones(len(z))))


def _profile(problem: Any, z: np.ndarray, ci95: dict[str, tuple[float, float]],
             warnings: list[str]) -> dict[str, Any]:
    """Profile-likelihood intervals into ``ci95`` (the linear ones kept in the info)."""
    t0 = time.perf_counter()
    profiles = profile_intervals(problem, z)
    info: dict[str, Any] = {
        "method": "profile",
        "linear": {n: list(v) for n, v in ci95.items()},
        "open_ends": {n: list(p.open_ends) for n, p in profiles.items()},
        "solves": sum(p.n_solves for p in profiles.values()),
        "seconds": time.perf_counter() - t0,
    }
    first = next(iter(profiles.values()), None)
    if first is not None and first.moved:
        info["polished_ssr"] = first.ssr_min
        warnings.append(
            "the fit did not end at the least-squares minimum (no or unconverged "
            "refinement): the profile intervals are centred on a polished optimum "
            f"(sum of squares {first.ssr_min:.6g}), not on the reported values"
        )
    for name, prof in profiles.items():
        ci95[name] = prof.interval
        if prof.lower_minimum:
            warnings.append(
                f"{name}: its profile found a lower sum of squares than the optimum "
                "(another minimum exists), so the profile intervals are not reliable"
            )
        warnings += [
            f"{name}: the profile stays below the 95 % threshold up to the {side} "
            "end of the search box, so the interval is open there"
            for side, is_open in zip(("lower", "upper"), prof.open_ends, strict=True)
            if is_open]
    return info


def _coloured(problem: Any, z: np.ndarray, fit: tuple[np.ndarray, np.ndarray, np.ndarray],
              ci95: dict[str, tuple[float, float]], std: dict[str, float],
              warnings: list[str], info: dict[str, Any]) -> np.ndarray:
    """The covariance of the fitting coordinates under the residual's noise colour.

    ``fit`` is the residual Jacobian ``J``, the residual ``r`` and the white-noise
    covariance. When the residual's ARMA(1,1) noise model says white-noise intervals are
    more than :data:`COLOURED_FACTOR` too narrow, linear intervals (``ci95``, ``std``,
    updated in place) come from the sandwich covariance with that noise model
    (:func:`hhra_phys.noise.coloured_covariance`), which is returned: white-noise ones
    covered the truth on under half the records with AR(1) 0.9 noise (docs/measuring.md).
    Profile intervals and undetermined directions keep theirs (and a warning says by how
    much white-noise ones understate the spread); otherwise the given covariance returns.
    """
    J, r, cov = fit
    colour = interval_factor(r)
    if colour["factor"] <= COLOURED_FACTOR:
        return cov
    info["coloured_noise"] = colour
    if info["method"] != "linear" or not np.all(np.isfinite(cov)):
        warnings.append(
            f"the residual is coloured (noise model pole {colour['a']:.2f}, zero "
            f"{colour['c']:+.2f}): the intervals assume white residuals and are up "
            f"to {colour['factor']:.1f}x too narrow")
        return cov
    cov_c = coloured_covariance(J, r, cov, colour)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    sd_c = np.sqrt(np.clip(np.diag(cov_c), 0, None))
    names = list(problem.free_names)
    colour["widened"] = {n: float(sd_c[i] / sd[i]) if sd[i] > 0 else 1.0
                         for i, n in enumerate(names)}
    ci95.update(_linear_intervals(problem, z, sd_c)[0])
    std.update({n: float(sd_c[i]) for i, n in enumerate(names)})
    widest = max(colour["widened"].values(), default=1.0)
    warnings.append(
        f"the residual is coloured (noise model pole {colour['a']:.2f}, zero "
        f"{colour['c']:+.2f}): the linearised intervals take it into account "
        f"(sandwich covariance with that noise model, up to {widest:.1f}x wider "
        "than white-noise ones)")
    return cov_c


def _edge_warnings(problem: Any, z: np.ndarray, sd: np.ndarray,
                   warnings: list[str]) -> dict[str, str]:
    """Warnings on parameters at a box edge or spanning decades; ``{name: side}`` at edges."""
    edges = dict(at_edges(problem, z))
    for i, name in enumerate(problem.free_names):
        if i in edges:
            warnings.append(
                f"{name} ended at its {edges[i]} bound: the data push it out of the box, so its "
                "value and interval are not meaningful (widen the bound or fix it)"
            )
        elif problem.free_params[i].scale == "log" and np.isfinite(sd[i]) and sd[i] > 0.5:
            decades = 2 * 1.96 * sd[i]
            warnings.append(
                f"{name} is poorly determined by these data: its 95 % interval spans "
                f"{decades:.3g} decades"
            )
    return {problem.free_names[i]: side for i, side in edges.items()}


def _result(
    problem: Problem,
    z: np.ndarray,
    search: tuple[list[Stage], list[float]],
    held_out: tuple[list[Dataset | None], list[Dataset]],
    opts: FitOptions,
    datasheet: Any | None,
    records: list[Dataset],
    t_start: float,
) -> FitResult:
    """The :class:`~hhra_phys.result.FitResult` of a fit at coordinates ``z``.

    ``values``/``x0`` hold the shared parameters and the first record's own;
    ``records`` has one entry per estimation record (``name``, ``fs``, ``n_est``,
    ``n_val``, ``x0``, ``values`` of its per-record parameters, ``est`` and ``val``
    metrics) and then one per whole validation record (``est`` empty); ``metrics`` are
    the records' pooled (:func:`~hhra_phys.multi.pooled_score`).
    """
    stages, history = search
    parts, whole = held_out
    model = problem.model
    v = problem.from_z(z)
    unc = _intervals(problem, z, opts.intervals)
    warnings = unc.warnings
    # Records are named as given (before any split), when they are the problem's.
    names = ([record_label(ds, k) for k, ds in enumerate(records, start=1)]
             if len(records) == len(problem.records) else problem.names)
    entries, metrics, diverged = _record_scores(problem, v, parts, whole, names)
    if diverged:
        warnings.insert(0, "DIVERGED: the simulation with these parameters does not stay "
                        "finite on the estimation record, so the fit failed; check the units "
                        "of the input and output and the values given with --fix / fixed")
    warnings += _extrapolation_warnings(problem, parts, whole)
    settings = _settings(problem, opts.optimizer, opts.refine, opts.pop_size, opts.max_iter,
                         opts.lam, opts.split, 0.0)
    settings["integration"] = _integration(problem, z)
    err, tol = settings["integration"].get("error_at_fit"), settings["integration"].get(
        "tolerance")
    if err is not None and tol is not None and err > tol:
        warnings.append(
            f"the integration error estimated at the fitted values ({err:.3g}) exceeds 10 % "
            f"of the record's noise level ({tol:.3g}) with {problem.sim.method.upper()} x "
            f"{problem.sim.substeps} substeps: the fit is biased by the discretisation")
    settings.update(_data_settings(problem, records, parts, whole))
    settings["seconds"] = time.perf_counter() - t_start
    return assemble_result(problem, model.params.as_dict(problem.full(v)), entries[0]["x0"],
                           metrics, unc, SearchRecord(stages, history, opts.seed), settings,
                           datasheet=datasheet, metadata=records[0].metadata,
                           status="diverged" if diverged else "ok", records=entries)


def _record_scores(problem: Problem, v: np.ndarray, parts: list[Dataset | None],
                   whole: list[Dataset], names: list[str],
                   ) -> tuple[list[dict[str, Any]], dict[str, Any], bool]:
    """Each record's scores (estimation, its held-out part), the whole validation records'
    (first record's values), the pooled metrics, and whether a simulation diverged."""
    model = problem.model
    entries: list[dict[str, Any]] = []
    est: tuple[list[Dataset], list[np.ndarray]] = ([], [])
    val: tuple[list[Dataset], list[np.ndarray]] = ([], [])
    for k, ((pr, vk), part) in enumerate(zip(problem.per_record_values(v), parts,
                                             strict=True)):
        y_est = pr.simulate_values(vk)
        entry: dict[str, Any] = {
            "name": names[k], "source": pr.data.source, "fs": float(pr.data.fs),
            "n_est": len(pr.data), "n_val": len(part) if part is not None else 0,
            "x0": dict(zip(model.state_names, pr.initial_states(vk)[0].tolist(), strict=True)),
            "values": {n: float(pr.full(vk)[model.params.index(n)])
                       for n in problem.per_record},
            "est": _score(pr.data, y_est), "val": {},
        }
        est[0].append(pr.data)
        est[1].append(y_est)
        if part is not None:
            y_val = pr.simulate_values(vk, data=part)
            entry["val"] = _score(part, y_val)
            val[0].append(part)
            val[1].append(y_val)
        entries.append(entry)
    for ds in whole:
        y_val = problem.simulate_values(v, data=ds)
        entries.append({"name": ds.name or ds.source or "validation", "source": ds.source,
                        "fs": float(ds.fs), "n_est": 0, "n_val": len(ds), "est": {},
                        "val": _score(ds, y_val)})
        val[0].append(ds)
        val[1].append(y_val)
    diverged = not all(np.all(np.isfinite(y)) for y in est[1])
    metrics = {"est": _pooled(*est), "val": _pooled(*val) if val[0] else {}}
    return entries, metrics, diverged


def _pooled(records: list[Dataset], outputs: list[np.ndarray]) -> dict[str, float]:
    """Metrics of the records together (:func:`~hhra_phys.multi.pooled_score`; one
    record's own, :func:`_score`); ``nan`` where a simulation diverged."""
    if len(records) == 1:
        return _score(records[0], outputs[0])
    if not all(np.all(np.isfinite(y)) for y in outputs):
        return {k: float("nan") for k in ("mse", "rmse", "vaf", "itae", "fit", "max_abs")}
    return pooled_score(records, outputs)


def _extrapolation_warnings(problem: Problem, parts: list[Dataset | None],
                            whole: list[Dataset]) -> list[str]:
    """Held-out outputs outside their estimation range, for position-dependent models."""
    if not any(getattr(part, "position_dependent", False) for part in problem.model.parts):
        return []
    lo_all = min(float(ds.y.min()) for ds in problem.datasets)
    hi_all = max(float(ds.y.max()) for ds in problem.datasets)
    pairs = [(ds.y.min(), ds.y.max(), pr.data.y.min(), pr.data.y.max())
             for pr, ds in zip(problem.records, parts, strict=True) if ds is not None]
    pairs += [(ds.y.min(), ds.y.max(), lo_all, hi_all) for ds in whole]
    out = []
    for v_lo, v_hi, e_lo, e_hi in pairs:
        if v_lo < e_lo or v_hi > e_hi:
            out.append(f"validation output leaves the estimation range [{float(e_lo):.3g}, "
                       f"{float(e_hi):.3g}]: position-dependent terms are extrapolated there")
    return out


def _data_settings(problem: Problem, records: list[Dataset], parts: list[Dataset | None],
                   whole: list[Dataset]) -> dict[str, Any]:
    """The records' description in the result's settings: one record's ``data``
    (``name``, ``source``, ``n``, ``n_est``, ``n_val``); several records' ``data``,
    ``validation`` (one entry each) and ``per_record``."""
    if len(problem.records) == 1:
        held = parts[0] if parts[0] is not None else (whole[0] if whole else None)
        return {"data": {"name": records[0].name, "source": records[0].source,
                         "n": len(records[0]), "n_est": len(problem.data),
                         "n_val": len(held) if held is not None else 0}}
    return {"per_record": list(problem.per_record),
            "data": [_describe(ds) for ds in problem.datasets],
            "validation": [_describe(ds) for ds in whole]}


def _describe(ds: Dataset) -> dict[str, Any]:
    return {"name": ds.name, "source": ds.source, "n": len(ds), "fs": float(ds.fs)}


def assemble_result(problem: Any, values: dict[str, float], x0: dict[str, float],
                    metrics: dict[str, Any], unc: Intervals, search: SearchRecord,
                    settings: dict[str, Any], *, datasheet: Any | None = None,
                    metadata: Any = None, status: str = "ok",
                    records: list[dict[str, Any]] | None = None) -> FitResult:
    """The :class:`~hhra_phys.result.FitResult` of a fit: one place for the
    fit of one record or several (:class:`~hhra_phys.problem.Problem`).

    ``values`` are the model's parameters by name, ``x0`` the (first) record's
    initial state by state name, ``unc`` the :func:`_intervals` at the optimum (its
    warnings list, with the caller's added, becomes the result's), ``search`` the
    stages, history and seed. The physical view is derived from ``values`` and
    ``datasheet``/``metadata``; its note joins the warnings. The model's derived
    quantities get their delta-method intervals (:func:`~hhra_phys.result.derived_estimates`).
    """
    model = problem.model
    warns = unc.warnings
    units = {p.name: p.unit for p in model.params}
    units.update({p.name: p.unit for p in problem.free_params})
    physical, why = model.physical_view(values, datasheet, metadata)
    if why:
        warns.append(why)
    # A several-record fit's first record's own parameters stand for the model's.
    free = [base if k == 1 and base in values else n
            for n, (base, k) in ((n, split_record_name(n)) for n in problem.free_names)]
    derived = derived_estimates(model.derived_quantities(), values, free, unc.covariance,
                                at_edge=[free[problem.free_names.index(n)]
                                         for n in unc.info.get("at_edge", {})])
    return FitResult(
        model_spec=model.to_json(),
        values=values,
        free=problem.free_names,
        units=units,
        ci95=unc.ci95,
        std=unc.std,
        correlation=unc.correlation,
        warnings=warns,
        metrics=metrics,
        stages=[s.to_json() for s in search.stages],
        history=search.history,
        tf=model.tf_coefficients_of(values),
        x0=x0,
        settings=settings,
        seed=search.seed,
        physical=physical,
        intervals=unc.info,
        problem=problem,
        status=status,
        records=list(records or []),
        covariance=unc.covariance,
        derived=derived,
    )


def _settings(problem: Any, optimizer: str, refine: Any, pop_size: int, max_iter: int,
              lam: float, split: float, seconds: float) -> dict[str, Any]:
    """What reproduces a fit (without the data description)."""
    return {
        "optimizer": optimizer,
        "refine": refine if isinstance(refine, (str, type(None))) else list(refine),
        "pop_size": pop_size,
        "max_iter": max_iter,
        "cost": problem.cost,
        "lam": lam,
        "split": split,
        "initial_state": problem.initial_state,
        "free": problem.free_names,
        "fixed": problem.fixed,
        "bounds": {p.name: [p.lower, p.upper] for p in problem.free_params},
        "fs": problem.sim.fs,
        "substeps": problem.sim.substeps,
        "method": problem.sim.method,
        "intersample": problem.sim.intersample,
        "seconds": seconds,
    }


def _score(ds: Dataset, y_sim: np.ndarray) -> dict[str, float]:
    if not np.all(np.isfinite(y_sim)):  # a diverged simulation has no score
        return {k: float("nan") for k in ("mse", "rmse", "vaf", "itae", "fit", "max_abs")}
    return {k: float(v) for k, v in score(ds.y, y_sim, ds.t).items()}


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
