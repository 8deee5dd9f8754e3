"""The :class:`Dataset`: one uniformly sampled input/output record.

A dataset is one uniformly sampled record of an input ``u`` (valve current [mA] by default)
and an output ``y`` (shaft angle [deg] by default) on a time axis ``t`` [s], with optional
extra measured channels and free-form metadata. The output channel and its unit are
metadata, so a pressure output (``output_name="pressure"``, ``output_unit="raw"``) is as
valid as an angle. It is validated on construction (see :mod:`hhra_phys.data.checks`).

Inter-sample behaviour. What the input did between its samples is a property of the
record, ``metadata["intersample"]`` (:attr:`Dataset.intersample`): ``"zoh"`` (the
default) when the input was held over each sample, as a DAC driving a valve holds it;
``"foh"`` when it moved linearly from one sample to the next, the usual approximation for
a continuous input that was merely sampled (a signal generator's multisine read by the
same ADC as the output); ``"cubic"`` when it was a smooth, band-limited signal, which the
cubic convolution through four samples (Catmull-Rom) follows far closer than a straight
line when the record has only a few samples per period of its fastest content (a
continuous multisine sampled near its bandwidth). Every simulation of the record follows it
(:class:`hhra_phys.simulate.Simulator` ``intersample``), and it travels with the record
through the CSV side-car, the NPZ meta entry, splits and slices.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hhra_phys.data.checks import (
    DataChecks,
    _check_rate,
    _prefix,
    _time_axis,
    _validate,
)
from hhra_phys.errors import DataError, ParameterError

__all__ = ["Dataset", "INTERSAMPLE"]

#: Inter-sample behaviours of an input (module docstring): zero-order hold (held over
#: each sample), first-order hold (linear between samples) and the cubic convolution.
INTERSAMPLE: tuple[str, ...] = ("zoh", "foh", "cubic")


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
        ``metadata["intersample"]`` (``"zoh"``, ``"foh"`` or ``"cubic"``, default ``"zoh"``)
        says what the input did between samples (module docstring, :attr:`intersample`).
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
        kind = self.metadata.get("intersample", "zoh")
        if kind not in INTERSAMPLE:
            raise DataError(
                f"{_prefix(self.source)}metadata['intersample'] must be one of "
                f"{', '.join(map(repr, INTERSAMPLE))} (input held over each sample, linear or "
                f"cubic between samples), got {kind!r}"
            )

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

    @property
    def intersample(self) -> str:
        """What the input did between samples: ``"zoh"`` (held, default), ``"foh"`` (linear)
        or ``"cubic"`` (cubic convolution).

        Stored as ``metadata["intersample"]``; see the module docstring.
        """
        return str(self.metadata.get("intersample", "zoh"))

    def with_intersample(self, kind: str) -> Dataset:
        """A copy of the record with inter-sample behaviour ``kind`` (:data:`INTERSAMPLE`).

        Raises
        ------
        ParameterError
            ``kind`` is not one of :data:`INTERSAMPLE`.
        """
        if kind not in INTERSAMPLE:
            raise ParameterError(
                f"intersample must be one of {', '.join(map(repr, INTERSAMPLE))}, got {kind!r}"
            )
        return self.with_metadata(intersample=kind)

    def __repr__(self) -> str:
        extra = f", extra={sorted(self.extra)}" if self.extra else ""
        rate = f"fs={self.fs:.6g} Hz" if self.time_unit == "s" else "sample units"
        return (
            f"Dataset(name={self.name!r}, n={self.n}, {rate}, "
            f"u={self.input_name} [{self.input_unit}], y={self.output_name} [{self.output_unit}]"
            f"{extra}{'' if self.intersample == 'zoh' else ', intersample=' + self.intersample}, "
            f"source={self.source!r})"
        )

    # ---------------------------------------------------------------- derived datasets

    def _replace(self, **changes: Any) -> Dataset:
        new = dataclasses.replace(self, **changes)
        if not {"t", "u", "y"} & changes.keys():  # the same samples: the same place
            new.__dict__["_origin"] = self.origin
        return new

    @property
    def origin(self) -> tuple[Dataset, int] | None:
        """The record this one was cut from (:meth:`split`, :meth:`split_at`,
        :meth:`slice`) and the index of its first sample there, or ``None``.

        Kept through copies that keep the samples (:meth:`with_metadata`,
        :meth:`with_intersample`), dropped by any that change them (a unit conversion):
        what precedes a part in its record is then unknown. A part's leading window
        (:meth:`hhra_phys.problem.RecordProblem.lead_window`) reads the samples before it.
        """
        return self.__dict__.get("_origin")

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
            part = self._replace(
                t=self.t[start:stop],
                u=self.u[start:stop],
                y=self.y[start:stop],
                extra={k: v[start:stop] for k, v in self.extra.items()},
                metadata=meta,
                name=name,
            )
        except DataError as exc:
            raise type(exc)(f"{exc} [segment {start}:{stop} of {self.n} samples]") from None
        root, offset = self.origin or (self, 0)
        part.__dict__["_origin"] = (root, offset + start)
        return part

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

    # ---------------------------------------------------------------- pandas

    @classmethod
    def from_dataframe(
        cls,
        df: Any,
        time: str | None = "t",
        input: str = "u",  # shadows the builtin: the role's name, like u= elsewhere
        output: str = "y",
        extra: Sequence[str] | Mapping[str, str] | None = None,
        *,
        fs: float | None = None,
        **meta: Any,
    ) -> Dataset:
        """Build a dataset from columns of a :class:`pandas.DataFrame`.

        Parameters
        ----------
        df : pandas.DataFrame
        time, input, output : str
            Column names of time [s], input and output. ``time=None`` builds the time axis
            from ``fs`` (or sample units), as :meth:`from_arrays` does; to use the index,
            ``df.reset_index()`` first.
        extra : sequence of str, or mapping of name to column, optional
            Further columns for ``Dataset.extra`` (a mapping is ``{new name: column}``).
        fs : float, optional
            Sample rate [Hz]; see :meth:`from_arrays`.
        **meta
            As in :meth:`from_arrays`. Names, units, name and metadata default to what
            :meth:`to_dataframe` stored in ``df.attrs["hhra_phys"]``.

        Raises
        ------
        DataError
            A missing column (:class:`MissingColumnError`, listing the columns) and every
            validation error; ``ImportError`` naming the extra when pandas is missing.
        """
        pd = _pandas()
        from hhra_phys.data.errors import MissingColumnError

        if not isinstance(df, pd.DataFrame):
            raise ParameterError(f"from_dataframe needs a pandas.DataFrame, got {type(df)}")
        pairs = dict(extra.items()) if isinstance(extra, Mapping) else {e: e for e in extra or ()}
        roles = {"u": input, "y": output, **pairs}
        if time is not None:
            roles["t"] = time
        available = [str(c) for c in df.columns]
        cols: dict[str, np.ndarray] = {}
        for role, column in roles.items():
            if column not in df.columns:
                raise MissingColumnError(
                    f"DataFrame: no column {column!r} (for {role}); columns: "
                    + ", ".join(available)
                )
            series = df[column]
            try:  # nullable dtypes: pd.NA -> NaN, reported by the finiteness check
                cols[role] = series.to_numpy(dtype=np.float64, na_value=np.nan)
            except (TypeError, ValueError):
                cols[role] = series.to_numpy()  # validation names the non-numeric rows
        stored = df.attrs.get("hhra_phys") if isinstance(df.attrs, Mapping) else None
        defaults = {k: v for k, v in (stored or {}).items() if k in _FRAME_FIELDS}
        ex = {k: v for k, v in cols.items() if k not in ("t", "u", "y")}
        return cls.from_arrays(
            cols["u"], cols["y"], fs=fs, t=cols.get("t"), **{**defaults, "extra": ex, **meta}
        )

    def to_dataframe(self) -> Any:
        """The record as a :class:`pandas.DataFrame` with columns ``t``, ``u``, ``y``, extras.

        Names, units, name and metadata go to ``df.attrs["hhra_phys"]``, so
        ``Dataset.from_dataframe(ds.to_dataframe())`` gives the same record back.
        """
        pd = _pandas()
        df = pd.DataFrame({"t": self.t, "u": self.u, "y": self.y, **self.extra})
        df.attrs["hhra_phys"] = copy.deepcopy(
            {k: getattr(self, k) for k in _FRAME_FIELDS}
        )
        return df


#: Dataset fields that travel with a DataFrame in ``df.attrs["hhra_phys"]``.
_FRAME_FIELDS = (
    "input_name", "input_unit", "output_name", "output_unit", "name", "source", "metadata",
)


def _pandas() -> Any:
    """pandas, imported on first use: it is an optional dependency."""
    try:
        import pandas
    except ImportError:
        raise ImportError(
            "pandas is needed for Dataset.from_dataframe/to_dataframe; install it with "
            "pip install 'hhra-phys[pandas]' (or pip install pandas)"
        ) from None
    return pandas
