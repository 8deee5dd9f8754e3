"""Errors of the data layer: one subclass of :class:`~hhra_phys.errors.DataError` per problem.

The base hierarchy (``HHRAError``, ``DataError``, ...) lives in :mod:`hhra_phys.errors`; these
subclasses let callers tell a missing file from a missing column or a bad time axis, and
each also derives from the closest built-in (``FileNotFoundError``, ``KeyError``) so
generic handlers keep working.
"""

from __future__ import annotations

from hhra_phys.errors import DataError, OutputExistsError

__all__ = [
    "DataFileExistsError",
    "DataFileNotFoundError",
    "DataFormatError",
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
]


class DataFileNotFoundError(DataError, FileNotFoundError):
    """A data file (or the public data set) does not exist where it was looked for."""


class DataFileExistsError(DataError, OutputExistsError):
    """A writer refused to replace an existing file (pass ``overwrite=True``).

    Also an :class:`~hhra_phys.errors.OutputExistsError` (and ``FileExistsError``), like every
    "exists" refusal of the package.
    """


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
