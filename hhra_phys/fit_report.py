"""A fit's report: a Markdown file and the fit's figure.

:func:`fit_report` writes what ``hhra-phys fit --report`` writes (the parameters with their
intervals, the derived quantities, the errors, the warnings and the fit's figure,
:func:`~hhra_phys.plots.plot_fit`); :meth:`hhra_phys.result.FitResult.report` calls it.
Apart from :mod:`hhra_phys.report` (the diagnosis loop's), which imports the diagnosis: a
fit's result reaches this one without it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hhra_phys.errors import ParameterError
from hhra_phys.outputs import FIGURE_SUFFIXES, atomic_write_text, check_output_path
from hhra_phys.outputs import format_metric as _fmt  # one formatter for every number written

__all__ = ["fit_figure_path", "fit_markdown", "fit_report"]



def fit_figure_path(path: str | Path) -> str:
    """The figure of a fit report at ``path``: ``<stem>_fit.png`` beside it."""
    return f"{Path(path).with_suffix('')}_fit.png"


def fit_report(res: Any, path: str | Path, data: Any, overwrite: bool = False) -> Path:
    """Write the Markdown report of a fit and its figure (:func:`fit_figure_path`).

    Parameters
    ----------
    res : FitResult
        The fit (:func:`hhra_phys.fit`).
    path : str or path-like
        The Markdown file (``.md``); the figure ``<stem>_fit.png`` goes beside it.
    data : Dataset or sequence of Dataset
        The record(s) the fit ran on: one record is drawn as its estimation and validation
        parts (the fit's estimation length), several each whole (a result does not keep
        its records).
    overwrite : bool
        Replace existing files (by default an existing report or figure is refused
        before anything is drawn).

    Returns
    -------
    pathlib.Path
        The report written.

    Raises
    ------
    ParameterError
        No record, or one that is not the fit's (its length differs from the fit's).
    OutputExistsError, OutputPathError
        A file exists (and not ``overwrite``) or cannot be written.
    """
    from hhra_phys.plots import plot_fit

    parts = _fit_parts(res, data)
    fig = fit_figure_path(path)
    p = check_output_path(path, overwrite=overwrite, what="report")
    check_output_path(fig, overwrite=overwrite, what="report's figure",
                      suffixes=FIGURE_SUFFIXES)
    drawn = plot_fit(fig, [(label, ds, res.predict(ds)) for label, ds in parts], res.history,
                     title=f"fit of {_records_name(data)}", overwrite=overwrite,
                     stages=res.stages)
    atomic_write_text(p, fit_markdown(res, drawn, p))
    return p


def _records_name(data: Any) -> str:
    """The figure's name of the record(s) a fit ran on."""
    if isinstance(data, (list, tuple)):
        return f"{len(data)} records"
    return data.name or data.source or "the record"


def _fit_parts(res: Any, data: Any) -> list[tuple[str, Any]]:
    """``(label, record)`` to draw: one record's estimation and validation parts, or each
    of several records whole."""
    if data is None:
        raise ParameterError("report: the fit's record(s) are needed for the figure; pass "
                             "data= (a fit result does not keep them)")
    if isinstance(data, (list, tuple)):
        return [(ds.name or f"record {i + 1}", ds) for i, ds in enumerate(data)]
    info = res.settings.get("data")
    info = info if isinstance(info, dict) else {}
    n, n_est = int(info.get("n", len(data))), int(info.get("n_est", len(data)))
    if n != len(data):
        raise ParameterError(f"report: data has {len(data)} samples, the fit was made on a "
                             f"record of {n}: pass the record the fit ran on")
    if 0 < n_est < len(data):
        est, val = data.split_at(n_est)
        return [("estimation", est), ("validation", val)]
    return [("estimation", data)]


def fit_markdown(res: Any, figure: str | Path | None, report_path: str | Path) -> str:
    """The Markdown text of a :class:`~hhra_phys.result.FitResult`'s report."""
    st = res.settings
    info = st.get("data") if isinstance(st.get("data"), dict) else {}
    name = info.get("name") or "the record"
    refine = st.get("refine") or "none"
    refine = " then ".join(refine) if isinstance(refine, (list, tuple)) else refine
    lines = [f"# Fit of {name}", "",
             f"Model {res.model.name}; {st.get('optimizer', '-')} (population "
             f"{st.get('pop_size', '-')}, {st.get('max_iter', '-')} iterations) then {refine}, "
             f"seed {res.seed}; status {res.status}.", ""]
    if info:
        lines += [f"{info.get('n')} samples: estimation {info.get('n_est')}, validation "
                  f"{info.get('n_val')}.", ""]
    lines += ["## Parameters", "", "| parameter | value | unit | 95 % CI | free |",
              "|---|---|---|---|---|"]
    for pname, est in res.params.items():
        ci = est["ci95"]
        ci_text = "-" if not ci else f"[{_fmt(ci[0], '.6g')}, {_fmt(ci[1], '.6g')}]"
        lines.append(f"| {pname} | {_fmt(est['value'], '.6g')} | {est['unit']} | {ci_text} | "
                     f"{'yes' if est['free'] else 'no'} |")
    if res.derived:
        lines += ["", "## Derived quantities", "", "| quantity | value | unit | 95 % CI |",
                  "|---|---|---|---|"]
        for qname, q in res.derived.items():
            ci = q.ci95
            ci_text = "-" if ci is None else f"[{_fmt(ci[0], '.6g')}, {_fmt(ci[1], '.6g')}]"
            lines.append(f"| {qname} | {_fmt(q.value, '.6g')} | {q.unit} | {ci_text} |")
    lines += ["", "## Errors", "", "| part | RMSE | VAF [%] | MSE | ITAE |",
              "|---|---|---|---|---|"]
    for part, label in (("est", "estimation"), ("val", "validation")):
        m = res.metrics.get(part) or {}
        if m:
            lines.append(f"| {label} | {_fmt(m.get('rmse'))} | {_fmt(m.get('vaf'))} | "
                         f"{_fmt(m.get('mse'))} | {_fmt(m.get('itae'))} |")
    if res.warnings:
        lines += ["", "## Warnings", ""] + [f"- {w}" for w in res.warnings]
    if figure:
        base = Path(report_path).parent.resolve()
        full = Path(figure).resolve()
        rel = full.relative_to(base) if full.is_relative_to(base) else Path(figure)
        lines += ["", "## Figure", "", f"![fit]({rel})"]
    return "\n".join(lines) + "\n"
