"""The benchmark study: the reference paper's Table 2, reproduced and extended.

An experiment run with the optimisers of :mod:`hhra_phys.optim` (``hhra-phys benchmark``,
``experiments/table2.py``), kept in the paper's package, apart from the optimisers, which
hold only the algorithms and their driver.

Tables (each a ``{function: {method: cell}}`` mapping):

``results``
    The paper's protocol: every method runs ``max_iter`` iterations with ``pop_size`` members,
    so H-GWO spends about twice the evaluations of the others.
``equal_budget``
    Every method gets the same number of objective evaluations, ``pop_size * (max_iter + 1)``
    (the budget of GWO, PSO and DE above); H-GWO then runs fewer iterations.
``shifted``
    The paper's protocol on the shifted functions (optimum moved away from the origin,
    :meth:`hhra_phys.paper.benchmarks.Benchmark.shifted`), which exposes H-GWO's pull toward the
    origin.
``shifted_equal_budget``
    Both changes at once.
``variants``
    H-GWO with ``lam = 1`` and with ``target_vector = "previous"`` beside the default and GWO,
    and PSO with Mirjalili's decreasing inertia (0.9 to 0.2), on the original and the shifted
    functions (rows ``f1`` and ``f1_shifted`` ...), at the equal budget.

Every table but ``variants`` also has SciPy's ``differential_evolution`` (its default best1bin
strategy) at the equal budget as an external reference (``"scipy_de"``). A cell holds the mean
and sample standard deviation (ddof = 1) of the best cost over the runs, the evaluations per
run (``nfev``), the wall time per run (``seconds``), and the median NOI (first iteration
within 0.1 % of the run's final best, :func:`hhra_phys.optim.history.noi`).

Seeds: run ``r`` of function ``f`` uses ``SeedSequence(seed, spawn_key=(f, r, k))`` with
``k = 0`` for the optimiser, 1 for f3's noise and 2 for the shift, so every method sees the same
noise stream and the same shifted optimum in run ``r``.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import differential_evolution
from scipy.stats import qmc

from hhra_phys.errors import ParameterError
from hhra_phys.optim.core import check_int
from hhra_phys.optim.driver import make_optimiser, minimize
from hhra_phys.optim.history import noi
from hhra_phys.optim.registry import LABELS, METHODS
from hhra_phys.outputs import (
    FIGURE_SUFFIXES,
    atomic_path,
    atomic_write_text,
    check_output_path,
    jsonable,
)
from hhra_phys.paper.benchmarks import BENCHMARK_KEYS, Benchmark, get_benchmark

__all__ = [
    "StudySettings",
    "Run",
    "Cell",
    "run_study",
    "run_function",
    "run_method",
    "run_scipy_de",
    "iterations_for_budget",
    "make_problem",
    "table_rows",
    "format_table",
    "format_report",
    "plot_convergence",
    "plot_paths",
]

#: The paper's four methods, in the order of our tables.
PAPER_METHODS: tuple[str, ...] = ("hgwo", "gwo", "pso", "de")

#: Display names: the optimisers' (:data:`hhra_phys.optim.registry.LABELS`), SciPy's DE
#: and the variants.
METHOD_LABELS: dict[str, str] = {
    **LABELS,
    "scipy_de": "SciPy DE",
    "hgwo_lam1": "H-GWO lam=1",
    "hgwo_previous": "H-GWO target=previous",
    "pso_w_decreasing": "PSO w 0.9->0.2",
}

#: The paper's settings (Section 3.5) as ``minimize`` options.
PAPER_OPTIONS: dict[str, dict[str, Any]] = {
    "hgwo": {"F": 0.5, "lam": 0.25, "target_vector": "moved"},
    "gwo": {},
    "pso": {"w": 0.8, "c1": 2.0, "c2": 2.0, "vmax": 6.0},
    "de": {"F": 0.5},
}

#: H-GWO variants of the ``variants`` table: (method, options).
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "hgwo": ("hgwo", PAPER_OPTIONS["hgwo"]),
    "hgwo_lam1": ("hgwo", {**PAPER_OPTIONS["hgwo"], "lam": 1.0}),
    "hgwo_previous": ("hgwo", {**PAPER_OPTIONS["hgwo"], "target_vector": "previous"}),
    "gwo": ("gwo", PAPER_OPTIONS["gwo"]),
    "pso_w_decreasing": ("pso", {**PAPER_OPTIONS["pso"], "w_start": 0.9, "w_end": 0.2}),
}

#: The paper's Table 2: mean and standard deviation per function and method.
PUBLISHED: dict[str, dict[str, tuple[float, float]]] = {
    "f1": {
        "pso": (5.107963, 2.045059),
        "gwo": (8.74e-4, 0.002765),
        "de": (1.3874, 4.0215),
        "hgwo": (3.72e-9, 2.03e-8),
    },
    "f2": {
        "pso": (68.341611, 39.848151),
        "gwo": (27.960574, 0.00391),
        "de": (28.940232, 0.02895),
        "hgwo": (25.901103, 0.671705),
    },
    "f3": {
        "pso": (8.714045, 6.275347),
        "gwo": (0.003067, 0.003762),
        "de": (0.030475, 0.039981),
        "hgwo": (9.29e-4, 0.001465),
    },
    "f4": {
        "pso": (184.0, 38.039407),
        "gwo": (31.421778, 1.544107),
        "de": (35.973785, 81.892454),
        "hgwo": (17.961906, 0.513119),
    },
    "f5": {
        "pso": (3.080351, 0.351753),
        "gwo": (0.004442, 0.014036),
        "de": (8.20e-6, 1.06e-5),
        "hgwo": (2.38e-6, 1.30e-5),
    },
    "f6": {
        "pso": (18.80006, 5.574793),
        "gwo": (0.006625, 0.020953),
        "de": (1.51e-8, 5.08e-8),
        "hgwo": (2.64e-8, 1.45e-7),
    },
    "f7": {
        "pso": (-1.031628, 5.72e-7),
        "gwo": (-1.031628, 3.92e-8),
        "de": (-1.028604, 0.003393),
        "hgwo": (-1.031628, 5.52e-8),
    },
    "f8": {
        "pso": (0.001655, 0.003372),
        "gwo": (5.53e-4, 1.60e-4),
        "de": (0.002952, 0.001598),
        "hgwo": (3.92e-4, 1.39e-4),
    },
    "f9": {
        "pso": (3.00001, 1.08e-5),
        "gwo": (3.000219, 2.21e-4),
        "de": (6.944784, 4.913727),
        "hgwo": (3.000008, 9.57e-6),
    },
}

#: Tables of the full study, in the order they are run.
TABLES: tuple[str, ...] = ("results", "equal_budget", "shifted", "shifted_equal_budget", "variants")


@dataclass
class StudySettings:
    """Settings of a study run (all recorded in the JSON output).

    Attributes
    ----------
    runs, pop_size, max_iter, seed : int
        Runs per cell, population size, iterations (paper: 30, 30, 100) and the base seed.
    functions, methods : tuple of str
        Benchmark keys and paper methods to run.
    tables : tuple of str
        Which of :data:`TABLES` to produce.
    scipy_reference : bool
        Add SciPy's ``differential_evolution`` to every table.
    """

    runs: int = 30
    pop_size: int = 30
    max_iter: int = 100
    seed: int = 0
    functions: tuple[str, ...] = BENCHMARK_KEYS
    methods: tuple[str, ...] = PAPER_METHODS
    tables: tuple[str, ...] = TABLES
    scipy_reference: bool = True

    def __post_init__(self) -> None:
        for name in ("runs", "pop_size", "max_iter"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ParameterError(f"{name}: expected a positive integer, got {value!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ParameterError(f"seed: expected a non-negative integer, got {self.seed!r}")
        self.functions = tuple(self.functions)
        self.methods = tuple(self.methods)
        self.tables = tuple(self.tables)
        _check_names(self.functions, BENCHMARK_KEYS, "functions")
        _check_names(self.methods, tuple(METHODS), "methods")
        _check_names(self.tables, TABLES, "tables")

    @property
    def budget(self) -> int:
        """Evaluations per run of the equal-budget tables: ``pop_size * (max_iter + 1)``."""
        return self.pop_size * (self.max_iter + 1)


def _check_names(given: Sequence[str], allowed: Sequence[str], name: str) -> None:
    bad = [g for g in given if g not in allowed]
    if bad or not given:
        raise ParameterError(f"{name}: expected a non-empty subset of {list(allowed)}, got {bad}")


@dataclass
class Run:
    """Outcome of one run."""

    fun: float
    nfev: int
    seconds: float
    noi: int
    best: np.ndarray  # best cost so far per iteration
    best_nfev: np.ndarray  # evaluations at the end of each iteration


@dataclass
class Cell:
    """All runs of one method on one function."""

    runs: list[Run] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        """JSON-ready statistics: mean, std (ddof = 1), evaluations and seconds per run, ..."""
        f = np.array([r.fun for r in self.runs])
        return {
            "mean": float(np.mean(f)),
            "std": float(np.std(f, ddof=1)) if f.size > 1 else 0.0,
            "median": float(np.median(f)),
            "min": float(np.min(f)),
            "max": float(np.max(f)),
            "nfev": float(np.mean([r.nfev for r in self.runs])),
            "seconds": float(np.mean([r.seconds for r in self.runs])),
            "noi_median": float(np.median([r.noi for r in self.runs])),
            "runs": int(f.size),
            "failed_runs": int(np.sum(~np.isfinite(f))),
        }

    def convergence(self, f_min: float) -> dict[str, list[float]]:
        """Median and quartiles of ``best - f_min`` per iteration, against evaluations."""
        n = min(r.best.size for r in self.runs)
        curves = np.array([r.best[:n] for r in self.runs]) - f_min
        q25, med, q75 = np.percentile(curves, [25, 50, 75], axis=0)
        return {
            "nfev": [int(v) for v in self.runs[0].best_nfev[:n]],
            "median": med.tolist(),
            "q25": q25.tolist(),
            "q75": q75.tolist(),
        }


def _seed(settings: StudySettings, f_index: int, run: int, k: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(settings.seed, spawn_key=(f_index, run, k))


def make_problem(
    settings: StudySettings, key: str, run: int, shifted: bool
) -> tuple[Benchmark, np.random.SeedSequence]:
    """The benchmark of run ``run`` (noise and shift seeded) and the optimiser's seed."""
    fi = BENCHMARK_KEYS.index(key)
    bench = get_benchmark(
        key,
        seed=_seed(settings, fi, run, 1),
        shift_seed=_seed(settings, fi, run, 2) if shifted else None,
    )
    return bench, _seed(settings, fi, run, 0)


