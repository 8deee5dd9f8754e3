"""CSV and TSV records: :func:`load_csv` and :func:`save_csv` (with the JSON side-car).

A text table with a header row: the bytes decoded and the delimiter detected
(:mod:`hhra_phys.data._text`), every row checked against the header, the columns of time,
input, output and extra channels found by name, index or a name with its unit in
brackets, and messages that give the file, the column and the line. Names, units and
metadata go to the side-car (:mod:`.sidecar`).
"""

from __future__ import annotations

import csv
import io
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
from hhra_phys.data.dataset import Dataset
from hhra_phys.data.errors import (
    DataFileExistsError,
    DataFormatError,
    MissingColumnError,
    NonNumericError,
)
from hhra_phys.data.sidecar import (
    PathLike,
    _check_description,
    _check_extra_name,
    _dataset_fields,
    _existing_file,
    _read_sidecar,
    _role,
    _sidecar_fs,
    _to_json,
    _writable,
    sidecar_path,
)
from hhra_phys.errors import DataError, ParameterError
from hhra_phys.outputs import OVERWRITE_HINT, atomic_write_text

__all__ = ["load_csv", "save_csv"]


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
