"""What every file format of a record shares: file checks and the record's description.

The description beside the samples (names, units, sample rate, extra channels, metadata) is
the CSV's JSON side-car and the NPZ's meta entry: written, read, checked against the
samples and merged with the loader's arguments here. Also the checks of the file to read
or write and how messages name a column's role. Separate from the loaders
(:mod:`.csv_format`, :mod:`.array_formats`) because both use it.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hhra_phys.data import _text
from hhra_phys.data.dataset import INTERSAMPLE, Dataset
from hhra_phys.data.errors import (
    DataFileExistsError,
    DataFileNotFoundError,
    DataFormatError,
)
from hhra_phys.errors import DataError, OutputExistsError
from hhra_phys.outputs import check_output_path, jsonable

__all__ = ["PathLike", "sidecar_path"]

PathLike = str | os.PathLike

_SIDECAR_FORMAT = "hhra-phys dataset"


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


def _role(role: str) -> str:
    """How messages name a column's role."""
    return {"t": "the time t", "u": "the input u", "y": "the output y"}.get(
        role, f"extra channel {role!r}"
    )


def _check_extra_name(key: str, source: PathLike) -> None:
    if key in ("t", "u", "y"):
        raise DataError(
            f"{source}: extra channel name {key!r} clashes with the dataset's t, u, y; name it "
            "differently with a mapping {name: column}"
        )
