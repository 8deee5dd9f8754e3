"""Figures: measured against simulated output, residuals, convergence.

Matplotlib with the non-interactive Agg backend, so plots work on machines
without a display; every function writes the file it is given (``.png``, ``.svg``,
``.pdf`` ...), atomically, and returns its path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import ticker  # noqa: E402

from hhra_phys.data import Dataset  # noqa: E402
from hhra_phys.outputs import FIGURE_SUFFIXES, atomic_path, check_output_path  # noqa: E402

__all__ = [
    "COST_LABELS",
    "plot_fit",
    "plot_outputs",
]


#: Units of the global-search costs, in terms of the output unit ``{y}`` and time ``{t}``.
COST_LABELS = {
    "itae": "ITAE = sum t |e| dt  [{y} {t}^2]",
    "mse": "MSE  [{y}^2]",
    "rmse": "RMSE  [{y}]",
    "ssr": "sum of squared residuals  [{y}^2]",
}


def _axis(name: str, unit: str) -> str:
    """``name [unit]``, or ``name`` alone for a record with no unit (scale unknown)."""
    return f"{name} [{unit}]" if unit else name


def plot_fit(
    path: str | Path,
    parts: Sequence[tuple[str, Dataset, np.ndarray]],
    history: Sequence[float] | None = None,
    title: str = "",
    overwrite: bool = False,
    *,
    stages: Sequence[Mapping[str, Any]] | None = None,
    zoom: float = 0.02,
) -> Path:
    """Figure of a fit: input, measured and model output, residual, zoom and convergence.

    Panels, on one time axis: the input (its unit), the measured output (black) and the
    model's free-run output (blue, dashed) with the estimation/validation split marked, and
    the residual ``y - y_model`` in the output's unit. Below: a zoom on the stretch of
    ``zoom`` x the record around the largest validation residual (where measured and model
    differ most, and are distinguishable even when they overlap elsewhere), and the
    convergence of every stage: the global search's best cost per iteration (its cost
    named, left axis) and each refiner's least-squares cost from its start to its end
    (right axis).

    Parameters
    ----------
    path : str or Path
        Figure to write (``.png``, ``.svg``, ``.pdf`` ...).
    parts : sequence of (label, Dataset, simulated output)
        E.g. ``[("estimation", est, y_est), ("validation", val, y_val)]``, in time order.
    history : sequence of float, optional
        Best cost per iteration of the global search(es).
    title : str
        Figure title.
    overwrite : bool
        Replace an existing file.
    stages : sequence of dict, optional
        :attr:`FitResult.stages <hhra_phys.result.FitResult.stages>`: names the costs
        and adds the refiners to the convergence panel.
    zoom : float
        Fraction of the record shown in the zoom panel.

    Returns
    -------
    pathlib.Path
    """
    p = check_output_path(path, overwrite=overwrite, what="figure", suffixes=FIGURE_SUFFIXES)
    ds0 = parts[0][1]
    t_unit = "samples" if ds0.time_unit == "samples" else "s"
    y_unit, u_unit = ds0.output_unit, ds0.input_unit
    show_conv = bool(history) or any(st.get("name") for st in stages or ())
    fig = plt.figure(figsize=(11, 10))
    grid = fig.add_gridspec(4, 2, height_ratios=[0.8, 1.3, 0.9, 1.1])
    ax_u = fig.add_subplot(grid[0, :])
    ax_y = fig.add_subplot(grid[1, :], sharex=ax_u)
    ax_r = fig.add_subplot(grid[2, :], sharex=ax_u)
    ax_z = fig.add_subplot(grid[3, 0] if show_conv else grid[3, :])
    measured = {"color": "k", "lw": 0.9}
    model = {"color": "C0", "lw": 0.9, "ls": "--"}
    xs = _time_axes([ds for _, ds, _ in parts])
    for k, ((label, ds, y_sim), x) in enumerate(zip(parts, xs, strict=True)):
        first = k == 0
        ax_u.plot(x, ds.u, color="C2", lw=0.8, label="input" if first else None)
        ax_y.plot(x, ds.y, label="measured" if first else None, **measured)
        ax_y.plot(x, y_sim, label="model (free run)" if first else None, **model)
        rms = float(np.sqrt(np.mean(np.square(ds.y - y_sim))))
        ax_r.plot(x, ds.y - y_sim, color="C3", lw=0.6)
        mid = float(x[0] + x[-1]) / 2
        ax_u.text(mid, 1.0, label, transform=ax_u.get_xaxis_transform(), ha="center",
                  va="bottom", fontsize=9)
        ax_r.text(mid, 0.97, f"{label}: RMSE {rms:.3g} {y_unit}",
                  transform=ax_r.get_xaxis_transform(), ha="center", va="top",
                  fontsize=8 if len(parts) <= 2 else 6.5,
                  bbox={"facecolor": "white", "alpha": 0.8, "lw": 0})
        if not first:
            for ax in (ax_u, ax_y, ax_r):
                ax.axvline(float(x[0]), color="0.3", lw=0.8, ls=":")
                if k % 2:  # alternate parts shaded
                    ax.axvspan(float(x[0]), float(x[-1]), color="C2", alpha=0.06)
    ax_u.set_ylabel(_axis(ds0.input_name, u_unit))
    ax_y.set_ylabel(_axis(ds0.output_name, y_unit))
    ax_r.set_ylabel(_axis("residual y - y_model", y_unit))
    placed = any(x is not ds.t for x, (_, ds, _) in zip(xs, parts, strict=True))
    ax_r.set_xlabel(f"time [{t_unit}]" + (" (records placed end to end)" if placed else ""))
    plt.setp(ax_u.get_xticklabels(), visible=False)
    plt.setp(ax_y.get_xticklabels(), visible=False)

    # Zoom where the model is worst on the last part (validation when there is one).
    label, ds, y_sim = parts[-1]
    x = xs[-1]
    width = max(10, int(zoom * sum(len(d) for _, d, _ in parts)))
    centre = int(np.nanargmax(np.abs(ds.y - y_sim))) if np.isfinite(y_sim).any() else 0
    a = int(np.clip(centre - width // 2, 0, max(0, len(ds) - width)))
    sl = slice(a, a + width)
    ax_z.plot(ds.t[sl], ds.y[sl], marker=".", ms=2.5, label="measured", **measured)
    ax_z.plot(ds.t[sl], y_sim[sl], label="model", **model)
    ax_z.set(xlabel=f"time [{t_unit}]", ylabel=_axis(ds0.output_name, y_unit))
    ax_z.set_title(f"zoom: {label}, around its largest residual", fontsize=9)
    ax_z.legend(fontsize=7)
    ax_y.axvspan(float(x[sl][0]), float(x[sl][-1]), color="C1", alpha=0.35,
                 label="zoomed below")
    ax_y.legend(fontsize=7, loc="upper right")

    if show_conv:
        _convergence(fig.add_subplot(grid[3, 1]), history or [], stages or [], y_unit, t_unit)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(p) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return p


def _time_axes(records: Sequence[Dataset]) -> list[np.ndarray]:
    """Each part's time axis; parts that overlap in time (several records, each from 0)
    are placed end to end instead, so none is drawn over another."""
    ordered = all(b.t[0] >= a.t[-1] for a, b in zip(records, records[1:], strict=False))
    if ordered:
        return [ds.t for ds in records]
    out, end = [], None
    for ds in records:
        x = ds.t - ds.t[0] + (0.0 if end is None else end + ds.dt)
        out.append(x)
        end = float(x[-1])
    return out


def _convergence(
    ax: Any, history: Sequence[float], stages: Sequence[Mapping[str, Any]], y_unit: str,
    t_unit: str,
) -> None:
    """Global search best cost per iteration (left), refiners' least squares (right)."""
    glob = [st for st in stages if "nit" in (st.get("info") or {})]
    cost = (glob[0]["info"].get("cost") if glob else None) or "itae"
    name = COST_LABELS.get(cost, cost).format(y=y_unit or 'output unit', t=t_unit)
    h = np.asarray(history, dtype=float)
    if h.size:
        ax.semilogy(np.arange(h.size), np.where(np.isfinite(h), h, np.nan), color="C0",
                    label=" + ".join(st["name"] for st in glob) or "global search")
    # A widened box restarts the search: mark where each later global stage begins.
    edge = 0
    for st in glob[:-1]:
        edge += int(st["info"]["nit"])
        ax.axvline(edge, color="0.5", lw=0.7, ls=":")
    ax.set_xlabel("global-search iteration; refiners after it")
    ax.set_ylabel(name, color="C0", fontsize=8)
    ax.set_title("convergence of every stage", fontsize=9)
    refiners = [st for st in stages if st not in glob]
    if refiners:
        ax2 = ax.twinx()
        step = max(1.0, 0.1 * h.size)
        x = float(h.size)
        for k, st in enumerate(refiners):
            x += step
            c0, c1 = st.get("cost_before"), st.get("cost")
            if c0 is None or c1 is None:
                continue
            its = (st.get("info") or {}).get("iterations")
            ax2.semilogy([x, x], [c0, c1], color=f"C{k + 1}", marker="o", ms=4,
                         label=f"{st['name']}: {c0:.3g} -> {c1:.3g}"
                               + (f" ({its} it.)" if its is not None else ""))
            ax2.annotate("", xy=(x, c1), xytext=(x, c0),
                         arrowprops={"arrowstyle": "->", "color": f"C{k + 1}"})
        ax2.set_ylabel(f"refiners: 0.5 sum r^2  [{y_unit or 'output unit'}^2]", fontsize=8)
        _plain_log_ticks(ax2)
        ax2.legend(fontsize=6, loc="upper right")
    if h.size:
        ax.legend(fontsize=7, loc="lower left")
        _plain_log_ticks(ax)


def _plain_log_ticks(ax: Any) -> None:
    """Log-axis ticks as plain numbers ("118", not "1.18 x 10^2") on short ranges."""
    fmt = ticker.FuncFormatter(lambda v, _: f"{v:.3g}")
    # Minor ticks: only 2 and 5 times a power of ten are labelled, and only on a range of
    # less than two decades (wider ranges have enough major ticks).
    minor = ticker.FuncFormatter(
        lambda v, _: f"{v:.3g}" if f"{v:.0e}"[0] in "25" else "")
    lo, hi = ax.get_ylim()
    ax.yaxis.set_major_formatter(fmt)
    ax.yaxis.set_minor_formatter(minor if hi < 100 * lo else ticker.NullFormatter())
    ax.tick_params(axis="y", which="both", labelsize=7)


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
    ax.set_ylabel(_axis(data.output_name, data.output_unit))
    ax.legend(fontsize=7, ncol=3)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    with atomic_path(p) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return p
