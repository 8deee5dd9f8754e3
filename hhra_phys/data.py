"""Input/output records: the :class:`Dataset`, its validation, loaders and writers.

A dataset is one uniformly sampled record of an input ``u`` (valve current [mA] by default)
and an output ``y`` (shaft angle [deg] by default) on a time axis ``t`` [s], with optional
extra measured channels and free-form metadata. The output channel and its unit are
metadata, so a pressure output (``output_name="pressure"``, ``output_unit="raw"``) is as
valid as an angle.

Every record is validated when it is built, whether from arrays or from a file, and every
problem raises its own subclass of :class:`~hhra_phys.errors.DataError` whose message names
the file (``source``), the column and the row(s). Rows are 0-based sample indices; messages
about CSV files also give the 1-based line of the file.

Formats: CSV with a header row (plus a JSON side-car for metadata), MATLAB ``.mat`` (the user
names the variables and their orientation) and NumPy ``.npz``. See ``docs/data.md``.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import math
import os
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.io

from hhra_phys.errors import DataError, ParameterError

__all__ = [
    "PUBLIC_ACTUATOR_FILE",
    "DataChecks",
    "DataFileExistsError",
    "DataFileNotFoundError",
    "DataFormatError",
    "Dataset",
    "DimensionError",
    "LengthMismatchError",
    "MissingColumnError",
    "NonExcitingInputError",
    "NonFiniteError",
    "NonMonotonicTimeError",
    "NonNumericError",
    "NonUniformTimeError",
    "TimeAxisError",
    "TooFewSamplesError",
    "UnsupportedFormatError",
    "find_public_data",
    "load",
    "load_csv",
    "load_mat",
    "load_npz",
    "load_public_actuator",
    "save",
    "save_csv",
    "save_npz",
    "sidecar_path",
]

PathLike = str | os.PathLike

#: File name of the public hydraulic-actuator record (see ``/work/shared/data/README.md``).
PUBLIC_ACTUATOR_FILE = "hydraulic_actuator.mat"

_SIDECAR_FORMAT = "hhra-phys dataset"
_NPZ_META_KEY = "__hhra_meta__"
_NPZ_EXTRA_PREFIX = "extra__"
_MAX_ROWS_SHOWN = 5


# --------------------------------------------------------------------------- errors


class DataFileNotFoundError(DataError, FileNotFoundError):
    """A data file (or the public data set) does not exist where it was looked for."""


class DataFileExistsError(DataError, FileExistsError):
    """A writer refused to replace an existing file (pass ``overwrite=True``)."""


class UnsupportedFormatError(DataError):
    """The file suffix is not one of the supported formats (.csv, .tsv, .mat, .npz)."""


class DataFormatError(DataError):
    """A file is malformed: no header, ragged rows, unreadable MAT file, bad side-car."""


class MissingColumnError(DataError, KeyError):
    """A requested column, variable, row or key is not in the file; lists what is there."""

    def __str__(self) -> str:
        # KeyError.__str__ would print the repr of the message, with quotes.
        return str(self.args[0]) if self.args else ""


class NonNumericError(DataError):
    """A cell or array holds something that is not a real number."""


class NonFiniteError(DataError):
    """A column holds NaN or Inf values (the message lists the rows)."""


class LengthMismatchError(DataError):
    """Columns of one record have different lengths."""


class DimensionError(DataError):
    """An array that must be 1-D (one sample per row) has another shape."""


class TimeAxisError(DataError):
    """The time axis is unusable (base class of the two cases below)."""


class NonMonotonicTimeError(TimeAxisError):
    """Time does not strictly increase."""


class NonUniformTimeError(TimeAxisError):
    """Time steps differ by more than the relative tolerance ``DataChecks.time_rtol``."""


class TooFewSamplesError(DataError):
    """Fewer samples than ``DataChecks.min_samples``."""


class NonExcitingInputError(DataError):
    """The input is constant or nearly so, so it does not excite the system."""


# --------------------------------------------------------------------------- checks


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
    ex: dict[str, np.ndarray] = {}
    for key, value in extra.items():
        if not isinstance(key, str) or not key.strip():
            raise DataError(f"{pre}extra channel names must be non-empty strings, got {key!r}")
        if key in ("t", "u", "y"):
            raise DataError(f"{pre}extra channel name {key!r} clashes with the columns t, u, y")
        ex[key] = _as_vector(value, lab(key), source)

    columns = {"t": tt, "u": uu, "y": yy, **ex}
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

    n = tt.size
    if n < checks.min_samples:
        raise TooFewSamplesError(
            f"{pre}only {n} sample{'s' * (n != 1)}; at least {checks.min_samples} are needed "
            "(DataChecks.min_samples)"
        )

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

    if checks.require_excitation:
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
    return tt, uu, yy, ex


# --------------------------------------------------------------------------- Dataset


@dataclass(eq=False, repr=False)
class Dataset:
    """One uniformly sampled input/output record.

    Parameters
    ----------
    t : numpy.ndarray, shape (N,)
        Time [s] (or sample index when ``metadata["time_unit"] == "samples"``), strictly
        increasing and uniform within ``checks.time_rtol``. Need not start at 0.
    u : numpy.ndarray, shape (N,)
        Input, in ``input_unit`` (valve current [mA] by default).
    y : numpy.ndarray, shape (N,)
        Output, in ``output_unit`` (shaft angle [deg] by default).
    input_name, input_unit, output_name, output_unit : str
        Names and units of the two channels.
    extra : dict of str to numpy.ndarray
        Further measured channels, each of shape (N,).
    metadata : dict
        Free-form, JSON-able information (for simulated data: the true parameters and effects).
    source : str or None
        File the record came from; shown in every error message.
    name : str or None
        Short label for reports.
    checks : DataChecks
        Validation thresholds; derived datasets (split, slice) inherit them.

    Raises
    ------
    DataError
        One of its subclasses (see module docstring) when the record is unusable.

    Notes
    -----
    All arrays are float64 copies: nothing passed in is shared or modified, and methods that
    derive datasets return new objects.
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    input_name: str = "current"
    input_unit: str = "mA"
    output_name: str = "angle"
    output_unit: str = "deg"
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)
    source: str | None = None
    name: str | None = None
    checks: DataChecks = field(default_factory=DataChecks)

    def __post_init__(self) -> None:
        if self.source is not None:
            self.source = str(self.source)
        if not isinstance(self.checks, DataChecks):
            raise ParameterError(f"checks must be a DataChecks, got {type(self.checks).__name__}")
        if not isinstance(self.extra, Mapping):
            raise DataError(f"{_prefix(self.source)}extra must be a dict of name -> array")
        if not isinstance(self.metadata, Mapping):
            raise DataError(f"{_prefix(self.source)}metadata must be a dict")
        for attr in ("input_name", "input_unit", "output_name", "output_unit"):
            if not isinstance(getattr(self, attr), str):
                raise DataError(f"{_prefix(self.source)}{attr} must be a string")
        self.t, self.u, self.y, self.extra = _validate(
            self.t,
            self.u,
            self.y,
            self.extra,
            checks=self.checks,
            source=self.source,
            input_desc=f"{self.input_name} [{self.input_unit}]",
        )
        self.metadata = copy.deepcopy(dict(self.metadata))

    # ---------------------------------------------------------------- properties

    @property
    def n(self) -> int:
        """Number of samples N."""
        return int(self.t.size)

    def __len__(self) -> int:
        return self.n

    @property
    def dt(self) -> float:
        """Sample period [s]: ``(t[-1] - t[0]) / (N - 1)``, the mean step."""
        return float((self.t[-1] - self.t[0]) / (self.n - 1))

    @property
    def fs(self) -> float:
        """Sample rate [Hz] = 1 / dt."""
        return 1.0 / self.dt

    @property
    def duration(self) -> float:
        """Length of the record [s] = N * dt (each sample held for one period)."""
        return self.n * self.dt

    @property
    def time_unit(self) -> str:
        """Unit of ``t``: "s", or "samples" when the sample period is unknown."""
        return str(self.metadata.get("time_unit", "s"))

    def __repr__(self) -> str:
        extra = f", extra={sorted(self.extra)}" if self.extra else ""
        rate = f"fs={self.fs:.6g} Hz" if self.time_unit == "s" else "sample units"
        return (
            f"Dataset(name={self.name!r}, n={self.n}, {rate}, "
            f"u={self.input_name} [{self.input_unit}], y={self.output_name} [{self.output_unit}]"
            f"{extra}, source={self.source!r})"
        )

    # ---------------------------------------------------------------- derived datasets

    def _replace(self, **changes: Any) -> Dataset:
        return dataclasses.replace(self, **changes)

    def _segment(self, start: int, stop: int, part: str | None = None, **split: Any) -> Dataset:
        """Samples ``start:stop`` as a new dataset; metadata["segment"] holds absolute indices."""
        meta = copy.deepcopy(self.metadata)
        base = int(meta.get("segment", {}).get("start", 0))
        meta["segment"] = {"start": base + start, "stop": base + stop}
        if part is not None:
            meta["split"] = {"part": part, **split}
        name = self.name
        if part is not None:
            name = f"{self.name} ({part})" if self.name else part
        try:
            return self._replace(
                t=self.t[start:stop],
                u=self.u[start:stop],
                y=self.y[start:stop],
                extra={k: v[start:stop] for k, v in self.extra.items()},
                metadata=meta,
                name=name,
            )
        except DataError as exc:
            raise type(exc)(f"{exc} [segment {start}:{stop} of {self.n} samples]") from None

    def split(self, fraction: float = 0.5) -> tuple[Dataset, Dataset]:
        """Split into an estimation part (first) and a validation part.

        Parameters
        ----------
        fraction : float
            Share of the samples in the estimation part, 0 < fraction < 1. The split index is
            ``round(fraction * N)`` (1024 samples and 0.5 give 512 + 512).

        Returns
        -------
        estimation, validation : Dataset
            Both keep the original time axis (the validation part does not restart at 0).
            ``metadata["split"]`` records the part, the split index and the fraction;
            ``metadata["segment"]`` the absolute sample range.
        """
        if not (isinstance(fraction, int | float) and 0.0 < fraction < 1.0):
            raise ParameterError(
                f"split fraction must lie strictly between 0 and 1, got {fraction!r}"
            )
        return self.split_at(int(round(fraction * self.n)), _fraction=float(fraction))

    def split_at(self, index: int, *, _fraction: float | None = None) -> tuple[Dataset, Dataset]:
        """Split before sample ``index`` (negative counts from the end); see :meth:`split`."""
        if not isinstance(index, int | np.integer):
            raise ParameterError(f"split index must be an integer, got {index!r}")
        k = int(index) + (self.n if index < 0 else 0)
        if not 0 < k < self.n:
            raise ParameterError(
                f"split index {index} leaves an empty part of a {self.n}-sample record"
            )
        frac = k / self.n if _fraction is None else _fraction
        info = {"index": k, "fraction": frac, "n_total": self.n}
        return (
            self._segment(0, k, "estimation", **info),
            self._segment(k, self.n, "validation", **info),
        )

    def slice(self, start: int | None = None, stop: int | None = None) -> Dataset:
        """Samples ``start:stop`` (Python slice rules, step 1) as a new dataset.

        The time axis is kept; ``metadata["segment"]`` records the absolute sample range.
        """
        begin, end, _ = slice(start, stop).indices(self.n)
        return self._segment(begin, max(begin, end))

    def with_metadata(self, **kw: Any) -> Dataset:
        """A copy whose metadata is updated with ``kw`` (this dataset is left unchanged)."""
        return self._replace(metadata={**self.metadata, **kw})

    # ---------------------------------------------------------------- constructors

    @classmethod
    def from_arrays(
        cls,
        u: Any,
        y: Any,
        fs: float | None = None,
        t: Any = None,
        **meta: Any,
    ) -> Dataset:
        """Build a dataset from arrays.

        Parameters
        ----------
        u, y : array_like, shape (N,)
            Input and output samples.
        fs : float, optional
            Sample rate [Hz]. Used to build ``t = arange(N) / fs`` when ``t`` is not given;
            when both are given they must agree within ``checks.time_rtol``. With neither,
            the record is in sample units: ``t = arange(N)``, fs = 1, and
            ``metadata["time_unit"] = "samples"``.
        t : array_like, shape (N,), optional
            Time [s].
        **meta
            Dataset fields by name (``input_name``, ``input_unit``, ``output_name``,
            ``output_unit``, ``extra``, ``metadata``, ``source``, ``name``, ``checks``);
            any other keyword is stored in ``metadata``.
        """
        names = {f.name for f in dataclasses.fields(cls)} - {"t", "u", "y"}
        kwargs = {k: v for k, v in meta.items() if k in names}
        metadata = dict(kwargs.pop("metadata", None) or {})
        metadata.update({k: v for k, v in meta.items() if k not in names})
        checks = kwargs.get("checks") or DataChecks()
        time, sample_units = _time_axis(t, fs, np.shape(u)[0] if np.ndim(u) >= 1 else 0)
        if sample_units:
            metadata.setdefault("time_unit", "samples")
        ds = cls(t=time, u=u, y=y, metadata=metadata, **kwargs)
        if t is not None and fs is not None:
            _check_rate(ds.fs, fs, checks, ds.source)
        return ds


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


