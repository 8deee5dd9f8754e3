"""The paper's black-box path: Tustin discretisation, ARX models and their estimators.

Structure (the paper's eq. 11/13, general orders)::

    y(k) = -a_1 y(k-1) - ... - a_na y(k-na) + b_1 u(k-nk) + ... + b_nb u(k-nk-nb+1)

i.e. ``A(q^-1) y(k) = q^-nk B(q^-1) u(k)`` with ``A = 1 + a_1 q^-1 + ...`` and
``B = b_1 + b_2 q^-1 + ...``. The coefficient vector is ``theta = [a_1..a_na, b_1..b_nb]`` and
the regressor ``phi(k) = [-y(k-1) .. -y(k-na), u(k-nk) .. u(k-nk-nb+1)]``. The paper's model
(eq. 13) is ``na = nb = 3, nk = 1``. Units follow the data: ``y`` in the output unit (deg for the
rig), ``u`` in the input unit (mA), ``a_i`` dimensionless, ``b_i`` [output unit / input unit].

Contents

* :func:`tustin_coefficients` / :func:`tustin_inverse`: the Tustin image of the paper's
  ``G(s) = k_v / (a s^3 + b s^2 + c s)`` with the corrected algebra of eq. 12, and back.
* :class:`ARXModel`: free-run :meth:`~ARXModel.simulate` (from the input only),
  one-step :meth:`~ARXModel.predict`, :meth:`~ARXModel.to_control`.
* :func:`regression_matrix`; estimators :func:`fit_ls`, :func:`fit_rls`, :func:`fit_ffrls`;
  :func:`fit_metaheuristic` (PSO, GWO, H-GWO minimising the ITAE of the free-run output,
  vectorised over the population with :func:`simulate_population`) and the paper's hybrid
  :func:`fit_ffrls_hgwo` with the search box of eq. 29 (:func:`hybrid_box`).

Initial conditions. :meth:`ARXModel.simulate` and :meth:`ARXModel.predict` take the samples
before the first one as ``y_init`` and ``u_init`` (chronological, the last value is ``y(-1)``);
without them the past is zero (the LTI zero state, which is what python-control's
``forced_response`` uses). The fitting functions that simulate (:func:`fit_metaheuristic`,
:func:`fit_ffrls_hgwo`) instead assume by default that the record *starts at rest at its first
measured output*: past outputs equal ``y[0]``, past inputs zero. The regression-based
estimators never invent a past: without ``y_init``/``u_init`` the first
``max(na, nk + nb - 1)`` samples serve only as history.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import scipy.signal

from hhra_phys.errors import DataError, ParameterError
from hhra_phys.options import with_overrides

__all__ = [
    "DEFAULT_ZETA_S",
    "FFRLS_XI0",
    "FFRLS_XI_INIT",
    "MAX_POLE_RADIUS",
    "METAHEURISTIC_OPTIONS",
    "PAPER_BOX",
    "RLS_P0",
    "RLS_THETA0",
    "ARXFit",
    "ARXModel",
    "ConditioningWarning",
    "HybridOptions",
    "MetaheuristicOptions",
    "fit_ffrls",
    "fit_ffrls_hgwo",
    "fit_ls",
    "fit_metaheuristic",
    "fit_rls",
    "forgetting_factor",
    "hybrid_box",
    "itae_cost",
    "pole_radius",
    "recursive_least_squares",
    "regression_matrix",
    "simulate_population",
    "tustin_arx",
    "tustin_coefficients",
    "tustin_inverse",
]

#: RLS/FFRLS initial covariance ``P(0) = RLS_P0 * I`` (paper: alpha = 1e5).
RLS_P0 = 1e5
#: RLS/FFRLS initial estimate, every component (paper: epsilon = 1e-6).
RLS_THETA0 = 1e-6
#: FFRLS forgetting-factor rate xi0 in ``xi(k) = xi0 * xi(k-1) + (1 - xi0)`` (our reading).
FFRLS_XI0 = 0.99
#: FFRLS initial forgetting factor xi(0) (our reading of the paper's second "xi0 = 0.95").
FFRLS_XI_INIT = 0.95
#: The paper's search box for PSO, GWO and H-GWO, every coefficient.
PAPER_BOX = (-5.0, 5.0)
#: Default expansion gain zeta_s of the hybrid's box (eq. 29); the paper gives none.
DEFAULT_ZETA_S = 0.5
#: Candidates with a pole outside this radius count as unstable (cost inf).
MAX_POLE_RADIUS = 1.0
#: Optimiser settings of the paper's identification experiment (section 4.3), per method.
METAHEURISTIC_OPTIONS: dict[str, dict[str, Any]] = {
    "pso": {"w_start": 0.9, "w_end": 0.1, "c1": 2.0, "c2": 2.0},
    "gwo": {},
    "hgwo": {"F": 0.5, "lam": 0.25},
}

# Poles are compared with the limit with this slack, so that an exact integrator (a pole at
# z = 1 computed as 1 + 1e-15) is not thrown out as unstable.
_POLE_SLACK = 1e-9


class ConditioningWarning(RuntimeWarning):
    """The LS regression matrix is ill-conditioned: the estimate is sensitive to noise."""


# --------------------------------------------------------------------------- checks


def _order(value: Any, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ParameterError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _orders(na: Any, nb: Any, nk: Any) -> tuple[int, int, int]:
    return _order(na, "na", 0), _order(nb, "nb", 1), _order(nk, "nk", 0)


def _signal(x: Any, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim != 1 or arr.size == 0:
        raise DataError(f"{name} must be a non-empty 1-D array, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise DataError(
            f"{name} has non-finite values at rows {np.flatnonzero(~np.isfinite(arr))[:5]}"
        )
    return arr


def _pair(u: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
    uu, yy = _signal(u, "u"), _signal(y, "y")
    if uu.size != yy.size:
        raise DataError(f"u and y must have the same length, got {uu.size} and {yy.size}")
    return uu, yy


def _history(x_init: Any, length: int, name: str) -> np.ndarray:
    """The last ``length`` samples before a record, chronological; zeros when ``None``.

    A scalar means "held at that value".
    """
    if x_init is None:
        return np.zeros(length)
    arr = np.asarray(x_init, dtype=float)
    if arr.ndim == 0:
        return np.full(length, float(arr))
    if arr.ndim != 1 or arr.size < length:
        raise ParameterError(
            f"{name} must be a scalar or a 1-D array of at least {length} past samples "
            f"(chronological), got shape {arr.shape}"
        )
    if not np.isfinite(arr).all():
        raise ParameterError(f"{name} has non-finite values")
    return arr[arr.size - length :].copy()


def _lag_matrix(x: np.ndarray, lags: range, history: np.ndarray) -> np.ndarray:
    """Columns ``x(k - lag)`` for ``k = 0..N-1``, reaching into ``history`` for ``k < lag``."""
    n, depth = x.size, history.size
    padded = np.concatenate([history, x])
    if not len(lags):
        return np.empty((n, 0))
    return np.column_stack([padded[depth - lag : depth - lag + n] for lag in lags])


# --------------------------------------------------------------------------- Tustin


def tustin_coefficients(
    a: float, b: float, c: float, kv: float, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Tustin (bilinear) discretisation of ``G(s) = kv / (a s^3 + b s^2 + c s)``.

    With ``s = (2/T)(z-1)/(z+1)`` and ``T = dt`` (the paper's eq. 12 with its slip corrected)::

        G(z) = kv (z+1)^3 / [ (8a/T^3)(z-1)^3 + (4b/T^2)(z-1)^2(z+1) + (2c/T)(z-1)(z+1)^2 ]

    normalised so that the leading denominator coefficient is 1. The denominator has a root at
    ``z = 1`` (the integrator) and the numerator a direct feed-through ``b_0``, so the exact image
    is an ARX model with ``na = 3, nb = 4, nk = 0`` (see :func:`tustin_arx`), not the paper's
    eq. 13 structure (``nb = 3, nk = 1``).

    Parameters
    ----------
    a, b, c : float
        Denominator coefficients [s^3], [s^2], [s] times a common scale (e.g. ``a = 1``).
    kv : float
        Numerator in the same scale [output unit / input unit], e.g. rad/mA.
    dt : float
        Sample period T [s].

    Returns
    -------
    num, den : numpy.ndarray, shape (4,)
        ``num = [b_0, b_1, b_2, b_3]`` and ``den = [1, a_1, a_2, a_3]``: coefficients of
        ascending powers of ``z^-1`` (equally, descending powers of ``z``); the same as
        ``scipy.signal.cont2discrete(..., method='bilinear')``.
    """
    for name, value in (("a", a), ("b", b), ("c", c), ("kv", kv)):
        if not np.isfinite(value):
            raise ParameterError(f"{name} must be finite, got {value!r}")
    if not (np.isfinite(dt) and dt > 0):
        raise ParameterError(f"dt must be a positive sample period in s, got {dt!r}")
    big_a, big_b, big_c = 8.0 * a / dt**3, 4.0 * b / dt**2, 2.0 * c / dt
    # (z-1)^3, (z-1)^2 (z+1), (z-1)(z+1)^2 in descending powers of z.
    den = big_a * np.array([1.0, -3.0, 3.0, -1.0])
    den += big_b * np.array([1.0, -1.0, -1.0, 1.0])
    den += big_c * np.array([1.0, 1.0, -1.0, -1.0])
    if den[0] == 0.0:
        raise ParameterError("8a/T^3 + 4b/T^2 + 2c/T is zero: the Tustin image is not proper")
    num = kv * np.array([1.0, 3.0, 3.0, 1.0])
    return num / den[0], den / den[0]


