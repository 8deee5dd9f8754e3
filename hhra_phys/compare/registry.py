"""The registry of comparison methods: their contract, registration, lookup and plug-ins.

A method is a function ``fn(est, val, settings) -> MethodOutcome``: it fits on the estimation
part ``est`` (a :class:`~hhra_phys.data.Dataset`), and returns its *free-run simulated*
output on both parts in a :class:`MethodOutcome`; ``settings`` is the :class:`CompareSettings`
of the comparison. :func:`register_method` adds one to :data:`METHODS` under a name (the key
of the report). The package's own methods (the ARX rows of :mod:`.arx` and the physical rows
of :mod:`.physical`) are registered directly when :mod:`hhra_phys.compare` is imported, so
they are there whether or not the package is installed.

Other methods plug in from any module that calls :func:`register_method` when imported:
:func:`load_plugins` imports such modules by name (the CLI's ``--plugin MODULE``) and, once,
every entry point of the group :data:`ENTRY_POINT_GROUP` (``hhra_phys.compare_methods``), the
way a third-party package adds methods::

    [project.entry-points."hhra_phys.compare_methods"]
    mymethods = "mypackage.compare_rows"            # a module that registers on import
    # or "mypackage.compare_rows:register"          # a callable, called once

Name clashes: an entry point never replaces a method that is already registered (a built-in
row, or one registered before the plug-ins were loaded), not even with ``replace=True``: the
registered method is kept and a warning names the plug-in and the names, which the plug-in
must change. Entry points into :mod:`hhra_phys` itself are skipped: the package registers its
own rows on import and declares no entry point, so such an entry is left over in the metadata
of an older installation, and loading it would register the rows twice. Replacing a method
on purpose stays possible from code, with :func:`register_method` and ``replace=True``.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field
from importlib import import_module
from importlib.metadata import EntryPoint, entry_points
from typing import Any

import numpy as np

from hhra_phys import arx
from hhra_phys.data import Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.outputs import jsonable

__all__ = [
    "ENTRY_POINT_GROUP",
    "METHODS",
    "METHOD_LABELS",
    "CompareSettings",
    "MethodFn",
    "MethodOutcome",
    "available_methods",
    "load_plugins",
    "method_label",
    "register_method",
]

#: Entry-point group whose modules (or callables) register more methods.
ENTRY_POINT_GROUP = "hhra_phys.compare_methods"

#: Display names for tables and figures, filled by :func:`register_method` (``label=``).
METHOD_LABELS: dict[str, str] = {}

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class CompareSettings:
    """Settings every method receives.

    Attributes
    ----------
    seed : int
        Seed of every random choice (each metaheuristic is seeded with it).
    pop_size, max_iter : int
        Population size and iterations of the metaheuristics (paper: 100 and 200).
    na, nb, nk : int
        ARX structure (paper, eq. 13: 3, 3, 1).
    bounds : (float, float)
        Search box of PSO, GWO and H-GWO for every ARX coefficient (paper: [-5, 5]).
    zeta_s : float
        Expansion gain of the hybrid's box (eq. 29); the paper gives no value.
    progress : bool
        Show optimiser progress bars.
    options : dict
        Per-method optimiser options, ``{"pso": {...}, ...}``, merged over the paper's.
    extra : dict
        Free-form settings for plug-in methods.
    """

    seed: int = 0
    pop_size: int = 100
    max_iter: int = 200
    na: int = 3
    nb: int = 3
    nk: int = 1
    bounds: tuple[float, float] = arx.PAPER_BOX
    zeta_s: float = arx.DEFAULT_ZETA_S
    progress: bool = False
    options: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, low in (
            ("seed", 0),
            ("pop_size", 2),
            ("max_iter", 1),
            ("na", 0),
            ("nb", 1),
            ("nk", 0),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
                raise ParameterError(f"{name} must be an integer >= {low}, got {value!r}")
        lo, hi = (float(v) for v in self.bounds)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ParameterError(f"bounds must be (lo, hi) with finite lo < hi, got {self.bounds}")
        if not (math.isfinite(self.zeta_s) and 0 < self.zeta_s <= 1):
            raise ParameterError(f"zeta_s must lie in (0, 1], got {self.zeta_s!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able copy."""
        return jsonable(asdict(self), default=str)


