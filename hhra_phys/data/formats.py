"""File formats of a :class:`~hhra_phys.data.Dataset`: CSV (+ JSON side-car), MAT and NPZ.

CSV with a header row (plus a JSON side-car for names, units and metadata), MATLAB ``.mat``
(the user names the variables and their orientation) and NumPy ``.npz``; :func:`load` and
:func:`save` dispatch on the suffix. Every loader validates what it read (see
:mod:`hhra_phys.data.checks`) and raises a :class:`~hhra_phys.errors.DataError` subclass that
names the file. See ``docs/data.md``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.data import _text
from hhra_phys.data.checks import (
    DataChecks,
    _check_rate,
    _rows_text,
    _time_axis,
    _validate,
)
from hhra_phys.data.dataset import INTERSAMPLE, Dataset
from hhra_phys.data.errors import (
    DataFileExistsError,
    DataFileNotFoundError,
    DataFormatError,
    DimensionError,
    LengthMismatchError,
    MissingColumnError,
    NonNumericError,
    UnsupportedFormatError,
)
from hhra_phys.errors import DataError, OutputExistsError, ParameterError
from hhra_phys.outputs import (
    OVERWRITE_HINT,
    atomic_path,
    atomic_write_text,
    check_output_path,
    jsonable,
)

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

PathLike = str | os.PathLike

_SIDECAR_FORMAT = "hhra-phys dataset"
_NPZ_META_KEY = "__hhra_meta__"
_NPZ_EXTRA_PREFIX = "extra__"


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


def _writable(path: PathLike, overwrite: bool, what: str = "data file") -> Path:
    """The package's output check, with the data layer's own "exists" error."""
    try:
        return check_output_path(path, overwrite=overwrite, what=what)
    except OutputExistsError as exc:
        raise DataFileExistsError(str(exc)) from None


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
        return json.dumps(jsonable(_description(ds)), indent=2)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{target}: metadata is not JSON-able ({exc})") from None


def _from_json(text: str, source: PathLike) -> dict[str, Any]:
    try:
        info = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise DataFormatError(f"{source}: invalid JSON ({exc})") from None
    if not isinstance(info, dict):  # a list, a number: no description of a record at all
        raise DataFormatError(
            f"{source}: a side-car must be a JSON object (written by save), got "
            f"{type(info).__name__} {_short(info)}; fix or delete it (or pass sidecar=False)")
    if info.get("format") != _SIDECAR_FORMAT:
        return {}  # someone else's JSON file: not ours to interpret
    # Ours: check the types here so that a hand-edited side-car gives a message, not a
    # TypeError deep in the loader.
    expected: dict[str, tuple[type, ...]] = {
        "name": (str,), "input_name": (str,), "input_unit": (str,), "output_name": (str,),
        "output_unit": (str,), "extra": (list,), "n": (int,), "fs": (int, float),
        "metadata": (dict,),
    }
    for key, types in expected.items():
        value = info.get(key)
        if value is not None and (not isinstance(value, types) or isinstance(value, bool)):
            raise DataFormatError(
                f"{source}: field {key!r} must be {' or '.join(t.__name__ for t in types)}, "
                f"got {value!r}"
            )
    if not all(isinstance(e, str) for e in info.get("extra") or []):
        raise DataFormatError(f"{source}: 'extra' must list channel names, got {info['extra']!r}")
    _check_values(info, source)
    return info


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _check_values(info: dict[str, Any], source: PathLike) -> None:
    """The values of a side-car's fields (their types are checked already): a sample rate
    that is no rate, a negative count, an unknown inter-sample behaviour are refused with
    the file and the key named (they used to be ignored silently)."""
    fix = "; fix or delete it (or pass sidecar=False)"
    fs = info.get("fs")
    if fs is not None and not (math.isfinite(fs) and fs > 0):
        raise DataFormatError(f"{source}: field 'fs' must be a sample rate > 0 Hz, got "
                              f"{fs!r}{fix}")
    n = info.get("n")
    if n is not None and n < 0:
        raise DataFormatError(f"{source}: field 'n' must be a count >= 0, got {n!r}{fix}")
    meta = info.get("metadata") or {}
    for key, value in (("intersample", info.get("intersample", None)),
                       ("metadata.intersample", meta.get("intersample"))):
        if key == "intersample" and "intersample" not in info:
            continue
        if value is not None and value not in INTERSAMPLE:
            raise DataFormatError(
                f"{source}: field {key!r} must be one of "
                f"{', '.join(map(repr, INTERSAMPLE))}, got {_short(value)}{fix}")
    if "intersample" in info:  # where a hand-written side-car may put it: honoured there too
        if "intersample" in meta and meta["intersample"] != info["intersample"]:
            raise DataFormatError(
                f"{source}: 'intersample' {info['intersample']!r} and 'metadata.intersample' "
                f"{meta['intersample']!r} disagree{fix}")
        if info["intersample"] is not None:
            info["metadata"] = {**meta, "intersample": info["intersample"]}


def _read_sidecar(side: Path) -> dict[str, Any]:
    try:
        data = side.read_bytes()
    except OSError as exc:
        raise DataFormatError(f"{side}: cannot read the side-car ({exc.strerror})") from None
    text, _ = _text.decode(data, str(side))
    return _from_json(text, side)


def _sidecar_fs(info: Mapping[str, Any]) -> float | None:
    fs = info.get("fs")
    return float(fs) if isinstance(fs, int | float) and math.isfinite(fs) and fs > 0 else None


def _check_description(
    info: Mapping[str, Any],
    where: str,
    ds: Dataset,
    *,
    time_from_file: bool,
    channels: Sequence[str],
    units: Mapping[str, str | None] | None = None,
) -> None:
    """A side-car (or NPZ meta entry) that disagrees with the samples is an error.

    It would otherwise silently relabel the record (a wrong fs changes every time constant).
    ``channels`` are the columns/keys the file has; ``units`` the units found in the file
    for "input_unit"/"output_unit" (e.g. ``angle [deg]`` in a CSV header).
    """
    fix = "; fix or delete it (or pass sidecar=False)"
    n = info.get("n")
    if n is not None and n != ds.n:
        raise DataError(f"{where} says n = {n} samples but {ds.source} has {ds.n}{fix}")
    fs = _sidecar_fs(info)
    if time_from_file and fs is not None and abs(ds.fs - fs) > max(ds.checks.time_rtol, 1e-9) * fs:
        raise DataError(
            f"{where} says fs = {fs:.9g} Hz but the time column of {ds.source} implies "
            f"fs = {ds.fs:.9g} Hz{fix}"
        )
    missing = [e for e in info.get("extra") or [] if e not in channels]
    if missing:
        raise DataError(
            f"{where} lists extra channel {missing[0]!r} but {ds.source} has no such column "
            f"(it has: {', '.join(channels)}){fix}"
        )
    for key, found in (units or {}).items():
        said = info.get(key)
        if found is not None and said is not None and found != said:
            raise DataError(
                f"{where} says {key} = {said!r} but the header of {ds.source} says {found!r}"
                f"{fix}"
            )


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
    found_units: Mapping[str, str | None] | None = None,
) -> dict[str, Any]:
    """Names, units and metadata: explicit argument > file's description > default.

    ``found_units`` are units the file itself states (``angle [rad]`` in a CSV header):
    they replace the defaults, so a labelled column is never read in another unit.
    """
    found = {k: v for k, v in (found_units or {}).items() if v}

    def pick(key: str, explicit: str | None, default: str | None) -> Any:
        if explicit is not None:
            return explicit
        return info.get(key) if info.get(key) is not None else default

    meta = dict(info.get("metadata") or {})
    meta.update(metadata or {})
    return {
        "input_name": pick("input_name", input_name, "current"),
        "input_unit": pick("input_unit", input_unit, found.get("input_unit", "mA")),
        "output_name": pick("output_name", output_name, "angle"),
        "output_unit": pick("output_unit", output_unit, found.get("output_unit", "deg")),
        "name": pick("name", name, default_name),
        "metadata": meta,
    }


# --------------------------------------------------------------------------- CSV


def _csv_records(
    path: Path, delimiter: str | None, comments: str | None, encoding: str | None
) -> tuple[str, list[tuple[int, list[str]]], str]:
    """``(delimiter, [(line_number, fields), ...], header_text)`` of a text record.

    Every non-blank, non-comment line is one record (numeric data has no quoted
    multi-line fields); line numbers are 1-based lines of the file. The bytes are decoded
    by :func:`hhra_phys.data._text.decode` and ``delimiter=None`` is detected.
    """
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read ({exc.strerror})") from None
    text, _ = _text.decode(data, str(path), encoding)
    numbers: list[int] = []
    kept: list[str] = []
    # newline="": split on \n, \r\n and \r only, as open(newline="") does for csv.
    for number, line in enumerate(io.StringIO(text, newline=""), start=1):
        stripped = line.strip()
        if not stripped or (comments and stripped.startswith(comments)):
            continue
        numbers.append(number)
        kept.append(line)
    if delimiter is None:
        delimiter = _text.detect_delimiter(kept)
    header_text = kept[0] if kept else ""
    if delimiter == _text.WHITESPACE:
        split = [(n, ln.split()) for n, ln in zip(numbers, kept, strict=True)]
        return delimiter, split, header_text
    records: list[tuple[int, list[str]]] = []
    reader = csv.reader(kept, delimiter=delimiter)
    try:
        for fields in reader:
            records.append((numbers[reader.line_num - 1], [f.strip() for f in fields]))
    except csv.Error as exc:
        line = numbers[min(reader.line_num, len(numbers)) - 1] if numbers else 0
        raise DataFormatError(f"{path}: line {line}: {exc}") from None
    return delimiter, records, header_text


def _role(role: str) -> str:
    """How messages name a column's role."""
    return {"t": "the time t", "u": "the input u", "y": "the output y"}.get(
        role, f"extra channel {role!r}"
    )