# Maps [8a/T^3, 4b/T^2, 2c/T] to the Tustin denominator (columns as in tustin_coefficients).
_TUSTIN_DEN = np.array([[1.0, 1.0, 1.0], [-3.0, -1.0, 1.0], [3.0, -1.0, -1.0], [-1.0, 1.0, -1.0]])
_TUSTIN_NUM = np.array([1.0, 3.0, 3.0, 1.0])


def tustin_inverse(num: Any, den: Any, dt: float, rtol: float = 1e-6) -> dict[str, float]:
    """Continuous ``a, b, c, kv`` whose Tustin image is the discrete ``num / den``.

    The inverse exists only when the discrete model has the Tustin image's structure: a
    denominator ``[d_0, d_1, d_2, d_3]`` with a root at ``z = 1`` (``sum(den) = 0``) and a
    numerator proportional to ``(1 + z^-1)^3``. Both conditions are checked with relative
    tolerance ``rtol``; the continuous coefficients are then the least-squares solution of the
    linear map of :func:`tustin_coefficients`. A fitted eq.-13 ARX (``b_0 = 0``, no forced
    integrator) is generally not such an image: pass ``rtol=numpy.inf`` to get the nearest
    continuous coefficients anyway (denominator and numerator projected separately), and read
    the deviations in the error message of the strict call to know how far off they are.

    Parameters
    ----------
    num, den : array_like, shape (4,)
        Coefficients of ascending powers of ``z^-1`` (``den[0] != 0``).
    dt : float
        Sample period T [s].
    rtol : float
        Relative tolerance of the structure checks.

    Returns
    -------
    dict
        ``{"a": 1.0, "b": .., "c": .., "kv": ..}`` normalised to ``a = 1`` (as
        :meth:`hhra_phys.model.HHRAModel.tf_coefficients`): ``b`` [1/s], ``c`` [1/s^2], ``kv``
        [output unit / (input unit s^3)]; plus ``den_deviation`` and ``num_deviation``, the
        relative deviations of the two structure checks.

    Raises
    ------
    ParameterError
        If ``num``/``den`` do not have 4 finite coefficients, or the structure checks fail (the
        message gives the deviations), or the fitted ``a`` is zero.
    """
    n = np.asarray(num, dtype=float).ravel()
    d = np.asarray(den, dtype=float).ravel()
    if n.shape != (4,) or d.shape != (4,) or not (np.isfinite(n).all() and np.isfinite(d).all()):
        raise ParameterError(
            f"num and den must each hold 4 finite coefficients (z^0..z^-3), got {n} and {d}"
        )
    if d[0] == 0.0:
        raise ParameterError("den[0] must be non-zero")
    if not (np.isfinite(dt) and dt > 0):
        raise ParameterError(f"dt must be a positive sample period in s, got {dt!r}")
    n, d = n / d[0], d / d[0]
    abc, *_ = np.linalg.lstsq(_TUSTIN_DEN, d, rcond=None)
    den_dev = float(np.linalg.norm(_TUSTIN_DEN @ abc - d) / np.linalg.norm(d))
    gain = float(n @ _TUSTIN_NUM / (_TUSTIN_NUM @ _TUSTIN_NUM))
    scale = np.linalg.norm(n)
    num_dev = float(np.linalg.norm(n - gain * _TUSTIN_NUM) / scale) if scale > 0 else 0.0
    if den_dev > rtol or num_dev > rtol:
        raise ParameterError(
            "num/den is not the Tustin image of kv/(a s^3 + b s^2 + c s): relative deviation of "
            f"the denominator from one with a root at z = 1: {den_dev:.3g}, of the numerator from "
            f"kv*(1 + z^-1)^3: {num_dev:.3g} (rtol = {rtol:g}); pass rtol=numpy.inf for the "
            "nearest continuous coefficients"
        )
    a = abc[0] * dt**3 / 8.0
    if a == 0.0:
        raise ParameterError("the continuous s^3 coefficient is zero; cannot normalise to a = 1")
    return {
        "a": 1.0,
        "b": float(abc[1] * dt**2 / 4.0 / a),
        "c": float(abc[2] * dt / 2.0 / a),
        "kv": float(gain / a),
        "den_deviation": den_dev,
        "num_deviation": num_dev,
    }


