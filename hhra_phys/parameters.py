"""Named model parameters with units, nominal values, bounds and fitting scales.

A :class:`Parameter` describes one scalar; a :class:`ParameterSet` is the ordered
collection a model exposes. Parameter vectors everywhere in hhra-phys follow the
order of the model's ``ParameterSet``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from hhra_phys.errors import ParameterError

__all__ = [
    "Parameter",
    "ParameterSet",
    "record_name",
    "split_record_name",
]

#: Relative tolerance of :meth:`ParameterSet.check_values` at a box edge: values
#: round-tripped through fitting coordinates land up to about 1e-7 beyond it.
BOX_SLACK = 1e-6

Scale = Literal["log", "linear"]


def as_number(value: object, what: str) -> float:
    """``value`` as a float, or a :class:`ParameterError` naming ``what`` (a string such as
    ``"abc"``, None, a list are not numbers; a bool is refused too).

    Parameters
    ----------
    value : object
    what : str
        What the value is, for the message (``"fixed g_leak='abc'"``).
    """
    if isinstance(value, bool) or not isinstance(value, int | float | np.number):
        raise ParameterError(f"{what}: the value must be a number, got "
                             f"{type(value).__name__} {value!r}")
    return float(value)


@dataclass(frozen=True)
class Parameter:
    """One scalar model parameter.

    Parameters
    ----------
    name : str
        Identifier used in vectors, the CLI (``--free``, ``--fix``) and JSON.
    unit : str
        Physical unit (SI unless stated, ``"-"`` for dimensionless).
    nominal : float
        Default value, in ``unit``.
    lower, upper : float
        Bounds used by fitting and by simulation stability checks, in ``unit``.
    scale : {"log", "linear"}
        Fitting coordinate: ``"log"`` (positive quantities spanning decades) or
        ``"linear"`` (signed quantities such as offsets).
    description : str
        One line saying what the parameter means physically.
    """

    name: str
    unit: str
    nominal: float
    lower: float
    upper: float
    scale: Scale = "log"
    description: str = ""

    def __post_init__(self) -> None:
        self._check_types()
        if not self.name.isidentifier():
            raise ParameterError(f"parameter name {self.name!r} is not a valid identifier")
        for field in ("nominal", "lower", "upper"):
            value = getattr(self, field)
            if not math.isfinite(value):
                raise ParameterError(
                    f"parameter {self.name!r}: {field} must be finite, got {value}"
                )
        if not self.lower <= self.nominal <= self.upper:
            raise ParameterError(
                f"parameter {self.name!r}: nominal {self.nominal} outside bounds "
                f"[{self.lower}, {self.upper}]"
            )
        if self.scale not in ("log", "linear"):
            raise ParameterError(f"parameter {self.name!r}: scale must be 'log' or 'linear'")
        if self.scale == "log" and self.lower <= 0:
            raise ParameterError(
                f"parameter {self.name!r}: log scale needs a positive lower bound, got {self.lower}"
            )

    def _check_types(self) -> None:
        """The fields' types (a str name and unit, numbers for the values), named."""
        if not isinstance(self.name, str):
            raise ParameterError(f"Parameter name must be a str, got {self.name!r} "
                                 f"({type(self.name).__name__})")
        if not isinstance(self.unit, str):
            raise ParameterError(f"parameter {self.name!r}: unit must be a str, got "
                                 f"{self.unit!r} ({type(self.unit).__name__})")
        for field in ("nominal", "lower", "upper"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number):
                raise ParameterError(f"parameter {self.name!r}: {field} must be a number, "
                                     f"got {value!r} ({type(value).__name__})")

    def with_(self, **changes: float | str) -> Parameter:
        """Return a copy with some fields changed (validated again)."""
        return replace(self, **changes)  # type: ignore[arg-type]


