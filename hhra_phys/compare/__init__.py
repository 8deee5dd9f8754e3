"""The identification comparison of the paper's Table 3 (and Figures 10-16) on one dataset.

Every method is an entry of the registry :data:`METHODS`: a function
``fn(est, val, settings) -> MethodOutcome`` that fits on the estimation part ``est`` and returns
its *free-run simulated* output on both parts. :func:`run_comparison` times each method, scores
both outputs with :func:`hhra_phys.metrics.score` (never a one-step prediction) and collects
everything in a :class:`Comparison`, whose :meth:`~Comparison.to_dict` is the JSON report.
The package's ARX and physical-model rows are registered on import. More methods plug in
with :func:`register_method`, from any module; the CLI imports such modules with
``--plugin MODULE`` and every module named by an entry point of the group
``hhra_phys.compare_methods`` (see :mod:`.registry`, also for name clashes).

Modules:

:mod:`.registry`
    The method contract (:class:`CompareSettings`, :class:`MethodOutcome`), :data:`METHODS`,
    :func:`register_method` and the plug-ins.
:mod:`.arx`
    The built-in ARX rows (the paper's methods) and their initial conditions.
:mod:`.physical`
    The built-in physical-model rows (``phys_*``, fits of :mod:`hhra_phys.fit`).
:mod:`.runner`
    :func:`run_comparison` and :func:`compare`: split, run, time and score.
:mod:`.report`
    JSON files, Markdown tables, statistics over several reports.
:mod:`.plots`
    The figures.

All of their public names are importable from ``hhra_phys.compare``.

JSON layout (outside checks read it; keys are only ever added)::

    {"dataset": str, "split": float | int, "split_index": int, "n_est": int, "n_val": int,
     "time_unit": "s" | "samples", "settings": {...}, "data": {...}, "scoring": {...},
     "methods": {name: {"est": {"mse", "rmse", "vaf", "itae", "fit", "max_abs"},
                        "val": {...}, "noi": int | null, "nfev": int | null, "seconds": float,
                        "diverged": bool, "error": str | null, "info": {...},
                        "convergence": {"best": [...], "nfev": [...]} | null, "paper": {...}}},
     "paper_table3": {...}}

With several records (``compare([ds1, ds2])``, ``hhra-phys compare A.csv B.csv``) the
top-level counts and every method's ``est``/``val`` pool the records (MSE, RMSE, VAF, fit,
max over all samples; ITAE the sum of the records'), and two keys are added:
``"records": [{"name", "source", "n", "fs", "n_est", "n_val"}]`` and per method
``"records": [{"name", "est", "val"}]``. A method that fits one record only has ``error``
set. One record: the layout above, unchanged.

Non-finite numbers (a diverged simulation) and undefined ones (NOI of LS) are JSON ``null``.
"""

from __future__ import annotations

# The built-in rows register on import, ARX first: the report lists methods in that order.
from hhra_phys.compare.arx import ARX_METHODS, arx_outcome
from hhra_phys.compare.physical import ROWS as PHYSICAL_ROWS
from hhra_phys.compare.physical import register as register_physical
from hhra_phys.compare.plots import plot_convergence, plot_outputs
from hhra_phys.compare.registry import (
    ENTRY_POINT_GROUP,
    METHOD_LABELS,
    METHODS,
    CompareSettings,
    MethodFn,
    MethodOutcome,
    available_methods,
    load_plugins,
    method_label,
    register_method,
)
from hhra_phys.compare.report import (
    PAPER_TABLE3,
    _fmt,  # noqa: F401  (experiments/table3.py formats its own tables with it)
    aggregate,
    markdown_summary,
    markdown_table,
    write_json,
)
from hhra_phys.compare.runner import Comparison, MethodResult, compare, run_comparison

__all__ = [
    "ARX_METHODS",
    "ENTRY_POINT_GROUP",
    "METHODS",
    "METHOD_LABELS",
    "PAPER_TABLE3",
    "PHYSICAL_ROWS",
    "CompareSettings",
    "Comparison",
    "MethodFn",
    "MethodOutcome",
    "MethodResult",
    "aggregate",
    "arx_outcome",
    "available_methods",
    "compare",
    "load_plugins",
    "markdown_summary",
    "markdown_table",
    "method_label",
    "plot_convergence",
    "plot_outputs",
    "register_method",
    "register_physical",
    "run_comparison",
    "write_json",
]