def iterations_for_budget(
    method: str, options: dict[str, Any], pop_size: int, dim: int, budget: int
) -> int:
    """Iterations of ``method`` whose evaluations (initialisation included) fit in ``budget``."""
    probe = make_optimiser(
        method, [(0.0, 1.0)] * dim, pop_size, max_iter=None, max_nfev=budget, options=options
    )
    return probe.max_iter


def run_method(
    bench: Benchmark,
    method: str,
    options: dict[str, Any],
    pop_size: int,
    max_iter: int,
    seed: np.random.SeedSequence,
) -> Run:
    """One run of one of our optimisers on a vectorised benchmark."""
    t0 = time.perf_counter()
    res = minimize(
        bench,
        bench.bounds,
        method=method,
        pop_size=pop_size,
        max_iter=max_iter,
        seed=seed,
        vectorized=True,
        options=options,
        record_diversity=False,
    )
    seconds = time.perf_counter() - t0
    h = res.history
    return Run(
        float(res.fun),
        int(res.nfev),
        seconds,
        int(res.noi),
        np.asarray(h.best),
        np.asarray(h.nfev),
    )


def run_scipy_de(
    bench: Benchmark, pop_size: int, max_iter: int, seed: np.random.SeedSequence
) -> Run:
    """SciPy's ``differential_evolution`` (its defaults, best1bin) at ``pop_size * (max_iter + 1)``
    evaluations.

    The initial population is a Latin hypercube of exactly ``pop_size`` points; polishing and
    the convergence test are off, so the whole budget is spent.
    """
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    lo = np.full(bench.dim, bench.lower)
    hi = np.full(bench.dim, bench.upper)
    init = qmc.scale(qmc.LatinHypercube(d=bench.dim, rng=rng).random(pop_size), lo, hi)
    best: list[float] = []
    nfev: list[int] = []

    def cost(x: np.ndarray) -> np.ndarray:
        # SciPy passes (d, S) when vectorized; non-finite costs become worst, as in our core
        f = bench(x.T)
        f = np.where(np.isfinite(f), f, np.inf)
        best.append(min(best[-1] if best else np.inf, float(np.min(f))))
        nfev.append((nfev[-1] if nfev else 0) + f.shape[0])
        return f

    res = differential_evolution(
        cost,
        list(zip(lo, hi, strict=True)),
        maxiter=max_iter,
        init=init,
        tol=0.0,
        atol=0.0,
        polish=False,
        updating="deferred",
        vectorized=True,
        rng=rng,
    )
    curve = np.asarray(best)
    # SciPy's own nfev counts calls when vectorized; count points instead
    return Run(
        float(res.fun),
        nfev[-1],
        time.perf_counter() - t0,
        noi(curve),
        curve,
        np.asarray(nfev),
    )


