"""The identification comparison of the paper's Table 3 (and Figures 10-16) on one dataset.

Every method is an entry of the registry :data:`METHODS`: a function
``fn(est, val, settings) -> MethodOutcome`` that fits on the estimation part ``est`` and returns
its *free-run simulated* output on both parts. :func:`run_comparison` times each method, scores
both outputs with :func:`hhra_phys.metrics.score` (never a one-step prediction) and collects
everything in a :class:`Comparison`, whose :meth:`~Comparison.to_dict` is the JSON report.
More methods (the physical-model fits, for instance) plug in with :func:`register_method`, from
any module; the CLI imports such modules with ``--plugin MODULE`` and every module named by an
entry point of the group ``hhra_phys.compare_methods``.

Built-in methods (the paper's ARX structure, eq. 13, by default ``na = nb = 3, nk = 1``):
``ls``, ``rls``, ``ffrls``, ``pso``, ``gwo``, ``hgwo`` (PSO, GWO, H-GWO on the box [-5, 5]) and
``ffrls_hgwo`` (the paper's hybrid), see :mod:`hhra_phys.arx`.

Initial conditions of the ARX free runs: the estimation part starts at rest at its first
measured output (past outputs ``y[0]``, past inputs 0); the validation part starts from the
measured samples just before the split (the usual "simulate from measured initial conditions";
with it the public record reproduces the baselines in ``shared/data/README.md``). After that
the output depends on the measured input only. Plug-in methods say in
``info["initial_condition"]`` how they start.

JSON layout (outside checks read it; keys are only ever added)::

    {"dataset": str, "split": float | int, "split_index": int, "n_est": int, "n_val": int,
     "time_unit": "s" | "samples", "settings": {...}, "data": {...}, "scoring": {...},
     "methods": {name: {"est": {"mse", "rmse", "vaf", "itae", "fit", "max_abs"},
                        "val": {...}, "noi": int | null, "nfev": int | null, "seconds": float,
                        "diverged": bool, "error": str | null, "info": {...},
                        "convergence": {"best": [...], "nfev": [...]} | null, "paper": {...}}},
     "paper_table3": {...}}

Non-finite numbers (a diverged simulation) and undefined ones (NOI of LS) are JSON ``null``.
"""

from __future__ import annotations

import json
import math
import re
import sys
import time
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from importlib import import_module
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys import arx
from hhra_phys.data import Dataset
from hhra_phys.errors import DataError, HHRAError, ParameterError
from hhra_phys.metrics import KEYS, score

__all__ = [
    "ARX_METHODS",
    "ENTRY_POINT_GROUP",
    "METHODS",
    "METHOD_LABELS",
    "PAPER_TABLE3",
    "CompareSettings",
    "Comparison",
    "MethodOutcome",
    "MethodResult",
    "aggregate",
    "arx_outcome",
    "available_methods",
    "compare",
    "load_plugins",
    "markdown_summary",
    "markdown_table",
    "plot_convergence",
    "plot_outputs",
    "register_method",
    "run_comparison",
    "write_json",
]

#: The built-in ARX methods, in the order of the paper's Table 3 (plus plain H-GWO).
ARX_METHODS: tuple[str, ...] = ("ls", "rls", "ffrls", "pso", "gwo", "hgwo", "ffrls_hgwo")

#: Entry-point group whose modules (or callables) register more methods.
ENTRY_POINT_GROUP = "hhra_phys.compare_methods"

#: The paper's Table 3 (MSE [deg^2], VAF [%], NOI), on its measured rig data (not public).
#: "ffrls_hgwo" is the paper's "proposed" method; the paper has no plain H-GWO row.
PAPER_TABLE3: dict[str, dict[str, float | int | None]] = {
    "ls": {"mse": 95.31, "vaf": 61.52, "noi": None},
    "rls": {"mse": 89.98, "vaf": 65.73, "noi": None},
    "ffrls": {"mse": 77.47, "vaf": 91.28, "noi": None},
    "pso": {"mse": 13.94, "vaf": 93.21, "noi": 142},
    "gwo": {"mse": 40.68, "vaf": 71.24, "noi": 175},
    "ffrls_hgwo": {"mse": 12.73, "vaf": 96.18, "noi": 118},
}

