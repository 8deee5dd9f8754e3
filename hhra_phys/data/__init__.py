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

The package is split by concept: :mod:`~hhra_phys.data.dataset` (the record),
:mod:`~hhra_phys.data.checks` (validation), :mod:`~hhra_phys.data.errors` (exceptions),
:mod:`~hhra_phys.data.formats` (files: :func:`load` and :func:`save` by suffix; the
loaders in :mod:`~hhra_phys.data.csv_format` and :mod:`~hhra_phys.data.array_formats`, the
side-car in :mod:`~hhra_phys.data.sidecar`) and :mod:`~hhra_phys.data.public` (the public
record). Import from ``hhra_phys.data``; the submodules are an implementation detail.
"""

from __future__ import annotations

from hhra_phys.data.checks import DataChecks
from hhra_phys.data.dataset import INTERSAMPLE, Dataset
from hhra_phys.data.errors import (
    DataFileExistsError,
    DataFileNotFoundError,
    DataFormatError,
    DimensionError,
    LengthMismatchError,
    MissingColumnError,
    NonExcitingInputError,
    NonFiniteError,
    NonMonotonicTimeError,
    NonNumericError,
    NonUniformTimeError,
    TimeAxisError,
    TooFewSamplesError,
    UnsupportedFormatError,
)
from hhra_phys.data.formats import (
    check_save_path,
    load,
    load_csv,
    load_mat,
    load_npz,
    save,
    save_csv,
    save_npz,
    sidecar_path,
)
from hhra_phys.data.public import PUBLIC_ACTUATOR_FILE, find_public_data, load_public_actuator

# Re-exported because callers import it from here (``from hhra_phys.data import DataError``).
from hhra_phys.errors import DataError as DataError

__all__ = [
    "PUBLIC_ACTUATOR_FILE",
    "DataChecks",
    "DataFileExistsError",
    "DataFileNotFoundError",
    "DataFormatError",
    "Dataset",
    "INTERSAMPLE",
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
    "check_save_path",
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
