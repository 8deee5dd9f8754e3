"""Reports of comparisons: JSON files, Markdown tables, statistics over several runs.

Everything here works on the JSON report (:meth:`hhra_phys.compare.Comparison.to_dict`, layout:
:mod:`hhra_phys.compare`), so it applies as well to reports read back from files.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.compare.registry import method_label
from hhra_phys.errors import ParameterError
from hhra_phys.metrics import KEYS
from hhra_phys.outputs import atomic_write_text, check_output_path, jsonable

__all__ = ["PAPER_TABLE3", "aggregate", "markdown_summary", "markdown_table", "write_json"]

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


def write_json(report: Mapping[str, Any], path: str | Path, overwrite: bool = False) -> Path:
    """Write a report (or any JSON-able mapping) as indented JSON.

    Raises
    ------
    ParameterError
        If ``path`` exists and ``overwrite`` is False.
    """
    p = check_output_path(path, overwrite=overwrite, what="JSON report")
    text = json.dumps(jsonable(report, default=str), indent=1, allow_nan=False) + "\n"
    atomic_write_text(p, text)
    return p


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
            cells = [method_label(name), f"failed: {m['error']}"] + [""] * (len(head) - 2)
            lines.append("| " + " | ".join(cells) + " |")
            continue
        e, v = m["est"], m["val"]
        row = [
            method_label(name),
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
    return "\n".join(lines) + "\n" + note + "\n" + _records_table(report)


def _records_table(report: Mapping[str, Any]) -> str:
    """Per-record validation scores of a comparison of several records ("" for one)."""
    recs = report.get("records")
    if not recs:
        return ""
    names = [r["name"] for r in recs]
    head = ["method"] + [f"{n}: val RMSE" for n in names] + [f"{n}: val VAF %" for n in names]
    lines = ["", f"{len(recs)} records, each split by {report.get('split')}; the table above "
             "pools their samples (ITAE: the sum of the records'). Per record:", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, m in report["methods"].items():
        if m.get("error") or not m.get("records"):
            continue
        row = [method_label(name)] + [_fmt(r["val"]["rmse"]) for r in m["records"]] + [
            _fmt(r["val"]["vaf"]) for r in m["records"]]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


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
            method_label(name),
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