#: The CLI flag that names the column of each role.
_ROLE_FLAG = {"t": "--time-col", "u": "--input-col", "y": "--output-col"}


def _parse_column(cells: list[str], label: str, lines: np.ndarray, path: Path) -> np.ndarray:
    try:
        return np.array(cells, dtype=np.float64)
    except (ValueError, OverflowError):
        pass
    # NumPy and float() disagree on a few spellings ("1_000"): float() decides, cell by cell.
    values = np.empty(len(cells))
    bad: list[int] = []
    for i, cell in enumerate(cells):
        try:
            values[i] = float(cell)
        except (TypeError, ValueError, OverflowError):
            bad.append(i)
    if not bad:
        return values
    first = cells[bad[0]]
    what = "an empty cell" if first == "" else repr(first)
    # A decimal comma (German/French exports, often ';'-separated and Latin-1): say so.
    comma = sum(bool(re.fullmatch(r"[-+]?\d*,\d+(?:[eE][-+]?\d+)?", cells[i].strip()))
                for i in bad)
    hint = ("; the cells use a decimal comma: export with a decimal point (or replace ',' "
            "by '.' in the numbers) and keep ';' as the separator"
            if comma > len(bad) // 2 else "")
    raise NonNumericError(
        f"{path}: column {label!r} has {len(bad)} non-numeric cell{'s' * (len(bad) > 1)} "
        f"at {_rows_text(np.array(bad), lines)}; first: {what}{hint}"
    )


def _check_extra_name(key: str, source: PathLike) -> None:
    if key in ("t", "u", "y"):
        raise DataError(
            f"{source}: extra channel name {key!r} clashes with the dataset's t, u, y; name it "
            "differently with a mapping {name: column}"
        )


def _column_index(
    spec: str | int, header: list[str], path: Path, role: str, hint: str = ""
) -> int:
    if isinstance(spec, int | np.integer) and not isinstance(spec, bool):
        if not -len(header) <= spec < len(header):
            raise MissingColumnError(
                f"{path}: column index {spec} for {_role(role)} is out of range; the file has "
                f"{len(header)} columns: {', '.join(header)}{hint}"
            )
        return int(spec) % len(header)
    if not isinstance(spec, str):
        raise ParameterError(f"column for {_role(role)} must be a name or an index, got {spec!r}")
    hits = [i for i, h in enumerate(header) if h == spec]
    if not hits:  # "y" names a column "y [rad]": the unit in brackets is the column's unit
        hits = [i for i, h in enumerate(header) if _UNIT.sub("", h).strip() == spec]
    if not hits:
        raise MissingColumnError(
            f"{path}: no column {spec!r} (for {_role(role)}); available columns: "
            + ", ".join(header)
            + (hint or f"; name it with {_ROLE_FLAG.get(role, '--time-col/--input-col/...')} "
                       "(Python: t=, u=, y=)")
        )
    if len(hits) > 1:
        raise DataFormatError(f"{path}: the header names column {spec!r} {len(hits)} times")
    return hits[0]


_UNIT = re.compile(r"\[([^\[\]]+)\]\s*$")


def _header_unit(name: str) -> str | None:
    """``"Winkel [°]"`` -> ``"°"``: the unit a CSV header gives in brackets, if any."""
    m = _UNIT.search(name)
    return m.group(1).strip() if m else None


def _parsed_delimiter(delimiter: str | None) -> str | None:
    """The delimiter a user named (``None``: detect it), a bad one as a ParameterError."""
    if delimiter is None:
        return None
    try:
        return _text.parse_delimiter(delimiter)
    except ValueError as exc:
        raise ParameterError(str(exc)) from None


def _csv_table(
    p: Path, delimiter: str | None, comments: str | None, encoding: str | None
) -> tuple[list[str], list[list[str]], np.ndarray, str]:
    """``(header, rows, line of each row, delimiter hint)`` of a CSV file.

    Every row must have as many fields as the header; the hint (empty, or a note on
    another delimiter the header looks split by) goes into the messages about columns.
    """
    used, records, header_text = _csv_records(p, delimiter, comments, encoding)
    if not records:
        raise DataFormatError(f"{p}: empty file (no header row)")
    (header_line, header), body = records[0], records[1:]
    hint = _text.delimiter_hint(header_text, used)
    rows: list[list[str]] = []
    lines: list[int] = []
    for number, fields in body:
        if len(fields) != len(header):
            raise DataFormatError(
                f"{p}: line {number} has {len(fields)} fields but the header (line {header_line}) "
                f"has {len(header)} (delimiter {_text.display(used)!r}){hint}"
            )
        rows.append(fields)
        lines.append(number)
    return header, rows, np.array(lines, dtype=np.int64), hint


def _column_roles(
    header: list[str],
    t: str | int | None,
    u: str | int,
    y: str | int,
    extra: Sequence[str | int] | Mapping[str, str | int],
    fs: float | None,
    p: Path,
    hint: str,
) -> dict[str, int]:
    """``{role: column index}`` for t (when the file has it), u, y and each extra channel."""
    roles: dict[str, str | int] = {}
    if t is not None and (isinstance(t, int) or t in header or fs is None):
        roles["t"] = t
    roles.update({"u": u, "y": y})
    pairs = extra.items() if isinstance(extra, Mapping) else ((e, e) for e in extra)
    for key, e in pairs:
        if not isinstance(key, str):  # an index without a name: use the header's
            key = header[_column_index(e, header, p, "extra", hint)]
        _check_extra_name(key, p)
        roles[key] = e
    return {role: _column_index(spec, header, p, role, hint) for role, spec in roles.items()}


def load_csv(
    path: PathLike,
    t: str | int | None = "t",
    u: str | int = "u",
    y: str | int = "y",
    extra: Sequence[str | int] | Mapping[str, str | int] | None = None,
    delimiter: str | None = None,
    fs: float | None = None,
    *,
    comments: str | None = "#",
    encoding: str | None = None,
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
        column is absent (or ``t=None``) the time axis is built from ``fs`` (or the
        side-car's fs): ``t = arange(N) / fs``; with neither the record is in sample units
        (fs = 1, ``metadata["time_unit"] = "samples"``).
    extra : sequence of str or int, or mapping of name to column, optional
        Further columns to keep in ``Dataset.extra``. A mapping is ``{new name: column}``:
        ``{"p_a": "pressure A"}`` stores the column "pressure A" as ``extra["p_a"]``.
        ``None`` (default): the extras the side-car lists, else none.
    delimiter : str or None
        Field separator: ``","``, ``";"``, ``"\\t"``, any one character, or ``"whitespace"``
        (runs of blanks and tabs). ``None`` (default) detects it among ``,`` ``;`` tab and
        whitespace from the header and the first lines.
    fs : float, optional
        Sample rate [Hz]; checked against the time column when both exist.
    comments : str or None
        Prefix of comment lines (default "#").
    encoding : str or None
        Text encoding; ``None`` (default) detects UTF-8 (with or without BOM), UTF-16/32
        with a BOM, and Windows-1252/Latin-1.
    sidecar : bool
        Read ``sidecar_path(path)`` (written by :func:`save_csv`) for names, units and
        metadata when it exists. Its ``n``, ``fs``, extra channels and units must agree
        with the file.
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
        the row (0-based sample index) and the line of the file. A binary or undecodable
        file raises :class:`DataFormatError`; a missing column in a header that looks
        delimited by something else says which delimiter to pass.
    """
    p = _existing_file(path)
    checks = checks or DataChecks()
    delimiter = _parsed_delimiter(delimiter)
    side = sidecar_path(p)
    info: dict[str, Any] = _read_sidecar(side) if sidecar and side.is_file() and side != p else {}
    where = f"the side-car {side}"

    header, rows, line_of, hint = _csv_table(p, delimiter, comments, encoding)
    if extra is None:
        extra = [e for e in info.get("extra") or [] if e in header]
    if fs is None and (t is None or (not isinstance(t, int) and t not in header)):
        fs = _sidecar_fs(info)  # no time column: the side-car knows the sample rate
    index = _column_roles(header, t, u, y, extra, fs, p, hint)
    columns = {role: [r[i] for r in rows] for role, i in index.items()}
    values = {
        role: _parse_column(cells, header[index[role]], line_of, p)
        for role, cells in columns.items()
    }

    time, sample_units = _time_axis(values.get("t"), fs, len(rows))
    header_units = {
        "input_unit": _header_unit(header[index["u"]]),
        "output_unit": _header_unit(header[index["y"]]),
    }
    fields_ = _dataset_fields(
        info,
        input_name=input_name,
        input_unit=input_unit,
        output_name=output_name,
        output_unit=output_unit,
        name=name,
        metadata=metadata,
        default_name=p.stem,
        found_units=header_units,
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
    if info:
        _check_description(
            info,
            where,
            ds,
            time_from_file="t" in values,
            channels=header,
            units=header_units,
        )
    return ds


def save_csv(ds: Dataset, path: PathLike, overwrite: bool = False) -> Path:
    """Write ``ds`` as CSV (columns ``t,u,y`` then the extras) plus a JSON side-car.

    Values are written with ``repr`` precision, so a round trip is exact. Names, units and
    metadata go to ``sidecar_path(path)`` (``rig.csv`` -> ``rig.json``). Both files are
    written atomically (a failure leaves no partial file).

    Parameters
    ----------
    ds : Dataset
    path : str or path-like
        Target CSV file; its folder must exist.
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
        _writable(side, overwrite, what="side-car")
    except DataFileExistsError:
        raise DataFileExistsError(
            f"{side} (the side-car of {p.name}) exists; {OVERWRITE_HINT} to replace it"
        ) from None
    text = _to_json(ds, side)
    data = np.column_stack([ds.t, ds.u, ds.y, *ds.extra.values()])
    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    writer.writerow(["t", "u", "y", *ds.extra])
    writer.writerows(data.tolist())  # csv writes floats with repr(): exact round trip
    atomic_write_text(p, buffer.getvalue())
    atomic_write_text(side, text + "\n")
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


# --------------------------------------------------------------------------- dispatch


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
