"""Figures: measured against simulated output, residuals, convergence.

Matplotlib with the non-interactive Agg backend, so plots work on machines
without a display; every function writes a PNG and returns its path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hhra_phys.data import Dataset  # noqa: E402
from hhra_phys.outputs import FIGURE_SUFFIXES, atomic_path, check_output_path  # noqa: E402

__all__ = [
    "plot_fit",
    "plot_outputs",
]


def plot_fit(
    path: str | Path,
    parts: Sequence[tuple[str, Dataset, np.ndarray]],
    history: Sequence[float] | None = None,
    title: str = "",
    overwrite: bool = False,
) -> Path:
    """Measured and simulated output per record part, residuals, and convergence.

    Parameters
    ----------
    path : str or Path
        PNG file to write.
    parts : sequence of (label, Dataset, simulated output)
        E.g. ``[("estimation", est, y_est), ("validation", val, y_val)]``.
    history : sequence of float, optional
        Best cost per iteration of the global search.
    title : str
        Figure title.
    overwrite : bool
        Replace an existing file.
    """
    p = check_output_path(path, overwrite=overwrite, what="figure", suffixes=FIGURE_SUFFIXES)
    rows = 3 if history else 2
    fig, axes = plt.subplots(rows, 1, figsize=(10, 2.6 * rows + 0.6))
    ax_y, ax_r = axes[0], axes[1]
    for label, ds, y_sim in parts:
        ax_y.plot(ds.t, ds.y, lw=0.8, label=f"measured ({label})")
        ax_y.plot(ds.t, y_sim, lw=0.8, ls="--", label=f"model ({label})")
        ax_r.plot(ds.t, ds.y - y_sim, lw=0.6, label=label)
    ds0 = parts[0][1]
    unit = "samples" if ds0.metadata.get("time_unit") == "samples" else "s"
    ax_y.set_ylabel(f"{ds0.output_name} [{ds0.output_unit}]")
    ax_y.legend(fontsize=7, ncol=2)
    ax_r.set_ylabel("residual")
    ax_r.set_xlabel(f"time [{unit}]")
    ax_r.legend(fontsize=7)
    if history:
        ax_h = axes[2]
        ax_h.semilogy(np.arange(len(history)), history)
        ax_h.set_xlabel("iteration")
        ax_h.set_ylabel("best cost")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(p) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return p


def plot_outputs(
    path: str | Path,
    data: Dataset,
    outputs: Mapping[str, np.ndarray],
    title: str = "",
    overwrite: bool = False,
) -> Path:
    """Measured output against several models' simulated outputs on one record."""
    p = check_output_path(path, overwrite=overwrite, what="figure", suffixes=FIGURE_SUFFIXES)
    fig, ax = plt.subplots(figsize=(10, 3.6))
    ax.plot(data.t, data.y, color="k", lw=1.0, label="measured")
    for label, y in outputs.items():
        ax.plot(data.t, y, lw=0.8, ls="--", label=label)
    ax.set_xlabel("time")
    ax.set_ylabel(f"{data.output_name} [{data.output_unit}]")
    ax.legend(fontsize=7, ncol=3)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    with atomic_path(p) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return p
