"""The noise stop: the noise level of a part and whether the residuals are at it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.stats import chi2

from hhra_phys.data import Dataset
from hhra_phys.diagnosis.fits import _free_values
from hhra_phys.diagnosis.residual import whiteness
from hhra_phys.diagnosis.selection import COLOURED_P, stops_at_noise
from hhra_phys.noise import noise_level
from hhra_phys.problem import Problem, as_records
from hhra_phys.result import FitResult

__all__ = ["selection_noise", "noise_stop"]


def selection_noise(problem: Problem, res: FitResult, sel: Any) -> dict[str, Any]:
    """Where a part's residual stands against the noise.

    Parameters
    ----------
    problem : Problem
        The fitted model's problem (on the estimation part of each record).
    res : FitResult
        Its fit.
    sel : Dataset or RecordSet or None
        The part to look at, one per record (a :class:`~hhra_phys.data.Dataset` for
        one record, a :class:`~hhra_phys.multi.RecordSet` for several): the selection
        parts (free run, initial state re-estimated on each), or ``None`` for the
        estimation parts themselves (the fit's residual, fitted initial states).

    Returns
    -------
    dict
        ``rmse`` (RMSE over all samples of the parts, output units), ``noise`` (their
        white-noise level, :func:`~hhra_phys.noise.noise_level`; the records' levels
        pooled by sample count), ``ratio`` (``rmse/noise``), ``ljung_box_p`` and
        ``white`` (``p > 0.05``) of the residual (with several records one Ljung-Box
        test of them together: statistics and degrees of freedom summed, records
        independent).
    """
    parts = [None] * len(problem.records) if sel is None else as_records(sel)
    ys = problem.simulate_parts(_free_values(problem, res), parts)
    datas = [pr.data if ds is None else ds
             for pr, ds in zip(problem.records, parts, strict=True)]
    rs = [d.y - yk for d, yk in zip(datas, ys, strict=True)]
    r = np.concatenate(rs)
    if not np.isfinite(r).all():
        return {"rmse": math.inf, "noise": math.nan, "ratio": math.inf, "ljung_box_p": 0.0,
                "white": False}
    sigmas = [noise_level(rk, (d.u, yk)) for rk, d, yk in zip(rs, datas, ys, strict=True)]
    tests = [whiteness(rk) for rk in rs]
    if len(rs) == 1:  # a pool of one is that record's own
        sigma, p, white = sigmas[0], float(tests[0]["ljung_box_p"]), bool(tests[0]["white"])
    else:
        sigma = float(np.sqrt(sum(rk.size * s ** 2 for rk, s in zip(rs, sigmas, strict=True))
                              / r.size))
        p = float(chi2.sf(sum(w["ljung_box_q"] for w in tests), sum(w["lags"] for w in tests)))
        white = p > 0.05
    rmse = float(np.sqrt(np.mean(r ** 2)))
    return {"rmse": rmse, "noise": sigma, "ratio": rmse / sigma if sigma > 0 else math.inf,
            "ljung_box_p": p, "white": white}


def _why_at_noise(level: Mapping[str, Any], noise_tol: float) -> str:
    """Which rule of :func:`at_noise_level` holds, in words (one need not imply the other:
    an RMSE within the allowance can still be a coloured residual)."""
    p = level["ljung_box_p"]
    if level["white"]:
        return f"white: Ljung-Box p {p:.2g} > 0.05"
    return (f"within the allowance 1 + noise_tol = {1 + noise_tol:.3g} x noise, though not "
            f"white: Ljung-Box p {p:.2g}")


def _why_not_at_noise(level: Mapping[str, Any], noise_tol: float) -> str:
    """Why the estimation part is not at the noise level, in words: above the allowance,
    or within it but clearly coloured (:data:`~hhra_phys.diagnosis.selection.COLOURED_P`)."""
    p = level["ljung_box_p"]
    if level["ratio"] <= 1 + noise_tol:
        return (f"RMSE {level['rmse']:.4g} = {level['ratio']:.3f} x noise, within the "
                f"allowance but clearly coloured: Ljung-Box p {p:.2g} < {COLOURED_P:g}")
    return f"RMSE {level['rmse']:.4g} = {level['ratio']:.3f} x noise, above the allowance"


def noise_stop(problem: Problem, res: FitResult, sel: Dataset, noise_tol: float,
               ) -> tuple[dict[str, Any], bool]:
    """The loop's noise-level stop: both non-test parts must be at the noise level.

    The selection part alone is a quarter of the record; a weak effect that it
    does not excite (a friction with few reversals in it) can leave it at the noise
    level while the estimation part, twice as long, still shows the effect. A
    round is therefore run when *either* part is above the noise level; the test
    part is never looked at. Whether a candidate is then accepted is still decided
    on selection by :func:`acceptance`, so a round that runs on the estimation
    part's evidence cannot add an effect the selection part does not confirm.

    Parameters
    ----------
    problem, res : Problem, FitResult
        The current model's problem and fit.
    sel : Dataset
        The selection part.
    noise_tol : float
        Structural-mismatch allowance (fraction of the noise level).

    Returns
    -------
    level : dict
        :func:`selection_noise` of the selection part, with the estimation part's
        under ``"estimation"``.
    stop : bool
        Both parts at the noise level (:func:`at_noise_level`).
    """
    level = selection_noise(problem, res, sel)
    level["estimation"] = selection_noise(problem, res, None)
    return level, stops_at_noise(level, noise_tol)


def _noise_stop_text(level: Mapping[str, Any], noise_tol: float) -> str:
    """The stop reason of :func:`noise_stop` in words (which rule held on each part)."""
    e = level["estimation"]
    text = (f"selection residual at the noise level (RMSE {level['rmse']:.4g} = "
            f"{level['ratio']:.3f} x noise {level['noise']:.3g}, "
            f"{_why_at_noise(level, noise_tol)}), estimation residual too (RMSE "
            f"{e['rmse']:.4g} = {e['ratio']:.3f} x noise, {_why_at_noise(e, noise_tol)})")
    return text
