"""Validation of a record: the :class:`DataChecks` thresholds and the checks themselves.

Every :class:`~hhra_phys.data.Dataset` and every loader goes through :func:`validate`, so a
record is checked the same way whether it was built from arrays or read from a file, and
every problem raises its own :class:`~hhra_phys.errors.DataError` subclass naming the file
(``source``), the column and the row(s). Rows are 0-based sample indices; messages about
text files also give the 1-based line of the file.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from hhra_phys.data.errors import (
    DimensionError,
    LengthMismatchError,
    NonExcitingInputError,
    NonFiniteError,
    NonMonotonicTimeError,
    NonNumericError,
    NonUniformTimeError,
    TooFewSamplesError,
)
from hhra_phys.errors import DataError, ParameterError

__all__ = ["DataChecks"]

_MAX_ROWS_SHOWN = 5

#: Largest magnitude a record's value may have. Squares of 1e154 overflow a double, and a
#: least-squares cost sums squares of differences of such values over every sample; no
#: instrument reads within 50 decades of this in any unit.
MAX_MAGNITUDE = 1e100


@dataclass(frozen=True)
class DataChecks:
    """Thresholds of the validation every :class:`Dataset` passes on construction.

    Parameters
    ----------
    min_samples : int
        Smallest accepted number of samples (default 20).
    time_rtol : float
        Relative tolerance [-] on the time step: every step ``t[k+1] - t[k]`` must lie within
        ``time_rtol * median_step`` of the median step (default 1e-3).
    input_rtol : float
        The input counts as non-exciting when ``std(u) <= input_rtol * max(abs(u))`` (default 1e-3,
        which also catches a constant current with converter noise on it).
    require_excitation : bool
        Set to False to accept a non-exciting input (for example a rest segment).
    """

    min_samples: int = 20
    time_rtol: float = 1e-3
    input_rtol: float = 1e-3
    require_excitation: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.min_samples, int | np.integer) or self.min_samples < 2:
            raise ParameterError(
                f"DataChecks.min_samples must be an integer >= 2, got {self.min_samples!r}"
            )
        for name in ("time_rtol", "input_rtol"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ParameterError(
                    f"DataChecks.{name} must be a finite number >= 0, got {value!r}"
                )


def _prefix(source: str | None) -> str:
    return f"{source}: " if source else ""


def _rows_text(rows: np.ndarray, lines: np.ndarray | None = None) -> str:
    """'rows 3, 7 (file lines 5, 9)' for the first few of ``rows`` plus the total count."""
    rows = np.asarray(rows)
    shown = rows[:_MAX_ROWS_SHOWN]
    word = "row" if rows.size == 1 else "rows"
    text = f"{word} {', '.join(str(int(r)) for r in shown)}"
    if rows.size > shown.size:
        text += f", ... ({rows.size} in all)"
    if lines is not None:
        text += f" (file line{'' if shown.size == 1 else 's'} "
        text += ", ".join(str(int(lines[r])) for r in shown) + ")"
    return text


def _as_vector(value: Any, label: str, source: str | None) -> np.ndarray:
    """A float64 copy of ``value`` as a 1-D array, or a DataError naming the column."""
    arr = np.asarray(value)
    if np.iscomplexobj(arr):
        raise NonNumericError(
            f"{_prefix(source)}column {label} holds complex numbers; real values are needed"
        )
    if arr.dtype.kind not in "biuf":
        try:
            arr = arr.astype(np.float64)
        except (TypeError, ValueError):
            flat = arr.ravel()
            bad = [i for i, v in enumerate(flat) if not _is_number(v)]
            first = flat[bad[0]] if bad else None
            raise NonNumericError(
                f"{_prefix(source)}column {label} holds non-numeric values (first: {first!r}) at "
                f"{_rows_text(np.array(bad))}"
            ) from None
    if arr.ndim != 1:
        raise DimensionError(
            f"{_prefix(source)}column {label} must be 1-D with one value per sample, got shape "
            f"{arr.shape}" + ("; use .ravel() or pick a row/column" if arr.ndim == 2 else "")
        )
    # A copy: the dataset never shares memory with what the user passed in.
    return np.array(arr, dtype=np.float64)


def _is_number(value: Any) -> bool:
    try:
        float(value)
    except (TypeError, ValueError):
        return False
    return True


def _validate(
    t: Any,
    u: Any,
    y: Any,
    extra: Mapping[str, Any],
    *,
    checks: DataChecks,
    source: str | None,
    labels: Mapping[str, str] | None = None,
    lines: np.ndarray | None = None,
    input_desc: str = "input",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Convert and check one record; return float64 copies ``(t, u, y, extra)``.

    ``labels`` maps the roles "t", "u", "y" and extra names to the column names shown in
    messages; ``lines`` maps a row (sample index) to its 1-based line in a text file.
    """
    labels = dict(labels or {})

    def lab(key: str) -> str:
        return repr(labels.get(key, key))

    pre = _prefix(source)
    tt = _as_vector(t, lab("t"), source)
    uu = _as_vector(u, lab("u"), source)
    yy = _as_vector(y, lab("y"), source)
    ex = _extra_vectors(extra, lab, source)
    _check_values({"t": tt, "u": uu, "y": yy, **ex}, lab, pre, lines)
    n = tt.size
    if n < checks.min_samples:
        raise TooFewSamplesError(
            f"{pre}only {n} sample{'s' * (n != 1)}; at least {checks.min_samples} are needed "
            "(DataChecks.min_samples)"
        )
    _check_time(tt, checks, lab, pre, lines)
    if checks.require_excitation:
        _check_excitation(uu, checks, lab, pre, input_desc)
    return tt, uu, yy, ex


