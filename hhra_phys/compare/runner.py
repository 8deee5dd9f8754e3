"""Running the registered methods on one record: the split, the timing and the scores.

:func:`run_comparison` splits the record, gives every method the estimation and validation
parts, times it, scores both free-run outputs with :func:`hhra_phys.metrics.score` (never a
one-step prediction) and collects everything in a :class:`Comparison`, whose
:meth:`~Comparison.to_dict` is the JSON report (layout: :mod:`hhra_phys.compare`).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from hhra_phys.compare.registry import (
    METHODS,
    CompareSettings,
    MethodOutcome,
    available_methods,
)
from hhra_phys.compare.report import PAPER_TABLE3
from hhra_phys.data import Dataset
from hhra_phys.errors import DataError, HHRAError, ParameterError
from hhra_phys.metrics import KEYS, score
from hhra_phys.multi import RecordSet, check_records, pooled_score
from hhra_phys.outputs import jsonable

__all__ = ["Comparison", "MethodResult", "compare", "run_comparison"]


@dataclass
class MethodResult:
    """One method's outcome and scores (``error`` set, scores empty, if it failed)."""

    name: str
    outcome: MethodOutcome | None
    est: dict[str, float]
    val: dict[str, float]
    seconds: float
    error: str | None = None
    #: Several records: ``[{"name", "est", "val"}]`` per record (``est``/``val`` pooled).
    records: list[dict[str, Any]] | None = None

    @property
    def diverged(self) -> bool:
        """Whether a simulated output was non-finite on either part."""
        return any(not math.isfinite(v) for part in (self.est, self.val) for v in part.values())

    def to_dict(self) -> dict[str, Any]:
        """The method's entry of the JSON report."""
        o = self.outcome
        entry: dict[str, Any] = {
            "est": dict(self.est) if o is not None else None,
            "val": dict(self.val) if o is not None else None,
            "noi": None if o is None else o.noi,
            "nfev": None if o is None else o.nfev,
            "seconds": self.seconds,
            "diverged": self.diverged if o is not None else None,
            "error": self.error,
            "info": {} if o is None else o.info,
            "convergence": None,
            "paper": PAPER_TABLE3.get(self.name),
        }
        if self.records is not None:
            entry["records"] = self.records
        if o is not None and o.history is not None:
            entry["convergence"] = {
                "fitness": o.fitness,
                "best": np.asarray(o.history, dtype=float).tolist(),
                "nfev": None if o.history_nfev is None else np.asarray(o.history_nfev).tolist(),
            }
        return jsonable(entry, default=str)


@dataclass
class Comparison:
    """A finished comparison: the data, the settings and one :class:`MethodResult` per method."""

    dataset: Dataset
    est: Dataset
    val: Dataset
    split: float | int
    settings: CompareSettings
    results: dict[str, MethodResult]

    def to_dict(self) -> dict[str, Any]:
        """The JSON report (layout: :mod:`hhra_phys.compare`)."""
        ds = self.dataset
        several = isinstance(ds, RecordSet)
        first = ds[0] if several else ds
        out = jsonable(
            {
                "dataset": ds.name or ds.source or "dataset",
                "split": self.split,
                "split_index": self.est.n,
                "n_est": self.est.n,
                "n_val": self.val.n,
                "time_unit": ds.time_unit,
                "settings": self.settings.to_dict(),
                "data": {
                    "source": first.source,
                    "n": ds.n,
                    "dt": ds.dt,
                    "input": f"{ds.input_name} [{ds.input_unit}]",
                    "output": f"{ds.output_name} [{ds.output_unit}]",
                    "std_y_est": float(np.std(self.est.y)),
                    "std_y_val": float(np.std(self.val.y)),
                    "metadata_seed": first.metadata.get("seed"),
                },
                "scoring": {
                    "simulation": "free run from the measured input (never one-step prediction)",
                    "metrics": list(KEYS),
                    "itae": "sum_k (t_k - t_0) |e_k| dt, t from the start of each part "
                    f"[{ds.output_unit} * {ds.time_unit}^2]",
                    "noi": "first iteration whose best fitness is within 0.1 % of the run's final "
                    "best (iteration 0 = initial population)",
                },
                "methods": {name: r.to_dict() for name, r in self.results.items()},
                "paper_table3": PAPER_TABLE3,
            },
            default=str,
        )
        if several:  # per record; the top-level counts and scores are pooled
            out["records"] = [{"name": name, "source": d.source, "n": d.n, "fs": float(d.fs),
                               "n_est": e.n, "n_val": v.n}
                              for name, d, e, v in zip(ds.names, ds, self.est, self.val,
                                                       strict=True)]
        return out


