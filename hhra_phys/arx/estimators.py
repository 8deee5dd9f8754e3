"""Regression estimators of ARX coefficients: least squares, RLS and forgetting-factor RLS.

:func:`fit_ls` (equation error, with a conditioning check), the recursion
:func:`recursive_least_squares` (the paper's eq. 28) behind :func:`fit_rls` and
:func:`fit_ffrls` (the time-varying factor of :func:`forgetting_factor`), and
:class:`ARXFit`, the result every ARX fit returns. The paper's initial values are the
defaults (:data:`RLS_P0`, :data:`RLS_THETA0`, :data:`FFRLS_XI0`, :data:`FFRLS_XI_INIT`).
Separate from the search-based fits (:mod:`.search`), which only use the FFRLS estimate.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hhra_phys.arx.structure import ARXModel, _order, _orders, regression_matrix
from hhra_phys.errors import DataError, ParameterError

__all__ = ["FFRLS_XI0", "FFRLS_XI_INIT", "RLS_P0", "RLS_THETA0", "ARXFit",
           "ConditioningWarning", "fit_ffrls", "fit_ls", "fit_rls", "forgetting_factor",
           "recursive_least_squares"]

#: RLS/FFRLS initial covariance ``P(0) = RLS_P0 * I`` (paper: alpha = 1e5).
RLS_P0 = 1e5
#: RLS/FFRLS initial estimate, every component (paper: epsilon = 1e-6).
RLS_THETA0 = 1e-6
#: FFRLS forgetting-factor rate xi0 in ``xi(k) = xi0 * xi(k-1) + (1 - xi0)`` (our reading).
FFRLS_XI0 = 0.99
#: FFRLS initial forgetting factor xi(0) (our reading of the paper's second "xi0 = 0.95").
FFRLS_XI_INIT = 0.95


class ConditioningWarning(RuntimeWarning):
    """The LS regression matrix is ill-conditioned: the estimate is sensitive to noise."""



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
