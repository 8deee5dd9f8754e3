"""The fixed-step integrators of every compiled simulation.

One module holds every method, used symbolically (CasADi SX or MX) by the
population simulator (:mod:`hhra_phys.simulate`), the forward sensitivities
(:mod:`hhra_phys.sensitivity`) and the closed-loop simulation
(:mod:`hhra_phys.control`), so that all of them integrate the same way.

Methods (:data:`METHODS`):

``"rk4"``
    Classical explicit Runge-Kutta 4: four right-hand sides per step, fourth
    order, stable only while ``|lambda| * h`` stays below about 2.8 for every
    eigenvalue ``lambda`` of the state Jacobian.
``"ros2"``
    The two-stage Rosenbrock method ROS2 of Verwer, Spee, Blom and Hundsdorfer
    (SIAM J. Sci. Comput. 20, 1999), ``gamma = 1 + 1/sqrt(2)``::

        W  = I - gamma*h*J(x)
        W k1 = f(x)
        W k2 = f(x + h*k1) - 2*k1
        x+ = x + h*(3/2*k1 + 1/2*k2)

    Linearly implicit: one exact Jacobian (CasADi derives it symbolically), one
    LU factorisation and two right-hand sides per step, second order for any
    ``J`` and L-stable, so a stiff mode (a friction switching within a few
    thousandths of a rad/s, a stiff oil column) is damped at any step instead of
    blowing up. Its error constant is large: on the rig's HHRA it needs 30
    substeps per sample for the accuracy RK4 has with 2 (``docs/performance.md``),
    so it is kept for comparison and for users who want L-stability.
``"ros4"``
    The four-stage, fourth-order Rosenbrock method of Kaps and Rentrop with
    Shampine's parameters (Shampine, ACM TOMS 8, 1982; the ``stiff`` routine of
    Numerical Recipes), ``gamma = 1/2``, in Hairer and Wanner's form::

        W  = I/(gamma*h) - J(x)
        W g1 = f(x)
        W g2 = f(x + 2*g1) - 8*g1/h
        W g3 = f3 + (372/25*g1 + 12/5*g2)/h,     f3 = f(x + 48/25*g1 + 6/25*g2)
        W g4 = f3 + (-112/125*g1 - 54/125*g2 - 2/5*g3)/h
        x+ = x + 19/9*g1 + 1/2*g2 + 25/108*g3 + 125/108*g4

    Three right-hand sides, one exact Jacobian, one LU and four substitutions
    per step; fourth order (as accurate as RK4 on the rig's HHRA at equal
    substeps) and A-stable with ``R(-inf) = 1/3``: a stiff real mode is damped
    by a factor of 3 per step whatever its speed. The simulator's choice for
    stiff models (:class:`hhra_phys.simulate.Simulator`).

The Rosenbrock methods' LU factorisation is written out without pivoting, as straight-line
arithmetic (no branch on a value), so the step compiles to the same scalar and
SIMD vector code as RK4. ``W = I - gamma*h*J`` is the identity plus a small
term for non-stiff models and diagonally weighted by the dissipative stiff
terms (damping, friction, leakage) otherwise; a model for which a pivot
vanishes returns non-finite states, which the simulator flags.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

__all__ = ["rk4_step", "rk4", "ros2_step", "ros2", "ros4_step", "ros4", "advance", "METHODS",
           "STABILITY_LIMIT", "ORDER", "lu_solve"]

#: Fixed-step methods by name.
METHODS: tuple[str, ...] = ("rk4", "ros2", "ros4")

#: Largest ``|lambda| * h`` each method is stable for (on the negative real and the
#: imaginary axis); ``inf`` for the A-stable Rosenbrock methods.
STABILITY_LIMIT: dict[str, float] = {"rk4": 2.8, "ros2": math.inf, "ros4": math.inf}

#: Order of accuracy of each method.
ORDER: dict[str, int] = {"rk4": 4, "ros2": 2, "ros4": 4}

#: ROS2's gamma (L-stability needs 1 + 1/sqrt(2) or 1 - 1/sqrt(2); the larger
#: one keeps the error constant small and the method positive).
ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


def rk4_step(f: Callable[[Any, Any, Any], Any], x: Any, u: Any, p: Any, h: float) -> Any:
    """One classical Runge-Kutta step of ``dx/dt = f(x, u, p)`` with ``u`` held.

    Parameters
    ----------
    f : callable
        Right-hand side ``(x, u, p) -> xdot`` (a CasADi function or any callable
        on CasADi expressions or arrays).
    x, u, p
        State (nx,), held input (n_lags + 1,) and parameters (n_params,).
    h : float
        Step [s].
    """
    k1 = f(x, u, p)
    k2 = f(x + h / 2 * k1, u, p)
    k3 = f(x + h / 2 * k2, u, p)
    k4 = f(x + h * k3, u, p)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def rk4(f: Callable[[Any, Any, Any], Any], x: Any, u: Any, p: Any, h: float,
        steps: int) -> Any:
    """``steps`` RK4 steps of size ``h`` with the input held (one sample of ``steps*h``)."""
    for _ in range(int(steps)):
        x = rk4_step(f, x, u, p, h)
    return x


def _lu(a: Any, n: int) -> tuple[list[list[Any]], list[list[Any]]]:
    """Doolittle LU of the (n, n) matrix ``a`` without pivoting: (L below the diagonal, U)."""
    A = [[a[i, j] for j in range(n)] for i in range(n)]
    L = [[None] * n for _ in range(n)]
    for k in range(n):
        for i in range(k + 1, n):
            L[i][k] = A[i][k] / A[k][k]
            for j in range(k + 1, n):
                A[i][j] = A[i][j] - L[i][k] * A[k][j]
    return L, A


def _lu_apply(L: list[list[Any]], U: list[list[Any]], b: Any, n: int, vertcat: Callable) -> Any:
    """Solve ``L U x = b`` by forward and back substitution."""
    y = [b[i] for i in range(n)]
    for i in range(n):
        for k in range(i):
            y[i] = y[i] - L[i][k] * y[k]
    for i in reversed(range(n)):
        for k in range(i + 1, n):
            y[i] = y[i] - U[i][k] * y[k]
        y[i] = y[i] / U[i][i]
    return vertcat(*y)


def _vertcat_of(x: Any) -> Callable:
    try:
        import casadi as ca

        if isinstance(x, (ca.SX, ca.MX, ca.DM)):
            return ca.vertcat
    except ImportError:  # pragma: no cover - casadi is a dependency
        pass
    import numpy as np

    return lambda *v: np.array([np.asarray(e).reshape(()) for e in v], dtype=float)


def lu_solve(a: Any, b: Any) -> Any:
    """Solve ``a x = b`` for a square ``a`` by LU without pivoting (straight-line code).

    Parameters
    ----------
    a : (n, n) CasADi matrix or NumPy array
    b : (n,) or (n, 1)

    Returns
    -------
    Same kind as ``b``, shape (n, 1) for CasADi, (n,) for NumPy.
    """
    n = int(a.shape[0])
    L, U = _lu(a, n)
    return _lu_apply(L, U, b, n, _vertcat_of(b))


def ros2_step(f: Callable[[Any, Any, Any], Any], jac: Callable[[Any, Any, Any], Any],
              x: Any, u: Any, p: Any, h: float) -> Any:
    """One ROS2 step (module docstring) of ``dx/dt = f(x, u, p)`` with ``u`` held.

    Parameters
    ----------
    f : callable
        Right-hand side ``(x, u, p) -> xdot``, shape (nx,).
    jac : callable
        Its state Jacobian ``(x, u, p) -> df/dx``, shape (nx, nx).
    x, u, p
        State (nx,), held input (n_lags + 1,) and parameters (n_params,).
    h : float
        Step [s].
    """
    n = int(x.shape[0])
    J = jac(x, u, p)
    W = -ROS2_GAMMA * h * J
    for i in range(n):
        W[i, i] = W[i, i] + 1.0
    L, U = _lu(W, n)
    cat = _vertcat_of(x)
    k1 = _lu_apply(L, U, f(x, u, p), n, cat)
    k2 = _lu_apply(L, U, f(x + h * k1, u, p) - 2 * k1, n, cat)
    return x + h * (1.5 * k1 + 0.5 * k2)


def ros2(f: Callable[[Any, Any, Any], Any], jac: Callable[[Any, Any, Any], Any], x: Any,
         u: Any, p: Any, h: float, steps: int) -> Any:
    """``steps`` ROS2 steps of size ``h`` with the input held."""
    for _ in range(int(steps)):
        x = ros2_step(f, jac, x, u, p, h)
    return x


#: Shampine's parameters of the Kaps-Rentrop ROS4 method (module docstring).
_ROS4 = {
    "gamma": 0.5, "a21": 2.0, "a31": 48.0 / 25.0, "a32": 6.0 / 25.0, "c21": -8.0,
    "c31": 372.0 / 25.0, "c32": 12.0 / 5.0, "c41": -112.0 / 125.0, "c42": -54.0 / 125.0,
    "c43": -2.0 / 5.0, "b": (19.0 / 9.0, 0.5, 25.0 / 108.0, 125.0 / 108.0),
}


def ros4_step(f: Callable[[Any, Any, Any], Any], jac: Callable[[Any, Any, Any], Any],
              x: Any, u: Any, p: Any, h: float) -> Any:
    """One ROS4 step (module docstring) of ``dx/dt = f(x, u, p)`` with ``u`` held.

    Parameters as :func:`ros2_step`.
    """
    c = _ROS4
    n = int(x.shape[0])
    W = -1.0 * jac(x, u, p)
    for i in range(n):
        W[i, i] = W[i, i] + 1.0 / (c["gamma"] * h)
    L, U = _lu(W, n)
    cat = _vertcat_of(x)
    g1 = _lu_apply(L, U, f(x, u, p), n, cat)
    g2 = _lu_apply(L, U, f(x + c["a21"] * g1, u, p) + (c["c21"] / h) * g1, n, cat)
    f3 = f(x + c["a31"] * g1 + c["a32"] * g2, u, p)
    g3 = _lu_apply(L, U, f3 + (c["c31"] / h) * g1 + (c["c32"] / h) * g2, n, cat)
    g4 = _lu_apply(L, U, f3 + (c["c41"] / h) * g1 + (c["c42"] / h) * g2 + (c["c43"] / h) * g3,
                   n, cat)
    b = c["b"]
    return x + b[0] * g1 + b[1] * g2 + b[2] * g3 + b[3] * g4


def ros4(f: Callable[[Any, Any, Any], Any], jac: Callable[[Any, Any, Any], Any], x: Any,
         u: Any, p: Any, h: float, steps: int) -> Any:
    """``steps`` ROS4 steps of size ``h`` with the input held."""
    for _ in range(int(steps)):
        x = ros4_step(f, jac, x, u, p, h)
    return x


def advance(method: str, f: Callable[[Any, Any, Any], Any],
            jac: Callable[[Any, Any, Any], Any] | None, x: Any, u: Any, p: Any, h: float,
            steps: int) -> Any:
    """``steps`` steps of ``method`` (:data:`METHODS`) of size ``h``: one held sample.

    Parameters
    ----------
    method : {"rk4", "ros2", "ros4"}
        The integrator.
    f, jac : callable
        Right-hand side and its state Jacobian (``jac`` read by the Rosenbrock
        methods only).
    x, u, p
        State, held input and parameters.
    h : float
        Step [s].
    steps : int
        Number of steps.
    """
    if method == "rk4":
        return rk4(f, x, u, p, h, steps)
    if method in ("ros2", "ros4"):
        if jac is None:
            raise ValueError(f"the {method} method needs the state Jacobian 'jac'")
        return (ros2 if method == "ros2" else ros4)(f, jac, x, u, p, h, steps)
    raise ValueError(f"unknown integration method {method!r}; known: {', '.join(METHODS)}")
