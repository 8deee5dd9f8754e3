"""The fixed-step integrator of every compiled simulation: classical RK4.

One definition, used symbolically (CasADi SX or MX) by the population simulator
(:mod:`hhra_phys.simulate`), the forward sensitivities
(:mod:`hhra_phys.sensitivity`) and the closed-loop simulation
(:mod:`hhra_phys.control`), so that all three integrate the same way.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["rk4_step", "rk4"]


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
