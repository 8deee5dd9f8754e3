"""Figures of a comparison: measured against simulated outputs, and convergence.

The paper's Figures 10-15 (:func:`plot_outputs`) and 16 (:func:`plot_convergence`).
Matplotlib is imported when a figure is drawn (the :class:`~matplotlib.figure.Figure` API,
no pyplot state), so the rest of the comparison does not need it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.compare.registry import method_label
from hhra_phys.compare.report import _fmt
from hhra_phys.compare.runner import Comparison
from hhra_phys.data import Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.outputs import FIGURE_SUFFIXES, atomic_path, check_output_path

__all__ = ["plot_convergence", "plot_outputs"]


def _save(fig: Any, path: str | Path | None, overwrite: bool, dpi: int) -> None:
    if path is None:
        return
    p = check_output_path(path, overwrite=overwrite, what="figure", suffixes=FIGURE_SUFFIXES)
    with atomic_path(p) as tmp:
        fig.savefig(tmp, dpi=dpi)


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

    if not isinstance(comparison.dataset, Dataset):
        raise ParameterError(
            f"plot_outputs draws one record; this comparison ran on "
            f"{len(comparison.dataset)} records: compare each record on its own to plot it "
            "(per-record scores: the 'records' of comparison.to_dict() and of each method)")
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
            f"{method_label(name)}: val MSE {_fmt(r.val['mse'], 3)}, VAF {_fmt(r.val['vaf'], 4)} %",
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
            label = f"{method_label(name)} (NOI {o.noi})" if len(comps) == 1 else method_label(name)
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