@dataclass
class MethodOutcome:
    """What a method returns.

    Attributes
    ----------
    y_est, y_val : numpy.ndarray
        Free-run simulated output on the estimation and validation parts [output unit], the same
        length as the parts. NaN/inf where the simulation diverged (scored as worst).
    noi : int or None
        Number of iterations (see :func:`hhra_phys.optim.noi`); None where undefined.
    nfev : int or None
        Objective evaluations; None where there is no objective (LS, RLS, FFRLS).
    seconds : float or None
        Wall time of the fit [s]; None lets :func:`run_comparison` use the time of the call.
    history : numpy.ndarray or None
        Best-so-far fitness per iteration (index 0 = initialisation), for convergence plots.
    history_nfev : numpy.ndarray or None
        Cumulative evaluations at each entry of ``history``.
    fitness : str or None
        What ``history`` measures, e.g. "ITAE of the free-run output on the estimation part".
    info : dict
        Free-form, JSON-able details (estimated parameters, initial condition, ...).
    """

    y_est: np.ndarray
    y_val: np.ndarray
    noi: int | None = None
    nfev: int | None = None
    seconds: float | None = None
    history: np.ndarray | None = None
    history_nfev: np.ndarray | None = None
    fitness: str | None = None
    info: dict[str, Any] = field(default_factory=dict)


MethodFn = Callable[[Dataset, Dataset, CompareSettings], MethodOutcome]

#: The registry: method name -> ``fn(est, val, settings) -> MethodOutcome``, in insertion order.
METHODS: dict[str, MethodFn] = {}


def register_method(
    name: str, fn: MethodFn | None = None, *, label: str | None = None, replace: bool = False
) -> Any:
    """Add a method to :data:`METHODS` (usable as a decorator when ``fn`` is omitted).

    Parameters
    ----------
    name : str
        Key in the report: lower-case letters, digits and underscores, starting with a letter
        (e.g. ``"phys_hgwo"``).
    fn : callable
        ``fn(est: Dataset, val: Dataset, settings: CompareSettings) -> MethodOutcome``.
    label : str, optional
        Display name for tables and figures.
    replace : bool
        Allow replacing an existing entry (otherwise that is an error).

    Returns
    -------
    callable
        ``fn`` (or the decorator).
    """
    if not isinstance(name, str) or not _NAME.match(name):
        raise ParameterError(
            f"method name must match [a-z][a-z0-9_]* (e.g. 'phys_hgwo'), got {name!r}"
        )

    def add(func: MethodFn) -> MethodFn:
        if not callable(func):
            raise ParameterError(f"method {name!r}: fn must be callable, got {func!r}")
        if name in METHODS and not replace and METHODS[name] is not func:
            raise ParameterError(
                f"method {name!r} is already registered; pass replace=True to replace it"
            )
        METHODS[name] = func
        if label:
            METHOD_LABELS[name] = label
        return func

    return add if fn is None else add(fn)


def method_label(name: str) -> str:
    """Display name of a method for tables and figures (the name itself when it has none).

    Parameters
    ----------
    name : str
        Registered (or reported) method name.
    """
    return METHOD_LABELS.get(name, name)


_plugins_loaded = False


def load_plugins(modules: Iterable[str] = ()) -> list[str]:
    """Import modules that register methods, and (once) those named by entry points.

    Parameters
    ----------
    modules : iterable of str
        Module names (e.g. ``"hhra_phys.physfit"``); each is imported, and its import is
        expected to call :func:`register_method`.

    Returns
    -------
    list of str
        The names of the methods registered after loading.

    Raises
    ------
    ParameterError
        If a given module cannot be imported. A broken entry point only warns.

    Notes
    -----
    Entry points never replace registered methods and entry points into :mod:`hhra_phys`
    are skipped (module docstring).
    """
    global _plugins_loaded
    for mod in modules:
        try:
            import_module(mod)
        except ImportError as exc:
            raise ParameterError(f"plugin module {mod!r} cannot be imported: {exc}") from exc
    if not _plugins_loaded:
        _plugins_loaded = True
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            _load_entry_point(ep)
    return list(METHODS)


def _load_entry_point(ep: EntryPoint) -> None:
    """Load one third-party entry point; it may add methods, never replace them."""
    if ep.module.partition(".")[0] == "hhra_phys":
        return  # the package's own rows are registered on import (module docstring)
    taken, labels = dict(METHODS), dict(METHOD_LABELS)
    try:
        obj = ep.load()
        if callable(obj):
            obj()
    except Exception as exc:  # a broken third-party plugin must not stop the built-ins
        warnings.warn(f"compare plugin {ep.name!r} failed to load: {exc}", stacklevel=3)
    clashes = [name for name, fn in taken.items() if METHODS.get(name) is not fn]
    for name in clashes:
        METHODS[name] = taken[name]
        if name in labels:
            METHOD_LABELS[name] = labels[name]
        else:
            METHOD_LABELS.pop(name, None)
    if clashes:
        warnings.warn(
            f"compare plugin {ep.name!r} registered {clashes}, names already taken; the "
            "registered methods are kept (the plugin must use names of its own)",
            stacklevel=3,
        )


def available_methods() -> tuple[str, ...]:
    """Names of every registered method (entry-point plugins included)."""
    load_plugins()
    return tuple(METHODS)
