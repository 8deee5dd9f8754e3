"""The ARX structure: the model, its free run, its one-step prediction and its regressors.

:class:`ARXModel` (``A(q^-1) y(k) = q^-nk B(q^-1) u(k)``) with :meth:`~ARXModel.simulate`
and :meth:`~ARXModel.predict`; :func:`simulate_population`, the free run of many models at
once that the metaheuristics score; :func:`pole_radius`, their stability check; and
:func:`regression_matrix`, the rows ``phi(k)`` every estimator and the one-step prediction
use. Also the checks of orders, signals and the samples before a record that the
estimators (:mod:`.estimators`, :mod:`.search`) share. What is estimated, and how, is
elsewhere: this module is what an ARX model is and does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.signal

from hhra_phys.errors import DataError, ParameterError

__all__ = ["MAX_POLE_RADIUS", "ARXModel", "pole_radius", "regression_matrix",
           "simulate_population"]

#: Candidates with a pole outside this radius count as unstable (cost inf).
MAX_POLE_RADIUS = 1.0

# Poles are compared with the limit with this slack, so that an exact integrator (a pole at
# z = 1 computed as 1 + 1e-15) is not thrown out as unstable.
_POLE_SLACK = 1e-9


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
