"""First-order response of a fitted model to a candidate column: the column propagated
through the model linearised at the fit, with what the model's own free parameters absorb
projected out.

Shared by the residual analysis (library effects' evidence, :mod:`.residual`) and
discovery's screening (:mod:`.screening`).
"""

from __future__ import annotations

import numpy as np
from scipy import signal as sps

from hhra_phys.errors import ParameterError
from hhra_phys.problem import Problem

__all__ = ["linear_response", "nuisance_basis"]


def _linear_response(problem: Problem, P: np.ndarray, entry: str, cols: np.ndarray,
                     umax: float) -> np.ndarray:
    """Output response (N, k) of the model linearised at the fit to ``cols`` at ``entry``."""
    model = problem.model
    dt = problem.sim.dt
    if entry == "output":
        return cols
    names = model.state_names
    A, B, C, _ = model.linearize(p=P, u=0.5 * umax, dt=dt)
    if entry == "input":
        # Average the two directions: orifice laws and dead zones are odd in u.
        A2, B2, _, _ = model.linearize(p=P, u=-0.5 * umax, dt=dt)
        A, B = 0.5 * (A + A2), 0.5 * (B + B2)
        Dm = np.zeros((1, 1))
    elif entry.startswith("rate:") and entry[5:] in names:
        B = np.zeros((len(names), 1))
        B[names.index(entry[5:]), 0] = 1.0
        Dm = np.zeros((1, 1))
    else:
        raise ParameterError(
            f"unknown entry point {entry!r} (input, output or rate:<state> with a state of "
            f"{', '.join(names)})")
    Ad, Bd, Cd, Dd, _ = sps.cont2discrete((A, B, C, Dm), dt, method="zoh")
    return _discrete_response(Ad, Bd[:, 0], Cd[0], float(Dd[0, 0]), cols)


def _discrete_response(A: np.ndarray, b: np.ndarray, c: np.ndarray, d: float,
                       cols: np.ndarray) -> np.ndarray:
    """Outputs (N, k) of ``x+ = A x + b u``, ``y = c x + d u`` from rest, every column at once.

    The recursion of :func:`scipy.signal.dlsim` advanced for all columns per sample:
    ``dlsim`` loops over the samples in Python once per column, which made the
    discovery's mode screening (tens of columns per entry) the loop's largest cost.
    """
    cols = np.asarray(cols, dtype=float)
    x = np.zeros((A.shape[0], cols.shape[1]))
    out = np.empty_like(cols)
    # An unstable A overflows to inf/nan; the callers check the response's finiteness.
    with np.errstate(over="ignore", invalid="ignore"):
        for i, ui in enumerate(cols):
            out[i] = c @ x + d * ui
            x = A @ x + np.outer(b, ui)
    return out


def _sensitivities(problem: Problem, values: np.ndarray, y0: np.ndarray) -> np.ndarray:
    """Output sensitivities to the free parameters in fitting coordinates, (N, n_free).

    The exact Jacobian of the discretised model (the refiners' compiled forward
    sensitivities, :class:`~hhra_phys.refine.CompiledLeastSquares`): the fit has
    already built it, so no population simulator is compiled for the analysis.
    ``y0`` (the fitted output) is not needed and kept for the signature.
    """
    from hhra_phys.refine import CompiledLeastSquares

    _, J = CompiledLeastSquares(problem)(problem.to_z(values))
    J = np.array(J, dtype=float)
    J[~np.isfinite(J)] = 0.0
    return J


def linear_response(problem: Problem, P: np.ndarray, entry: str, cols: np.ndarray,
                    umax: float) -> np.ndarray:
    """Output response of the model linearised at ``P`` to changes at an entry point.

    Parameters
    ----------
    problem : Problem
        The fitted problem (model, sample period).
    P : ndarray, shape (n_params,)
        Full parameter vector at which to linearise.
    entry : str
        ``"input"``, ``"output"`` or ``"rate:<state>"``.
    cols : ndarray, shape (N, k)
        Changes at the entry (entry units), one column per candidate.
    umax : float
        Largest input magnitude; the model is linearised at ``+-umax/2``.

    Returns
    -------
    ndarray, shape (N, k)
        Output changes (output units).
    """
    return _linear_response(problem, P, entry, cols, umax)


def nuisance_basis(problem: Problem, values: np.ndarray, yhat: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the output changes the model's own free parameters can make.

    Finite-difference output sensitivities to every free parameter (the fitted
    initial state among them), normalised and orthogonalised; directions the
    parameters cannot move are dropped. Projecting a residual or a candidate's
    response off this basis leaves what a refit of the base model could not absorb.

    Parameters
    ----------
    problem : Problem
    values : ndarray, shape (n_free,)
        Fitted free values.
    yhat : ndarray, shape (N,)
        Simulated output at ``values``.

    Returns
    -------
    ndarray, shape (N, m)
    """
    N = _sensitivities(problem, values, yhat)
    N = N / np.maximum(np.linalg.norm(N, axis=0), 1e-300)
    Q, R = np.linalg.qr(N)
    return Q[:, np.abs(np.diag(R)) > 1e-8]


def _project_out(Q: np.ndarray, M: np.ndarray) -> np.ndarray:
    """The columns of ``M`` with their part in the span of ``Q`` (orthonormal) removed."""
    return M - Q @ (Q.T @ M)
