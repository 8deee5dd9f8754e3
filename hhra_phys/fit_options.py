"""The settings of a fit: :class:`FitOptions`, validated as a whole, and the refiners' names.

What :func:`hhra_phys.fit.fit` accepts (every field of :class:`FitOptions` is also a keyword
of it), the global searches it knows (:data:`OPTIMIZERS`) and how ``refine`` and
``refine_options`` are read. Separate from :mod:`hhra_phys.fit` so that the settings and
their checks read on their own, before any of the work they steer; every name here is also
importable from :mod:`hhra_phys.fit`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hhra_phys.errors import ParameterError
from hhra_phys.optim.registry import METHODS
from hhra_phys.options import with_overrides

__all__ = [
    "FitOptions",
    "OPTIMIZERS",
]


#: Global searches of a fit: the registered optimisers (:mod:`hhra_phys.optim.registry`) and
#: ``"none"`` (the refiners alone).
OPTIMIZERS: tuple[str, ...] = (*METHODS, "none")


def _refiner_names(refine: str | Sequence[str] | None) -> list[str]:
    if refine is None:
        return []
    names = [refine] if isinstance(refine, str) else list(refine)
    out = []
    for name in names:
        low = name.lower()
        if low == "none":
            continue
        if low == "nlopt":
            low = "nlopt:LD_LBFGS"
        if not (low == "ipopt" or low.startswith("nlopt:")):
            raise ParameterError(
                f"refine must be 'ipopt', 'nlopt', 'nlopt:ALGORITHM' or 'none', got {name!r}"
            )
        out.append(low)
    return out


@dataclass(frozen=True)
class FitOptions:
    """Settings of a fit (:func:`fit`), validated as a whole.

    Every field is also a keyword of :func:`fit`, which overrides the options it is given
    (``fit(ds, options=FitOptions(pop_size=30), seed=2)``).

    Attributes
    ----------
    optimizer : {"hgwo", "gwo", "pso", "de", "none"}
        Global search (``"none"``: start the refiners from the nominal values or
        ``start``).
    refine : str or list of str or None
        ``"ipopt"`` (default), ``"nlopt"`` (``LD_LBFGS`` with the CasADi gradient),
        ``"nlopt:ALGORITHM"`` (e.g. ``"nlopt:LN_BOBYQA"``), a list of them run in
        turn, or ``"none"``.
    free, fixed, bounds, cost, initial_state
        See :class:`~hhra_phys.problem.Problem` (default free set: every parameter
        but the model's ``held`` ones, for the HHRA ``g_spring`` and ``g_load``; the
        initial values of the model's fitted states, the HHRA's angle, are fitted).
    split : float
        Fraction of the record used for estimation; the rest is validation.
    pop_size, max_iter : int
        Global search population and iterations (paper: 100 and 200).
    seed : int or None
        Seed of the global search.
    lam : float
        H-GWO's mutation factor (module docstring); ignored by other methods.
    optimizer_options : dict, optional
        Further optimiser options (``F``, ``w``, ...).
    refine_options : dict, optional
        Keyword arguments for the refiners (``hessian``, ``shooting``, ``max_iter``,
        ``stall_iter``, ``max_eval`` ...), applied to those that accept them.
    start : dict, optional
        Starting values (physical units) for the global search's first population
        and for ``optimizer="none"``.
    progress : bool
        Show a progress bar during the global search.
    seed_population : bool, optional
        Put the start values (``start``, or those of ``problem``) into the global
        search's first population (warm start). Default: when ``start`` is given.
    intervals : {"linear", "profile"}
        95 % intervals from the Gauss-Newton covariance at the optimum (fast), or
        profile-likelihood intervals (:mod:`hhra_phys.likelihood`; a few seconds more,
        better founded along curved, weakly determined directions).
    per_record : sequence of str, optional
        With several records: free model parameters estimated once per record
        (default: those the model's parts declare, such as a sensor offset).
    default_bounds : dict, optional
        ``{name: (lower, upper)}`` replacing the model's default boxes (e.g. the wider
        boxes of a record in sample units); unlike ``bounds`` they may be widened.
    widen_bounds : bool
        When a log-scaled free group ends at the edge of its default box (the model's,
        or ``default_bounds``) and moving it out lowers the sum of squares, widen that
        side by a decade (at most :data:`MAX_WIDEN_DECADES`, fewer when a refit does not
        lower the cost) and refit (:func:`widen_boxes`); the result's warnings and
        ``settings["widened"]`` say so. The same for one record, several records and a
        given ``problem`` (whose ``bounds`` are its explicit ones); groups with explicit
        ``bounds`` are never widened.
    allow_outside_box : bool
        Accept ``fixed`` values outside their parameter's box (checked by
        :class:`~hhra_phys.problem.Problem`; the CLI's ``--allow-outside-box``).

    """

    optimizer: str = "hgwo"
    refine: str | tuple[str, ...] | None = "ipopt"
    free: tuple[str, ...] | None = None
    fixed: Mapping[str, float] | None = None
    bounds: Mapping[str, tuple[float, float]] | None = None
    split: float = 0.5
    cost: str = "itae"
    initial_state: str = "fit"
    pop_size: int = 100
    max_iter: int = 200
    seed: int | None = 0
    lam: float = 1.0
    optimizer_options: Mapping[str, Any] | None = None
    refine_options: Mapping[str, Any] | None = None
    start: Mapping[str, float] | None = None
    progress: bool = False
    seed_population: bool | None = None
    intervals: str = "linear"
    per_record: tuple[str, ...] | None = None
    default_bounds: Mapping[str, tuple[float, float]] | None = None
    widen_bounds: bool = True
    allow_outside_box: bool = False

    def validate(self) -> FitOptions:
        """Check the settings a fit checks before any work; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        if self.intervals not in ("linear", "profile"):
            raise ParameterError(f"intervals must be 'linear' or 'profile', got "
                                 f"{self.intervals!r}")
        if self.optimizer not in OPTIMIZERS:
            raise ParameterError(f"optimizer must be one of {', '.join(OPTIMIZERS)}, got "
                                 f"{self.optimizer!r}")
        if not 0 < self.split <= 1:
            raise ParameterError(f"split must be in (0, 1], got {self.split}")
        from hhra_phys.options import MAX_ITERATIONS, MAX_POPULATION

        for name, most in (("pop_size", MAX_POPULATION), ("max_iter", MAX_ITERATIONS)):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0):
                raise ParameterError(f"{name} must be an integer >= 0, got {v!r}")
            if v > most:
                raise ParameterError(f"{name} must be at most {most:,} (see "
                                     f"hhra_phys.options), got {v:,}")
        return self

    @classmethod
    def of(cls, options: FitOptions | None = None, **overrides: Any) -> FitOptions:
        """``options`` (default: the defaults) with ``overrides`` applied, validated.

        Raises
        ------
        ParameterError
            An override that is not a setting (with the settings' names), or a bad value.
        """
        return with_overrides(options if options is not None else cls(), overrides, "fit",
                              ("free", "per_record", "refine")).validate()


#: The ``refine_options`` :func:`~hhra_phys.refine.refine_ipopt` takes (the fit's IPOPT
#: stages, the accuracy check's included).
_IPOPT_KEYS = ("hessian", "shooting", "segments", "max_iter", "tol", "verbose", "stall_iter",
               "stall_step")
