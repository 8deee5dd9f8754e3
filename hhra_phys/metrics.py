"""Goodness-of-fit metrics between a measured output ``y`` and a prediction ``yhat``.

Notation: ``e_k = y_k - yhat_k`` for samples ``k = 0 .. N-1``; ``var`` is the population
variance (``ddof = 0``); ``||.||`` the Euclidean norm.

======== ========================================================= ====================
key      formula                                                   unit
======== ========================================================= ====================
mse      ``mean(e**2)``                                            output unit squared
rmse     ``sqrt(mse)``                                             output unit
vaf      ``(1 - var(e) / var(y)) * 100``                           %
itae     ``sum_k (t_k - t_0) * |e_k| * dt``                        output unit * s**2
fit      ``100 * (1 - ||e|| / ||y - mean(y)||)``                   %
max_abs  ``max_k |e_k|``                                           output unit
======== ========================================================= ====================

The paper prints MSE without the square (its eq. 31); the mean of squared errors is meant
and used here. VAF ignores a constant offset of the prediction (it compares variances);
FIT does not.

Every function accepts a single prediction of shape (N,) (returns a float) or a batch of
shape (..., N), e.g. one row per member of an optimiser population (returns an array over
the leading axes). A prediction with a NaN or Inf anywhere scores as the worst possible
value (``inf`` for errors, ``-inf`` for VAF and FIT) instead of NaN, so a diverged
simulation never wins a comparison and never raises. The measured ``y`` must be finite and
shapes must match, otherwise :class:`~hhra_phys.errors.DataError` is raised.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hhra_phys.errors import DataError, ParameterError

__all__ = ["KEYS", "fit", "itae", "max_abs_error", "mse", "rmse", "score", "vaf"]

#: Keys of the dictionary returned by :func:`score`, in order.
KEYS = ("mse", "rmse", "vaf", "itae", "fit", "max_abs")

Result = float | np.ndarray


def _prepare(y: Any, yhat: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(y, yhat, bad)``: validated float arrays and the mask of non-finite prediction rows."""
    yy = np.asarray(y, dtype=float)
    yh = np.asarray(yhat, dtype=float)
    if yy.ndim != 1 or yy.size == 0:
        raise DataError(f"measured y must be a non-empty 1-D array, got shape {yy.shape}")
    if yh.ndim == 0 or yh.shape[-1] != yy.size:
        raise DataError(
            f"shape mismatch: y has shape {yy.shape} but yhat has shape {yh.shape}; yhat must be "
            f"({yy.size},) or (..., {yy.size})"
        )
    bad_y = np.flatnonzero(~np.isfinite(yy))
    if bad_y.size:
        raise DataError(
            f"measured y has {bad_y.size} non-finite value(s) at rows "
            f"{', '.join(map(str, bad_y[:5]))}{', ...' if bad_y.size > 5 else ''}"
        )
    bad = ~np.isfinite(yh).all(axis=-1)
    return yy, yh, bad


def _finish(value: np.ndarray, bad: np.ndarray, worst: float) -> Result:
    """Give non-finite rows (and NaN from overflow) the worst value; float for one row."""
    value = np.where(bad | np.isnan(value), worst, value)
    return float(value) if value.ndim == 0 else value


def _spread(y: np.ndarray, name: str) -> float:
    var = float(np.var(y))
    if var == 0.0:
        raise DataError(f"measured y is constant: {name} (relative to its variance) is undefined")
    return var


def mse(y: Any, yhat: Any) -> Result:
    """Mean squared error ``mean((y - yhat)**2)`` [output unit squared].

    Parameters
    ----------
    y : array_like, shape (N,)
        Measured output.
    yhat : array_like, shape (N,) or (..., N)
        Prediction(s).

    Returns
    -------
    float or numpy.ndarray
        ``inf`` for a prediction with NaN/Inf.
    """
    yy, yh, bad = _prepare(y, yhat)
    with np.errstate(all="ignore"):
        value = np.mean((yy - yh) ** 2, axis=-1)
    return _finish(value, bad, np.inf)


def rmse(y: Any, yhat: Any) -> Result:
    """Root mean squared error ``sqrt(mean((y - yhat)**2))`` [output unit]."""
    value = mse(y, yhat)
    return float(np.sqrt(value)) if isinstance(value, float) else np.sqrt(value)


