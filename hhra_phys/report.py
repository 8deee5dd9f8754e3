"""The diagnosis loop's report: a Markdown file and its residual figures (a fit's report is
:mod:`hhra_phys.fit_report`).

:func:`loop_report` writes what ``hhra-phys diagnose --report`` writes, from Python:
the Markdown text (:func:`markdown_report`: the data split and rule, the error before
and after, every candidate tried, the first round's evidence, the accepted effects
with their intervals, the warnings, the discovered terms) and, beside it, the
residual figures before and after (:func:`~hhra_phys.diagnosis.plots.plot_loop_residuals`)
and, when discovery built terms, before and after each term
(:func:`~hhra_phys.diagnosis.plots.plot_discovery`).
:meth:`hhra_phys.diagnosis.result.DiagnosisResult.report` calls it; the CLI calls that.

The module reads a loop's result by its attributes (``settings``, ``steps``,
``chosen``, ``base``, ``final``, ``diagnoses``, ...) and imports nothing of
:mod:`hhra_phys.diagnosis`, so the loop can offer the report without an import cycle.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hhra_phys.errors import ParameterError
from hhra_phys.outputs import FIGURE_SUFFIXES, atomic_write_text, check_output_path
from hhra_phys.outputs import format_metric as _fmt  # one formatter for every number written

__all__ = ["figure_paths", "loop_report", "markdown_report"]

#: Labels of the report's figures, in the order of :func:`figure_paths`.
FIGURE_LABELS = ("before", "after", "before and after the discovered terms")


def figure_paths(path: str | Path, discover: bool = True) -> list[str]:
    """The figure files of a report at ``path``: ``<stem>_before.png``,
    ``<stem>_after.png`` and, with discovery, ``<stem>_discovery.png``, beside it."""
    stem = Path(path).with_suffix("")
    figs = [f"{stem}_before.png", f"{stem}_after.png"]
    if discover:
        figs.append(f"{stem}_discovery.png")
    return figs


def loop_report(res: Any, path: str | Path, data: Any = None, overwrite: bool = False
                ) -> Path:
    """Write the Markdown report of a diagnosis loop and its figures.

    Parameters
    ----------
    res : DiagnosisResult
        What :func:`hhra_phys.diagnosis.engine.augment` returned.
    path : str or path-like
        The Markdown file (``.md``); the figures go beside it (:func:`figure_paths`).
    data : Dataset or sequence of Dataset, optional
        The record(s) the loop ran on (default: ``res.data``, which
        :func:`~hhra_phys.diagnosis.engine.augment` keeps).
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
        Without the record(s): a result that does not keep them and no ``data``.
    OutputExistsError, OutputPathError
        A file exists (and not ``overwrite``) or cannot be written.
    """
    data = data if data is not None else getattr(res, "data", None)
    if data is None:
        raise ParameterError("report: the loop's record(s) are needed for the residual "
                             "figures; pass data= (this result does not keep them)")
    found = [s for s in res.steps if getattr(s, "residuals", None)]
    figs = figure_paths(path, discover=bool(found))
    p = check_output_path(path, overwrite=overwrite, what="report")
    for f in figs:
        check_output_path(f, overwrite=overwrite, what="report's figure",
                          suffixes=FIGURE_SUFFIXES)
    from hhra_phys.diagnosis.plots import plot_loop_residuals

    paths = list(plot_loop_residuals(res, data, figs[0], figs[1], overwrite))
    if found:
        from hhra_phys.diagnosis.plots import plot_discovery

        paths.append(plot_discovery(found, figs[2], overwrite))
    atomic_write_text(p, markdown_report(res, paths, str(p)))
    return p



def markdown_report(res: Any, figures: Sequence[str | None], report_path: str | Path) -> str:
    """The Markdown text of a :class:`~hhra_phys.diagnosis.result.DiagnosisResult`'s report.

    ``figures`` are the before, after and discovery figures (``None`` where not
    drawn), linked relative to the report's folder when they are inside it.
    """
    out = res.to_json()
    lines = _header(res)
    lines += _errors(out)
    if res.skipped.get("discovery"):
        lines += ["", f"Discovery skipped: {res.skipped['discovery']}."]
    lines += _tried(res)
    lines += _evidence(res)
    lines += _accepted(res)
    if res.warnings or res.final.warnings:
        lines += ["## Warnings", ""] + [f"- {w}" for w in res.warnings + res.final.warnings]
    lines += discovery_section(res)
    lines += _figures(figures, report_path)
    return "\n".join(lines) + "\n"


def _header(res: Any) -> list[str]:
    ds, st = res.settings["data"], res.settings
    return [f"# Residual diagnosis of {ds['name'] or 'the record'}", "",
            f"{ds['n']} samples: estimation {ds.get('n_est')}, selection {ds.get('n_sel')}, "
            f"test {ds.get('n_test')} (the test part chooses nothing; 'val' is the selection "
            f"part), seed {st['seed']}; accept an effect when the selection RMSE "
            f"falls by {100 * st['margin']:.0f} % or more, by more than the noise "
            f"allowance (noise_tol {_tol(st.get('noise_tol'))}), and "
            f"{st['criterion'].upper()} on estimation agrees. Stopped: "
            f"{st.get('stop')}.", "",
            f"**Chosen effects:** {', '.join(res.chosen) or 'none'}", ""]


def _tol(value: Any) -> str:
    """The noise tolerance as printed: three digits (it is derived from the record's length)."""
    return f"{value:.3g}" if isinstance(value, (int, float)) else str(value)


def _errors(out: dict[str, Any]) -> list[str]:
    """The table of errors before and after, and per record with several."""
    lines = ["## Error before and after", "",
             "| part | model | RMSE | VAF [%] | MSE | ITAE |", "|---|---|---|---|---|---|"]
    for part in ("est", "val", "test"):
        for key in ("base", "final"):
            if part not in out[key]:
                continue
            m = out[key].get(part, {})
            lines.append(f"| {part} | {key} | {_fmt(m.get('rmse'))} | {_fmt(m.get('vaf'))} | "
                         f"{_fmt(m.get('mse'))} | {_fmt(m.get('itae'))} |")
    if not out["final"].get("records"):
        return lines
    lines += ["", "Per record (the rows above pool all records' samples):", "",
              "| record | part | base RMSE | final RMSE |", "|---|---|---|---|"]
    for rb, rf in zip(out["base"]["records"], out["final"]["records"], strict=True):
        lines += [f"| {rf['name']} | {part} | {_fmt(rb[part]['rmse'])} | "
                  f"{_fmt(rf[part]['rmse'])} |"
                  for part in ("est", "sel", "test") if rf[part].get("rmse") is not None]
    return lines


def _tried(res: Any) -> list[str]:
    """Every candidate tried, with its evidence and verdict."""
    lines = ["", "## Effects tried", "",
             "| round | effect | evidence score | detectability | val RMSE before -> after | "
             "accepted | notes |", "|---|---|---|---|---|---|---|"]
    for s in res.steps:
        ev = s.evidence
        notes = "; ".join(s.notes) or ""
        lines.append(f"| {s.round} | {s.effect} | {_fmt(ev.get('score'), '.3g')} | "
                     f"{_fmt(ev.get('detectability'), '.3g')} | {_fmt(s.val_rmse_before)} -> "
                     f"{_fmt(s.val.get('rmse'))} | {'yes' if s.accepted else 'no'} | "
                     f"{s.reason}{'; ' + notes if notes else ''} |")
    return lines


def _evidence(res: Any) -> list[str]:
    """The first round's diagnosis of the base model."""
    if not res.diagnoses:
        return []
    lines = ["", "## Evidence of the first round (base model)", "", "```",
             res.diagnoses[0].summary(), "```", ""]
    for e in res.diagnoses[0].ranked():
        regs = ", ".join(f"{k} r={v:.2f}" for k, v in e.regressors.items())
        lines.append(f"- **{e.name}**: {e.signature}. Regressors: {regs or '-'}."
                     f"{' ' + e.note if e.note else ''}")
    return lines


def _accepted(res: Any) -> list[str]:
    """Each accepted effect's parameters with their final values and intervals."""
    lines = ["", "## Accepted effects", ""]
    if not res.chosen:
        lines.append("None: no candidate lowered the validation error clearly with the "
                     "information criterion agreeing.")
    for s in res.steps:
        if not s.accepted:
            continue
        lines += [f"### {s.effect}", "", "| parameter | value | 95 % CI |", "|---|---|---|"]
        for n in s.params:
            v = res.final.values.get(n, s.params[n])
            ci = res.final.ci95.get(n, (math.nan, math.nan))
            lines.append(f"| {n} | {_fmt(v)} | [{_fmt(ci[0])}, {_fmt(ci[1])}] |")
        lines.append("")
    return lines


def _figures(figures: Sequence[str | None], report_path: str | Path) -> list[str]:
    """Links to the figures, relative to the report's folder when inside it."""
    lines = ["", "## Residual plots", ""]
    base = Path(report_path).parent.resolve()
    for label, p in zip(FIGURE_LABELS, figures, strict=False):
        if p:
            full = Path(p).resolve()
            rel = full.relative_to(base) if full.is_relative_to(base) else Path(p)
            lines += [f"![residual {label}]({rel})", ""]
    return lines


def discovery_section(res: Any) -> list[str]:
    """Markdown lines on the discovered terms tried (expression, CIs, verdict); none if off."""
    if not res.settings.get("discover", False):
        return []
    found = [s for s in res.steps if hasattr(s, "expression")]
    lines = ["", "## Discovered terms (outside the library)", ""]
    if not found:
        return lines + ["Discovery ran; no entry point gave a term that survived its sparse refit.",
                        ""]
    lines += ["| term | expression | same physics as | uses | selection RMSE before -> after "
              "| accepted | notes |",
              "|---|---|---|---|---|---|---|"]
    for s in found:
        notes = "; ".join(n for n in s.notes if "outside the range" in n)
        twins = ", ".join(f"{n} (discovered form)" for n in getattr(s, "same_as", ()))
        lines.append(f"| {s.effect} | `{s.expression}` | {twins or '-'} | {', '.join(s.uses)} | "
                     f"{_fmt(s.val_rmse_before)} -> {_fmt(s.val.get('rmse'))} | "
                     f"{'yes' if s.accepted else 'no'} | {s.reason}"
                     f"{'; ' + notes if notes else ''} |")
    for s in found:
        lines += ["", f"### {s.effect} ({s.entry}, {s.method})", "", f"`{s.expression}`", "",
                  "| parameter | value | 95 % CI |", "|---|---|---|"]
        for n, v in s.params.items():
            ci = s.ci95.get(n, (math.nan, math.nan))
            lines.append(f"| {n} | {_fmt(v)} | [{_fmt(ci[0])}, {_fmt(ci[1])}] |")
        # A term's notes tell its sparse refits; a resonant mode's its starts and checks.
        label = "Refits" if "period" in (s.screening or {}) else "Sparse refits"
        lines += ["", f"{label}: " + "; ".join(n for n in s.notes
                                                if "outside the range" not in n)]
    lines += ["", "Residual plots: before (base model) and after (every accepted effect and "
              "term), and the residual just before and after each discovered term (estimation "
              "and selection), are in the section below."]
    return lines + [""]