def table_rows(
    settings: StudySettings, table: str
) -> list[tuple[bool, str, list[tuple[str, str, dict[str, Any]]]]]:
    """Rows of ``table`` for one function: (shifted?, row suffix, [(column, method, options)])."""
    if table == "variants":
        entries = [(name, m, o) for name, (m, o) in VARIANTS.items()]
        return [(False, "", entries), (True, "_shifted", entries)]
    entries = [(m, m, PAPER_OPTIONS.get(m, {})) for m in settings.methods]
    if settings.scipy_reference:
        entries.append(("scipy_de", "scipy_de", {}))
    return [(table.startswith("shifted"), "", entries)]


def run_function(settings: StudySettings, key: str) -> dict[str, dict[str, dict[str, Cell]]]:
    """Every table's rows for one function: ``{table: {row: {column: Cell}}}``.

    A run is made once and shared by every table that needs it: for example GWO at the equal
    budget runs the same 100 iterations as in the paper's protocol, and SciPy's DE always runs
    at the equal budget.
    """
    memo: dict[tuple[Any, ...], Run] = {}
    dim = get_benchmark(key).dim
    out: dict[str, dict[str, dict[str, Cell]]] = {}
    for table in settings.tables:
        equal_budget = table not in ("results", "shifted")
        out[table] = {}
        for shifted, suffix, entries in table_rows(settings, table):
            row: dict[str, Cell] = {}
            for column, method, opts in entries:
                if method == "scipy_de":
                    iters = settings.max_iter
                elif equal_budget:
                    iters = iterations_for_budget(
                        method, opts, settings.pop_size, dim, settings.budget
                    )
                else:
                    iters = settings.max_iter
                cell = Cell()
                for run in range(settings.runs):
                    mkey = (method, tuple(sorted(opts.items())), iters, shifted, run)
                    if mkey not in memo:
                        bench, seed = make_problem(settings, key, run, shifted)
                        if method == "scipy_de":
                            memo[mkey] = run_scipy_de(bench, settings.pop_size, iters, seed)
                        else:
                            memo[mkey] = run_method(
                                bench, method, opts, settings.pop_size, iters, seed
                            )
                    cell.runs.append(memo[mkey])
                row[column] = cell
            out[table][key + suffix] = row
    return out