def vaf(y: Any, yhat: Any) -> Result:
    """Variance accounted for ``(1 - var(y - yhat) / var(y)) * 100`` [%].

    100 % for a perfect prediction up to a constant offset; 0 % for a prediction that
    explains nothing; negative when the error varies more than ``y``.

    Returns
    -------
    float or numpy.ndarray
        ``-inf`` for a prediction with NaN/Inf.

    Raises
    ------
    DataError
        If ``y`` is constant (VAF undefined).
    """
    yy, yh, bad = _prepare(y, yhat)
    var_y = _spread(yy, "VAF")
    with np.errstate(all="ignore"):
        value = (1.0 - np.var(yy - yh, axis=-1) / var_y) * 100.0
    return _finish(value, bad, -np.inf)


def fit(y: Any, yhat: Any) -> Result:
    """Normalised fit ``100 * (1 - ||y - yhat|| / ||y - mean(y)||)`` [%].

    100 % is a perfect fit; 0 % is no better than the constant ``mean(y)``. Equal to
    ``100 * (1 - rmse / std(y))``.

    Returns
    -------
    float or numpy.ndarray
        ``-inf`` for a prediction with NaN/Inf.

    Raises
    ------
    DataError
        If ``y`` is constant (FIT undefined).
    """
    yy, yh, bad = _prepare(y, yhat)
    scale = np.sqrt(_spread(yy, "FIT") * yy.size)  # ||y - mean(y)||
    with np.errstate(all="ignore"):
        value = 100.0 * (1.0 - np.linalg.norm(yy - yh, axis=-1) / scale)
    return _finish(value, bad, -np.inf)


def itae(y: Any, yhat: Any, t: Any = None, *, dt: float | None = None) -> Result:
    """Integral of time-weighted absolute error, discretised: ``sum_k (t_k - t_0)*|e_k|*dt``.

    The paper's fitness ``J = integral_0^T t*|e(t)| dt`` (its eq. 30) with time measured
    from the start of the record, so a validation segment whose time axis starts at 10 s
    is weighted like a record starting at 0 s.

    Parameters
    ----------
    y : array_like, shape (N,)
        Measured output.
    yhat : array_like, shape (N,) or (..., N)
        Prediction(s).
    t : array_like, shape (N,), optional
        Time axis of the data [s]; ``dt`` is its mean step ``(t[-1] - t[0]) / (N - 1)``.
    dt : float, optional
        Sample period [s] when ``t`` is not given (``t_k = k * dt``); default 1 (sample
        units).

    Returns
    -------
    float or numpy.ndarray
        [output unit * s**2]; ``inf`` for a prediction with NaN/Inf.
    """
    yy, yh, bad = _prepare(y, yhat)
    n = yy.size
    if t is not None:
        if dt is not None:
            raise ParameterError("give the time axis t or the sample period dt, not both")
        tt = np.asarray(t, dtype=float)
        if tt.shape != (n,):
            raise DataError(f"shape mismatch: t has shape {tt.shape}, y has shape {yy.shape}")
        if not np.isfinite(tt).all():
            raise DataError("time axis t has non-finite values")
        weight = tt - tt[0]
        step = (tt[-1] - tt[0]) / (n - 1) if n > 1 else 0.0
    else:
        step = 1.0 if dt is None else float(dt)
        if not (np.isfinite(step) and step > 0):
            raise ParameterError(f"dt must be a positive number, got {dt!r}")
        weight = np.arange(n) * step
    with np.errstate(all="ignore"):
        value = np.sum(weight * np.abs(yy - yh), axis=-1) * step
    return _finish(value, bad, np.inf)


def max_abs_error(y: Any, yhat: Any) -> Result:
    """Largest absolute error ``max_k |y_k - yhat_k|`` [output unit]."""
    yy, yh, bad = _prepare(y, yhat)
    with np.errstate(all="ignore"):
        value = np.max(np.abs(yy - yh), axis=-1)
    return _finish(value, bad, np.inf)


def score(y: Any, yhat: Any, t: Any = None) -> dict[str, Result]:
    """All metrics at once.

    Parameters
    ----------
    y : array_like, shape (N,)
        Measured output.
    yhat : array_like, shape (N,) or (..., N)
        Prediction(s).
    t : array_like, shape (N,), optional
        Time axis [s] for ITAE; without it ITAE is in sample units (dt = 1).

    Returns
    -------
    dict
        Keys ``"mse", "rmse", "vaf", "itae", "fit", "max_abs"`` (see the module docstring
        for formulas and units); floats for one prediction, arrays for a batch.
    """
    return {
        "mse": mse(y, yhat),
        "rmse": rmse(y, yhat),
        "vaf": vaf(y, yhat),
        "itae": itae(y, yhat, t),
        "fit": fit(y, yhat),
        "max_abs": max_abs_error(y, yhat),
    }
