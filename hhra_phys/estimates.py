"""Typed estimates: :class:`Estimate`, and derived quantities with delta-method intervals.

What :attr:`hhra_phys.result.FitResult.estimates` and :attr:`~hhra_phys.result.FitResult.derived`
hold (module docstring of :mod:`hhra_phys.result`, "Typed estimates"): a value with its
unit, 95 % interval and status, the delta method that carries the free parameters'
covariance (:func:`physical_covariance`) to the quantities a model derives from them
(:func:`derived_estimates`). Separate from :mod:`hhra_phys.result` because an estimate is a
value of its own, read and written without the result around it; every name here is also
importable from :mod:`hhra_phys.result`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import casadi as ca
import numpy as np

from hhra_phys.model import DerivedQuantity

__all__ = [
    "Estimate",
    "derived_estimates",
]


#: Two-sided 95 % quantile of the normal distribution (the intervals' half-width in
#: standard deviations).
Z95 = 1.96

Status = Literal["free", "fixed", "at-edge"]


@dataclass(frozen=True)
class Estimate:
    """One estimated (or held) quantity of a fit.

    Attributes
    ----------
    value : float
        The value, in ``unit``.
    unit : str
        Its unit.
    ci95 : (float, float) or None
        95 % confidence interval (``None`` for a fixed quantity; ``(nan, nan)`` when the
        data do not determine it).
    status : {"free", "fixed", "at-edge"}
        ``"fixed"``: held, not fitted (a derived quantity: it depends on no free
        parameter); ``"at-edge"``: fitted, but it ended at an edge of its box (for a
        derived quantity: one of the free parameters it depends on did), so the
        value and interval are not meaningful; ``"free"``: fitted.
    std : float or None
        Standard deviation in ``unit`` (linearised; ``None`` when not computed).
    description : str
        What it is (derived quantities).
    """

    value: float
    unit: str = ""
    ci95: tuple[float, float] | None = None
    status: Status = "free"
    std: float | None = None
    description: str = ""

    @property
    def free(self) -> bool:
        """Fitted (``"free"`` or ``"at-edge"``), not held."""
        return self.status != "fixed"

    @property
    def determined(self) -> bool:
        """Has a finite interval."""
        return self.ci95 is not None and all(math.isfinite(c) for c in self.ci95)

    def to_json(self) -> dict[str, Any]:
        """``value``, ``unit``, ``ci95`` (``None`` for fixed, ``[null, null]``
        undetermined), ``free``, ``status``, and ``std``/``description`` when set."""
        out: dict[str, Any] = {"value": self.value, "unit": self.unit,
                               "ci95": list(self.ci95) if self.ci95 is not None else None,
                               "free": self.free, "status": self.status}
        if self.std is not None:
            out["std"] = self.std
        if self.description:
            out["description"] = self.description
        return out

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Estimate:
        """The estimate of :meth:`to_json` (``null`` numbers read as NaN)."""
        ci = d.get("ci95")
        status = d.get("status") or ("free" if d.get("free", True) else "fixed")
        std = d.get("std")
        return cls(value=_num(d["value"]), unit=d.get("unit", ""),
                   ci95=None if ci is None else (_num(ci[0]), _num(ci[1])),
                   status=status, std=None if "std" not in d else _num(std),
                   description=d.get("description", ""))


def derived_estimates(
    quantities: Mapping[str, DerivedQuantity],
    values: Mapping[str, float],
    free: Sequence[str],
    covariance: np.ndarray | None,
    at_edge: Sequence[str] = (),
) -> dict[str, Estimate]:
    """Values and 95 % intervals of derived quantities by the delta method.

    Each quantity ``g(theta)`` is built once with CasADi symbols for the free
    parameters (every other parameter at its value), its exact gradient ``dg`` taken
    by automatic differentiation, and its variance is ``dg C dg^T`` with ``C`` the
    covariance of the free parameters (physical units). The delta method is invariant
    to the fitting coordinates to first order, so the log-scaled groups need no
    special care. A quantity declared ``positive`` gets its interval on its logarithm,
    ``g exp(+-1.96 sd/g)``; the others ``g +- 1.96 sd``.

    Parameters
    ----------
    quantities : mapping of str to DerivedQuantity
        What to derive (:meth:`~hhra_phys.model.Model.derived_quantities`).
    values : mapping of str to float
        Every parameter the quantities use, by name.
    free : sequence of str
        Names of the free parameters, in the order of ``covariance``; names that are
        not keys of ``values`` (initial states, another record's parameters) are
        skipped.
    covariance : ndarray, shape (len(free), len(free)), or None
        Covariance of the free parameters, physical units (``inf``/``nan`` where the
        data do not determine them). ``None``: no intervals.
    at_edge : sequence of str
        Free parameters that ended at a box edge (their quantities are ``"at-edge"``).

    Returns
    -------
    dict of str to Estimate
        A quantity that uses an undetermined parameter has interval ``(nan, nan)``;
        one that uses no free parameter is ``"fixed"``; one that cannot be
        evaluated (a parameter missing) is left out.
    """
    idx = [i for i, n in enumerate(free) if n in values]
    names = [free[i] for i in idx]
    sym = ca.SX.sym("theta", len(names))
    env: dict[str, Any] = dict(values)
    env.update({n: sym[k] for k, n in enumerate(names)})
    point = np.array([float(values[n]) for n in names])
    cov = (np.asarray(covariance, dtype=float)[np.ix_(idx, idx)] if covariance is not None
           else None)
    out: dict[str, Estimate] = {}
    for key, q in quantities.items():
        try:
            expr = ca.SX(q.function(env))
        except (KeyError, TypeError):
            continue
        fn = ca.Function("g", [sym], [expr, ca.jacobian(expr, sym)])
        val, grad = (np.asarray(a, dtype=float).ravel() for a in fn(point))
        out[key] = _delta(q, float(val[0]), grad, cov,
                          [names[k] for k in np.flatnonzero(grad)], at_edge)
    return out


def _delta(q: DerivedQuantity, value: float, grad: np.ndarray, cov: np.ndarray | None,
           uses: list[str], at_edge: Sequence[str]) -> Estimate:
    """The :class:`Estimate` of one derived quantity from its gradient."""
    if not uses:
        return Estimate(value, q.unit, None, "fixed", None, q.description)
    status: Status = "at-edge" if any(n in at_edge for n in uses) else "free"
    if cov is None:
        return Estimate(value, q.unit, None, status, None, q.description)
    used = np.flatnonzero(grad)
    sub = cov[np.ix_(used, used)]
    if not np.all(np.isfinite(sub)):  # a parameter the data do not determine
        return Estimate(value, q.unit, (math.nan, math.nan), status, math.inf, q.description)
    sd = float(math.sqrt(max(float(grad[used] @ sub @ grad[used]), 0.0)))
    if q.positive and value > 0:
        # exp of a huge relative spread (a quantity the fit hardly determines) overflows:
        # its upper end is then infinite, not an error.
        with np.errstate(over="ignore"):
            spread = float(np.exp(Z95 * sd / value))
        ci = (value / spread, value * spread)
    else:
        ci = (value - Z95 * sd, value + Z95 * sd)
    return Estimate(value, q.unit, ci, status, sd, q.description)


def physical_covariance(cov_z: np.ndarray, slopes: np.ndarray) -> np.ndarray:
    """Covariance in physical units from the fitting coordinates' (``D cov_z D``).

    Parameters
    ----------
    cov_z : ndarray, shape (n, n)
        Covariance of the fitting coordinates (:func:`uncertainty`).
    slopes : ndarray, shape (n,)
        ``d theta_i / d z_i`` at the optimum (the coordinate maps are elementwise).
    """
    d = np.asarray(slopes, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.asarray(cov_z, dtype=float) * np.outer(d, d)


def _num(x: Any) -> float:
    """A JSON number; ``null`` (NaN or an infinity when written) as NaN."""
    return math.nan if x is None else float(x)
