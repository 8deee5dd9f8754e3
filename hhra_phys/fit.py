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
from dataclasses import dataclass, fields
from functools import partial
from typing import Any

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.interrupt import interruptible, map_stopping
from hhra_phys.likelihood import profile_intervals
from hhra_phys.metrics import score
from hhra_phys.model import Model
from hhra_phys.multi import MultiProblem, pooled_score
from hhra_phys.noise import coloured_covariance, interval_factor
from hhra_phys.optim import minimize
from hhra_phys.options import with_overrides
from hhra_phys.parameters import split_record_name
from hhra_phys.problem import (  # noqa: F401  (default_free, MAX_WIDEN_DECADES re-exported)
    MAX_WIDEN_DECADES,
    Problem,
    default_free,
)
from hhra_phys.refine import (
    CompiledLeastSquares,
    Stage,
    refine_ipopt,
    refine_nlopt,
)
from hhra_phys.result import FitResult, uncertainty, weak_directions

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
    "fit_records",
    "fit_stacked",
    "records_result",
]

OPTIMIZERS: tuple[str, ...] = ("hgwo", "gwo", "pso", "de", "none")


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
        ``max_eval`` ...), applied to those that accept them.
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
        for name in ("pop_size", "max_iter"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 0):
                raise ParameterError(f"{name} must be an integer >= 0, got {v!r}")
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
        of records fitted jointly (:mod:`hhra_phys.multi`): shared parameters,
        per-record initial states (``x0_<state>_rec<k>``) and per-record
        parameters, each record split by ``split`` unless ``validation`` is
        given; metrics per record in :attr:`FitResult.records`, pooled in
        :attr:`FitResult.metrics`.
    model : Model, optional
        Model to fit (default: :func:`default_model`: the HHRA with the orifice
        valve, a pressure output if the data's output is pressure, rescaled to
        sample units for records without a sample time). With the default model a
        single record is first converted to its units (mA, deg) where it declares
        others, and implausible ranges are warned about
        (:func:`~hhra_phys.models.hhra.defaults.prepare_record`).
    options : FitOptions, optional
        The fit's settings (default :class:`FitOptions`'s).
    validation : Dataset or sequence of Dataset, optional
        Separate validation record(s) (then ``data`` is all estimation); with
        several records, whole validation records have their initial state
        estimated and the first record's per-record parameters.
    datasheet : object, optional
        Known physical symbols for the model's physical view
        (:meth:`Model.physical_view <hhra_phys.model.Model.physical_view>`; for the
        HHRA a :class:`~hhra_phys.models.hhra.physical.PhysicalParameters`); the
        fitted parameters are then also reported as physical symbols. Simulated
        rig data carries its own.
    callback : callable, optional
        Called after every global iteration (see :func:`hhra_phys.optim.minimize`).
    problem : Problem, optional
        A ready problem (then ``model``, ``free`` ... are taken from it).
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
    opts = FitOptions.of(options, **settings)
    (optimizer, refine, free, fixed, bounds, split, cost, initial_state, pop_size, max_iter,
     seed, lam, optimizer_options, refine_options, start, progress, seed_population,
     intervals, per_record, default_bounds, widen_bounds,
     allow_outside_box) = (getattr(opts, f.name) for f in fields(FitOptions))
    t_start = time.perf_counter()
    if data is None:
        from hhra_phys.models.hhra.rig import simulate_rig

        data = simulate_rig(seed=0)
    search = partial(_search_and_refine, optimizer=optimizer, refine=refine,
                     pop_size=pop_size, max_iter=max_iter, seed=seed, lam=lam,
                     options=optimizer_options, refine_options=refine_options, start=start,
                     seed_population=seed_population, progress=progress, callback=callback)
    if isinstance(data, (list, tuple)):

        if not 0 < split <= 1:
            raise ParameterError(f"split must be in (0, 1], got {split}")
        if problem is None:
            problem, val_parts, whole_val = fit_records(
                data, model, validation, split,
                {"cost": cost, "free": free, "fixed": fixed, "bounds": bounds,
                 "default_bounds": default_bounds, "initial_state": initial_state,
                 "start": start, "allow_outside_box": allow_outside_box}, per_record)
        else:
            val_parts, whole_val = [None] * len(problem.records), list(validation or [])
        with interruptible():
            problem, z, stages, history, widened = fit_and_widen(problem, search,
                                                                 widen_bounds)
        result = records_result(problem, z, stages, history, val_parts, whole_val,
                                _settings(problem, optimizer, refine, pop_size, max_iter, lam,
                                          split, time.perf_counter() - t_start),
                                seed, datasheet, intervals, t_start)
        _report_widening(result, widened, problem)
        return result
    record_notes: list[str] = []
    if model is None and problem is None:
        # The default HHRA knows its units: convert the record, warn about odd ranges.
        from hhra_phys.models.hhra.defaults import prepare_record

        data, notes, warns = prepare_record(data)
        record_notes = notes + warns
        if validation is not None:
            validation, notes, warns = prepare_record(validation)
            record_notes += notes + warns
    if validation is None:
        if not 0 < split <= 1:
            raise ParameterError(f"split must be in (0, 1], got {split}")
        est, val = data.split(split) if split < 1 else (data, None)
    else:
        est, val = data, validation
    if problem is None:
        if model is None:
            model, auto_bounds = default_model(data)
            default_bounds = {**auto_bounds, **(default_bounds or {})}
        # The user's explicit bounds are kept as given; default boxes may be widened.
        problem = Problem(model, est, cost=cost, free=free, fixed=fixed,  # type: ignore[arg-type]
                          bounds=bounds, default_bounds=default_bounds,
                          initial_state=initial_state,  # type: ignore[arg-type]
                          start=start, allow_outside_box=allow_outside_box)
    with interruptible():
        problem, z, stages, history, widened = fit_and_widen(problem, search, widen_bounds)
        problem, z = _accurate_at_fit(problem, z, stages, refine, refine_options)
    result = _result(problem, z, stages, history, val, data, optimizer, refine, pop_size,
                     max_iter, seed, lam, split, datasheet, time.perf_counter() - t_start,
                     intervals)
    _report_widening(result, widened, problem)
    result.warnings.extend(record_notes)
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
    problem : Problem or MultiProblem
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
        if last.get("gain", 1.0) < WIDEN_MIN_GAIN:
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
    usually a symptom of it; a release that pays that much is the box's doing). Rounds
    stop once a refit lowers the least-squares cost by less than :data:`WIDEN_MIN_GAIN`
    (relative). Each refit (``search``) starts its global search with the previous
    optimum in the population, so it cannot end worse.

    Parameters
    ----------
    problem : Problem or MultiProblem
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
        ``to`` (the box in physical units) and ``gain`` (the refit's relative fall of the
        least-squares cost).
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
        box: dict[str, list[float]] = {}
        changes = []
        gains = _release_gains(problem, z, edges)
        for (i, side), predicted in zip(edges, gains, strict=True):
            par = problem.free_params[i]
            name = split_record_name(par.name)[0]
            if name not in origin or name in box:
                continue
            k = 0 if side == "lower" else 1
            edge, first = [par.lower, par.upper][k], origin[name][k]
            # A signed parameter's side at zero is a sign (physics), not a guessed size.
            if edge == 0 or first == 0 or edge * first < 0:
                continue
            if abs(np.log10(edge / first)) >= MAX_WIDEN_DECADES - 0.5:
                continue
            # Model error, not a group beyond its box, unless the release clearly pays:
            # then the edge warning stays.
            if predicted < (WIDEN_MIN_GAIN if excess <= WIDEN_MAX_EXCESS
                            else WIDEN_CLEAR_GAIN):
                continue
            before = [par.lower, par.upper]
            new = widened_box(par, side)
            if new is None:
                continue
            box[name] = list(new)
            changes.append({"name": name, "side": side, "round": round_,
                            "from": before, "to": list(box[name])})
        if not changes:
            break
        values = problem.from_z(z)
        problem = problem.with_boxes({n: tuple(b) for n, b in box.items()})
        z, more, hist = search(problem, z_start=problem.to_z(values),
                               label=f" (widened {round_})")
        stages.extend(more)
        history.extend(hist)
        new_cost, excess = _cost_and_excess(problem, z)
        gain = (cost - new_cost) / cost if cost > 0 else 0.0
        for c in changes:
            c["gain"] = float(gain)
        widened.extend(changes)
        cost = new_cost
        edges = at_edges(problem, z)
        if gain < WIDEN_MIN_GAIN:
            break
    return problem, z, widened


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
) -> tuple[np.ndarray, list[Stage], list[float]]:
    """Global search then refiners on a problem (one record or stacked); (z, stages, history).

    ``z_start`` (a refit after widening a box) starts there, with it in the first
    population; ``label`` is appended to the stage names.
    """
    stages: list[Stage] = []
    history: list[float] = []
    warm = bool(start) if seed_population is None else seed_population
    if z_start is None:
        z_start = problem.to_z(problem.start_values())
    else:
        warm = True
    z = z_start
    if optimizer != "none":
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
    for name in _refiner_names(refine):
        if name == "ipopt":
            keys = ("hessian", "shooting", "segments", "max_iter", "tol", "verbose")
            st = refine_ipopt(problem, z, **{k: v for k, v in ropts.items() if k in keys})
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
    simulator :meth:`~hhra_phys.simulate.Simulator.accurate` gives there and IPOPT
    (when it is among the refiners) refines once more from ``z``.
    """
    acc = problem.sim.accuracy
    tol = float(acc.get("tolerance", np.inf)) if acc else np.inf
    if (not np.isfinite(tol) or acc.get("error_estimate") is None
            or "ipopt" not in _refiner_names(refine)):
        return problem, z
    v = problem.from_z(z)
    x0 = problem.initial_states(v)[0]
    sim = problem.sim.accurate(problem.u, problem.full(v), tol, x0=x0)
    if sim is problem.sim or sim.substeps <= problem.sim.substeps:
        return problem, z
    new = problem.with_boxes({})
    new.sim = sim
    ropts = dict(refine_options or {})
    keys = ("hessian", "shooting", "segments", "max_iter", "tol", "verbose")
    st = refine_ipopt(new, z, **{k: val for k, val in ropts.items() if k in keys})
    st.name += f" (accuracy: {sim.method} x {sim.substeps})"
    stages.append(st)
    return new, st.z


def _int_or_none(x: Any) -> int | None:
    try:
        return None if x is None else int(x)
    except (TypeError, ValueError):
        return None


def _coloured_intervals(problem: Any, z: np.ndarray, J: np.ndarray, r: np.ndarray,
                        cov: np.ndarray, sd: np.ndarray, ci95: dict[str, tuple[float, float]],
                        std: dict[str, float], warnings: list[str],
                        interval_info: dict[str, Any]) -> np.ndarray:
    """Linear intervals under a coloured residual: updates ``ci95`` and ``std`` in place
    and returns the standard deviations of the fitting coordinates (``sd`` if unchanged).

    When the residual's ARMA(1,1) noise model says white-noise intervals are more than
    :data:`COLOURED_FACTOR` too narrow, the linear intervals come from the sandwich
    covariance with that noise model (:func:`hhra_phys.noise.coloured_covariance`):
    white-noise ones covered the truth on under half the records with AR(1) 0.9 noise
    (docs/measuring.md). Profile intervals and undetermined directions keep theirs.
    """
    colour = interval_factor(r)
    if colour["factor"] <= COLOURED_FACTOR:
        return sd
    interval_info["coloured_noise"] = colour
    if interval_info["method"] != "linear" or not np.all(np.isfinite(cov)):
        warnings.append(
            f"the residual is coloured (noise model pole {colour['a']:.2f}, zero "
            f"{colour['c']:+.2f}): the intervals assume white residuals and are up "
            f"to {colour['factor']:.1f}x too narrow")
        return sd
    sd_c = np.sqrt(np.clip(np.diag(coloured_covariance(J, r, cov, colour)), 0, None))
    names = list(problem.free_names)
    colour["widened"] = {n: float(sd_c[i] / sd[i]) if sd[i] > 0 else 1.0
                         for i, n in enumerate(names)}
    lo, hi = problem.from_z(z - 1.96 * sd_c), problem.from_z(z + 1.96 * sd_c)
    for i, name in enumerate(names):
        ci95[name] = (float(min(lo[i], hi[i])), float(max(lo[i], hi[i])))
        std[name] = float(sd_c[i])
    widest = max(colour["widened"].values(), default=1.0)
    warnings.append(
        f"the residual is coloured (noise model pole {colour['a']:.2f}, zero "
        f"{colour['c']:+.2f}): the linearised intervals take it into account "
        f"(sandwich covariance with that noise model, up to {widest:.1f}x wider "
        "than white-noise ones)")
    return sd_c


def _intervals(
    problem: Any, z: np.ndarray, intervals: str
) -> tuple[dict[str, tuple[float, float]], dict[str, float], np.ndarray, list[str],
           dict[str, Any]]:
    """95 % intervals, standard deviations, correlation, warnings and interval info at ``z``.

    Works for a one-record :class:`Problem` and a stacked
    :class:`~hhra_phys.multi.MultiProblem` alike (intervals from all records).
    """
    # Uncertainty from the exact residual Jacobian at the optimum.
    r, J = CompiledLeastSquares(problem)(z)
    cov, corr, warnings = uncertainty(J, r, problem.free_names)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    ci95: dict[str, tuple[float, float]] = {}
    std: dict[str, float] = {}
    undetermined: list[str] = []
    for i, name in enumerate(problem.free_names):
        if not np.isfinite(sd[i]):
            ci95[name] = (float("nan"), float("nan"))
            undetermined.append(name)
        else:
            lo, hi = problem.from_z(z - 1.96 * sd)[i], problem.from_z(z + 1.96 * sd)[i]
            ci95[name] = (float(min(lo, hi)), float(max(lo, hi)))
        std[name] = float(sd[i])
    diverged = not (np.all(np.isfinite(r)) and np.all(np.isfinite(J)))
    interval_info: dict[str, Any] = {"method": "linear"}
    if intervals == "profile" and diverged:
        warnings.append("profile intervals skipped: the fit diverged")
    elif intervals == "profile":
        t0 = time.perf_counter()
        profiles = profile_intervals(problem, z)
        interval_info = {
            "method": "profile",
            "linear": {n: list(v) for n, v in ci95.items()},
            "open_ends": {n: list(p.open_ends) for n, p in profiles.items()},
            "solves": sum(p.n_solves for p in profiles.values()),
            "seconds": time.perf_counter() - t0,
        }
        first = next(iter(profiles.values()), None)
        if first is not None and first.moved:
            interval_info["polished_ssr"] = first.ssr_min
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
            for side, is_open in zip(("lower", "upper"), prof.open_ends, strict=True):
                if is_open:
                    warnings.append(
                        f"{name}: the profile stays below the 95 % threshold up to the {side} "
                        "end of the search box, so the interval is open there"
                    )
    if undetermined:
        interval_info["undetermined"] = undetermined
    if not diverged:
        sd = _coloured_intervals(problem, z, J, r, cov, sd, ci95, std, warnings, interval_info)
    weak = weak_directions(J, list(problem.free_names))
    if weak:
        # Which parameters trade off, and why their intervals are missing.
        interval_info["weak_directions"] = weak
        interval_info["reasons"] = {
            name: next(d["reason"] for d in weak if name in d["params"])
            for name in undetermined if any(name in d["params"] for d in weak)}

    edges = dict(at_edges(problem, z))
    for i, name in enumerate(problem.free_names):
        if i in edges:
            side = edges[i]
            warnings.append(
                f"{name} ended at its {side} bound: the data push it out of the box, so its value "
                "and interval are not meaningful (widen the bound or fix it)"
            )
        elif problem.free_params[i].scale == "log" and np.isfinite(sd[i]) and sd[i] > 0.5:
            decades = 2 * 1.96 * sd[i]
            warnings.append(
                f"{name} is poorly determined by these data: its 95 % interval spans "
                f"{decades:.3g} decades"
            )
    return ci95, std, corr, warnings, interval_info


def _result(
    problem: Problem,
    z: np.ndarray,
    stages: list[Stage],
    history: list[float],
    val: Dataset | None,
    data: Dataset,
    optimizer: str,
    refine: Any,
    pop_size: int,
    max_iter: int,
    seed: int | None,
    lam: float,
    split: float,
    datasheet: Any | None,
    seconds: float,
    intervals: str = "linear",
) -> FitResult:
    model = problem.model
    values_free = problem.from_z(z)
    P = problem.full(values_free)
    values = model.params.as_dict(P)
    ci95, std, corr, warnings, interval_info = _intervals(problem, z, intervals)
    X0 = problem.initial_states(values_free)[0]
    x0 = dict(zip(model.state_names, X0.tolist(), strict=True))
    y_est = problem.simulate_values(values_free)
    diverged = not np.all(np.isfinite(y_est))
    if diverged:
        warnings.insert(0, "DIVERGED: the simulation with these parameters does not stay "
                        "finite on the estimation record, so the fit failed; check the units "
                        "of the input and output and the values given with --fix / fixed")
    metrics = {"est": _score(problem.data, y_est), "val": {}}
    if val is not None:
        y_val = problem.simulate_values(values_free, data=val)
        metrics["val"] = _score(val, y_val)
        position_dependent = any(getattr(part, "position_dependent", False)
                                 for part in problem.model.parts)
        if position_dependent:
            lo_e, hi_e = float(problem.data.y.min()), float(problem.data.y.max())
            if val.y.min() < lo_e or val.y.max() > hi_e:
                warnings.append(
                    f"validation output leaves the estimation range [{lo_e:.3g}, {hi_e:.3g}]: "
                    "position-dependent terms are extrapolated there"
                )
    settings = _settings(problem, optimizer, refine, pop_size, max_iter, lam, split, seconds)
    settings["integration"] = _integration(problem, z)
    err, tol = settings["integration"].get("error_at_fit"), settings["integration"].get(
        "tolerance")
    if err is not None and tol is not None and err > tol:
        warnings.append(
            f"the integration error estimated at the fitted values ({err:.3g}) exceeds 10 % "
            f"of the record's noise level ({tol:.3g}) with {problem.sim.method.upper()} x "
            f"{problem.sim.substeps} substeps: the fit is biased by the discretisation")
    settings["data"] = {"name": data.name, "source": data.source, "n": len(data),
                        "n_est": len(problem.data), "n_val": len(val) if val is not None else 0}
    return assemble_result(problem, values, x0, metrics,
                           (ci95, std, corr, warnings, interval_info), stages, history,
                           settings, seed, datasheet, data.metadata,
                           status="diverged" if diverged else "ok")


def assemble_result(problem: Any, values: dict[str, float], x0: dict[str, float],
                    metrics: dict[str, Any], interval_parts: tuple[Any, ...],
                    stages: list[Stage], history: list[float], settings: dict[str, Any],
                    seed: int | None, datasheet: Any | None, metadata: Any, *,
                    status: str = "ok",
                    records: list[dict[str, Any]] | None = None) -> FitResult:
    """The :class:`~hhra_phys.result.FitResult` of a fit: one place for the
    single-record fit and the several-record fit (:mod:`hhra_phys.multi`).

    ``values`` are the model's parameters by name, ``x0`` the (first) record's
    initial state by state name, ``interval_parts`` the ``(ci95, std, correlation,
    warnings, info)`` of :func:`_intervals` (its warnings list, with the caller's
    added, becomes the result's). The physical view is derived from ``values`` and
    ``datasheet``/``metadata``; its note joins the warnings.
    """
    model = problem.model
    ci95, std, corr, warns, interval_info = interval_parts
    units = {p.name: p.unit for p in model.params}
    units.update({p.name: p.unit for p in problem.free_params})
    physical, why = model.physical_view(values, datasheet, metadata)
    if why:
        warns.append(why)
    return FitResult(
        model_spec=model.to_json(),
        values=values,
        free=problem.free_names,
        units=units,
        ci95=ci95,
        std=std,
        correlation=corr,
        warnings=warns,
        metrics=metrics,
        stages=[s.to_json() for s in stages],
        history=history,
        tf=model.tf_coefficients_of(values),
        x0=x0,
        settings=settings,
        seed=seed,
        physical=physical,
        intervals=interval_info,
        problem=problem,
        status=status,
        records=list(records or []),
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


# --- several records ------------------------------------------------------------------


def fit_records(
    records: Sequence[Dataset],
    model: Model | None,
    validation: Sequence[Dataset] | Dataset | None,
    split: float,
    problem_kwargs: Mapping[str, Any],
    per_record: Sequence[str] | None = None,
) -> tuple[MultiProblem, list[Dataset | None], list[Dataset]]:
    """Build the stacked problem of a multi-record fit (used by :func:`hhra_phys.fit.fit`).

    Returns the problem, the validation part of each estimation record (``None``
    without a split) and the whole validation records; the search and the result
    are :func:`~hhra_phys.fit.fit`'s. Without a model, the default model's
    automatic bounds are merged over the records (the widest of each).
    """
    records = list(records)
    for ds in records:
        if not isinstance(ds, Dataset):
            raise ParameterError(f"fit() takes Dataset records, got {type(ds).__name__}")
    whole_val = ([validation] if isinstance(validation, Dataset)
                 else list(validation or []))
    if whole_val or split >= 1:
        est, val_parts = records, [None] * len(records)
    else:
        if not 0 < split < 1:
            raise ParameterError(f"split must be in (0, 1], got {split}")
        pairs = [ds.split(split) for ds in records]
        est, val_parts = [p[0] for p in pairs], [p[1] for p in pairs]
    kw = dict(problem_kwargs)
    bounds = kw.pop("bounds", None)
    defaults = dict(kw.pop("default_bounds", None) or {})
    if model is None:
        model, auto = default_model(records[0])
        for ds in records[1:]:
            for name, (lo, hi) in default_model(ds)[1].items():
                old = auto.get(name, (lo, hi))
                auto[name] = (min(old[0], lo), max(old[1], hi))
        defaults = {**auto, **defaults}
    names = [ds.name or ds.source or f"record {k}" for k, ds in enumerate(records, start=1)]
    # Automatic and default boxes may be widened by the fit, the user's ``bounds`` not.
    problem = MultiProblem(model, est, bounds=bounds, default_bounds=defaults,
                           per_record=per_record, names=names, **kw)
    return problem, val_parts, whole_val


def _describe(ds: Dataset) -> dict[str, Any]:
    return {"name": ds.name, "source": ds.source, "n": len(ds), "fs": float(ds.fs)}


def records_result(
    problem: MultiProblem,
    z: np.ndarray,
    stages: list[Any],
    history: list[float],
    val_parts: Sequence[Dataset | None],
    whole_val: Sequence[Dataset],
    settings: dict[str, Any],
    seed: int | None,
    datasheet: Any | None,
    intervals: str,
    t_start: float,
) -> Any:
    """The :class:`~hhra_phys.result.FitResult` of a multi-record fit at coordinates ``z``.

    ``values``/``x0`` hold the shared parameters and the first record's own;
    ``records`` one entry per estimation record (``name``, ``fs``, ``n_est``,
    ``n_val``, ``x0``, ``values`` of its per-record parameters, ``est`` and
    ``val`` metrics) and then one per whole validation record (``est`` empty);
    ``metrics`` the pooled ``est`` and ``val`` (:func:`pooled_score`).
    """
    model = problem.model
    v = problem.from_z(z)
    ci95, std, corr, warnings, interval_info = _intervals(problem, z, intervals)
    records: list[dict[str, Any]] = []
    est_y, est_sim, val_y, val_sim = [], [], [], []
    for k, (pr, part) in enumerate(zip(problem.records, val_parts, strict=True)):
        vk = problem.record_values(v, k)
        x0 = pr.initial_states(vk)[0]
        y_est = pr.simulate_values(vk)
        entry: dict[str, Any] = {
            "name": problem.names[k], "source": pr.data.source, "fs": float(pr.data.fs),
            "n_est": len(pr.data), "n_val": len(part) if part is not None else 0,
            "x0": dict(zip(model.state_names, x0.tolist(), strict=True)),
            "values": {n: float(pr.full(vk)[model.params.index(n)])
                       for n in problem.per_record},
            "est": {kk: float(vv) for kk, vv in score(pr.data.y, y_est, pr.data.t).items()},
            "val": {},
        }
        est_y.append(pr.data)
        est_sim.append(y_est)
        if part is not None:
            y_val = pr.simulate_values(vk, data=part)
            entry["val"] = {kk: float(vv) for kk, vv in score(part.y, y_val, part.t).items()}
            val_y.append(part)
            val_sim.append(y_val)
        records.append(entry)
    first = problem.records[0]
    v0 = problem.record_values(v, 0)
    for ds in whole_val:
        y_val = first.simulate_values(v0, data=ds)
        records.append({"name": ds.name or ds.source or "validation", "source": ds.source,
                        "fs": float(ds.fs), "n_est": 0, "n_val": len(ds), "est": {},
                        "val": {kk: float(vv) for kk, vv in score(ds.y, y_val, ds.t).items()}})
        val_y.append(ds)
        val_sim.append(y_val)
    metrics = {"est": pooled_score(est_y, est_sim),
               "val": pooled_score(val_y, val_sim) if val_y else {}}
    values = model.params.as_dict(first.full(v0))
    settings = dict(settings)
    settings["per_record"] = list(problem.per_record)
    settings["data"] = [_describe(pr.data) for pr in problem.records]
    settings["validation"] = [_describe(ds) for ds in whole_val]
    settings["seconds"] = time.perf_counter() - t_start
    return assemble_result(problem, values, records[0]["x0"], metrics,
                           (ci95, std, corr, warnings, interval_info), stages, history,
                           settings, seed, datasheet, first.data.metadata, records=records)


def fit_stacked(
    problem: MultiProblem,
    selection: Sequence[Dataset],
    *,
    optimizer: str = "hgwo",
    refine: str = "ipopt",
    pop_size: int = 100,
    max_iter: int = 200,
    seed: int | None = 0,
    seed_population: bool = False,
    refine_options: Mapping[str, Any] | None = None,
    split: float = 0.5,
) -> Any:
    """Fit a ready :class:`MultiProblem` and score each record's own held-out part.

    :func:`hhra_phys.fit.fit`'s search and refiners and :func:`records_result`,
    with ``selection[k]`` the part held out of estimation record ``k`` (scored
    with that record's own per-record parameters; ``val`` of its entry and,
    pooled, of ``metrics``). The diagnosis loop's fits of several records.
    """
    t0 = time.perf_counter()
    z, stages, history = _search_and_refine(
        problem, optimizer, refine, pop_size, max_iter, seed, 1.0, None, refine_options,
        None, seed_population, False, None)
    settings = _settings(problem, optimizer, refine, pop_size, max_iter, 1.0, split,
                         time.perf_counter() - t0)
    return records_result(problem, z, stages, history, list(selection), [], settings, seed,
                          None, "linear", t0)
