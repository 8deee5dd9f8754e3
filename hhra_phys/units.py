"""Units of a record's channels: conversion to a model's units and plausibility checks.

A model is written in fixed units (the HHRA: valve current in mA, shaft angle in degrees,
time in seconds). A record that says, in its header or side-car, that its output is in
radians is converted when the factor is known (:func:`convert_record`); a unit that cannot
be converted is an error that names both units, because fitting it as is would silently
rescale every parameter. ``"raw"`` (or an empty unit) means "scale unknown": the record is
taken as it is, and the model's gains absorb the scale.

Records whose *values* do not fit the unit they claim (an angle record in radians labelled
degrees, an input in A labelled mA, a time column in milliseconds) cannot be caught from
the labels; :func:`range_warnings` compares the ranges with what a model declares plausible
and says what the likely mistake is.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.errors import DataError, ParameterError

__all__ = [
    "GENERIC_LABELS",
    "HHRA_LABELS",
    "SCALE_FREE_UNITS",
    "TIME_UNITS",
    "ChannelRange",
    "conversion_factor",
    "convert_record",
    "range_warnings",
    "label_record",
    "rescale_time",
]

#: The HHRA's channel names and units: what the loaders give a record that states none.
HHRA_LABELS: dict[str, str] = {"input_name": "current", "input_unit": "mA",
                               "output_name": "angle", "output_unit": "deg"}
#: Labels of a record that states none, for a model that is not the HHRA and declares
#: none (an empty unit: scale unknown, never converted).
GENERIC_LABELS: dict[str, str] = {"input_name": "input", "input_unit": "",
                                  "output_name": "output", "output_unit": ""}

#: Units that say "the scale is unknown": never converted, never a conflict.
SCALE_FREE_UNITS = ("", "raw", "-", "1", "counts", "a.u.")

#: Factor from each unit to the first unit of its family (value_in_base = value * factor).
_FAMILIES: tuple[dict[str, float], ...] = (
    {"deg": 1.0, "°": 1.0, "degree": 1.0, "degrees": 1.0, "rad": 180.0 / math.pi,
     "mrad": 0.18 / math.pi, "rev": 360.0, "turn": 360.0},
    {"mA": 1.0, "A": 1000.0, "uA": 1e-3, "µA": 1e-3},
    {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "min": 60.0},
    {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "bar": 1e5, "mbar": 100.0, "psi": 6894.757293168},
    {"V": 1.0, "mV": 1e-3},
    {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "um": 1e-6},
)

#: Time units ``--time-unit`` accepts, with their factor to seconds.
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6}


def _family(unit: str) -> dict[str, float] | None:
    for fam in _FAMILIES:
        if unit in fam:
            return fam
    return None


def conversion_factor(from_unit: str, to_unit: str) -> float | None:
    """Factor ``k`` with ``value_in_to = k * value_in_from``, or None if unknown.

    Parameters
    ----------
    from_unit, to_unit : str
        Unit strings as written in headers and side-cars (``"deg"``, ``"rad"``, ``"mA"``,
        ``"A"``, ``"ms"`` ...). Equal strings give 1.

    Returns
    -------
    float or None
        None when the units are not of one known family (``"V"`` to ``"deg"``).
    """
    if from_unit == to_unit:
        return 1.0
    fam = _family(from_unit)
    if fam is None or to_unit not in fam:
        return None
    return fam[from_unit] / fam[to_unit]


def convert_record(
    data: Dataset, *, input_unit: str | None = None, output_unit: str | None = None
) -> tuple[Dataset, list[str]]:
    """``data`` in the units a model is written in, and a note per converted channel.

    Parameters
    ----------
    data : Dataset
        The record, with the units its file declared (``input_unit``, ``output_unit``).
    input_unit, output_unit : str, optional
        The model's units (None: any unit is accepted for that channel).

    Returns
    -------
    Dataset
        The same object when nothing was converted, else a copy with converted values,
        the model's unit strings and ``metadata["converted_units"]``.
    list of str
        One sentence per conversion ("output converted from rad to deg (x 57.3)").

    Raises
    ------
    DataError
        A channel's unit is neither the model's, nor convertible to it, nor scale-free;
        the message names the file, the channel and both units.
    """
    changes: dict[str, object] = {}
    notes: list[str] = []
    done: dict[str, list[object]] = {}
    for role, want in (("input", input_unit), ("output", output_unit)):
        have = getattr(data, f"{role}_unit")
        if want is None or have == want or have.strip().lower() in SCALE_FREE_UNITS:
            continue
        k = conversion_factor(have, want)
        if k is None:
            raise DataError(
                f"{data.source or data.name or 'record'}: the {role} "
                f"{getattr(data, f'{role}_name')!r} is in {have!r} but the model expects "
                f"{want!r}, and hhra-phys knows no conversion between them; fix the unit in "
                "the file's header or side-car (or use 'raw' to fit it without a unit)"
            )
        arr = data.u if role == "input" else data.y
        changes["u" if role == "input" else "y"] = arr * k
        changes[f"{role}_unit"] = want
        done[role] = [have, want, k]
        if k != 1.0:  # a synonym ("°" for "deg") is relabelled without a word
            notes.append(f"{role} {getattr(data, f'{role}_name')!r} converted from {have} to "
                         f"{want} (x {k:.6g}) for the model")
    if not changes:
        return data, notes
    meta = {**data.metadata, "converted_units": done}
    return data._replace(metadata=meta, **changes), notes


def rescale_time(data: Dataset, unit: str) -> Dataset:
    """The record with its time column read in ``unit`` (``"ms"``: divided by 1000).

    Parameters
    ----------
    data : Dataset
        A record with a time axis (not in sample units).
    unit : {"s", "ms", "us"}
        Unit the file's time column is in.

    Raises
    ------
    ParameterError
        Unknown unit, or a record without a time column (in sample units).
    """
    if unit not in TIME_UNITS:
        raise ParameterError(f"--time-unit must be one of {', '.join(TIME_UNITS)}, got {unit!r}")
    if unit == "s":
        return data
    if data.time_unit == "samples":
        raise ParameterError(
            f"--time-unit {unit}: {data.source or 'the record'} has no time column to rescale "
            "(it is in sample units); give --fs instead"
        )
    meta = {**data.metadata, "time_column_unit": unit}
    return data._replace(t=data.t * TIME_UNITS[unit], metadata=meta)


@dataclass(frozen=True)
class ChannelRange:
    """What a model considers a plausible range of one channel in its unit.

    Attributes
    ----------
    unit : str
        The unit the range is in.
    low, high : float
        Plausible bounds of the channel's *span* (max - min) for outputs, or its peak
        magnitude for inputs (``kind``); outside them a warning is given.
    kind : {"span", "peak"}
        Which statistic is compared.
    too_low, too_high : str
        The likely mistake when the statistic is below ``low`` / above ``high``.
    """

    unit: str
    low: float
    high: float
    kind: str = "span"
    too_low: str = ""
    too_high: str = ""


def _statistic(x: np.ndarray, kind: str) -> float:
    return float(np.max(x) - np.min(x)) if kind == "span" else float(np.max(np.abs(x)))


def range_warnings(
    data: Dataset,
    ranges: Mapping[str, ChannelRange],
    fs_range: tuple[float, float] | None = None,
) -> list[str]:
    """Warnings for channels whose values do not fit the unit the model works in.

    Parameters
    ----------
    data : Dataset
    ranges : mapping of "input"/"output" to ChannelRange
        Only channels whose unit equals the range's unit are checked (a "raw" channel
        has no plausible range).
    fs_range : (float, float), optional
        Plausible sample rates [Hz] of a record with a time axis; outside it the time
        column is probably in another unit.

    Returns
    -------
    list of str
        One sentence per implausible channel, naming the file, the channel, the value
        found and the likely mistake.
    """
    where = data.source or data.name or "record"
    out: list[str] = []
    for role, rng in ranges.items():
        unit = getattr(data, f"{role}_unit")
        if unit != rng.unit:
            continue
        x = data.u if role == "input" else data.y
        value = _statistic(x, rng.kind)
        what = "range" if rng.kind == "span" else "largest magnitude"
        name = getattr(data, f"{role}_name")
        if value < rng.low and rng.too_low:
            out.append(f"{where}: the {role} {name!r} has a {what} of {value:.3g} {unit}, "
                       f"below the plausible {rng.low:g} {unit}: {rng.too_low}")
        elif value > rng.high and rng.too_high:
            out.append(f"{where}: the {role} {name!r} has a {what} of {value:.3g} {unit}, "
                       f"above the plausible {rng.high:g} {unit}: {rng.too_high}")
    if fs_range is not None and data.time_unit == "s":
        lo, hi = fs_range
        if data.fs < lo:
            out.append(f"{where}: sample rate {data.fs:.3g} Hz (period {data.dt:.3g} s) is "
                       f"below the plausible {lo:g} Hz: is the time column in ms? "
                       "(pass --time-unit ms)")
        elif data.fs > hi:
            out.append(f"{where}: sample rate {data.fs:.3g} Hz is above the plausible "
                       f"{hi:g} Hz: is the time column in s while labelled otherwise?")
    return out


def label_record(data: Dataset, given: Mapping[str, str | None] | None = None,
                 model: object | None = None) -> tuple[Dataset, list[str]]:
    """A record's channel names and units for a model that is not the HHRA.

    Precedence per channel: ``given`` (the command line's ``--input-unit`` ...) > what
    the record states (header, side-car) > what the model declares (attributes
    ``input_name``, ``input_unit``, ``output_name``, ``output_unit`` of the model
    object, if it has them; :class:`~hhra_phys.model.Model`'s own symbols ``u`` and
    ``y`` are not a declaration) > :data:`GENERIC_LABELS`. A channel whose name and unit
    are both the HHRA's (:data:`HHRA_LABELS`, the loaders' default) is taken as not
    stated: a plain CSV of volts is then not read as mA and degrees.

    Parameters
    ----------
    data : Dataset
        The record as loaded.
    given : mapping, optional
        Explicit labels by field name (``None`` values: not given).
    model : object, optional
        The user's model.

    Returns
    -------
    data : Dataset
        Relabelled (a new dataset; values unchanged).
    notes : list of str
        What was relabelled, in words.
    """
    given = {k: v for k, v in (given or {}).items() if v is not None}
    new: dict[str, str] = {}
    notes: list[str] = []
    for side in ("input", "output"):
        nk, uk = f"{side}_name", f"{side}_unit"
        stated = not (getattr(data, nk) == HHRA_LABELS[nk]
                      and getattr(data, uk) == HHRA_LABELS[uk])
        for key in (nk, uk):
            if key in given:
                value = given[key]
            elif stated:
                continue
            else:
                declared = getattr(model, key, None)
                # The base Model's own "u"/"y" are symbols, not a declaration.
                value = (declared if isinstance(declared, str) and declared
                         and declared not in ("u", "y") else GENERIC_LABELS[key])
            if value != getattr(data, key):
                new[key] = value
    if new:
        notes.append("record labelled " + ", ".join(f"{k} {v!r}" for k, v in new.items())
                     + " (--input-unit, --output-unit, --input-name, --output-name set them)")
        data = replace(data, **new)
    return data, notes