def _split(dataset: Dataset, split: Any) -> tuple[Dataset, Dataset]:
    if isinstance(split, bool):
        raise ParameterError(f"split must be a fraction in (0, 1) or a sample index, got {split!r}")
    if isinstance(split, int | np.integer):
        return dataset.split_at(int(split))
    if isinstance(split, float) and 0.0 < split < 1.0:
        return dataset.split(split)
    raise ParameterError(
        f"split must be a fraction strictly between 0 and 1 or an integer sample index, got "
        f"{split!r}"
    )


def _reporter(progress: bool | Callable[[str], None]) -> Callable[[str], None] | None:
    if callable(progress):
        return progress
    if progress:
        return lambda line: print(line, file=sys.stderr, flush=True)
    return None


def run_comparison(
    dataset: Dataset | Sequence[Dataset],
    split: float | int = 0.5,
    methods: Sequence[str] | None = None,
    seed: int = 0,
    pop_size: int = 100,
    max_iter: int = 200,
    progress: bool | Callable[[str], None] = False,
    *,
    settings: CompareSettings | None = None,
    **overrides: Any,
) -> Comparison:
    """Fit and score every method on one dataset.

    Parameters
    ----------
    dataset : Dataset or sequence of Dataset
        The record; split into estimation (first) and validation parts. Several
        records (one plant, the same signals and units): each is split by the
        fraction ``split``; methods that fit several records (``several_records``
        attribute: the physical rows jointly, LS/RLS/FFRLS on their regression rows
        stacked) return one output per record, scored per record and pooled
        (:func:`hhra_phys.multi.pooled_score`); the others are reported with
        ``error`` "fits one record only". One record behaves as before.
    split : float or int
        Fraction of samples for estimation (strictly between 0 and 1), or the sample index of
        the split (e.g. 512 for the public record).
    methods : sequence of str, optional
        Registered method names, in report order; default every registered method.
    seed, pop_size, max_iter : int
        See :class:`CompareSettings`.
    progress : bool or callable
        True: a line per method on stderr plus optimiser progress bars; a callable receives
        the lines instead (no bars).
    settings : CompareSettings, optional
        Full settings; ``seed``, ``pop_size``, ``max_iter`` and ``overrides`` replace its fields.
    **overrides
        Further :class:`CompareSettings` fields (``na``, ``nb``, ``nk``, ``zeta_s``, ...).

    Returns
    -------
    Comparison

    Raises
    ------
    ParameterError
        On an unknown method, bad settings or split.
    DataError
        If a method returns outputs of the wrong length.

    Notes
    -----
    A method that raises an :class:`~hhra_phys.errors.HHRAError` (e.g. no stable candidate
    found) is reported with ``error`` set and null scores; other exceptions propagate.
    """
    dataset = _records(dataset)
    s = _settings(settings, seed, pop_size, max_iter, progress, overrides)
    names = _method_names(methods)
    est, val = _parts(dataset, split)
    say = _reporter(progress)
    results: dict[str, MethodResult] = {}
    for i, name in enumerate(names, 1):
        results[name] = _run_method(f"[{i}/{len(names)}] {name}", name, est, val, s, say)
    return Comparison(dataset, est, val, split, s, results)


def _records(dataset: Dataset | Sequence[Dataset]) -> Dataset | RecordSet:
    """One record as it is; several (checked to belong together) as a :class:`RecordSet`."""
    records = list(dataset) if isinstance(dataset, (list, tuple)) else [dataset]
    if not records or not all(isinstance(d, Dataset) for d in records):
        raise ParameterError(f"dataset must be a hhra_phys.data.Dataset or a list of them, "
                             f"got {type(dataset)}")
    check_records(records)
    return records[0] if len(records) == 1 else RecordSet(records)


def _settings(settings: CompareSettings | None, seed: int, pop_size: int, max_iter: int,
              progress: bool | Callable[[str], None],
              overrides: dict[str, Any]) -> CompareSettings:
    """``settings`` (default :class:`CompareSettings`) with the arguments' fields replaced."""
    base = settings or CompareSettings()
    fields = {**asdict(base), "seed": seed, "pop_size": pop_size, "max_iter": max_iter}
    unknown = sorted(set(overrides) - set(fields))
    if unknown:
        raise ParameterError(f"unknown settings {unknown}; known: {sorted(fields)}")
    fields.update(overrides)
    # Bars only for progress=True: a callable receives lines and would be garbled by bars.
    fields["progress"] = progress is True or (not callable(progress) and base.progress)
    return CompareSettings(**fields)