#: Display names for tables and figures (unknown names are shown as they are).
METHOD_LABELS: dict[str, str] = {
    "ls": "LS",
    "rls": "RLS",
    "ffrls": "FFRLS",
    "pso": "PSO",
    "gwo": "GWO",
    "hgwo": "H-GWO",
    "ffrls_hgwo": "FFRLS+H-GWO",
}

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class CompareSettings:
    """Settings every method receives.

    Attributes
    ----------
    seed : int
        Seed of every random choice (each metaheuristic is seeded with it).
    pop_size, max_iter : int
        Population size and iterations of the metaheuristics (paper: 100 and 200).
    na, nb, nk : int
        ARX structure (paper, eq. 13: 3, 3, 1).
    bounds : (float, float)
        Search box of PSO, GWO and H-GWO for every ARX coefficient (paper: [-5, 5]).
    zeta_s : float
        Expansion gain of the hybrid's box (eq. 29); the paper gives no value.
    progress : bool
        Show optimiser progress bars.
    options : dict
        Per-method optimiser options, ``{"pso": {...}, ...}``, merged over the paper's.
    extra : dict
        Free-form settings for plug-in methods.
    """

    seed: int = 0
    pop_size: int = 100
    max_iter: int = 200
    na: int = 3
    nb: int = 3
    nk: int = 1
    bounds: tuple[float, float] = arx.PAPER_BOX
    zeta_s: float = arx.DEFAULT_ZETA_S
    progress: bool = False
    options: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, low in (
            ("seed", 0),
            ("pop_size", 2),
            ("max_iter", 1),
            ("na", 0),
            ("nb", 1),
            ("nk", 0),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
                raise ParameterError(f"{name} must be an integer >= {low}, got {value!r}")
        lo, hi = (float(v) for v in self.bounds)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ParameterError(f"bounds must be (lo, hi) with finite lo < hi, got {self.bounds}")
        if not (math.isfinite(self.zeta_s) and 0 < self.zeta_s <= 1):
            raise ParameterError(f"zeta_s must lie in (0, 1], got {self.zeta_s!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able copy."""
        return _jsonable(asdict(self))


# --------------------------------------------------------------------------- registry


@dataclass
class MethodOutcome:
    """What a method returns.

    Attributes
    ----------
    y_est, y_val : numpy.ndarray
        Free-run simulated output on the estimation and validation parts [output unit], the same
        length as the parts. NaN/inf where the simulation diverged (scored as worst).
    noi : int or None
        Number of iterations (see :func:`hhra_phys.optim.noi`); None where undefined.
    nfev : int or None
        Objective evaluations; None where there is no objective (LS, RLS, FFRLS).
    seconds : float or None
        Wall time of the fit [s]; None lets :func:`run_comparison` use the time of the call.
    history : numpy.ndarray or None
        Best-so-far fitness per iteration (index 0 = initialisation), for convergence plots.
    history_nfev : numpy.ndarray or None
        Cumulative evaluations at each entry of ``history``.
    fitness : str or None
        What ``history`` measures, e.g. "ITAE of the free-run output on the estimation part".
    info : dict
        Free-form, JSON-able details (estimated parameters, initial condition, ...).
    """

    y_est: np.ndarray
    y_val: np.ndarray
    noi: int | None = None
    nfev: int | None = None
    seconds: float | None = None
    history: np.ndarray | None = None
    history_nfev: np.ndarray | None = None
    fitness: str | None = None
    info: dict[str, Any] = field(default_factory=dict)


MethodFn = Callable[[Dataset, Dataset, CompareSettings], MethodOutcome]

#: The registry: method name -> ``fn(est, val, settings) -> MethodOutcome``, in insertion order.
METHODS: dict[str, MethodFn] = {}


def register_method(
    name: str, fn: MethodFn | None = None, *, label: str | None = None, replace: bool = False
) -> Any:
    """Add a method to :data:`METHODS` (usable as a decorator when ``fn`` is omitted).

    Parameters
    ----------
    name : str
        Key in the report: lower-case letters, digits and underscores, starting with a letter
        (e.g. ``"phys_hgwo"``).
    fn : callable
        ``fn(est: Dataset, val: Dataset, settings: CompareSettings) -> MethodOutcome``.
    label : str, optional
        Display name for tables and figures.
    replace : bool
        Allow replacing an existing entry (otherwise that is an error).

    Returns
    -------
    callable
        ``fn`` (or the decorator).
    """
    if not isinstance(name, str) or not _NAME.match(name):
        raise ParameterError(
            f"method name must match [a-z][a-z0-9_]* (e.g. 'phys_hgwo'), got {name!r}"
        )

    def add(func: MethodFn) -> MethodFn:
        if not callable(func):
            raise ParameterError(f"method {name!r}: fn must be callable, got {func!r}")
        if name in METHODS and not replace and METHODS[name] is not func:
            raise ParameterError(
                f"method {name!r} is already registered; pass replace=True to replace it"
            )
        METHODS[name] = func
        if label:
            METHOD_LABELS[name] = label
        return func

    return add if fn is None else add(fn)


_plugins_loaded = False


def load_plugins(modules: Iterable[str] = ()) -> list[str]:
    """Import modules that register methods, and those named by entry points.

    Parameters
    ----------
    modules : iterable of str
        Module names (e.g. ``"hhra_phys.physfit"``); each is imported, and its import is
        expected to call :func:`register_method`.

    Returns
    -------
    list of str
        The names of the methods registered after loading.

    Raises
    ------
    ParameterError
        If a given module cannot be imported. A broken entry point only warns.
    """
    global _plugins_loaded
    for mod in modules:
        try:
            import_module(mod)
        except ImportError as exc:
            raise ParameterError(f"plugin module {mod!r} cannot be imported: {exc}") from exc
    if not _plugins_loaded:
        _plugins_loaded = True
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            try:
                obj = ep.load()
                if callable(obj):
                    obj()
            except Exception as exc:  # a broken third-party plugin must not stop the built-ins
                warnings.warn(f"compare plugin {ep.name!r} failed to load: {exc}", stacklevel=2)
    return list(METHODS)


def available_methods() -> tuple[str, ...]:
    """Names of every registered method (entry-point plugins included)."""
    load_plugins()
    return tuple(METHODS)


# --------------------------------------------------------------------------- ARX methods


def _history_fields(fit: arx.ARXFit) -> dict[str, Any]:
    if fit.convergence is None:
        return {}
    return {
        "history": fit.convergence,
        "history_nfev": fit.convergence_nfev,
        "fitness": "ITAE of the free-run output on the estimation part",
    }


def arx_outcome(fit: arx.ARXFit, est: Dataset, val: Dataset) -> MethodOutcome:
    """A :class:`MethodOutcome` from an ARX fit: free runs on both parts (initial conditions:
    module docstring), with the model, its poles and the fit's details in ``info``.

    Parameters
    ----------
    fit : hhra_phys.arx.ARXFit
        The fitted model.
    est, val : Dataset
        Estimation and validation parts.
    """
    model = fit.model
    y_est = model.simulate(est.u, y_init=est.y[0], u_init=0.0)
    y_val = model.simulate(val.u, y_init=est.y, u_init=est.u)
    info: dict[str, Any] = {
        "model": model.to_dict(),
        "pole_radius": float(arx.pole_radius(model.a[None, :])[0]),
        "initial_condition": "est: at rest at y[0] (past u = 0); val: measured samples before "
        "the split",
        **fit.info,
    }
    if est.time_unit == "s" and model.na:
        s = model.continuous_poles(est.dt)
        info["continuous_poles"] = [[float(p.real), float(p.imag)] for p in s]
    return MethodOutcome(
        y_est,
        y_val,
        noi=fit.noi,
        nfev=fit.nfev,
        seconds=fit.seconds,
        info=info,
        **_history_fields(fit),
    )


def _orders(s: CompareSettings) -> dict[str, int]:
    return {"na": s.na, "nb": s.nb, "nk": s.nk}


def _method_ls(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", arx.ConditioningWarning)
        fit = arx.fit_ls(est.u, est.y, **_orders(s))
    out = arx_outcome(fit, est, val)
    if caught:
        out.info["warnings"] = [str(w.message) for w in caught]
    return out


def _method_rls(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
    return arx_outcome(arx.fit_rls(est.u, est.y, **_orders(s)), est, val)


def _method_ffrls(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
    return arx_outcome(arx.fit_ffrls(est.u, est.y, **_orders(s)), est, val)


def _metaheuristic(method: str) -> MethodFn:
    def run(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
        fit = arx.fit_metaheuristic(
            est.u,
            est.y,
            est.t,
            method=method,
            bounds=s.bounds,
            pop_size=s.pop_size,
            max_iter=s.max_iter,
            seed=s.seed,
            options=s.options.get(method),
            progress=s.progress,
            **_orders(s),
        )
        return arx_outcome(fit, est, val)

    run.__name__ = f"_method_{method}"
    run.__doc__ = f"ARX coefficients by {METHOD_LABELS[method]} minimising the free-run ITAE."
    return run


def _method_ffrls_hgwo(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
    fit = arx.fit_ffrls_hgwo(
        est.u,
        est.y,
        est.t,
        zeta_s=s.zeta_s,
        pop_size=s.pop_size,
        max_iter=s.max_iter,
        seed=s.seed,
        options=s.options.get("ffrls_hgwo"),
        progress=s.progress,
        **_orders(s),
    )
    return arx_outcome(fit, est, val)


register_method("ls", _method_ls)
register_method("rls", _method_rls)
register_method("ffrls", _method_ffrls)
for _m in ("pso", "gwo", "hgwo"):
    register_method(_m, _metaheuristic(_m))
register_method("ffrls_hgwo", _method_ffrls_hgwo)


# --------------------------------------------------------------------------- running


@dataclass
class MethodResult:
    """One method's outcome and scores (``error`` set, scores empty, if it failed)."""

    name: str
    outcome: MethodOutcome | None
    est: dict[str, float]
    val: dict[str, float]
    seconds: float
    error: str | None = None

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
        if o is not None and o.history is not None:
            entry["convergence"] = {
                "fitness": o.fitness,
                "best": np.asarray(o.history, dtype=float).tolist(),
                "nfev": None if o.history_nfev is None else np.asarray(o.history_nfev).tolist(),
            }
        return _jsonable(entry)


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
        """The JSON report (layout in the module docstring)."""
        ds = self.dataset
        return _jsonable(
            {
                "dataset": ds.name or ds.source or "dataset",
                "split": self.split,
                "split_index": self.est.n,
                "n_est": self.est.n,
                "n_val": self.val.n,
                "time_unit": ds.time_unit,
                "settings": self.settings.to_dict(),
                "data": {
                    "source": ds.source,
                    "n": ds.n,
                    "dt": ds.dt,
                    "input": f"{ds.input_name} [{ds.input_unit}]",
                    "output": f"{ds.output_name} [{ds.output_unit}]",
                    "std_y_est": float(np.std(self.est.y)),
                    "std_y_val": float(np.std(self.val.y)),
                    "metadata_seed": ds.metadata.get("seed"),
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
            }
        )


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
    dataset: Dataset,
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
    dataset : Dataset
        The record; split into estimation (first) and validation parts.
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
    if not isinstance(dataset, Dataset):
        raise ParameterError(f"dataset must be a hhra_phys.data.Dataset, got {type(dataset)}")
    base = settings or CompareSettings()
    fields = {**asdict(base), "seed": seed, "pop_size": pop_size, "max_iter": max_iter}
    unknown = sorted(set(overrides) - set(fields))
    if unknown:
        raise ParameterError(f"unknown settings {unknown}; known: {sorted(fields)}")
    fields.update(overrides)
    # Bars only for progress=True: a callable receives lines and would be garbled by bars.
    fields["progress"] = progress is True or (not callable(progress) and base.progress)
    s = CompareSettings(**fields)
    if isinstance(methods, str):
        raise ParameterError("methods must be a sequence of names, e.g. ['ls', 'pso']")
    names = list(available_methods() if methods is None else methods)
    registered = available_methods()
    bad = [m for m in names if m not in registered]
    if bad or not names or len(set(names)) != len(names):
        raise ParameterError(
            f"methods: unknown or repeated {bad or names}; registered: {', '.join(registered)}"
        )
    est, val = _split(dataset, split)
    say = _reporter(progress)
    results: dict[str, MethodResult] = {}
    for i, name in enumerate(names, 1):
        if say:
            say(f"[{i}/{len(names)}] {name} ...")
        start = time.perf_counter()
        try:
            outcome = METHODS[name](est, val, s)
        except HHRAError as exc:
            results[name] = MethodResult(name, None, {}, {}, time.perf_counter() - start, str(exc))
            if say:
                say(f"[{i}/{len(names)}] {name}: failed: {exc}")
            continue
        elapsed = time.perf_counter() - start
        results[name] = _scored(name, outcome, est, val, elapsed)
        if say:
            v = results[name].val
            say(
                f"[{i}/{len(names)}] {name}: {results[name].seconds:.1f} s, validation "
                f"MSE {v['mse']:.4g}, VAF {v['vaf']:.2f} %"
            )
    return Comparison(dataset, est, val, split, s, results)


def _scored(
    name: str, outcome: MethodOutcome, est: Dataset, val: Dataset, elapsed: float
) -> MethodResult:
    if not isinstance(outcome, MethodOutcome):
        raise ParameterError(
            f"method {name!r} returned {type(outcome).__name__}, not MethodOutcome"
        )
    parts = {}
    for label, part, y in (("est", est, outcome.y_est), ("val", val, outcome.y_val)):
        yy = np.asarray(y, dtype=float)
        if yy.shape != part.y.shape:
            raise DataError(
                f"method {name!r}: y_{label} has shape {yy.shape}, the {label} part has "
                f"{part.y.shape}"
            )
        parts[label] = {k: float(v) for k, v in score(part.y, yy, part.t).items()}
    seconds = elapsed if outcome.seconds is None else float(outcome.seconds)
    return MethodResult(name, outcome, parts["est"], parts["val"], seconds)


def compare(
    dataset: Dataset,
    split: float | int = 0.5,
    methods: Sequence[str] | None = None,
    seed: int = 0,
    pop_size: int = 100,
    max_iter: int = 200,
    progress: bool | Callable[[str], None] = False,
    **kw: Any,
) -> dict[str, Any]:
    """Run :func:`run_comparison` and return its JSON report (layout: module docstring)."""
    return run_comparison(
        dataset, split, methods, seed, pop_size, max_iter, progress, **kw
    ).to_dict()


# --------------------------------------------------------------------------- JSON


def _jsonable(obj: Any) -> Any:
    """Plain Python types; non-finite floats become None (JSON null)."""
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, bool | np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, complex | np.complexfloating):
        return [_jsonable(obj.real), _jsonable(obj.imag)]
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)


def write_json(report: Mapping[str, Any], path: str | Path, overwrite: bool = False) -> Path:
    """Write a report (or any JSON-able mapping) as indented JSON.

    Raises
    ------
    ParameterError
        If ``path`` exists and ``overwrite`` is False.
    """
    p = Path(path)
    if p.exists() and not overwrite:
        raise ParameterError(f"{p} exists; pass overwrite=True (--overwrite) to replace it")
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(_jsonable(report), indent=1, allow_nan=False) + "\n")
    return p


# --------------------------------------------------------------------------- tables


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, int | np.integer):
        return str(int(v))
    v = float(v)
    if not math.isfinite(v):
        return "diverged"
    if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}"


def _label(name: str) -> str:
    return METHOD_LABELS.get(name, name)


def markdown_table(report: Mapping[str, Any], paper: bool = True) -> str:
    """One comparison as a Markdown table, beside the paper's published Table 3.

    Parameters
    ----------
    report : dict
        From :func:`compare` (or :meth:`Comparison.to_dict`).
    paper : bool
        Add the paper's MSE, VAF and NOI columns (its data is not public: compare the ranking,
        not the absolute values).
    """
    ou = report.get("data", {}).get("output", "")
    head = [
        "method",
        "est MSE",
        "est VAF %",
        "val MSE",
        "val RMSE",
        "val VAF %",
        "val FIT %",
        "val ITAE",
        "NOI",
        "evals",
        "time s",
    ]
    if paper:
        head += ["paper MSE", "paper VAF %", "paper NOI"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, m in report["methods"].items():
        if m.get("error"):
            cells = [_label(name), f"failed: {m['error']}"] + [""] * (len(head) - 2)
            lines.append("| " + " | ".join(cells) + " |")
            continue
        e, v = m["est"], m["val"]
        row = [
            _label(name),
            _fmt(e["mse"]),
            _fmt(e["vaf"]),
            _fmt(v["mse"]),
            _fmt(v["rmse"]),
            _fmt(v["vaf"]),
            _fmt(v["fit"]),
            _fmt(v["itae"]),
            _fmt(m["noi"]),
            _fmt(m["nfev"]),
            f"{m['seconds']:.2f}",
        ]
        if paper:
            p = PAPER_TABLE3.get(name) or {}
            row += [_fmt(p.get("mse")), _fmt(p.get("vaf")), _fmt(p.get("noi"))]
        lines.append("| " + " | ".join(row) + " |")
    note = (
        f"\nScores of the free-run output ({ou}); MSE in output units squared, ITAE in output "
        f"unit * {report.get('time_unit', 's')}^2. NOI: first iteration within 0.1 % of the "
        "final best fitness; evals: objective evaluations."
    )
    if paper:
        note += " Paper: Table 3 of the reference paper, on its own (non-public) rig data."
    return "\n".join(lines) + "\n" + note + "\n"


def aggregate(reports: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Mean, spread and range of every score over several reports (e.g. seeds).

    Parameters
    ----------
    reports : sequence of dict
        Reports of :func:`compare` on comparable data.

    Returns
    -------
    dict
        ``{"n_reports": n, "datasets": [...], "methods": {name: {"est": {metric: stats},
        "val": {...}, "noi": stats, "nfev": stats, "seconds": stats, "failed": k,
        "diverged": k}}}`` with ``stats = {"mean", "std", "min", "max", "median", "n"}``
        (``std`` with ddof = 1; ``n`` counts the finite values used; all None when n = 0).
    """
    if not reports:
        raise ParameterError("aggregate needs at least one report")
    names: list[str] = []
    for r in reports:
        names += [n for n in r["methods"] if n not in names]

    def stats(values: list[Any]) -> dict[str, Any]:
        xs = np.array([float(x) for x in values if x is not None and math.isfinite(float(x))])
        if xs.size == 0:
            return {"mean": None, "std": None, "min": None, "max": None, "median": None, "n": 0}
        return {
            "mean": float(xs.mean()),
            "std": float(xs.std(ddof=1)) if xs.size > 1 else 0.0,
            "min": float(xs.min()),
            "max": float(xs.max()),
            "median": float(np.median(xs)),
            "n": int(xs.size),
        }

    out: dict[str, Any] = {}
    for name in names:
        entries = [r["methods"][name] for r in reports if name in r["methods"]]
        ok = [e for e in entries if not e.get("error")]
        out[name] = {
            part: {k: stats([(e[part] or {}).get(k) for e in ok]) for k in KEYS}
            for part in ("est", "val")
        }
        for key in ("noi", "nfev", "seconds"):
            out[name][key] = stats([e.get(key) for e in ok])
        out[name]["runs"] = len(entries)
        out[name]["failed"] = len(entries) - len(ok)
        out[name]["diverged"] = sum(bool(e.get("diverged")) for e in ok)
    return {
        "n_reports": len(reports),
        "datasets": [r.get("dataset") for r in reports],
        "methods": out,
        "paper_table3": PAPER_TABLE3,
    }


def markdown_summary(agg: Mapping[str, Any], paper: bool = True) -> str:
    """An :func:`aggregate` result as a Markdown table: mean +- standard deviation [min, max]."""

    def ms(st: Mapping[str, Any], digits: int = 4) -> str:
        if not st or st.get("n", 0) == 0:
            return "-"
        return f"{_fmt(st['mean'], digits)} ± {_fmt(st['std'], 2)}"

    def rng(st: Mapping[str, Any]) -> str:
        if not st or st.get("n", 0) == 0:
            return "-"
        return f"[{_fmt(st['min'], 3)}, {_fmt(st['max'], 3)}]"

    head = [
        "method",
        "est MSE",
        "val MSE",
        "val MSE range",
        "val VAF %",
        "val FIT %",
        "NOI",
        "evals",
        "time s",
        "failed/diverged",
    ]
    if paper:
        head += ["paper MSE", "paper VAF %", "paper NOI"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, m in agg["methods"].items():
        row = [
            _label(name),
            ms(m["est"]["mse"]),
            ms(m["val"]["mse"]),
            rng(m["val"]["mse"]),
            ms(m["val"]["vaf"]),
            ms(m["val"]["fit"]),
            ms(m["noi"]),
            ms(m["nfev"]),
            ms(m["seconds"], 2),
            f"{m['failed']}/{m['diverged']} of {m['runs']}",
        ]
        if paper:
            p = PAPER_TABLE3.get(name) or {}
            row += [_fmt(p.get("mse")), _fmt(p.get("vaf")), _fmt(p.get("noi"))]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- figures


def _save(fig: Any, path: str | Path | None, overwrite: bool, dpi: int) -> None:
    if path is None:
        return
    p = Path(path)
    if p.exists() and not overwrite:
        raise ParameterError(f"{p} exists; pass overwrite=True (--overwrite) to replace it")
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=dpi)


def plot_outputs(
    comparison: Comparison,
    methods: Sequence[str] | None = None,
    path: str | Path | None = None,
    *,
    errors: bool = False,
    overwrite: bool = False,
    dpi: int = 80,
) -> Any:
    """Measured against free-run simulated output, one panel per method (paper's Figs. 10-15).

    Parameters
    ----------
    comparison : Comparison
        From :func:`run_comparison`.
    methods : sequence of str, optional
        Which methods (default all that succeeded).
    path : path, optional
        Save the figure there (PNG by suffix).
    errors : bool
        Plot the simulation error ``y - yhat`` instead (readable when the outputs overlap).
    overwrite : bool
        Replace an existing file.
    dpi : int
        Resolution of the saved file.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    names = [n for n in (methods or comparison.results) if comparison.results[n].outcome]
    if not names:
        raise ParameterError("no successful method to plot")
    est, val, ds = comparison.est, comparison.val, comparison.dataset
    fig = Figure(figsize=(8.0, 0.6 + 1.45 * len(names)), layout="constrained")
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    for ax, name in zip(axes, names, strict=True):
        r = comparison.results[name]
        assert r.outcome is not None
        if errors:
            ax.plot(est.t, est.y - r.outcome.y_est, color="C0", lw=0.6, label="error (est)")
            ax.plot(val.t, val.y - r.outcome.y_val, color="C3", lw=0.6, label="error (val)")
            ax.axhline(0.0, color="0.5", lw=0.5)
        else:
            ax.plot(ds.t, ds.y, color="0.55", lw=1.6, label="measured")
            ax.plot(est.t, r.outcome.y_est, color="C0", lw=0.8, label="simulated (est)")
            ax.plot(val.t, r.outcome.y_val, color="C3", lw=0.8, label="simulated (val)")
            lo, hi = float(ds.y.min()), float(ds.y.max())
            pad = 0.15 * (hi - lo)
            ax.set_ylim(lo - pad, hi + pad)  # a diverged run must not squash the measured trace
        ax.axvline(val.t[0], color="k", ls="--", lw=0.7)
        ax.set_title(
            f"{_label(name)}: val MSE {_fmt(r.val['mse'], 3)}, VAF {_fmt(r.val['vaf'], 4)} %",
            fontsize=8,
            loc="left",
        )
        ax.tick_params(labelsize=7)
        unit = f"[{ds.output_unit}]"
        ax.set_ylabel(f"error {unit}" if errors else f"{ds.output_name} {unit}", fontsize=7)
    axes[0].legend(fontsize=6, ncol=3, loc="upper right")
    axes[-1].set_xlabel(f"t [{ds.time_unit}]", fontsize=7)
    _save(fig, path, overwrite, dpi)
    return fig


def plot_convergence(
    comparison: Comparison | Sequence[Comparison],
    path: str | Path | None = None,
    *,
    methods: Sequence[str] | None = None,
    overwrite: bool = False,
    dpi: int = 80,
) -> Any:
    """Best fitness per iteration and per evaluation for every method with a history (Fig. 16).

    Several comparisons (e.g. seeds) are drawn as lines of one colour per method.

    Parameters
    ----------
    comparison : Comparison or sequence of Comparison
        From :func:`run_comparison`.
    path : path, optional
        Save the figure there.
    methods : sequence of str, optional
        Which methods (default every one with a history).
    overwrite : bool
        Replace an existing file.
    dpi : int
        Resolution of the saved file.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    comps = [comparison] if isinstance(comparison, Comparison) else list(comparison)
    fig = Figure(figsize=(8.0, 3.0), layout="constrained")
    ax_it, ax_ev = fig.subplots(1, 2, sharey=True)
    colours: dict[str, str] = {}
    fitness = None
    for comp in comps:
        for name, r in comp.results.items():
            o = r.outcome
            if o is None or o.history is None or (methods is not None and name not in methods):
                continue
            fitness = fitness or o.fitness
            colour = colours.setdefault(name, f"C{len(colours)}")
            first = len(comps) == 1 or comp is comps[0]
            label = f"{_label(name)} (NOI {o.noi})" if len(comps) == 1 else _label(name)
            best = np.asarray(o.history, dtype=float)
            ax_it.plot(
                np.arange(best.size), best, color=colour, lw=1.0, label=label if first else None
            )
            if o.history_nfev is not None:
                ax_ev.plot(o.history_nfev, best, color=colour, lw=1.0)
    if not colours:
        raise ParameterError("no method with a convergence history to plot")
    for ax, xl in ((ax_it, "iteration"), (ax_ev, "objective evaluations")):
        ax.set_yscale("log")
        ax.set_xlabel(xl, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    ax_it.set_ylabel("best fitness (ITAE)" if fitness else "best fitness", fontsize=8)
    ax_it.legend(fontsize=7)
    _save(fig, path, overwrite, dpi)
    return fig