# --------------------------------------------------------------------------- model


@dataclass(frozen=True, eq=False)
class ARXModel:
    """A single-input single-output ARX model ``A(q^-1) y(k) = q^-nk B(q^-1) u(k)``.

    Parameters
    ----------
    a : array_like, shape (na,)
        ``a_1 .. a_na`` (dimensionless); may be empty (FIR model).
    b : array_like, shape (nb,)
        ``b_1 .. b_nb`` [output unit / input unit].
    nk : int
        Input delay in samples (``nk = 0``: direct feed-through).
    """

    a: np.ndarray
    b: np.ndarray
    nk: int = 1

    def __post_init__(self) -> None:
        a = np.array(self.a, dtype=float).ravel()
        b = np.array(self.b, dtype=float).ravel()
        if b.size == 0:
            raise ParameterError("b must hold at least one coefficient (nb >= 1)")
        if not (np.isfinite(a).all() and np.isfinite(b).all()):
            raise ParameterError(f"ARX coefficients must be finite, got a={a}, b={b}")
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "nk", _order(self.nk, "nk", 0))

    @classmethod
    def from_theta(cls, theta: Any, na: int = 3, nb: int = 3, nk: int = 1) -> ARXModel:
        """Build from ``theta = [a_1..a_na, b_1..b_nb]``."""
        na, nb, nk = _orders(na, nb, nk)
        th = np.asarray(theta, dtype=float).ravel()
        if th.size != na + nb:
            raise ParameterError(f"theta must have na + nb = {na + nb} entries, got {th.size}")
        return cls(th[:na], th[na:], nk)

    @property
    def na(self) -> int:
        """Number of autoregressive coefficients."""
        return int(self.a.size)

    @property
    def nb(self) -> int:
        """Number of input coefficients."""
        return int(self.b.size)

    @property
    def theta(self) -> np.ndarray:
        """``[a_1..a_na, b_1..b_nb]`` (a copy)."""
        return np.concatenate([self.a, self.b])

    @property
    def history_length(self) -> int:
        """Past samples a prediction needs: ``max(na, nk + nb - 1)``."""
        return max(self.na, self.nk + self.nb - 1)

    def filter_coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        """``(b_full, a_full)`` for :func:`scipy.signal.lfilter` (ascending powers of ``z^-1``)."""
        return np.concatenate([np.zeros(self.nk), self.b]), np.concatenate([[1.0], self.a])

    def __repr__(self) -> str:
        return (
            f"ARXModel(na={self.na}, nb={self.nb}, nk={self.nk}, a={self.a.tolist()}, "
            f"b={self.b.tolist()})"
        )

    def simulate(self, u: Any, y_init: Any = None, u_init: Any = None) -> np.ndarray:
        """Free-run (simulation) output from the input alone.

        Parameters
        ----------
        u : array_like, shape (N,)
            Input [input unit].
        y_init, u_init : scalar or array_like, optional
            Outputs and inputs before the first sample, chronological (the last entry is
            ``y(-1)``); at least ``na`` resp. ``nk + nb - 1`` values (more are cut from the
            front); a scalar is held. Default: zero.

        Returns
        -------
        numpy.ndarray, shape (N,)
            The simulated output [output unit]. An unstable model may overflow to inf.
        """
        uu = _signal(u, "u")
        return simulate_population(
            self.theta[None, :], uu, self.na, self.nb, self.nk, y_init, u_init, max_pole_radius=None
        )[0]

    def predict(self, u: Any, y: Any, y_init: Any = None, u_init: Any = None) -> np.ndarray:
        """One-step-ahead prediction ``yhat(k) = phi(k)^T theta`` from measured past outputs.

        Parameters
        ----------
        u, y : array_like, shape (N,)
            Measured input and output.
        y_init, u_init : scalar or array_like, optional
            As in :meth:`simulate` (default zero).

        Returns
        -------
        numpy.ndarray, shape (N,)
            [output unit]. Never use this to score a model for simulation: see
            :meth:`simulate`.
        """
        uu, yy = _pair(u, y)
        phi, _ = regression_matrix(
            uu,
            yy,
            self.na,
            self.nb,
            self.nk,
            y_init=_history(y_init, self.na, "y_init"),
            u_init=_history(u_init, self.nk + self.nb - 1, "u_init"),
        )
        return phi @ self.theta

    def poles(self) -> np.ndarray:
        """Roots of ``z^na A(z^-1)`` (empty for a FIR model)."""
        return np.roots(np.concatenate([[1.0], self.a])) if self.na else np.empty(0, complex)

    def continuous_poles(self, dt: float) -> np.ndarray:
        """The poles mapped to the s-plane by the inverse Tustin map ``s = (2/T)(z-1)/(z+1)``.

        Parameters
        ----------
        dt : float
            Sample period T [s]. Returns [1/s]; a pole at ``z = -1`` maps to infinity.
        """
        z = self.poles()
        with np.errstate(divide="ignore", invalid="ignore"):
            return 2.0 / dt * (z - 1.0) / (z + 1.0)

    def is_stable(self, max_radius: float = 1.0) -> bool:
        """Whether every pole lies within ``max_radius`` (the unit circle counts as stable)."""
        return bool(pole_radius(self.a[None, :])[0] <= max_radius + _POLE_SLACK)

    def to_control(self, dt: float) -> Any:
        """The model as a python-control discrete ``TransferFunction`` with sample time ``dt``.

        Parameters
        ----------
        dt : float
            Sample period [s] (``True`` for an unspecified period is not accepted here).
        """
        import control

        if not (np.isfinite(dt) and dt > 0):
            raise ParameterError(f"dt must be a positive sample period in s, got {dt!r}")
        b_full, a_full = self.filter_coefficients()
        # Ascending powers of z^-1 -> descending powers of z: pad both to the same degree.
        n = max(b_full.size, a_full.size)
        num = np.concatenate([b_full, np.zeros(n - b_full.size)])
        den = np.concatenate([a_full, np.zeros(n - a_full.size)])
        return control.tf(num, den, dt)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description."""
        return {
            "na": self.na,
            "nb": self.nb,
            "nk": self.nk,
            "a": self.a.tolist(),
            "b": self.b.tolist(),
        }


def tustin_arx(a: float, b: float, c: float, kv: float, dt: float) -> ARXModel:
    """The exact Tustin image of ``kv / (a s^3 + b s^2 + c s)`` as an ARX(3, 4, 0) model."""
    num, den = tustin_coefficients(a, b, c, kv, dt)
    return ARXModel(den[1:], num, nk=0)


# --------------------------------------------------------------------------- simulation


def pole_radius(a: Any) -> np.ndarray:
    """Largest pole modulus of each row of autoregressive coefficients.

    Parameters
    ----------
    a : array_like, shape (m, na)
        One row ``[a_1..a_na]`` per model.

    Returns
    -------
    numpy.ndarray, shape (m,)
        Spectral radius of each companion matrix (0 for ``na = 0``, inf for a row with
        NaN/inf).
    """
    aa = np.atleast_2d(np.asarray(a, dtype=float))
    m, na = aa.shape
    if na == 0:
        return np.zeros(m)
    finite = np.isfinite(aa).all(axis=1)
    comp = np.zeros((m, na, na))
    comp[:, 0, :] = np.where(finite[:, None], -aa, 0.0)  # eigvals refuses NaN/inf entries
    comp[:, np.arange(1, na), np.arange(na - 1)] = 1.0
    return np.where(finite, np.abs(np.linalg.eigvals(comp)).max(axis=1), np.inf)


def simulate_population(
    theta: Any,
    u: Any,
    na: int = 3,
    nb: int = 3,
    nk: int = 1,
    y_init: Any = None,
    u_init: Any = None,
    *,
    max_pole_radius: float | None = MAX_POLE_RADIUS,
) -> np.ndarray:
    """Free-run outputs of many ARX models driven by the same input.

    The input part ``B(q) u`` of every model comes from one matrix product over the population;
    the autoregressive recursion runs in :func:`scipy.signal.lfilter` (compiled) per model, with
    the initial state from :func:`scipy.signal.lfiltic`.

    Parameters
    ----------
    theta : array_like, shape (m, na + nb) or (na + nb,)
        One coefficient vector ``[a, b]`` per row.
    u : array_like, shape (N,)
        Input [input unit].
    na, nb, nk : int
        Structure.
    y_init, u_init : scalar or array_like, optional
        Samples before the record, as in :meth:`ARXModel.simulate` (default zero).
    max_pole_radius : float or None
        Rows whose largest pole modulus exceeds this (unstable models) are not simulated: their
        output is NaN, which :mod:`hhra_phys.metrics` scores as the worst value. ``None``
        simulates everything (an unstable model may then overflow to inf).

    Returns
    -------
    numpy.ndarray, shape (m, N)
        [output unit].
    """
    na, nb, nk = _orders(na, nb, nk)
    uu = _signal(u, "u")
    th = np.atleast_2d(np.asarray(theta, dtype=float))
    if th.ndim != 2 or th.shape[1] != na + nb:
        raise ParameterError(
            f"theta must have shape (m, na + nb) = (m, {na + nb}), got {np.shape(theta)}"
        )
    y_hist = _history(y_init, na, "y_init")
    u_hist = _history(u_init, nk + nb - 1, "u_init")
    # B(q) u for every model at once: (m, N), rows contiguous for lfilter.
    lags = _lag_matrix(uu, range(nk, nk + nb), u_hist)
    x = np.ascontiguousarray(th[:, na:]) @ np.ascontiguousarray(lags.T)  # contiguous: BLAS path
    # Fold the known past outputs into the first na samples of x (the terms a_i y(k-i) with
    # k - i < 0 move to the right-hand side), so every model filters from a zero state: the
    # same result as an initial state from lfiltic, without a Python-level call per model.
    for k in range(min(na, uu.size)):
        for i in range(k + 1, na + 1):
            x[:, k] -= th[:, i - 1] * y_hist[na + k - i]
    out = np.full((th.shape[0], uu.size), np.nan)
    ok = np.isfinite(th).all(axis=1)
    if max_pole_radius is not None:
        ok &= pole_radius(th[:, :na]) <= max_pole_radius + _POLE_SLACK
    one = np.ones(1)
    with np.errstate(all="ignore"):  # an unchecked unstable model may overflow; that is its score
        for i in np.flatnonzero(ok):
            out[i] = scipy.signal.lfilter(one, np.concatenate([one, th[i, :na]]), x[i])
    return out


# --------------------------------------------------------------------------- regression


def regression_matrix(
    u: Any,
    y: Any,
    na: int = 3,
    nb: int = 3,
    nk: int = 1,
    y_init: Any = None,
    u_init: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Regressors ``phi(k)`` and targets ``y(k)`` of the ARX structure.

    Parameters
    ----------
    u, y : array_like, shape (N,), or lists of them
        Measured input and output; lists of several records' signals give each
        record's rows stacked (no row spans two records; :func:`fit_ls`,
        :func:`fit_rls` and :func:`fit_ffrls` accept such lists too).
    na, nb, nk : int
        Structure.
    y_init, u_init : scalar or array_like, optional
        Samples before the record (as in :meth:`ARXModel.simulate`); give both to get one row
        per sample. Without them no past is invented: rows start at
        ``k = max(na, nk + nb - 1)``.

    Returns
    -------
    phi : numpy.ndarray, shape (rows, na + nb)
        Rows ``[-y(k-1) .. -y(k-na), u(k-nk) .. u(k-nk-nb+1)]``.
    target : numpy.ndarray, shape (rows,)
        ``y(k)``.
    """
    na, nb, nk = _orders(na, nb, nk)
    if isinstance(u, (list, tuple)) and isinstance(y, (list, tuple)):
        # Several records: each one's rows from its own samples, stacked, so that no
        # row spans two records (each record's first rows are left out as above).
        if y_init is not None or u_init is not None or len(u) != len(y) or not u:
            raise ParameterError("several records: give as many inputs as outputs, and no "
                                 "y_init/u_init (each record's past is its own)")
        rows = [regression_matrix(uk, yk, na, nb, nk) for uk, yk in zip(u, y, strict=True)]
        return np.vstack([r[0] for r in rows]), np.concatenate([r[1] for r in rows])
    uu, yy = _pair(u, y)
    if (y_init is None) != (u_init is None):
        raise ParameterError("give both y_init and u_init, or neither")
    if y_init is None:
        start = max(na, nk + nb - 1)
        if uu.size - start < 1:
            raise DataError(
                f"{uu.size} samples leave no regression row for na={na}, nb={nb}, nk={nk}"
            )
        y_hist, u_hist = yy[start - na : start], uu[start - (nk + nb - 1) : start]
        uu_rows, yy_rows = uu[start:], yy[start:]
    else:
        y_hist = _history(y_init, na, "y_init")
        u_hist = _history(u_init, nk + nb - 1, "u_init")
        uu_rows, yy_rows = uu, yy
    phi = np.hstack(
        [
            -_lag_matrix(yy_rows, range(1, na + 1), y_hist),
            _lag_matrix(uu_rows, range(nk, nk + nb), u_hist),
        ]
    )
    return phi, yy_rows.copy()