def _extra_vectors(extra: Mapping[str, Any], lab: Callable[[str], str],
                   source: str | None) -> dict[str, np.ndarray]:
    """The extra channels as vectors, refusing names that are empty or clash with t, u, y."""
    pre = _prefix(source)
    ex: dict[str, np.ndarray] = {}
    for key, value in extra.items():
        if not isinstance(key, str) or not key.strip():
            raise DataError(f"{pre}extra channel names must be non-empty strings, got {key!r}")
        if key in ("t", "u", "y"):
            raise DataError(f"{pre}extra channel name {key!r} clashes with the columns t, u, y")
        ex[key] = _as_vector(value, lab(key), source)
    return ex


def _check_values(columns: dict[str, np.ndarray], lab: Callable[[str], str], pre: str,
                  lines: np.ndarray | None) -> None:
    """Refuse columns of different lengths, non-finite values and values beyond any unit."""
    sizes = {key: arr.size for key, arr in columns.items()}
    if len(set(sizes.values())) > 1:
        listing = ", ".join(f"{lab(k)} {n}" for k, n in sizes.items())
        raise LengthMismatchError(f"{pre}columns have different lengths (samples): {listing}")

    for key, arr in columns.items():
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            kinds = "NaN" if np.isnan(arr[bad]).all() else "NaN/Inf"
            raise NonFiniteError(
                f"{pre}column {lab(key)} has {bad.size} non-finite value{'s' * (bad.size > 1)} "
                f"({kinds}) at {_rows_text(bad, lines)}"
            )

    for key, arr in columns.items():  # finite, but beyond any measurement
        bad = np.flatnonzero(np.abs(arr) > MAX_MAGNITUDE)
        if bad.size:
            raise DataError(
                f"{pre}column {lab(key)} has {bad.size} value{'s' * (bad.size > 1)} beyond "
                f"+-{MAX_MAGNITUDE:g} at {_rows_text(bad, lines)} (first: "
                f"{arr[bad[0]]:.3g}): not a measurement in any unit, and the fit's squares "
                "and products of such values overflow; fix or remove those rows"
            )


def _check_time(tt: np.ndarray, checks: DataChecks, lab: Callable[[str], str], pre: str,
                lines: np.ndarray | None) -> None:
    """Refuse a time axis that does not strictly increase or is not uniformly sampled."""
    step = np.diff(tt)
    bad = np.flatnonzero(step <= 0) + 1
    if bad.size:
        k = int(bad[0])
        raise NonMonotonicTimeError(
            f"{pre}time column {lab('t')} is not strictly increasing at {_rows_text(bad, lines)}: "
            f"t[{k}] = {tt[k]:.9g} follows t[{k - 1}] = {tt[k - 1]:.9g}"
        )
    median = float(np.median(step))
    deviation = np.abs(step - median) / median
    bad = np.flatnonzero(deviation > checks.time_rtol) + 1
    if bad.size:
        worst = int(np.argmax(deviation)) + 1
        raise NonUniformTimeError(
            f"{pre}time column {lab('t')} is not uniformly sampled: the step into "
            f"{_rows_text(bad, lines)} differs from the median step {median:.9g} by more than "
            f"time_rtol = {checks.time_rtol:g} (relative); largest: {deviation[worst - 1]:.3g} at "
            f"row {worst} (t[{worst}] - t[{worst - 1}] = {step[worst - 1]:.9g}). Resample the "
            "record or loosen DataChecks(time_rtol=...)"
        )


def _check_excitation(uu: np.ndarray, checks: DataChecks, lab: Callable[[str], str], pre: str,
                      input_desc: str) -> None:
    """Refuse an input that is constant or nearly so: nothing can be identified from it."""
    scale = float(np.max(np.abs(uu)))
    spread = float(np.std(uu))
    if spread <= checks.input_rtol * scale or spread == 0.0:
        raise NonExcitingInputError(
            f"{pre}input column {lab('u')} ({input_desc}) is constant or nearly so "
            f"(std {spread:.3g} <= {checks.input_rtol:g} * max(abs(u)) = "
            f"{checks.input_rtol * scale:.3g}): it does not excite the system, so nothing can "
            "be identified from it. Use DataChecks(require_excitation=False) to accept it "
            "anyway"
        )


def _time_axis(t: Any, fs: float | None, n: int) -> tuple[Any, bool]:
    """``(t, sample_units)``: ``t`` itself, or built from ``fs``, or the sample index."""
    if fs is not None and not (isinstance(fs, int | float) and math.isfinite(fs) and fs > 0):
        raise ParameterError(f"fs must be a positive sample rate in Hz, got {fs!r}")
    if t is not None:
        return t, False
    if fs is None:
        return np.arange(n, dtype=np.float64), True
    return np.arange(n, dtype=np.float64) / float(fs), False


def _check_rate(actual: float, given: float, checks: DataChecks, source: str | None) -> None:
    if abs(actual - given) > max(checks.time_rtol, 1e-9) * given:
        raise DataError(
            f"{_prefix(source)}the time axis implies fs = {actual:.9g} Hz but fs = {given:.9g} Hz "
            "was given; drop one of them"
        )