def _method_names(methods: Sequence[str] | None) -> list[str]:
    """The methods to run, in report order (default every registered one), each known once."""
    if isinstance(methods, str):
        raise ParameterError("methods must be a sequence of names, e.g. ['ls', 'pso']")
    names = list(available_methods() if methods is None else methods)
    registered = available_methods()
    bad = [m for m in names if m not in registered]
    if bad or not names or len(set(names)) != len(names):
        raise ParameterError(
            f"methods: unknown or repeated {bad or names}; registered: {', '.join(registered)}"
        )
    return names


def _parts(dataset: Dataset | RecordSet, split: Any) -> tuple[Any, Any]:
    """The estimation and validation parts (of each record, for several: by a fraction)."""
    if isinstance(dataset, RecordSet):
        if not isinstance(split, float):
            raise ParameterError(f"split: several records are each split by a fraction in "
                                 f"(0, 1), got {split!r}")
        parts = [_split(d, split) for d in dataset]
        return RecordSet(p[0] for p in parts), RecordSet(p[1] for p in parts)
    return _split(dataset, split)


def _run_method(tag: str, name: str, est: Any, val: Any, s: CompareSettings,
                say: Callable[[str], None] | None) -> MethodResult:
    """Fit and score one method; its failure (an :class:`HHRAError`) is its result's error.

    ``tag`` (``"[i/n] name"``) starts each progress line.
    """
    if say:
        say(f"{tag} ...")
    start = time.perf_counter()
    if isinstance(est, RecordSet) and not getattr(METHODS[name], "several_records", False):
        if say:
            say(f"{tag}: skipped: fits one record only")
        return MethodResult(name, None, {}, {}, 0.0, "this method fits one record only")
    try:
        outcome = METHODS[name](est, val, s)
    except HHRAError as exc:
        result = MethodResult(name, None, {}, {}, time.perf_counter() - start, str(exc))
        if say:
            say(f"{tag}: failed: {exc}")
        return result
    elapsed = time.perf_counter() - start
    result = _scored(name, outcome, est, val, elapsed)
    if say:
        v = result.val
        say(f"{tag}: {result.seconds:.1f} s, validation MSE {v['mse']:.4g}, VAF {v['vaf']:.2f} %")
    return result


def _scored(
    name: str, outcome: MethodOutcome, est: Dataset, val: Dataset, elapsed: float
) -> MethodResult:
    if not isinstance(outcome, MethodOutcome):
        raise ParameterError(
            f"method {name!r} returned {type(outcome).__name__}, not MethodOutcome"
        )
    seconds = elapsed if outcome.seconds is None else float(outcome.seconds)
    if isinstance(est, RecordSet):  # one output per record: each scored, then pooled
        per: list[dict[str, Any]] = [{"name": n} for n in est.names]
        pooled = {}
        for label, part, ys in (("est", est, outcome.y_est), ("val", val, outcome.y_val)):
            ys = [np.asarray(y, dtype=float) for y in ys]
            for k, (d, y) in enumerate(zip(part, ys, strict=True)):
                if y.shape != d.y.shape:
                    raise DataError(f"method {name!r}: y_{label} of record {k + 1} has shape "
                                    f"{y.shape}, its {label} part has {d.y.shape}")
                per[k][label] = {kk: float(v) for kk, v in score(d.y, y, d.t).items()}
            pooled[label] = pooled_score(list(part), ys)
        return MethodResult(name, outcome, pooled["est"], pooled["val"], seconds, records=per)
    parts = {}
    for label, part, y in (("est", est, outcome.y_est), ("val", val, outcome.y_val)):
        yy = np.asarray(y, dtype=float)
        if yy.shape != part.y.shape:
            raise DataError(
                f"method {name!r}: y_{label} has shape {yy.shape}, the {label} part has "
                f"{part.y.shape}"
            )
        parts[label] = {k: float(v) for k, v in score(part.y, yy, part.t).items()}
    return MethodResult(name, outcome, parts["est"], parts["val"], seconds)


def compare(
    dataset: Dataset | Sequence[Dataset],
    split: float | int = 0.5,
    methods: Sequence[str] | None = None,
    seed: int = 0,
    pop_size: int = 100,
    max_iter: int = 200,
    progress: bool | Callable[[str], None] = False,
    **kw: Any,
) -> dict[str, Any]:
    """Run :func:`run_comparison` and return its JSON report (layout: :mod:`hhra_phys.compare`).

    ``dataset`` may be several records (:func:`run_comparison`).
    """
    return run_comparison(
        dataset, split, methods, seed, pop_size, max_iter, progress, **kw
    ).to_dict()