# --------------------------------------------------------------------------- estimators


@dataclass
class ARXFit:
    """An estimated ARX model and how it was obtained.

    Attributes
    ----------
    model : ARXModel
        The estimate.
    method : str
        "ls", "rls", "ffrls", "pso", "gwo", "hgwo" or "ffrls_hgwo".
    nfev : int or None
        Objective evaluations (metaheuristics only).
    noi : int or None
        Number of iterations as defined by :func:`hhra_phys.optim.noi` (metaheuristics only).
    seconds : float
        Wall time [s].
    trajectory : numpy.ndarray or None
        Recursive estimators: the estimate after each update, shape (rows, na + nb).
    convergence : numpy.ndarray or None
        Metaheuristics: best-so-far ITAE per iteration (index 0 = initial population).
    convergence_nfev : numpy.ndarray or None
        Metaheuristics: cumulative evaluations at each entry of ``convergence``.
    info : dict
        JSON-able details (condition number, forgetting factors, box, optimiser message ...).
    """

    model: ARXModel
    method: str
    nfev: int | None = None
    noi: int | None = None
    seconds: float = 0.0
    trajectory: np.ndarray | None = None
    convergence: np.ndarray | None = None
    convergence_nfev: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)


def fit_ls(
    u: Any,
    y: Any,
    na: int = 3,
    nb: int = 3,
    nk: int = 1,
    *,
    cond_limit: float = 1e8,
    on_ill_conditioned: str = "warn",
) -> ARXFit:
    """Least-squares ARX estimate (equation error), solved with :func:`numpy.linalg.lstsq`.

    The columns of the regression matrix are scaled to unit norm before solving, so the
    condition number measures collinearity of the regressors rather than their units.

    Parameters
    ----------
    u, y : array_like, shape (N,)
        Measured input and output (estimation data).
    na, nb, nk : int
        Structure (paper: 3, 3, 1).
    cond_limit : float
        Condition number of the scaled regression matrix above which the problem counts as
        ill-conditioned.
    on_ill_conditioned : {"warn", "raise", "ignore"}
        Emit a :class:`ConditioningWarning`, raise :class:`~hhra_phys.errors.DataError`, or say
        nothing.

    Returns
    -------
    ARXFit
        ``info["cond"]`` holds the condition number, ``info["rank"]`` the numerical rank.

    Raises
    ------
    DataError
        If the regression matrix is rank deficient (the input does not excite the
        ``na + nb`` coefficients, e.g. a constant input), or too short, or ill-conditioned with
        ``on_ill_conditioned="raise"``.
    """
    if on_ill_conditioned not in ("warn", "raise", "ignore"):
        raise ParameterError(
            f"on_ill_conditioned must be 'warn', 'raise' or 'ignore', got {on_ill_conditioned!r}"
        )
    start = time.perf_counter()
    na, nb, nk = _orders(na, nb, nk)
    phi, target = regression_matrix(u, y, na, nb, nk)
    p = na + nb
    if phi.shape[0] < p:
        raise DataError(
            f"{phi.shape[0]} regression rows for {p} coefficients (na={na}, nb={nb}, nk={nk}): "
            "more data needed"
        )
    norms = np.linalg.norm(phi, axis=0)
    if np.any(norms == 0):
        zero = [_column_name(j, na, nk) for j in np.flatnonzero(norms == 0)]
        raise DataError(
            f"regression columns {zero} are identically zero (na={na}, nb={nb}, nk={nk}): the "
            "data do not excite these coefficients"
        )
    theta_s, _, rank, sv = np.linalg.lstsq(phi / norms, target, rcond=None)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    if rank < p:
        raise DataError(
            f"the regression matrix is rank deficient (rank {rank} < na + nb = {p}, na={na}, "
            f"nb={nb}, nk={nk}): the input is not persistently exciting of this order, or the "
            "orders are too high; lower na/nb or use a richer input"
        )
    if cond > cond_limit:
        msg = (
            f"LS regression matrix is ill-conditioned: condition number {cond:.3g} > cond_limit "
            f"{cond_limit:.3g} (na={na}, nb={nb}, nk={nk}); the estimate is sensitive to noise"
        )
        if on_ill_conditioned == "raise":
            raise DataError(msg)
        if on_ill_conditioned == "warn":
            warnings.warn(msg, ConditioningWarning, stacklevel=2)
    model = ARXModel.from_theta(theta_s / norms, na, nb, nk)
    return ARXFit(
        model,
        "ls",
        seconds=time.perf_counter() - start,
        info={"cond": cond, "rank": int(rank), "rows": int(phi.shape[0])},
    )