def run_study(
    settings: StudySettings,
    progress: Callable[[str], None] | None = None,
    jobs: int = 1,
    executor: Executor | None = None,
) -> dict[str, Any]:
    """Run every table of ``settings`` and return the JSON-ready report.

    Parameters
    ----------
    settings : StudySettings
        What to run.
    progress : callable, optional
        Called with a line of text after each function.
    jobs : int
        Worker processes (one function per task); 1 runs everything in this process.
    executor : concurrent.futures.Executor, optional
        Run the functions there instead (one job each; e.g. a Dask cluster's executor);
        overrides ``jobs``. Every run is seeded, so the report is the same.

    Returns
    -------
    dict
        ``settings``; one key per table (``results``, ``equal_budget``, ``shifted``, ...), each
        ``{function: {method: {"mean", "std", "nfev", "seconds", ...}}}``; ``published`` (the
        paper's Table 2); ``timing`` (wall seconds in total and per function); ``convergence``
        (median and quartiles of ``best - f_min`` against evaluations, per table, function and
        method).
    """
    jobs = check_int(jobs, "jobs", 1)
    start = time.perf_counter()
    timing: dict[str, Any] = {"per_function": {}}
    if executor is not None:
        per_function = _run_on(executor, settings, progress, start)
    elif jobs == 1:
        per_function = _run_here(settings, progress, start, timing["per_function"])
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            per_function = _run_on(pool, settings, progress, start)
    timing["total"] = time.perf_counter() - start
    timing["jobs"] = jobs if executor is None else type(executor).__name__
    return _study_report(settings, per_function, timing)


