"""File formats of a :class:`~hhra_phys.data.Dataset`: CSV (+ JSON side-car), MAT and NPZ.

CSV with a header row (plus a JSON side-car for names, units and metadata), MATLAB ``.mat``
(the user names the variables and their orientation) and NumPy ``.npz``; :func:`load` and
:func:`save` dispatch on the suffix. Every loader validates what it read (see
:mod:`hhra_phys.data.checks`) and raises a :class:`~hhra_phys.errors.DataError` subclass that
names the file. See ``docs/data.md``.

This module holds the dispatch (:func:`load`, :func:`save`, :func:`check_save_path`); the
loaders and writers are one module per family of format: :mod:`hhra_phys.data.csv_format`
(CSV/TSV), :mod:`hhra_phys.data.array_formats` (MAT/NPZ), with the side-car and the file
checks both share in :mod:`hhra_phys.data.sidecar`. Every name stays importable from here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hhra_phys.data.array_formats import load_mat, load_npz, save_npz
from hhra_phys.data.csv_format import load_csv, save_csv
from hhra_phys.data.dataset import Dataset
from hhra_phys.data.errors import DataFileExistsError, UnsupportedFormatError
from hhra_phys.data.sidecar import PathLike as PathLike
from hhra_phys.data.sidecar import _writable, sidecar_path
from hhra_phys.errors import ParameterError
from hhra_phys.outputs import OVERWRITE_HINT

__all__ = [
    "load",
    "load_csv",
    "load_mat",
    "load_npz",
    "save",
    "save_csv",
    "save_npz",
    "check_save_path",
    "sidecar_path",
]


def check_save_path(path: PathLike, overwrite: bool = False) -> list[Path]:
    """Check, before any work, that :func:`save` could write ``path``.

    Parameters
    ----------
    path : str or path-like
        A ``.csv`` (its side-car is checked too) or ``.npz`` file.
    overwrite : bool
        Accept existing files.

    Returns
    -------
    list of pathlib.Path
        The files :func:`save` would write.

    Raises
    ------
    UnsupportedFormatError, DataFileExistsError, OutputPathError
        Naming the path and the problem.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in (".csv", ".npz"):
        raise UnsupportedFormatError(
            f"{path}: can write .csv or .npz, not {suffix or '(no suffix)'!r}"
        )
    p = _writable(path, overwrite)
    if suffix == ".npz":
        return [p]
    side = sidecar_path(p)
    try:
        _writable(side, overwrite, what="side-car")
    except DataFileExistsError:
        raise DataFileExistsError(
            f"{side} (the side-car of {p.name}) exists; {OVERWRITE_HINT} to replace it"
        ) from None
    return [p, side]


def load(path: PathLike, **kw: Any) -> Dataset:
    """Load by suffix: ``.csv`` / ``.tsv`` (tab-separated), ``.mat``, ``.npz``.

    Keyword arguments go to :func:`load_csv`, :func:`load_mat` or :func:`load_npz`;
    ``delimiter`` and ``encoding`` (text options) are accepted as ``None`` for every format,
    so a caller may pass them unconditionally.
    """
    suffix = Path(path).suffix.lower()
    if suffix in (".mat", ".npz"):
        for key in ("delimiter", "encoding"):
            if kw.pop(key, None) is not None:
                raise ParameterError(
                    f"{path}: {key} applies to text files (.csv, .tsv), not {suffix}"
                )
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
    """Write by suffix: ``.csv`` (with side-car) or ``.npz``; see :func:`check_save_path`."""
    check_save_path(path, overwrite)
    if Path(path).suffix.lower() == ".csv":
        return save_csv(ds, path, overwrite=overwrite)
    return save_npz(ds, path, overwrite=overwrite)
