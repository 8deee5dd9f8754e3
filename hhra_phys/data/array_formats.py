"""Records stored as named arrays: MATLAB ``.mat`` and NumPy ``.npz``.

:func:`load_mat` and :func:`load_npz` pick the signals by variable specs (``"y"``,
``"X[0]"`` a row, ``"X[:,1]"`` a column, 0-based) and check what each variable holds;
:func:`save_npz` writes a compressed archive with the description in its
``__hhra_meta__`` entry. scipy.io is imported only when a ``.mat`` file is read.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.data.checks import (
    DataChecks,
    _check_rate,
    _time_axis,
    _validate,
)
from hhra_phys.data.dataset import Dataset
from hhra_phys.data.errors import (
    DataFormatError,
    DimensionError,
    LengthMismatchError,
    MissingColumnError,
    NonNumericError,
)
from hhra_phys.data.sidecar import (
    PathLike,
    _check_description,
    _check_extra_name,
    _dataset_fields,
    _existing_file,
    _from_json,
    _role,
    _to_json,
    _writable,
)
from hhra_phys.errors import ParameterError
from hhra_phys.outputs import atomic_path

__all__ = ["load_mat", "load_npz", "save_npz"]

_NPZ_META_KEY = "__hhra_meta__"
_NPZ_EXTRA_PREFIX = "extra__"


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
            f"{who}: variable {var!r} is not a numeric array (dtype {arr.dtype}); structs, "
            "cells, strings and Python objects cannot be used: store numbers"
        )
    if arr.ndim == 0:
        raise DimensionError(f"{who}: variable {var!r} is a single number ({arr.item()!r}), "
                             "not a signal: store one value per sample")
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
    import scipy.io  # here, not at import: a third of `import hhra_phys`

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
        loaded = np.load(p, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):  # a .npy saved under .npz
            raise DataFormatError(
                f"{p}: a single NumPy array (.npy format, shape "
                f"{'x'.join(map(str, np.shape(loaded)))}), not an .npz archive of named "
                "signals: save it with np.savez(path, t=..., u=..., y=...)")
        with loaded as archive:
            variables = {}
            for k in archive.files:
                try:
                    variables[k] = archive[k]
                except ValueError as exc:
                    if "allow_pickle" not in str(exc):
                        raise
                    # Objects are stored pickled; unpickling a file runs code, so never.
                    raise DataFormatError(
                        f"{p}: member {k!r} holds Python objects, which are not read (loading "
                        "them would run code from the file): store numeric arrays") from None
    except DataFormatError:
        raise
    except Exception as exc:  # zipfile and format errors
        # NumPy reads any file that is neither zip nor .npy as a pickle, and says so.
        why = ("neither a zip archive nor a .npy array: damaged, or another format"
               if "pickle" in str(exc) else f"{type(exc).__name__}: {exc}")
        raise DataFormatError(
            f"{p}: not a readable .npz archive ({why}); write it with "
            "np.savez(path, t=..., u=..., y=...)") from None
    info: dict[str, Any] = {}
    if _NPZ_META_KEY in variables:
        info = _from_json(str(variables.pop(_NPZ_META_KEY)), f"{p} ({_NPZ_META_KEY})")
    stored = [k[len(_NPZ_EXTRA_PREFIX) :] for k in variables if k.startswith(_NPZ_EXTRA_PREFIX)]
    if extra is None:
        extra = {name: _NPZ_EXTRA_PREFIX + name for name in stored}
    ds = _from_variables(
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
    if info:
        time_key = _parse_spec(t)[0] if t is not None else None
        _check_description(
            info,
            f"the {_NPZ_META_KEY} entry of {p}",
            ds,
            time_from_file=time_key in variables,
            channels=stored,
        )
    return ds


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
    with atomic_path(p) as tmp, tmp.open("wb") as fh:
        # A file object keeps numpy from appending ".npz"; it is closed before the rename.
        np.savez_compressed(fh, **arrays)
    return p