#: One function's tables: ``{table: {row: {method: Cell}}}`` (:func:`run_function`).
_FunctionTables = dict[str, dict[str, dict[str, Cell]]]


def _say_done(progress: Callable[[str], None] | None, key: str, start: float) -> None:
    """The progress line after function ``key`` (wall seconds since ``start``)."""
    if progress is not None:
        progress(f"{key} done ({time.perf_counter() - start:.1f} s)")


def _run_on(executor: Executor, settings: StudySettings,
            progress: Callable[[str], None] | None, start: float) -> dict[str, _FunctionTables]:
    """Every function of ``settings`` as one task each on ``executor``, in order."""
    futures = {key: executor.submit(run_function, settings, key) for key in settings.functions}
    per_function: dict[str, _FunctionTables] = {}
    for key, fut in futures.items():
        per_function[key] = fut.result()
        _say_done(progress, key, start)
    return per_function


def _run_here(settings: StudySettings, progress: Callable[[str], None] | None, start: float,
              seconds: dict[str, float]) -> dict[str, _FunctionTables]:
    """Every function of ``settings`` in this process; each one's wall time goes to
    ``seconds``."""
    per_function: dict[str, _FunctionTables] = {}
    for key in settings.functions:
        t0 = time.perf_counter()
        per_function[key] = run_function(settings, key)
        seconds[key] = time.perf_counter() - t0
        _say_done(progress, key, start)
    return per_function


def _study_report(settings: StudySettings, per_function: dict[str, _FunctionTables],
                  timing: dict[str, Any]) -> dict[str, Any]:
    """The JSON-ready report of :func:`run_study` from each function's tables."""
    report: dict[str, Any] = {
        "settings": {
            **asdict(settings),
            "budget": settings.budget,
            "paper_options": PAPER_OPTIONS,
            "variants": {k: {"method": m, "options": o} for k, (m, o) in VARIANTS.items()},
            "std": "sample standard deviation (ddof=1) over runs",
            "noi": "first iteration whose best cost is within 0.1 % of the run's final best",
            "nfev": "objective evaluations per run (mean over runs)",
            "seconds": "wall time per run (mean over runs)",
        },
        "published": {
            f: {m: {"mean": v[0], "std": v[1]} for m, v in row.items()}
            for f, row in PUBLISHED.items()
        },
        "timing": timing,
        "convergence": {},
    }
    for table in settings.tables:
        report[table] = {}
        report["convergence"][table] = {}
        for key in settings.functions:
            f_min = get_benchmark(key).f_min
            for row_key, row in per_function[key][table].items():
                report[table][row_key] = {m: c.summary() for m, c in row.items()}
                report["convergence"][table][row_key] = {
                    m: c.convergence(f_min) for m, c in row.items()
                }
    return report