class ParameterSet:
    """Ordered, name-addressable collection of :class:`Parameter`.

    Parameters
    ----------
    params : iterable of Parameter
        The parameters, in vector order. Names must be unique.
    """

    def __init__(self, params: Iterable[Parameter]) -> None:
        self._params: tuple[Parameter, ...] = tuple(params)
        self._index: dict[str, int] = {}
        for i, p in enumerate(self._params):
            if p.name in self._index:
                raise ParameterError(f"duplicate parameter name {p.name!r}")
            self._index[p.name] = i

    def __iter__(self) -> Iterator[Parameter]:
        return iter(self._params)

    def __len__(self) -> int:
        return len(self._params)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __getitem__(self, key: str | int) -> Parameter:
        if isinstance(key, str):
            return self._params[self.index(key)]
        return self._params[key]

    def __repr__(self) -> str:
        return f"ParameterSet({', '.join(self.names)})"

    @property
    def names(self) -> list[str]:
        """Parameter names in vector order."""
        return [p.name for p in self._params]

    def index(self, name: str) -> int:
        """Position of ``name`` in parameter vectors; clear error when unknown."""
        try:
            return self._index[name]
        except KeyError:
            raise ParameterError(
                f"unknown parameter {name!r}; known parameters: {', '.join(self.names)}"
            ) from None

    def nominal(self) -> np.ndarray:
        """Vector of nominal values, shape (n,)."""
        return np.array([p.nominal for p in self._params], dtype=float)

    def bounds(self) -> np.ndarray:
        """Bounds as an (n, 2) array of (lower, upper)."""
        return np.array([(p.lower, p.upper) for p in self._params], dtype=float)

    def vector(self, values: Mapping[str, float] | None = None, **kw: float) -> np.ndarray:
        """Nominal vector with some entries replaced by name.

        Examples
        --------
        >>> model.params.vector(g_leak=3.0)  # doctest: +SKIP
        """
        v = self.nominal()
        for name, value in {**(values or {}), **kw}.items():
            v[self.index(name)] = float(value)
        return v

    def as_dict(self, vector: np.ndarray) -> dict[str, float]:
        """Map a parameter vector of shape (n,) to ``{name: value}``."""
        vec = np.asarray(vector, dtype=float)
        if vec.shape != (len(self),):
            raise ParameterError(
                f"parameter vector has shape {vec.shape}, expected ({len(self)},) for "
                f"{', '.join(self.names)}"
            )
        return {p.name: float(x) for p, x in zip(self._params, vec, strict=True)}

    def check_population(self, P: np.ndarray) -> np.ndarray:
        """Return ``P`` as a float (n_pop, n_params) array, or raise a clear error."""
        arr = np.asarray(P, dtype=float)
        if arr.ndim == 1:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != len(self):
            raise ParameterError(
                f"parameter array has shape {np.shape(P)}, expected (n_pop, {len(self)}) or "
                f"({len(self)},) with columns {', '.join(self.names)}"
            )
        return arr

    def check_values(
        self,
        values: Mapping[str, float],
        *,
        allow_outside_box: bool = False,
        what: str = "--fix",
    ) -> list[str]:
        """Check held values against each parameter's sign and box.

        Parameters
        ----------
        values : mapping of str to float
            ``{name: value}`` in the parameters' units (e.g. the CLI's ``--fix``).
        allow_outside_box : bool
            Accept a finite value of the right sign outside ``[lower, upper]`` (the
            returned notes then say so); otherwise it is an error.
        what : str
            How the values were given, for messages.

        Returns
        -------
        list of str
            Notes about accepted values outside the box.

        Raises
        ------
        ParameterError
            Unknown name, non-finite value, a value <= 0 for a log-scaled (positive)
            parameter, or a value outside the box without ``allow_outside_box``.
        """
        notes: list[str] = []
        for name, value in values.items():
            try:
                par = self[self.index(name)]
            except ParameterError as exc:
                raise ParameterError(f"{what} {name}={value}: {exc}") from None
            v = as_number(value, f"{what} {name}={value!r}")
            if not math.isfinite(v):
                raise ParameterError(f"{what} {name}={value}: the value must be finite")
            if par.scale == "log" and v <= 0:
                raise ParameterError(
                    f"{what} {name}={value}: {name} ({par.description or par.unit}) is a "
                    f"positive quantity; give a value > 0 (its box is [{par.lower:g}, "
                    f"{par.upper:g}] {par.unit})"
                )
            # A value a fit ended at an edge comes back through the log/scale coordinates
            # a few ulps to 1e-7 off it (64.0000024 for 64): that is on the edge.
            slack = BOX_SLACK * max(abs(par.lower), abs(par.upper))
            if not par.lower - slack <= v <= par.upper + slack:
                text = (f"{what} {name}={value} lies outside its box [{par.lower:g}, "
                        f"{par.upper:g}] {par.unit}")
                if not allow_outside_box:
                    raise ParameterError(
                        f"{text}; check the value and its unit, or pass --allow-outside-box "
                        "(allow_outside_box=True) if it is meant"
                    )
                notes.append(f"{text} (accepted: outside the box was allowed)")
        return notes

    def replace(self, name: str, **changes: float | str) -> ParameterSet:
        """Return a new set with one parameter's fields changed."""
        i = self.index(name)
        params = list(self._params)
        params[i] = params[i].with_(**changes)
        return ParameterSet(params)

    def to_json(self) -> list[dict[str, object]]:
        """JSON-able description of every parameter."""
        return [
            {
                "name": p.name,
                "unit": p.unit,
                "nominal": p.nominal,
                "lower": p.lower,
                "upper": p.upper,
                "scale": p.scale,
                "description": p.description,
            }
            for p in self._params
        ]


_REC = re.compile(r"^(?P<base>.+)_rec(?P<k>[1-9][0-9]*)$")


def record_name(name: str, k: int) -> str:
    """Name of parameter ``name`` of record ``k`` (counted from 1): ``<name>_rec<k>``."""
    return f"{name}_rec{k}"


def split_record_name(name: str) -> tuple[str, int | None]:
    """``"x0_theta_rec2"`` -> ``("x0_theta", 2)``; a shared name -> ``(name, None)``."""
    m = _REC.match(name)
    return (m["base"], int(m["k"])) if m else (name, None)