# --------------------------------------------------------------------------- file helpers


def sidecar_path(path: PathLike) -> Path:
    """The JSON side-car of a CSV file: same path, suffix .json (``rig.csv`` -> ``rig.json``)."""
    return Path(path).with_suffix(".json")


def _existing_file(path: PathLike) -> Path:
    p = Path(path).expanduser()
    if not p.exists():
        raise DataFileNotFoundError(f"data file not found: {p} (looked at {p.absolute()})")
    if not p.is_file():
        raise DataFormatError(f"{p}: not a regular file")
    return p


def _writable(path: PathLike, overwrite: bool) -> Path:
    p = Path(path).expanduser()
    if p.exists() and not overwrite:
        raise DataFileExistsError(f"{p} exists; pass overwrite=True to replace it")
    if p.is_dir():
        raise DataFormatError(f"{p} is a directory")
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, set | frozenset):
        return sorted(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _description(ds: Dataset) -> dict[str, Any]:
    """What the side-car (CSV) and the meta entry (NPZ) store besides the samples."""
    return {
        "format": _SIDECAR_FORMAT,
        "format_version": 1,
        "name": ds.name,
        "input_name": ds.input_name,
        "input_unit": ds.input_unit,
        "output_name": ds.output_name,
        "output_unit": ds.output_unit,
        "extra": list(ds.extra),
        "n": ds.n,
        "fs": ds.fs,
        "metadata": ds.metadata,
    }


def _to_json(ds: Dataset, target: Path) -> str:
    try:
        return json.dumps(_description(ds), default=_json_default, indent=2)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{target}: metadata is not JSON-able ({exc})") from None


def _from_json(text: str, source: PathLike) -> dict[str, Any]:
    try:
        info = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DataFormatError(f"{source}: invalid JSON ({exc})") from None
    if not isinstance(info, dict) or info.get("format") != _SIDECAR_FORMAT:
        return {}  # someone else's JSON file: not ours to interpret
    return info


def _dataset_fields(
    info: Mapping[str, Any],
    *,
    input_name: str | None,
    input_unit: str | None,
    output_name: str | None,
    output_unit: str | None,
    name: str | None,
    metadata: Mapping[str, Any] | None,
    default_name: str,
) -> dict[str, Any]:
    """Names, units and metadata: explicit argument > file's description > default."""

    def pick(key: str, explicit: str | None, default: str | None) -> Any:
        if explicit is not None:
            return explicit
        return info.get(key) if info.get(key) is not None else default

    meta = dict(info.get("metadata") or {})
    meta.update(metadata or {})
    return {
        "input_name": pick("input_name", input_name, "current"),
        "input_unit": pick("input_unit", input_unit, "mA"),
        "output_name": pick("output_name", output_name, "angle"),
        "output_unit": pick("output_unit", output_unit, "deg"),
        "name": pick("name", name, default_name),
        "metadata": meta,
    }


# --------------------------------------------------------------------------- CSV


def _csv_records(
    path: Path, delimiter: str | None, comments: str | None
) -> Iterator[tuple[int, list[str]]]:
    """``(line_number, fields)`` for every non-blank, non-comment line (1-based lines)."""
    with path.open("r", newline="", encoding="utf-8-sig") as fh:  # -sig: drop an Excel BOM
        kept: list[int] = []

        def data_lines() -> Iterator[str]:
            for number, line in enumerate(fh, start=1):
                stripped = line.strip()
                if not stripped or (comments and stripped.startswith(comments)):
                    continue
                kept.append(number)
                yield line

        if delimiter is None:
            for line in data_lines():
                yield kept[-1], line.split()
        else:
            # One record per line: numeric data has no quoted multi-line fields.
            for fields in csv.reader(data_lines(), delimiter=delimiter):
                yield kept[-1], [f.strip() for f in fields]


def _role(role: str) -> str:
    """How messages name a column's role."""
    return {"t": "the time t", "u": "the input u", "y": "the output y"}.get(
        role, f"extra channel {role!r}"
    )


def _parse_column(cells: list[str], label: str, lines: np.ndarray, path: Path) -> np.ndarray:
    try:
        return np.array(cells, dtype=np.float64)
    except ValueError:
        pass
    bad = np.array([i for i, c in enumerate(cells) if not _is_number(c)])
    first = cells[int(bad[0])]
    what = "an empty cell" if first == "" else repr(first)
    raise NonNumericError(
        f"{path}: column {label!r} has {bad.size} non-numeric cell{'s' * (bad.size > 1)} "
        f"at {_rows_text(bad, lines)}; first: {what}"
    )


def _check_extra_name(key: str, source: PathLike) -> None:
    if key in ("t", "u", "y"):
        raise DataError(
            f"{source}: extra channel name {key!r} clashes with the dataset's t, u, y; name it "
            "differently with a mapping {name: column}"
        )


def _column_index(spec: str | int, header: list[str], path: Path, role: str) -> int:
    if isinstance(spec, int | np.integer) and not isinstance(spec, bool):
        if not -len(header) <= spec < len(header):
            raise MissingColumnError(
                f"{path}: column index {spec} for {_role(role)} is out of range; the file has "
                f"{len(header)} columns: {', '.join(header)}"
            )
        return int(spec) % len(header)
    if not isinstance(spec, str):
        raise ParameterError(f"column for {_role(role)} must be a name or an index, got {spec!r}")
    hits = [i for i, h in enumerate(header) if h == spec]
    if not hits:
        raise MissingColumnError(
            f"{path}: no column {spec!r} (for {_role(role)}); available columns: "
            + ", ".join(header)
        )
    if len(hits) > 1:
        raise DataFormatError(f"{path}: the header names column {spec!r} {len(hits)} times")
    return hits[0]


def load_csv(
    path: PathLike,
    t: str | int | None = "t",
    u: str | int = "u",
    y: str | int = "y",
    extra: Sequence[str | int] | Mapping[str, str | int] | None = None,
    delimiter: str | None = ",",
    fs: float | None = None,
    *,
    comments: str | None = "#",
    sidecar: bool = True,
    input_name: str | None = None,
    input_unit: str | None = None,
    output_name: str | None = None,
    output_unit: str | None = None,
    name: str | None = None,
    metadata: Mapping[str, Any] | None = None,
    checks: DataChecks | None = None,
) -> Dataset:
    """Load a CSV file with a header row.

    Parameters
    ----------
    path : str or path-like
        The file. Blank lines and lines starting with ``comments`` are skipped; the first
        remaining line is the header.
    t, u, y : str or int
        Column names (or 0-based indices) of time [s], input and output. When the time
        column is absent (or ``t=None``) and ``fs`` is given, ``t = arange(N) / fs``; with
        ``t=None`` and no ``fs`` the record is in sample units (fs = 1,
        ``metadata["time_unit"] = "samples"``).
    extra : sequence of str or int, or mapping of name to column, optional
        Further columns to keep in ``Dataset.extra`` (a mapping renames them, e.g.
        ``{"p_a": "u"}``). ``None`` (default): the extras the side-car lists, else none.
    delimiter : str or None
        Field separator (default ","); ``None`` splits on runs of whitespace.
    fs : float, optional
        Sample rate [Hz]; checked against the time column when both exist.
    sidecar : bool
        Read ``sidecar_path(path)`` (written by :func:`save_csv`) for names, units and
        metadata when it exists.
    input_name, input_unit, output_name, output_unit, name : str, optional
        Override the side-car (and the defaults current/mA, angle/deg).
    metadata : dict, optional
        Merged over the side-car's metadata.
    checks : DataChecks, optional
        Validation thresholds.

    Returns
    -------
    Dataset
        With ``source`` set to ``path``.

    Raises
    ------
    DataFileNotFoundError, MissingColumnError, NonNumericError, DataFormatError
        And every validation error of :class:`Dataset`; messages give the file, the column,
        the row (0-based sample index) and the line of the file.
    """
    p = _existing_file(path)
    checks = checks or DataChecks()
    info: dict[str, Any] = {}
    side = sidecar_path(p)
    if sidecar and side.is_file() and side != p:
        info = _from_json(side.read_text(encoding="utf-8"), side)

    records = _csv_records(p, delimiter, comments)
    try:
        header_line, header = next(records)
    except StopIteration:
        raise DataFormatError(f"{p}: empty file (no header row)") from None
    rows: list[list[str]] = []
    lines: list[int] = []
    for number, fields in records:
        if len(fields) != len(header):
            raise DataFormatError(
                f"{p}: line {number} has {len(fields)} fields but the header (line {header_line}) "
                f"has {len(header)}"
            )
        rows.append(fields)
        lines.append(number)
    line_of = np.array(lines, dtype=np.int64)

    if extra is None:
        extra = [e for e in info.get("extra", []) if e in header]
    roles: dict[str, str | int] = {}
    if t is not None and (isinstance(t, int) or t in header or fs is None):
        roles["t"] = t
    roles.update({"u": u, "y": y})
    pairs = extra.items() if isinstance(extra, Mapping) else ((e, e) for e in extra)
    for key, e in pairs:
        if not isinstance(key, str):  # an index without a name: use the header's
            key = header[_column_index(e, header, p, "extra")]
        _check_extra_name(key, p)
        roles[key] = e
    index = {role: _column_index(spec, header, p, role) for role, spec in roles.items()}
    columns = {role: [r[i] for r in rows] for role, i in index.items()}
    values = {
        role: _parse_column(cells, header[index[role]], line_of, p)
        for role, cells in columns.items()
    }

    time, sample_units = _time_axis(values.get("t"), fs, len(rows))
    fields_ = _dataset_fields(
        info,
        input_name=input_name,
        input_unit=input_unit,
        output_name=output_name,
        output_unit=output_unit,
        name=name,
        metadata=metadata,
        default_name=p.stem,
    )
    if sample_units:
        fields_["metadata"].setdefault("time_unit", "samples")
    ex = {k: v for k, v in values.items() if k not in ("t", "u", "y")}
    labels = {role: header[i] for role, i in index.items()}
    labels.setdefault("t", "t (built from fs)" if fs is not None else "t (sample index)")
    _validate(
        time,
        values["u"],
        values["y"],
        ex,
        checks=checks,
        source=str(p),
        labels=labels,
        lines=line_of,
        input_desc=f"{fields_['input_name']} [{fields_['input_unit']}]",
    )
    ds = Dataset(
        t=time, u=values["u"], y=values["y"], extra=ex, source=str(p), checks=checks, **fields_
    )
    if "t" in values and fs is not None:
        _check_rate(ds.fs, fs, checks, ds.source)
    return ds


def save_csv(ds: Dataset, path: PathLike, overwrite: bool = False) -> Path:
    """Write ``ds`` as CSV (columns ``t,u,y`` then the extras) plus a JSON side-car.

    Values are written with ``repr`` precision, so a round trip is exact. Names, units and
    metadata go to ``sidecar_path(path)`` (``rig.csv`` -> ``rig.json``).

    Parameters
    ----------
    ds : Dataset
    path : str or path-like
        Target CSV file; parent directories are created.
    overwrite : bool
        Replace existing files (the CSV and its side-car); otherwise raise
        :class:`DataFileExistsError`.

    Returns
    -------
    pathlib.Path
        The CSV file written.
    """
    p = Path(path).expanduser()
    side = sidecar_path(p)
    if side == p:
        raise DataFormatError(f"{p}: a CSV file must not have the suffix .json (its side-car's)")
    for bad in ("t", "u", "y"):
        if bad in ds.extra:  # Dataset forbids this, but a mutated instance could slip through
            raise DataError(f"{p}: extra channel {bad!r} clashes with the columns t, u, y")
    _writable(p, overwrite)
    try:
        _writable(side, overwrite)
    except DataFileExistsError:
        raise DataFileExistsError(
            f"{side} (the side-car of {p.name}) exists; pass overwrite=True to replace it"
        ) from None
    text = _to_json(ds, side)
    data = np.column_stack([ds.t, ds.u, ds.y, *ds.extra.values()])
    with p.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(["t", "u", "y", *ds.extra])
        writer.writerows(data.tolist())  # csv writes floats with repr(): exact round trip
    side.write_text(text + "\n", encoding="utf-8")
    return p


# --------------------------------------------------------------------------- MAT / NPZ

_SPEC = re.compile(r"^\s*([A-Za-z_]\w*)\s*(?:\[(.*)\])?\s*$")
_INDEX = re.compile(r"^\s*(-?\d+)\s*(?:,\s*:\s*)?$|^\s*:\s*,\s*(-?\d+)\s*$")


def _parse_spec(spec: str) -> tuple[str, str | None, int | None]:
    """Parse a spec: "X[0]" -> (X, row, 0); "X[:,1]" -> (X, col, 1); "y" -> (y, None, None)."""
    m = _SPEC.match(spec) if isinstance(spec, str) else None
    if not m:
        raise ParameterError(
            f"bad variable spec {spec!r}: use 'NAME', 'NAME[i]' / 'NAME[i,:]' (row i) or "
            "'NAME[:,j]' (column j), indices 0-based"
        )
    var, index = m.group(1), m.group(2)
    if index is None:
        return var, None, None
    im = _INDEX.match(index)
    if not im:
        raise ParameterError(
            f"bad index in variable spec {spec!r}: use 'NAME[i]', 'NAME[i,:]' or 'NAME[:,j]'"
        )
    if im.group(1) is not None:
        return var, "row", int(im.group(1))
    return var, "col", int(im.group(2))


def _pick(variables: Mapping[str, Any], spec: str, source: str, role: str) -> np.ndarray:
    """The 1-D array a spec designates in a MAT/NPZ variable table."""
    var, kind, index = _parse_spec(spec)
    who = f"{source}: {spec!r} (for {_role(role)})"
    if var not in variables:
        listing = (
            ", ".join(f"{k} ({'x'.join(map(str, np.shape(v)))})" for k, v in variables.items())
            or "none"
        )
        raise MissingColumnError(f"{who}: no variable {var!r}; available: {listing}")
    arr = np.asarray(variables[var])
    if arr.dtype.kind not in "biuf":
        raise NonNumericError(
            f"{who}: variable {var!r} is not a numeric array (dtype {arr.dtype}); MATLAB "
            "structs, cells and strings cannot be used"
        )
    shape = "x".join(map(str, arr.shape))
    if kind is None:
        if arr.ndim == 1 or (arr.ndim == 2 and 1 in arr.shape):
            return arr.ravel()
        raise DimensionError(
            f"{who}: variable {var!r} has shape {shape}; say which row or column, e.g. "
            f"'{var}[0]' (row 0) or '{var}[:,0]' (column 0); indices are 0-based"
        )
    if arr.ndim != 2:
        raise DimensionError(f"{who}: a row or column needs a 2-D variable, {var!r} is {shape}")
    axis = 0 if kind == "row" else 1
    count = arr.shape[axis]
    if not -count <= index < count:
        what = "rows" if kind == "row" else "columns"
        raise MissingColumnError(
            f"{who}: out of range, {var!r} has shape {shape}, i.e. {count} {what} "
            f"(0-based: 0..{count - 1})"
        )
    return arr[index, :] if kind == "row" else arr[:, index]


def _from_variables(
    variables: Mapping[str, Any],
    source: str,
    *,
    t: str | None,
    u: str,
    y: str,
    extra: Mapping[str, str] | Sequence[str] | None,
    fs: float | None,
    info: Mapping[str, Any],
    default_name: str,
    checks: DataChecks | None,
    t_optional: bool,
    **names: Any,
) -> Dataset:
    checks = checks or DataChecks()
    if extra is None:
        extra = {}
    elif not isinstance(extra, Mapping):
        extra = {str(spec): spec for spec in extra}
    for key in extra:
        _check_extra_name(key, source)
    specs = {"u": u, "y": y, **extra}
    if t is not None and not (t_optional and fs is not None and _parse_spec(t)[0] not in variables):
        specs["t"] = t
    values = {role: _pick(variables, spec, source, role) for role, spec in specs.items()}
    labels = {role: str(spec) for role, spec in specs.items()}
    sizes = {role: v.size for role, v in values.items()}
    if len(set(sizes.values())) > 1:  # before a time axis is built from one of them
        listing = ", ".join(f"{labels[k]!r} {n}" for k, n in sizes.items())
        raise LengthMismatchError(f"{source}: columns have different lengths (samples): {listing}")
    time, sample_units = _time_axis(values.get("t"), fs, values["u"].size)
    fields_ = _dataset_fields(info, default_name=default_name, **names)
    if sample_units:
        fields_["metadata"].setdefault("time_unit", "samples")
        fields_["metadata"].setdefault(
            "time_note", "sample period unknown: t is the sample index and fs = 1"
        )
    ex = {k: v for k, v in values.items() if k not in ("t", "u", "y")}
    labels.setdefault("t", "t (built from fs)" if fs is not None else "t (sample index)")
    _validate(
        time,
        values["u"],
        values["y"],
        ex,
        checks=checks,
        source=source,
        labels=labels,
        input_desc=f"{fields_['input_name']} [{fields_['input_unit']}]",
    )
    ds = Dataset(
        t=time, u=values["u"], y=values["y"], extra=ex, source=source, checks=checks, **fields_
    )
    if "t" in values and fs is not None:
        _check_rate(ds.fs, fs, checks, source)
    return ds


def load_mat(
    path: PathLike,
    u: str = "X[0]",
    y: str = "y[0]",
    t: str | None = None,
    fs: float | None = None,
    *,
    extra: Mapping[str, str] | Sequence[str] | None = None,
    input_name: str | None = None,
    input_unit: str | None = None,
    output_name: str | None = None,
    output_unit: str | None = None,
    name: str | None = None,
    metadata: Mapping[str, Any] | None = None,
    checks: DataChecks | None = None,
) -> Dataset:
    """Load a MATLAB .mat file (v4 to v7; v7.3 is HDF5 and not read by scipy).

    Parameters
    ----------
    path : str or path-like
    u, y, t : str
        Variable specs, indices 0-based (Python, not MATLAB): ``"y"`` a vector (1xN, Nx1
        or N), ``"X[0]"`` or ``"X[0,:]"`` row 0 of matrix X, ``"X[:,1]"`` column 1.
        The defaults fit the public actuator record (input = row 0 of X, output = y).
    fs : float, optional
        Sample rate [Hz]. Without ``t`` and ``fs`` the record is in sample units:
        ``t = arange(N)``, fs = 1 and ``metadata["time_unit"] = "samples"``.
    extra : mapping of name to spec, or sequence of specs, optional
        Further channels, e.g. ``{"x1": "X[1]"}`` (a bare spec is its own name).
    input_name, input_unit, output_name, output_unit, name, metadata, checks
        As in :func:`load_csv`.

    Returns
    -------
    Dataset
    """
    p = _existing_file(path)
    try:
        variables = scipy.io.loadmat(p, squeeze_me=False)
    except NotImplementedError:
        raise DataFormatError(
            f"{p}: MATLAB v7.3 (HDF5) files are not supported; save with -v7 or convert"
        ) from None
    except Exception as exc:  # scipy raises several types for a corrupt file
        raise DataFormatError(f"{p}: not a readable MATLAB file ({exc})") from None
    variables = {k: v for k, v in variables.items() if not k.startswith("__")}
    return _from_variables(
        variables,
        str(p),
        t=t,
        u=u,
        y=y,
        extra=extra,
        fs=fs,
        info={},
        default_name=p.stem,
        checks=checks,
        t_optional=False,
        input_name=input_name,
        input_unit=input_unit,
        output_name=output_name,
        output_unit=output_unit,
        name=name,
        metadata=metadata,
    )


def load_npz(
    path: PathLike,
    u: str = "u",
    y: str = "y",
    t: str | None = "t",
    fs: float | None = None,
    *,
    extra: Mapping[str, str] | Sequence[str] | None = None,
    input_name: str | None = None,
    input_unit: str | None = None,
    output_name: str | None = None,
    output_unit: str | None = None,
    name: str | None = None,
    metadata: Mapping[str, Any] | None = None,
    checks: DataChecks | None = None,
) -> Dataset:
    """Load a NumPy .npz archive (as written by :func:`save_npz`, or any other).

    Parameters
    ----------
    path : str or path-like
    u, y, t : str
        Keys, with the same row/column specs as :func:`load_mat` (``"X[0]"``, ``"X[:,1]"``).
        A missing time key with ``fs`` given builds ``t = arange(N) / fs``.
    fs : float, optional
        Sample rate [Hz].
    extra : mapping of name to spec, or sequence of specs, optional
        ``None`` (default): every ``extra__NAME`` key (what :func:`save_npz` writes).
    input_name, input_unit, output_name, output_unit, name, metadata, checks
        As in :func:`load_csv`; names, units and metadata default to the archive's
        ``__hhra_meta__`` entry when present.

    Returns
    -------
    Dataset
    """
    p = _existing_file(path)
    try:
        with np.load(p, allow_pickle=False) as archive:
            variables = {k: archive[k] for k in archive.files}
    except Exception as exc:  # zipfile, pickle and format errors
        raise DataFormatError(f"{p}: not a readable .npz archive ({exc})") from None
    info: dict[str, Any] = {}
    if _NPZ_META_KEY in variables:
        info = _from_json(str(variables.pop(_NPZ_META_KEY)), p)
    if extra is None:
        extra = {
            k[len(_NPZ_EXTRA_PREFIX) :]: k for k in variables if k.startswith(_NPZ_EXTRA_PREFIX)
        }
    return _from_variables(
        variables,
        str(p),
        t=t,
        u=u,
        y=y,
        extra=extra,
        fs=fs,
        info=info,
        default_name=p.stem,
        checks=checks,
        t_optional=True,
        input_name=input_name,
        input_unit=input_unit,
        output_name=output_name,
        output_unit=output_unit,
        name=name,
        metadata=metadata,
    )


def save_npz(ds: Dataset, path: PathLike, overwrite: bool = False) -> Path:
    """Write ``ds`` as a compressed .npz archive.

    Keys: ``t``, ``u``, ``y``, ``extra__NAME`` per extra channel and ``__hhra_meta__`` (a
    JSON string with names, units and metadata). The path is used as given (no ``.npz`` is
    appended). Existing files are kept unless ``overwrite=True``.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    p = _writable(path, overwrite)
    arrays = {"t": ds.t, "u": ds.u, "y": ds.y}
    arrays.update({_NPZ_EXTRA_PREFIX + k: v for k, v in ds.extra.items()})
    arrays[_NPZ_META_KEY] = np.array(_to_json(ds, p))
    with p.open("wb") as fh:  # a file object keeps numpy from appending ".npz"
        np.savez_compressed(fh, **arrays)
    return p


# --------------------------------------------------------------------------- dispatch


def load(path: PathLike, **kw: Any) -> Dataset:
    """Load by suffix: ``.csv`` / ``.tsv`` (tab-separated), ``.mat``, ``.npz``.

    Keyword arguments go to :func:`load_csv`, :func:`load_mat` or :func:`load_npz`.
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".csv":
        return load_csv(path, **kw)
    if suffix == ".tsv":
        kw.setdefault("delimiter", "\t")
        return load_csv(path, **kw)
    if suffix == ".mat":
        return load_mat(path, **kw)
    if suffix == ".npz":
        return load_npz(path, **kw)
    raise UnsupportedFormatError(
        f"{path}: unsupported file type {suffix or '(no suffix)'!r}; use .csv, .tsv, .mat or .npz "
        "(or call load_csv directly for other text files)"
    )


def save(ds: Dataset, path: PathLike, overwrite: bool = False) -> Path:
    """Write by suffix: ``.csv`` (with side-car) or ``.npz``."""
    suffix = Path(path).suffix.lower()
    if suffix == ".csv":
        return save_csv(ds, path, overwrite=overwrite)
    if suffix == ".npz":
        return save_npz(ds, path, overwrite=overwrite)
    raise UnsupportedFormatError(f"{path}: can write .csv or .npz, not {suffix or '(no suffix)'!r}")


# --------------------------------------------------------------------------- public data


def _public_candidates(path: PathLike | None) -> Iterable[Path]:
    if path is not None:
        p = Path(path).expanduser()
        yield p / PUBLIC_ACTUATOR_FILE if p.is_dir() else p
        return
    env = os.environ.get("HHRA_SHARED_DATA")
    if env:
        p = Path(env).expanduser()
        yield p if p.suffix == ".mat" else p / PUBLIC_ACTUATOR_FILE
    repo_root = Path(__file__).resolve().parents[1]
    for base in (Path.cwd(), repo_root):
        yield (base / ".." / "shared" / "data" / PUBLIC_ACTUATOR_FILE).resolve()


def find_public_data(path: PathLike | None = None) -> Path:
    """Locate ``hydraulic_actuator.mat``.

    Search order: ``path`` (a file or its directory) when given, and nothing else; else the
    directory in the environment variable ``HHRA_SHARED_DATA``; else ``../shared/data``
    relative to the current directory and then to the repository root.

    Raises
    ------
    DataFileNotFoundError
        Listing every place tried.
    """
    tried = []
    for candidate in _public_candidates(path):
        if candidate.is_file():
            return candidate
        tried.append(str(candidate))
    raise DataFileNotFoundError(
        f"public data file {PUBLIC_ACTUATOR_FILE} not found; tried: {'; '.join(tried)}. Pass its "
        "path or set HHRA_SHARED_DATA to the directory that holds it"
    )


def load_public_actuator(
    path: PathLike | None = None, *, checks: DataChecks | None = None
) -> Dataset:
    """Load the public hydraulic-actuator record (Sjöberg et al. 1995), 1024 samples.

    Input ``u`` = row 0 of ``X`` (valve opening, raw units); output ``y`` = ``y`` (oil
    pressure, ``output_name="pressure"``, ``output_unit="raw"``); extra channel ``"x1"`` =
    row 1 of ``X`` (undocumented; most likely the arm or piston position, with a one-sample
    glitch near sample 985). The sample period is not stored, so the record is in sample
    units (fs = 1, ``metadata["time_unit"] = "samples"``). The usual split is 512 + 512
    (``ds.split(0.5)``).

    Parameters
    ----------
    path : str or path-like, optional
        The file or its directory; see :func:`find_public_data` for the search otherwise.
    checks : DataChecks, optional
        Validation thresholds.
    """
    found = find_public_data(path)
    return load_mat(
        found,
        u="X[0]",
        y="y[0]",
        extra={"x1": "X[1]"},
        input_name="valve_opening",
        input_unit="raw",
        output_name="pressure",
        output_unit="raw",
        name="hydraulic_actuator",
        metadata={
            "description": "Hydraulic actuator of a robot arm: valve opening -> oil pressure",
            "reference": (
                "Sjoberg et al., Nonlinear black-box modeling in system identification: a "
                "unified overview, Automatica 31(12), 1995"
            ),
            "usual_split_index": 512,
            "notes": [
                "x1 = X row 1: undocumented third channel, likely arm/piston position",
                "x1 has a one-sample glitch near sample 985",
                "the output oscillates with a period of about 25 samples",
            ],
        },
        checks=checks,
    )
