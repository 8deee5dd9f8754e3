"""Figures of a diagnosis: residuals of a fit, before/after the loop, and discovery's
screening. Matplotlib is imported inside each function (not at import).
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.diagnosis.discovery import DiscoveredStep
from hhra_phys.diagnosis.residual import Diagnosis
from hhra_phys.errors import ParameterError
from hhra_phys.outputs import FIGURE_SUFFIXES, atomic_path, check_output_path
from hhra_phys.problem import as_records

__all__ = ["plot_loop_residuals", "plot_residuals", "plot_discovery"]


def plot_residuals(
    diag: Diagnosis,
    path: str,
    title: str = "",
    overwrite: bool = False,
    *,
    before: Diagnosis | None = None,
    accepted: Sequence[str] | None = None,
    validation: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
    unit: str = "",
    marks: Sequence[tuple[float, str]] = (),
) -> str:
    """Residual figure of a diagnosis, optionally against the one before; returns the path.

    Panels: the residual over time (estimation part, and the validation part when
    ``validation`` is given, right of a line marking the split); its autocorrelation
    and its cross-correlation with the input, each with the 95 % band of a white
    residual (``+-1.96/sqrt(N)``: bars inside it are what white noise of that length
    gives by chance); and its spectrum. With ``before``, the diagnosis before the loop
    is drawn in grey on the same axes.

    Parameters
    ----------
    diag : Diagnosis
        The diagnosis to show ("after", or the only one).
    path : str
        Figure file (``.png``, ``.svg``, ``.pdf`` ...).
    title : str
        Figure title.
    overwrite : bool
        Replace an existing file.
    before : Diagnosis, optional
        The base model's diagnosis, drawn in grey for comparison.
    accepted : sequence of str, optional
        Effects the loop accepted; when it is empty "after" is the base model, and
        the figure says so instead of drawing the same curves twice.
    validation : mapping, optional
        ``{"before": (t, residual), "after": (t, residual)}`` on the validation part
        (time in the record's unit, residual in output units).
    unit : str
        Output unit, for the residual and spectrum axes.
    marks : sequence of (float, str)
        Further part boundaries on the residual panel: (time, name of the part that
        starts there), e.g. the loop's test part.

    Raises
    ------
    OutputPathError, OutputExistsError
        ``path`` cannot be written, or exists and ``overwrite`` is False.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    target = check_output_path(path, overwrite=overwrite, what="residual figure",
                               suffixes=FIGURE_SUFFIXES)
    same = before is not None and accepted is not None and not accepted
    if same:
        before = None  # nothing accepted: "after" is the base model, drawn once
    grey = {"color": "0.6", "lw": 0.7}
    fig = plt.figure(figsize=(11, 8.5))
    grid = fig.add_gridspec(3, 2, height_ratios=[1.2, 1, 1])
    ax_t = fig.add_subplot(grid[0, :])
    ax_a, ax_x = fig.add_subplot(grid[1, 0]), fig.add_subplot(grid[1, 1])
    ax_s = fig.add_subplot(grid[2, :])
    now = "after" if before is not None else ("base model = after" if same else "residual")

    _plot_residual_time(ax_t, diag, before, validation, marks, now, unit)

    band_label = "95 % band of a white residual (+-1.96/sqrt(N))"
    for ax, get, xlabel, ylabel, what in (
        (ax_a, lambda d: (np.arange(d.whiteness["acf"].size), d.whiteness["acf"],
                          d.whiteness["band"]),
         "lag [samples]", "autocorrelation [-]",
         f"residual autocorrelation (Ljung-Box p={diag.whiteness['ljung_box_p']:.2g})"),
        (ax_x, lambda d: (np.asarray(d.xcorr_input["lags"]), d.xcorr_input["values"],
                          d.xcorr_input["band"]),
         "lag [samples] (> 0: input earlier)", "cross-correlation [-]",
         "residual vs input cross-correlation"),
    ):
        if before is not None:
            lag_b, val_b, _ = get(before)
            ax.plot(lag_b, val_b, ".", ms=3, color="0.6", label="before")
        lag, val, band = get(diag)
        ax.plot(lag, val, ".-", ms=3, lw=0.6, color="C0", label=now)
        ax.axhspan(-band, band, color="C1", alpha=0.25, label=band_label)
        ax.set(xlabel=xlabel, ylabel=ylabel, title=what)
        ax.title.set_fontsize(9)
        ax.legend(fontsize=7)

    sp = diag.spectrum
    if before is not None:
        ax_s.semilogy(before.spectrum["f"][1:], before.spectrum["pxx"][1:], label="before",
                      **grey)
    ax_s.semilogy(sp["f"][1:], sp["pxx"][1:], color="C0", lw=0.8, label=now)
    ax_s.set(xlabel=f"frequency [{sp['unit']}]",
             ylabel=f"PSD [{unit or 'unit'}^2/{'Hz' if sp['unit'] == 'Hz' else 'cycle/sample'}]",
             title="residual spectrum (Welch), estimation part")
    ax_s.title.set_fontsize(9)
    ax_s.legend(fontsize=7)
    if same:
        fig.text(0.5, 0.005, "No effect was accepted: the model after the loop is the base "
                 "model, so 'after' equals 'before' (drawn once).", ha="center", fontsize=9,
                 color="C3")
    elif accepted:
        fig.text(0.5, 0.005, f"accepted: {', '.join(accepted)}", ha="center", fontsize=9)
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return path


def _plot_residual_time(
    ax_t: Any,
    diag: Diagnosis,
    before: Diagnosis | None,
    validation: Mapping[str, tuple[np.ndarray, np.ndarray]] | None,
    marks: Sequence[tuple[float, str]],
    now: str,
    unit: str,
) -> None:
    """The residual-over-time panel of :func:`plot_residuals` (``now`` labels ``diag``)."""
    u = f" [{unit}]" if unit else ""
    t_unit = "samples" if diag.spectrum.get("unit") == "1/sample" else "s"
    grey = {"color": "0.6", "lw": 0.7}
    # Residual over time: estimation, then validation right of the split.
    if before is not None:
        ax_t.plot(before.t, before.residual, label=f"before, estimation (RMSE {before.rmse:.3g})",
                  **grey)
    ax_t.plot(diag.t, diag.residual, color="C0", lw=0.7,
              label=f"{now}, estimation (RMSE {diag.rmse:.3g})")
    if validation:
        split_t = float(diag.t[-1])
        ax_t.axvspan(split_t, float(max(v[0][-1] for v in validation.values())),
                     color="C2", alpha=0.07)
        ax_t.axvline(split_t, color="k", lw=0.8, ls=":")
        # With a test part after it (marks), the part right of the split is the selection.
        first = "selection" if marks else "validation"
        ax_t.text(split_t, 1.0, f" {first} >", transform=ax_t.get_xaxis_transform(),
                  va="top", fontsize=8)
        ax_t.text(split_t, 1.0, "< estimation ", transform=ax_t.get_xaxis_transform(),
                  va="top", ha="right", fontsize=8)
        for t_mark, name in marks:
            ax_t.axvline(t_mark, color="k", lw=0.8, ls=":")
            ax_t.text(t_mark, 1.0, f" {name} >", transform=ax_t.get_xaxis_transform(),
                      va="top", fontsize=8)
        for key, (tv, rv) in validation.items():
            if key == "before" and before is None:
                continue
            rms = float(np.sqrt(np.mean(np.square(rv))))
            style = grey if key == "before" else {"color": "C3", "lw": 0.7}
            rest = first + "".join(f" + {name}" for _, name in marks)
            label = ("before" if key == "before" else now) + f", {rest} (RMSE {rms:.3g})"
            ax_t.plot(tv, rv, label=label, **style)
    ax_t.axhspan(-diag.noise, diag.noise, color="C1", alpha=0.15,
                 label=f"+-noise estimate ({diag.noise:.2g}{' ' + unit if unit else ''})")
    ax_t.set(xlabel=f"time [{t_unit}]", ylabel=f"residual y - y_model{u}")
    ax_t.legend(fontsize=7, ncol=3, loc="lower left")


def plot_loop_residuals(
    res: Any,
    data: Dataset,
    before_path: str | None,
    after_path: str | None,
    overwrite: bool = False,
    label: str = "",
) -> list[str | None]:
    """The before/after residual figures of a diagnosis loop (:func:`plot_residuals`).

    Both show the estimation part and everything after it (the selection part and, when
    the loop held one out, the test part, marked); "after" draws "before" in grey on the
    same axes, and says so on the figure when no effect was accepted.

    Parameters
    ----------
    res : DiagnosisResult
        Result of :func:`hhra_phys.diagnose` (its ``base``/``final`` fits,
        ``diagnoses``, ``final_diagnosis``, ``chosen`` and ``settings["split"]``).
    data : Dataset or sequence of Dataset
        The whole record the loop ran on; for a loop over several records, those
        records: then the figures show the records' estimation residuals one after
        another (time continued from one record to the next, as
        :func:`combine_diagnoses` joins them), without the selection and test
        parts, which belong to each record.
    before_path, after_path : str or None
        Figure files (None: not drawn).
    overwrite : bool
        Replace existing files.
    label : str
        Prefix of the titles (e.g. the record's name).

    Returns
    -------
    list of (str or None)
        The two paths written (None where not drawn).
    """
    from hhra_phys.diagnosis.selection import split_record

    records = as_records(data)
    if len(records) > 1 or len(res.final.records) > 1:  # several records, or validation ones
        return _records_loop_residuals(res, data, before_path, after_path, overwrite, label)
    data = records[0]
    split, test = float(res.settings["split"]), float(res.settings.get("test") or 0.0)
    _, _, held = split_record(data, split, test)
    # Everything after the estimation part: selection, then (if any) the test part.
    val = data.split(split)[1]
    r_val = {"before": (val.t, val.y - res.base.predict(val)),
             "after": (val.t, val.y - res.final.predict(val))}
    marks = [(float(held.t[0]), "test")] if held is not None else []
    first = res.diagnoses[0] if res.diagnoses else None
    prefix = f"{label}: " if label else ""
    out: list[str | None] = [None, None]
    if before_path and first is not None:
        out[0] = plot_residuals(first, before_path, f"{prefix}before: base model", overwrite,
                                validation={"after": r_val["before"]}, unit=data.output_unit,
                                marks=marks)
    if after_path and res.final_diagnosis is not None:
        title = (f"{prefix}after: base model + {', '.join(res.chosen)}" if res.chosen
                 else f"{prefix}after: no effect accepted (the base model)")
        out[1] = plot_residuals(res.final_diagnosis, after_path, title, overwrite, before=first,
                                accepted=res.chosen, validation=r_val, unit=data.output_unit,
                                marks=marks)
    return out


def _records_loop_residuals(res: Any, data: Any, before_path: str | None,
                            after_path: str | None, overwrite: bool,
                            label: str) -> list[str | None]:
    """:func:`plot_loop_residuals` of a loop over several records (its docstring)."""
    unit = as_records(data)[0].output_unit
    first = res.diagnoses[0] if res.diagnoses else None
    names = " + ".join(r["name"] for r in res.final.records if r.get("n_est"))
    prefix = f"{label}: " if label else ""
    out: list[str | None] = [None, None]
    if before_path and first is not None:
        out[0] = plot_residuals(first, before_path, f"{prefix}before: base model ({names}, "
                                "estimation parts one after another)", overwrite, unit=unit)
    if after_path and res.final_diagnosis is not None:
        title = (f"{prefix}after: base model + {', '.join(res.chosen)}" if res.chosen
                 else f"{prefix}after: no effect accepted (the base model)")
        out[1] = plot_residuals(res.final_diagnosis, after_path, f"{title} ({names})",
                                overwrite, before=first, accepted=res.chosen, unit=unit)
    return out


def plot_discovery(steps: Sequence[DiscoveredStep], path: str, overwrite: bool = False) -> str:
    """Residuals before and after each discovered term (estimation and validation), as PNG.

    Parameters
    ----------
    steps : sequence of DiscoveredStep
        Steps with :attr:`DiscoveredStep.residuals` (those of the current run).
    path : str
        Output file (``.png``).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    str
        ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hhra_phys.outputs import FIGURE_SUFFIXES, atomic_path, check_output_path

    target = check_output_path(path, overwrite=overwrite, what="discovery figure",
                               suffixes=FIGURE_SUFFIXES)
    shown = [s for s in steps if s.residuals]
    if not shown:
        raise ParameterError("no discovered step with residuals to plot")
    fig, ax = plt.subplots(len(shown), 2, figsize=(11, 3.2 * len(shown)), squeeze=False)
    for i, s in enumerate(shown):
        for j, part in enumerate(("est", "val")):
            before, after = s.residuals[part]
            rb = float(np.sqrt(np.mean(before ** 2)))
            ra = float(np.sqrt(np.mean(after ** 2)))
            a = ax[i, j]
            a.plot(before, lw=0.7, color="0.6", label=f"before (RMSE {rb:.3g})")
            a.plot(after, lw=0.7, color="C0", label=f"after (RMSE {ra:.3g})")
            a.set(title=f"{'estimation' if part == 'est' else 'selection'}: {s.effect}"
                        f"{' (accepted)' if s.accepted else ''}",
                  xlabel="sample", ylabel="residual")
            a.legend(fontsize=8, loc="upper right")
        # Wrapped: a long expression would squeeze the panel in tight_layout.
        ax[i, 0].text(0.01, 0.02, textwrap.fill(s.expression, 75),
                      transform=ax[i, 0].transAxes, fontsize=8)
    fig.tight_layout()
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return path