def _column_name(j: int, na: int, nk: int) -> str:
    return f"-y(k-{j + 1})" if j < na else f"u(k-{nk + j - na})"


def forgetting_factor(n: int, xi0: float = FFRLS_XI0, xi_init: float = FFRLS_XI_INIT) -> np.ndarray:
    """The FFRLS time-varying forgetting factor for ``n`` updates.

    The recursion ``xi(k) = xi0 * xi(k-1) + (1 - xi0)`` (the paper's section 4.1) has the closed
    form ``xi(k) = 1 - (1 - xi(0)) * xi0**k``: it starts at ``xi(0)`` and rises to 1, so the
    estimator forgets old data early (memory of about ``1/(1 - xi)`` samples, 20 at the start)
    and becomes ordinary RLS later (memory 100 samples after about 160 updates, 1000 after about
    390 with the defaults). The paper prints "xi0 = 0.99, xi0 = 0.95"; we read 0.99 as the rate
    ``xi0`` and 0.95 as the start ``xi(0)``. Update number ``k`` (0-based) uses ``xi(k)``.
    ``xi0 = 1`` gives a constant forgetting factor ``xi_init``.

    Parameters
    ----------
    n : int
        Number of updates.
    xi0 : float
        Rate in [0, 1].
    xi_init : float
        Start value in (0, 1].

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    n = _order(n, "n", 0)
    if not 0.0 <= xi0 <= 1.0:
        raise ParameterError(f"xi0 must lie in [0, 1], got {xi0!r}")
    if not 0.0 < xi_init <= 1.0:
        raise ParameterError(f"xi_init must lie in (0, 1], got {xi_init!r}")
    return 1.0 - (1.0 - xi_init) * xi0 ** np.arange(n)


def recursive_least_squares(
    phi: Any,
    target: Any,
    *,
    p0: float = RLS_P0,
    theta0: Any = RLS_THETA0,
    forgetting: Any = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """(Forgetting-factor) recursive least squares over the rows of a regression problem.

    Per row ``k`` (the paper's eq. 28)::

        K = P phi / (xi + phi^T P phi)
        theta = theta + K (y - phi^T theta)
        P = (I - K phi^T) P / xi

    ``P`` is symmetrised after every update (round-off would otherwise make it drift).

    Parameters
    ----------
    phi : array_like, shape (rows, p)
        Regressors.
    target : array_like, shape (rows,)
        Outputs.
    p0 : float
        ``P(0) = p0 * I`` (paper: 1e5).
    theta0 : float or array_like, shape (p,)
        Initial estimate (paper: 1e-6 for every component).
    forgetting : float or array_like, shape (rows,)
        Forgetting factor per update in (0, 1]; 1 is plain RLS.

    Returns
    -------
    theta : numpy.ndarray, shape (p,)
        Final estimate.
    trajectory : numpy.ndarray, shape (rows, p)
        Estimate after each update.
    """
    ph = np.asarray(phi, dtype=float)
    tg = np.asarray(target, dtype=float).ravel()
    if ph.ndim != 2 or ph.shape[0] != tg.size:
        raise DataError(f"phi must have shape (rows, p) with rows = len(target), got {ph.shape}")
    rows, p = ph.shape
    if not (np.isfinite(p0) and p0 > 0):
        raise ParameterError(f"p0 must be a positive number, got {p0!r}")
    theta = np.broadcast_to(np.asarray(theta0, dtype=float), (p,)).copy()
    xi = np.broadcast_to(np.asarray(forgetting, dtype=float), (rows,))
    if not np.all((xi > 0) & (xi <= 1)):
        raise ParameterError("forgetting factors must lie in (0, 1]")
    cov = p0 * np.eye(p)
    traj = np.empty((rows, p))
    for k in range(rows):
        f = ph[k]
        pf = cov @ f
        gain = pf / (xi[k] + f @ pf)
        theta = theta + gain * (tg[k] - f @ theta)
        cov = (cov - np.outer(gain, pf)) / xi[k]
        cov = 0.5 * (cov + cov.T)
        traj[k] = theta
    return theta, traj


def _fit_recursive(
    method: str,
    u: Any,
    y: Any,
    na: int,
    nb: int,
    nk: int,
    p0: float,
    theta0: Any,
    forgetting: Any,
    info: dict[str, Any],
) -> ARXFit:
    start = time.perf_counter()
    na, nb, nk = _orders(na, nb, nk)
    phi, target = regression_matrix(u, y, na, nb, nk)
    if callable(forgetting):
        forgetting = forgetting(phi.shape[0])
    theta, traj = recursive_least_squares(phi, target, p0=p0, theta0=theta0, forgetting=forgetting)
    if not np.isfinite(theta).all():
        raise DataError(f"{method.upper()} diverged (non-finite estimate); check the data scaling")
    return ARXFit(
        ARXModel.from_theta(theta, na, nb, nk),
        method,
        seconds=time.perf_counter() - start,
        trajectory=traj,
        info={"p0": p0, "theta0": np.ravel(theta0).tolist(), **info},
    )


def fit_rls(
    u: Any,
    y: Any,
    na: int = 3,
    nb: int = 3,
    nk: int = 1,
    *,
    p0: float = RLS_P0,
    theta0: Any = RLS_THETA0,
) -> ARXFit:
    """Recursive least squares (no forgetting), the paper's ``P(0) = 1e5 I, theta(0) = 1e-6``.

    The result is the final estimate after one pass over the rows of
    :func:`regression_matrix`; it equals the LS estimate regularised by
    ``(Phi^T Phi + I/p0)^-1 (Phi^T y + theta0/p0)``.

    Parameters
    ----------
    u, y : array_like, shape (N,)
        Measured input and output.
    na, nb, nk : int
        Structure.
    p0, theta0 : float
        Initial covariance scale and estimate.
    """
    return _fit_recursive("rls", u, y, na, nb, nk, p0, theta0, 1.0, {})


def fit_ffrls(
    u: Any,
    y: Any,
    na: int = 3,
    nb: int = 3,
    nk: int = 1,
    *,
    xi0: float = FFRLS_XI0,
    xi_init: float = FFRLS_XI_INIT,
    p0: float = RLS_P0,
    theta0: Any = RLS_THETA0,
) -> ARXFit:
    """Forgetting-factor RLS with the time-varying factor of :func:`forgetting_factor`.

    Parameters
    ----------
    u, y : array_like, shape (N,)
        Measured input and output.
    na, nb, nk : int
        Structure.
    xi0, xi_init : float
        Rate and start of the forgetting factor (defaults: our reading of the paper, 0.99 and
        0.95).
    p0, theta0 : float
        As in :func:`fit_rls`.

    Returns
    -------
    ARXFit
        The final estimate; ``info["xi_final"]`` is the last forgetting factor used.
    """
    forgetting_factor(1, xi0, xi_init)  # validates before any work

    def factors(rows: int) -> np.ndarray:
        return forgetting_factor(rows, xi0, xi_init)

    fit = _fit_recursive(
        "ffrls", u, y, na, nb, nk, p0, theta0, factors, {"xi0": xi0, "xi_init": xi_init}
    )
    rows = 0 if fit.trajectory is None else fit.trajectory.shape[0]
    fit.info["xi_final"] = float(factors(rows)[-1]) if rows else xi_init
    return fit


# --------------------------------------------------------------------------- metaheuristics


def itae_cost(
    u: Any,
    y: Any,
    t: Any = None,
    na: int = 3,
    nb: int = 3,
    nk: int = 1,
    y_init: Any = None,
    u_init: Any = None,
    *,
    max_pole_radius: float | None = MAX_POLE_RADIUS,
) -> Callable[[np.ndarray], np.ndarray]:
    """The paper's fitness: ITAE of the free-run output, as a vectorised cost of ``theta`` rows.

    Parameters
    ----------
    u, y : array_like, shape (N,), or lists of them
        Measured input and output; lists of several records' signals (and ``t`` a
        list of their time axes) give the sum of the records' ITAEs, each record's
        free run starting at rest at its own first output (:func:`fit_metaheuristic`
        and :func:`fit_ffrls_hgwo` accept such lists too).
    t : array_like, shape (N,), optional
        Time axis [s] (ITAE in sample units without it).
    na, nb, nk : int
        Structure.
    y_init, u_init : scalar or array_like, optional
        Samples before the record. Default: the record starts at rest at its first measured
        output (past outputs ``y[0]``, past inputs 0).
    max_pole_radius : float or None
        Unstable candidates (a pole beyond this radius) cost ``inf`` without being simulated.

    Returns
    -------
    callable
        ``cost(theta)`` with ``theta`` of shape (m, na + nb) returns shape (m,) [output unit *
        s^2]; ``inf`` for unstable, diverging or non-finite candidates, never an exception.
    """
    from hhra_phys.metrics import itae

    na, nb, nk = _orders(na, nb, nk)
    if isinstance(u, (list, tuple)) and isinstance(y, (list, tuple)):
        # Several records: the sum of their ITAEs, each free run from its own start.
        ts = list(t) if isinstance(t, (list, tuple)) else [None] * len(u)
        if y_init is not None or u_init is not None or not (len(u) == len(y) == len(ts)) \
                or not u:
            raise ParameterError("several records: give as many inputs, outputs and time "
                                 "axes, and no y_init/u_init (each record starts at rest)")
        costs = [itae_cost(uk, yk, tk, na, nb, nk, max_pole_radius=max_pole_radius)
                 for uk, yk, tk in zip(u, y, ts, strict=True)]
        return lambda theta: np.sum([c(theta) for c in costs], axis=0)
    uu, yy = _pair(u, y)
    tt = None if t is None else np.asarray(t, dtype=float)
    y_hist = _history(yy[0] if y_init is None else y_init, na, "y_init")
    u_hist = _history(u_init, nk + nb - 1, "u_init")

    def cost(theta: np.ndarray) -> np.ndarray:
        sims = simulate_population(
            theta, uu, na, nb, nk, y_hist, u_hist, max_pole_radius=max_pole_radius
        )
        return np.atleast_1d(np.asarray(itae(yy, sims, tt), dtype=float))

    return cost


def _bounds(bounds: Any, p: int) -> np.ndarray:
    arr = np.asarray(bounds, dtype=float)
    if arr.shape == (2,):
        arr = np.tile(arr, (p, 1))
    if arr.shape != (p, 2) or not np.isfinite(arr).all() or np.any(arr[:, 0] >= arr[:, 1]):
        raise ParameterError(
            f"bounds must be (lo, hi) or a ({p}, 2) array of finite limits with lo < hi, "
            f"got {bounds!r}"
        )
    return arr


@dataclass(frozen=True)
class _SearchOptions:
    """Settings both metaheuristic ARX fits share (see :class:`MetaheuristicOptions`)."""

    na: int = 3
    nb: int = 3
    nk: int = 1
    pop_size: int = 100
    max_iter: int = 200
    seed: int | None = 0
    optimizer_options: Mapping[str, Any] | None = None
    y_init: Any = None
    u_init: Any = None
    max_pole_radius: float | None = MAX_POLE_RADIUS
    progress: bool = False

    def _validate_search(self) -> None:
        _orders(self.na, self.nb, self.nk)
        for name in ("pop_size", "max_iter"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ParameterError(f"{name} must be an integer >= 1, got {value!r}")
        if self.optimizer_options is not None and not isinstance(self.optimizer_options, Mapping):
            raise ParameterError(f"optimizer_options (options=) must be a dict of the "
                                 f"optimiser's settings, got {self.optimizer_options!r}")
        r = self.max_pole_radius
        if r is not None and not (isinstance(r, int | float) and math.isfinite(r) and r > 0):
            raise ParameterError(f"max_pole_radius must be a positive number or None, got {r!r}")


def _search_options(cls: type[Any], options: Any, settings: dict[str, Any], what: str) -> Any:
    """``options`` (an instance of ``cls``, or a dict of optimiser settings as the old
    ``options=``) with ``settings`` applied, validated."""
    if options is None or isinstance(options, cls):
        base = options if options is not None else cls()
    elif isinstance(options, Mapping):
        base = cls(optimizer_options=dict(options))
    else:
        raise ParameterError(f"options must be a {cls.__name__} or a dict of the optimiser's "
                             f"settings, got {options!r}")
    return with_overrides(base, settings, what).validate()


@dataclass(frozen=True)
class MetaheuristicOptions(_SearchOptions):
    """Settings of :func:`fit_metaheuristic`, validated as a whole.

    Every field is also a keyword of :func:`fit_metaheuristic`, which overrides the options
    it is given (``fit_metaheuristic(u, y, t, options=MetaheuristicOptions(method="pso"),
    seed=2)``).

    Attributes
    ----------
    method : str
        Optimiser, a key of :data:`hhra_phys.optim.registry.METHODS` (the paper's ``"pso"``,
        ``"gwo"``, ``"hgwo"``; ``"de"`` works too).
    na, nb, nk : int
        Structure.
    bounds : (lo, hi) or array of shape (na + nb, 2)
        Search box (default the paper's [-5, 5] for every coefficient).
    pop_size, max_iter : int
        Population size and iterations (paper: 100 and 200).
    seed : int or None
        Seed of the optimiser; the same seed reproduces the fit.
    optimizer_options : dict, optional
        Optimiser options (the functions' ``options={...}``), merged over
        :data:`METAHEURISTIC_OPTIONS` for the method.
    x0 : array_like, optional
        Warm-start points, see :func:`hhra_phys.optim.minimize`.
    y_init, u_init : scalar or array_like, optional
        Samples before the record (default: at rest at ``y[0]``), see :func:`itae_cost`.
    max_pole_radius : float or None
        Stability limit of candidates.
    progress : bool
        Show a progress bar.
    """

    method: str = "hgwo"
    bounds: Any = PAPER_BOX
    x0: Any = None

    def validate(self) -> MetaheuristicOptions:
        """Check every setting before any work; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        from hhra_phys.optim.registry import optimiser_class

        self._validate_search()
        optimiser_class(self.method)
        _bounds(self.bounds, self.na + self.nb)
        return self


@dataclass(frozen=True)
class HybridOptions(_SearchOptions):
    """Settings of the paper's hybrid :func:`fit_ffrls_hgwo`, validated as a whole.

    Every field is also a keyword of :func:`fit_ffrls_hgwo`, which overrides the options it
    is given.

    Attributes
    ----------
    na, nb, nk, pop_size, max_iter, seed
        As in :class:`MetaheuristicOptions`, for the H-GWO stage (paper: 100, 200).
    optimizer_options, y_init, u_init, max_pole_radius, progress
        As in :class:`MetaheuristicOptions` (H-GWO's paper options: ``F = 0.5``,
        ``lam = 0.25``).
    zeta_s : float
        Expansion gain of the box (:func:`hybrid_box`), in (0, 1].
    warm_start : bool
        Also put the FFRLS estimate itself into the first population. The paper only uses it
        to place the box, so the default is False.
    xi0, xi_init, p0, theta0
        FFRLS settings, see :func:`fit_ffrls`.
    """

    zeta_s: float = DEFAULT_ZETA_S
    warm_start: bool = False
    xi0: float = FFRLS_XI0
    xi_init: float = FFRLS_XI_INIT
    p0: float = RLS_P0
    theta0: Any = RLS_THETA0

    def validate(self) -> HybridOptions:
        """Check every setting before any work; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        self._validate_search()
        z = self.zeta_s
        if not (isinstance(z, int | float) and math.isfinite(z) and 0.0 < z <= 1.0):
            raise ParameterError(f"zeta_s must lie in (0, 1], got {z!r}")
        forgetting_factor(1, self.xi0, self.xi_init)
        return self


def fit_metaheuristic(
    u: Any,
    y: Any,
    t: Any = None,
    *,
    options: MetaheuristicOptions | Mapping[str, Any] | None = None,
    **settings: Any,
) -> ARXFit:
    """ARX coefficients by PSO, GWO or H-GWO minimising the ITAE of the free-run output.

    The paper's setting (section 4.3): box [-5, 5] for every coefficient, population 100, 200
    iterations; PSO with inertia from 0.9 to 0.1 and ``c1 = c2 = 2``; H-GWO with ``F = 0.5``,
    ``lam = 0.25``, ``Cr = 0.5 (1 + rand)`` (:data:`METAHEURISTIC_OPTIONS`). The whole population
    is evaluated in one call (:func:`itae_cost`); unstable candidates cost ``inf``.

    Parameters
    ----------
    u, y : array_like, shape (N,)
        Measured input and output (estimation data).
    t : array_like, shape (N,), optional
        Time axis [s] for the ITAE.
    options : MetaheuristicOptions or dict, optional
        The fit's settings (default :class:`MetaheuristicOptions`'s); a plain dict holds only
        the optimiser's own options (``optimizer_options``).
    **settings
        Any field of :class:`MetaheuristicOptions`, overriding ``options``: ``method``
        (``"pso"``, ``"gwo"``, ``"hgwo"``), ``na``, ``nb``, ``nk``, ``bounds``, ``pop_size``,
        ``max_iter``, ``seed``, ``x0``, ``y_init``, ``u_init``, ``max_pole_radius``,
        ``progress``.

    Returns
    -------
    ARXFit
        With ``nfev``, ``noi``, ``convergence`` and ``info["best_itae"]``.

    Raises
    ------
    ParameterError
        On bad bounds, an unknown method or option, or any bad setting (before any work).
    DataError
        If no candidate with a finite cost was found (e.g. every one unstable).
    """
    from hhra_phys.optim import minimize

    o = _search_options(MetaheuristicOptions, options, settings, "fit_metaheuristic")
    na, nb, nk = _orders(o.na, o.nb, o.nk)
    box = _bounds(o.bounds, na + nb)
    key = str(o.method).lower()
    opts = {**METAHEURISTIC_OPTIONS.get(key, {}), **dict(o.optimizer_options or {})}
    cost = itae_cost(u, y, t, na, nb, nk, o.y_init, o.u_init, max_pole_radius=o.max_pole_radius)
    start = time.perf_counter()
    res = minimize(
        cost,
        box,
        method=key,
        pop_size=o.pop_size,
        max_iter=o.max_iter,
        seed=o.seed,
        vectorized=True,
        options=opts,
        progress=o.progress,
        x0=o.x0,
    )
    seconds = time.perf_counter() - start
    if not np.isfinite(res.fun):
        raise DataError(
            f"{key}: no candidate in the box gave a finite ITAE (all unstable or diverging); "
            "widen or move the box"
        )
    hist = res.history.as_arrays()
    return ARXFit(
        ARXModel.from_theta(res.x, na, nb, nk),
        key,
        nfev=int(res.nfev),
        noi=int(res.noi),
        seconds=seconds,
        convergence=hist["best"],
        convergence_nfev=hist["nfev"],
        info={
            "best_itae": float(res.fun),
            "nit": int(res.nit),
            "bounds": box.tolist(),
            "options": {k: v for k, v in opts.items() if np.isscalar(v)},
            "pop_size": int(o.pop_size),
            "seed": o.seed,
            "message": str(res.message),
        },
    )


def hybrid_box(
    theta_hat: Any, zeta_s: float = DEFAULT_ZETA_S, min_half_width: float | None = None
) -> np.ndarray:
    """The hybrid's search box, eq. 29: ``theta_hat -/+ zeta_s * |theta_hat|``.

    Parameters
    ----------
    theta_hat : array_like, shape (p,)
        Interim estimate (FFRLS).
    zeta_s : float
        Expansion gain in (0, 1] (the paper allows [0, 1]; 0 would fix every coefficient). The
        paper does not give the value it used; the default is 0.5.
    min_half_width : float, optional
        Smallest half-width of any interval, so that a zero component still gives a valid (if
        tiny) interval, i.e. stays essentially fixed at 0 as eq. 29 implies. Default
        ``1e-12 * max(1, max|theta_hat|)``.

    Returns
    -------
    numpy.ndarray, shape (p, 2)
        ``[lo, hi]`` per coefficient, ``lo < hi``.
    """
    th = np.asarray(theta_hat, dtype=float).ravel()
    if th.size == 0 or not np.isfinite(th).all():
        raise ParameterError(f"theta_hat must be a non-empty finite vector, got {th}")
    if not (np.isfinite(zeta_s) and 0.0 < zeta_s <= 1.0):
        raise ParameterError(f"zeta_s must lie in (0, 1], got {zeta_s!r}")
    floor = 1e-12 * max(1.0, float(np.abs(th).max())) if min_half_width is None else min_half_width
    if not (np.isfinite(floor) and floor > 0):
        raise ParameterError(f"min_half_width must be a positive number, got {min_half_width!r}")
    half = np.maximum(zeta_s * np.abs(th), floor)
    return np.column_stack([th - half, th + half])


def fit_ffrls_hgwo(
    u: Any,
    y: Any,
    t: Any = None,
    *,
    options: HybridOptions | Mapping[str, Any] | None = None,
    **settings: Any,
) -> ARXFit:
    """The paper's hybrid: FFRLS estimate, then H-GWO on the box of eq. 29 around it.

    Parameters
    ----------
    u, y, t : array_like
        As in :func:`fit_metaheuristic`.
    options : HybridOptions or dict, optional
        The fit's settings (default :class:`HybridOptions`'s); a plain dict holds only
        H-GWO's own options (``optimizer_options``).
    **settings
        Any field of :class:`HybridOptions`, overriding ``options``: ``na``, ``nb``, ``nk``,
        ``zeta_s``, ``pop_size``, ``max_iter``, ``seed``, ``warm_start``, ``xi0``,
        ``xi_init``, ``p0``, ``theta0``, ``y_init``, ``u_init``, ``max_pole_radius``,
        ``progress``.

    Returns
    -------
    ARXFit
        Method ``"ffrls_hgwo"``; ``info`` adds ``ffrls_theta``, ``zeta_s`` and the box; seconds
        include the FFRLS step.

    Notes
    -----
    H-GWO's mutation pulls toward ``lam * X_alpha``, i.e. toward the coordinate origin (see
    ``docs/benchmarks.md``). Here the coordinates are the raw coefficients, as in the paper,
    so the pull points toward zero coefficients, which lie outside the box when ``zeta_s < 1``
    (the excess is re-drawn inside the box).
    """
    o = _search_options(HybridOptions, options, settings, "fit_ffrls_hgwo")
    start = time.perf_counter()
    ff = fit_ffrls(u, y, o.na, o.nb, o.nk, xi0=o.xi0, xi_init=o.xi_init, p0=o.p0,
                   theta0=o.theta0)
    theta_hat = ff.model.theta
    box = hybrid_box(theta_hat, o.zeta_s)
    search = {f.name: getattr(o, f.name) for f in fields(_SearchOptions)}
    fit = fit_metaheuristic(
        u,
        y,
        t,
        method="hgwo",
        bounds=box,
        x0=theta_hat[None, :] if o.warm_start else None,
        **search,
    )
    fit.method = "ffrls_hgwo"
    fit.seconds = time.perf_counter() - start
    fit.info.update(
        ffrls_theta=theta_hat.tolist(),
        zeta_s=o.zeta_s,
        warm_start=o.warm_start,
        ffrls_stable=ff.model.is_stable(),
    )
    return fit