def _fmt(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return str(v)
    if v == 0.0:
        return "0"
    if 1e-3 <= abs(v) < 1e4:
        return f"{v:.6g}"
    return f"{v:.3e}"


def format_table(report: dict[str, Any], table: str) -> str:
    """A markdown table of one section of ``report`` (with the paper's values for ``results``)."""
    cells = report[table]
    with_paper = table == "results"
    head = ["f", "method", "mean", "std"]
    if with_paper:
        head += ["paper mean", "paper std"]
    head += ["nfev/run", "s/run", "NOI median"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for f, row in cells.items():
        for m, s in row.items():
            vals = [f, METHOD_LABELS.get(m, m), _fmt(s["mean"]), _fmt(s["std"])]
            if with_paper:
                pub = PUBLISHED.get(f, {}).get(m)
                vals += [_fmt(pub[0]), _fmt(pub[1])] if pub else ["", ""]
            vals += [f"{s['nfev']:.0f}", f"{s['seconds'] * 1e3:.1f} ms", _fmt(s["noi_median"])]
            lines.append("| " + " | ".join(vals) + " |")
    return "\n".join(lines)


def format_report(report: dict[str, Any], tables: Iterable[str] | None = None) -> str:
    """All tables of ``report`` as markdown, each with a heading and its wall time."""
    out = []
    for table in tables or [t for t in TABLES if t in report]:
        out.append(f"### {table}\n\n{format_table(report, table)}\n")
    return "\n".join(out)


def plot_convergence(report: dict[str, Any], table: str, path: str) -> None:
    """Median (line) and inter-quartile band of ``best - f_min`` against evaluations.

    One panel per function, log scale, values below 1e-30 (exact zeros too) drawn at 1e-30;
    written to ``path`` (format from its suffix).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conv = report["convergence"][table]
    keys = list(conv)
    ncol = min(3, len(keys))
    nrow = math.ceil(len(keys) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.2 * nrow), squeeze=False)
    for ax, key in zip(axes.flat, keys, strict=False):
        for m, c in conv[key].items():
            x = np.asarray(c["nfev"])
            floor = 1e-30  # log axis: smaller values (exact zeros too) are drawn at the floor
            med = np.maximum(np.asarray(c["median"]), floor)
            ax.plot(x, med, label=METHOD_LABELS.get(m, m))
            ax.fill_between(x, np.maximum(c["q25"], floor), np.maximum(c["q75"], floor), alpha=0.2)
        ax.set_yscale("log")
        ax.set_title(key)
        ax.set_xlabel("evaluations")
        ax.set_ylabel("best - f_min")
    for ax in list(axes.flat)[len(keys) :]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"{table}: median and inter-quartile range over runs")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def plot_paths(path: str | Path, tables: Iterable[str]) -> dict[str, Path]:
    """Convergence-plot file per table: ``path`` for the first, ``<stem>_<table><suffix>`` after.

    The ``variants`` table has no plot.
    """
    path = Path(path)
    out: dict[str, Path] = {}
    for table in tables:
        if table == "variants":
            continue
        out[table] = path if not out else path.with_name(f"{path.stem}_{table}{path.suffix}")
    return out


def check_outputs(paths: dict[str, Path | None], overwrite: bool) -> None:
    """Refuse to replace existing files unless ``overwrite``.

    Raises
    ------
    ParameterError
        Naming the option whose file exists.
    """
    for name, p in paths.items():
        if p is not None:
            figure = name.startswith("plot")  # plot_convergence's files go to savefig
            check_output_path(p, overwrite=overwrite, what=name,
                              suffixes=FIGURE_SUFFIXES if figure else None)


def write_json(report: dict[str, Any], path: str | Path, overwrite: bool = False) -> None:
    """Write ``report`` as strict JSON (``NaN``/``inf`` as ``null``)."""
    check_outputs({"json": Path(path)}, overwrite)
    # Strict JSON: non-finite floats become null (failed runs are counted in the cells).
    atomic_write_text(path, json.dumps(jsonable(report), indent=1) + "\n")


def run_and_write(
    settings: StudySettings,
    *,
    json_path: str | Path | None = None,
    plot_path: str | Path | None = None,
    markdown_path: str | Path | None = None,
    overwrite: bool = False,
    jobs: int = 1,
    progress: Callable[[str], None] | None = None,
    executor: Executor | None = None,
) -> tuple[dict[str, Any], str]:
    """Run the study and write its outputs; returns the report and its markdown text.

    Every output path is checked before anything runs: an existing file is an error unless
    ``overwrite``. Plots: see :func:`plot_paths`. The markdown ends with a line giving the
    settings and the total wall time.

    Raises
    ------
    ParameterError
        On bad settings or an existing output file without ``overwrite``.
    """
    plots = plot_paths(plot_path, settings.tables) if plot_path else {}
    check_outputs(
        {
            "json": Path(json_path) if json_path else None,
            "markdown": Path(markdown_path) if markdown_path else None,
            **{f"plot ({t})": p for t, p in plots.items()},
        },
        overwrite,
    )
    report = run_study(settings, progress=progress, jobs=jobs, executor=executor)
    text = format_report(report) + (
        f"\n{settings.runs} runs per cell, population {settings.pop_size}, "
        f"{settings.max_iter} iterations, seed {settings.seed}; "
        f"total {report['timing']['total']:.1f} s with "
        f"{jobs if executor is None else type(executor).__name__} job(s)\n"
    )
    if markdown_path:
        atomic_write_text(markdown_path, text)
    if json_path:
        write_json(report, json_path, overwrite=True)  # checked above
    for table, path in plots.items():
        plot_convergence(report, table, str(path))
    return report, text
