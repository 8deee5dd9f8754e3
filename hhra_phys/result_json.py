"""The fit JSON's format, and the checks a fit result read from JSON must pass.

:meth:`hhra_phys.result.FitResult.from_json` reads a result back through these: its
header (:data:`FORMAT_NAME`, :data:`FORMAT_VERSION`), its model (a known class), every
parameter's value (a finite number, within :data:`FAR_OUTSIDE` of its box), the free
names, the covariance and the records, each refused with a message naming the entry.
Separate from :mod:`hhra_phys.result` so that the result's own code reads without the
validation of edited files; every name here is also importable from
:mod:`hhra_phys.result`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from hhra_phys.errors import DataError, ModelError
from hhra_phys.model import Model

__all__: list[str] = []


FORMAT_NAME = "hhra-phys fit result"
FORMAT_VERSION = 1


#: A saved value this many times beyond its parameter's box is refused: no fit ends there
#: (a box is widened by a few decades at most), and the model's Jacobian overflows.
FAR_OUTSIDE = 1e12

_EDIT = "; give the JSON a fit wrote (FitResult.save, 'hhra-phys fit --json'), unedited"


def _check_header(d: Mapping[str, Any], source: str) -> None:
    """``format`` and ``version`` of a fit result: present, ours, and one this reads."""
    if "format" not in d:
        raise DataError(f"{source}: not an hhra-phys fit result (missing 'format')")
    if d["format"] != FORMAT_NAME:
        raise DataError(f"{source}: 'format' is {d['format']!r:.60}, not {FORMAT_NAME!r}: "
                        "not an hhra-phys fit result")
    version = d.get("version", FORMAT_VERSION)
    if isinstance(version, bool) or not isinstance(version, int) or not (
            1 <= version <= FORMAT_VERSION):
        raise DataError(f"{source}: 'version' is {version!r:.40}; this hhra-phys reads fit "
                        f"results of version 1 to {FORMAT_VERSION}{_EDIT}")


def _model_of(spec: Any, source: str) -> Model:
    """The model of a fit result's ``model`` entry; an unknown class is an error (it was
    silently rebuilt as a plain Model)."""
    if not isinstance(spec, Mapping) or not isinstance(spec.get("parts"), list):
        raise DataError(f"{source}: 'model' must be an object with a list of 'parts'{_EDIT}")
    from hhra_phys.model import MODEL_TYPES

    cls = spec.get("class", "Model")
    if cls != "Model" and cls not in MODEL_TYPES:
        raise DataError(f"{source}: 'model.class' {cls!r:.60} is not a known model (known: "
                        f"Model, {', '.join(sorted(MODEL_TYPES))}); import the module that "
                        "defines it first" + _EDIT)
    try:
        return Model.from_json(dict(spec))
    except (TypeError, AttributeError, ValueError) as exc:
        if isinstance(exc, ModelError):
            raise ModelError(f"{source}: 'model': {exc}") from None
        raise DataError(f"{source}: 'model' cannot be rebuilt ({exc}){_EDIT}") from None


def _values(params: Any, model: Model, source: str) -> dict[str, float]:
    """Each model parameter's ``params.NAME.value``: a finite number, positive for a
    log-scaled (positive) quantity."""
    if not isinstance(params, Mapping):
        raise DataError(f"{source}: 'params' must be an object{_EDIT}")
    values = {}
    for par in model.params:
        entry = params[par.name]
        value = entry.get("value") if isinstance(entry, Mapping) else None
        key = f"'params.{par.name}.value'"
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise DataError(f"{source}: {key} must be a number, got {value!r:.40}{_EDIT}")
        if not math.isfinite(value) or (par.scale == "log" and value <= 0):
            raise DataError(f"{source}: {key} is {value!r}; {par.name} is a "
                            + ("positive quantity" if par.scale == "log" else "finite number")
                            + _EDIT)
        span = max(abs(par.lower), abs(par.upper))
        far = (value > par.upper * FAR_OUTSIDE or value < par.lower / FAR_OUTSIDE
               if par.scale == "log" else abs(value) > span * FAR_OUTSIDE)
        if far:  # no fit ends there (boxes widen by a few decades at most)
            raise DataError(f"{source}: {key} is {value!r}, {FAR_OUTSIDE:.0e} times beyond "
                            f"{par.name}'s box [{par.lower:g}, {par.upper:g}]{_EDIT}")
        values[par.name] = float(value)
    return values


def _free_names(free: Any, model: Model, source: str) -> list[str]:
    """``free``: names of the model's parameters or initial states (``x0_<state>``), per
    record or shared."""
    from hhra_phys.parameters import split_record_name

    if not isinstance(free, list) or not all(isinstance(n, str) for n in free):
        raise DataError(f"{source}: 'free' must be a list of names, got {free!r:.60}{_EDIT}")
    known = set(model.params.names) | {f"x0_{s}" for s in model.state_names}
    for name in free:
        if split_record_name(name)[0] not in known:
            raise DataError(f"{source}: 'free' names {name!r}, not a parameter or initial "
                            f"state of the model {model.name!r}{_EDIT}")
    if len(set(free)) != len(free):
        raise DataError(f"{source}: 'free' lists a name twice{_EDIT}")
    return list(free)


def _check_covariance(cov: Any, n: int, source: str) -> None:
    """``covariance``: null, or an n x n list of numbers (null for NaN), n = len(free)."""
    if cov is None:
        return
    ok = isinstance(cov, list) and len(cov) == n and all(
        isinstance(row, list) and len(row) == n and all(
            c is None or (isinstance(c, int | float) and not isinstance(c, bool))
            for c in row) for row in cov)
    if not ok:
        shape = (f"{len(cov)} rows" if isinstance(cov, list) else type(cov).__name__)
        raise DataError(f"{source}: 'covariance' must be a {n} x {n} matrix of numbers (one "
                        f"row and column per name in 'free'), got {shape}{_EDIT}")


def _check_records(records: Any, source: str) -> None:
    """``records``: a list of objects whose ``fs`` (if any) is a sample rate > 0."""
    if records is None:
        return
    if not isinstance(records, list) or not all(isinstance(r, Mapping) for r in records):
        raise DataError(f"{source}: 'records' must be a list of objects{_EDIT}")
    for k, rec in enumerate(records):
        fs = rec.get("fs")
        if fs is not None and (isinstance(fs, bool) or not isinstance(fs, int | float)
                               or not math.isfinite(fs) or fs <= 0):
            raise DataError(f"{source}: 'records[{k}].fs' must be a sample rate > 0 Hz, "
                            f"got {fs!r:.40}{_EDIT}")
