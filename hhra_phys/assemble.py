"""A fit's :class:`~hhra_phys.result.FitResult`, assembled from its optimum.

Everything a result holds besides the values: each record's scores on its estimation part,
its held-out part and the whole validation records (pooled over the records), the
extrapolation warnings, the settings that reproduce the fit (with the integration's
accuracy at the fitted values), the intervals (:mod:`hhra_phys.fit_intervals`) and the
derived quantities. Separate from :mod:`hhra_phys.fit` because it only reports: it runs
after the search, the widening and the accuracy check are done; every name here is also
importable from :mod:`hhra_phys.fit`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.fit_accuracy import _integration
from hhra_phys.fit_intervals import Intervals, _intervals
from hhra_phys.fit_options import FitOptions
from hhra_phys.metrics import score
from hhra_phys.multi import pooled_score
from hhra_phys.parameters import split_record_name
from hhra_phys.problem import Problem, record_label
from hhra_phys.refine import Stage
from hhra_phys.result import FitResult, derived_estimates

__all__ = [
    "SearchRecord",
    "assemble_result",
]


@dataclass
class SearchRecord:
    """How a fit's optimum was found: its stages, the global search's history, its seed."""

    stages: list[Stage]
    history: list[float]
    seed: int | None


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
