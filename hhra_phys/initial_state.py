"""A record's initial state: the ``"data"`` rule and the least-squares estimate.

The rules of :mod:`hhra_phys.problem`'s docstring ("Initial state") that need no fitting
problem: :func:`data_rule_function` moves the fitted states so that the model's output
equals the first measured sample (:func:`initial_guess` for numbers), and
:func:`estimate_initial_state` fits the whole initial state of a record with the
parameters fixed (a held-out part, another record, a prediction). Separate from the
problems because results and predictions use them without one; every name here is also
importable from :mod:`hhra_phys.problem`.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from scipy.optimize import least_squares

from hhra_phys.model import Model
from hhra_phys.simulate import Simulator

__all__ = [
    "data_rule_function",
    "estimate_initial_state",
    "initial_guess",
]


#: Newton steps of the ``"data"`` rule (one is exact for an output linear in the states).
DATA_RULE_STEPS = 3


def data_rule_function(model: Model, dt: float) -> ca.Function:
    """CasADi function ``(y0, u0, p) -> x0`` of the ``"data"`` rule (module docstring).

    Symbolic in every argument, so the rule is differentiated exactly where the
    initial state depends on parameters (a pressure sensor's gain and offset).
    """
    cache = model.__dict__.setdefault("_data_rule_cache", {})
    key = float(dt)
    if key in cache:
        return cache[key]
    xs, us, ps = model.symbols()
    y0 = ca.SX.sym("y0")
    u0 = ca.SX.sym("u0")
    _, h = model.assemble(xs, us, ps, dt)
    fitted = [model.state_names.index(n) for n in model.fitted_states]
    x = ca.SX(model.x0())
    if fitted:
        xf = ca.vertcat(*[xs[i] for i in fitted])
        hu = ca.substitute(h, us, ca.repmat(u0, us.numel(), 1))
        J = ca.jacobian(hu, xf)
        jj = ca.mtimes(J, J.T)
        step = ca.Function("newton", [xs, y0, u0, ps],
                           [ca.if_else(jj > 0, J.T * (y0 - hu) / jj, ca.SX.zeros(len(fitted)))])
        for _ in range(DATA_RULE_STEPS):
            dxf = step(x, y0, u0, ps)
            x = ca.vertcat(*[x[i] + dxf[fitted.index(i)] if i in fitted else x[i]
                             for i in range(model.nx)])
    fn = ca.Function("x0_data_rule", [y0, u0, ps], [x], ["y0", "u0", "p"], ["x0"])
    cache[key] = fn
    return fn


def _sensitivity(sim: Simulator):
    """The simulator's compiled forward sensitivities (shared with the refiners), or None.

    Its first ``nx`` columns are the exact Jacobian of the outputs with respect to the
    initial state: one trajectory, and the code every refined model compiles anyway, where
    central differences need a population function of their own (a compile per model
    variant, 0.6 s, most of what a loop's cold start paid per candidate)."""
    from hhra_phys.sensitivity import TrajectorySensitivity

    try:
        return TrajectorySensitivity.of(sim)
    except Exception:  # a model CasADi cannot differentiate: central differences
        return None


def estimate_initial_state(
    sim: Simulator,
    u: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    x0: np.ndarray,
    iterations: int = 4,
    skip: int = 0,
) -> np.ndarray:
    """Least-squares estimate of the whole initial state of a record, parameters fixed.

    Like initial-condition estimation when comparing models on validation data
    (MATLAB's ``compare``): a record cut from the middle of a motion starts with
    unknown velocity and pressure, and its first noisy sample would set a
    constant offset that a free-run angle never forgets. SciPy's trust-region
    least squares (``least_squares``, ``"trf"``, scaled by the Jacobian's columns)
    with the exact Jacobian from the compiled forward sensitivities the refiners use
    (:class:`~hhra_phys.sensitivity.TrajectorySensitivity`; by central differences through
    the population simulator where they are not finite); the model parameters are untouched.
    A trust region, not plain Gauss-Newton steps: a discovered stiff or non-smooth term
    (``omega^3`` with a large coefficient, ``|theta|``) makes the linearisation a poor
    guide far from the guess, where undamped or halved Gauss-Newton steps stall (on such
    a held-out part they stopped at 0.080 deg where the state's optimum gives 0.052).

    Parameters
    ----------
    sim : Simulator
        Simulator of the model at the record's sample rate.
    u, y : ndarray, shape (N,)
        Input and measured output of the record.
    p : ndarray, shape (n_params,)
        Model parameters.
    x0 : ndarray, shape (nx,)
        Initial guess.
    iterations : int
        Budget: at most ``4 * iterations + 4`` simulations of the trajectory (each
        iteration of the trust region takes one or, after a rejected step, a few).
    skip : int
        Samples at the start left out of the fit (simulated, not compared: a leading
        window's first samples, whose delayed inputs lie before it).

    Returns
    -------
    ndarray, shape (nx,)
        The estimate (the guess itself if its trajectory is not finite, or if no
        state lowers the cost).
    """
    nx = x0.size
    step = 1e-4
    x = np.asarray(x0, dtype=float).copy()
    y_cmp = np.asarray(y, dtype=float)[skip:]
    P = np.tile(p, (2 * nx, 1))

    def residual(xk: np.ndarray) -> np.ndarray:
        return sim.simulate(u, p, x0=xk)[skip:] - y_cmp

    sens = _sensitivity(sim)

    def jacobian(xk: np.ndarray) -> np.ndarray:
        if sens is not None:
            with np.errstate(all="ignore"):
                J = sens(u, p, xk)[1][skip:, :nx]
            if np.isfinite(J).all():
                return J
        X = np.tile(xk, (2 * nx, 1))
        for i in range(nx):
            X[2 * i, i] -= step
            X[2 * i + 1, i] += step
        Y = sim.simulate(u, P, x0=X)[:, skip:]
        J = (Y[1::2] - Y[0::2]).T / (2 * step)
        return np.where(np.isfinite(J), J, 0.0)

    if y_cmp.size == 0:
        return x
    try:
        # A guess whose trajectory is not finite raises ValueError; the trust region only
        # accepts steps that lower the cost, so its answer is never worse than the guess.
        sol = least_squares(residual, x, jac=jacobian, method="trf", x_scale="jac",
                            max_nfev=4 * iterations + 4, xtol=1e-6, ftol=1e-4)
    except (ValueError, np.linalg.LinAlgError):
        return x
    return np.asarray(sol.x, dtype=float) if np.isfinite(sol.fun).all() else x


def initial_guess(model: Model, y0: float, p: np.ndarray, u0: float = 0.0,
                  dt: float = 0.004) -> np.ndarray:
    """Initial state of the ``"data"`` rule (module docstring) for a first output sample ``y0``.

    Parameters
    ----------
    model : Model
    y0 : float
        First measured output sample (output units).
    p : ndarray, shape (n_params,)
        Model parameters.
    u0 : float
        First input sample (input units).
    dt : float
        Sample period [s] (for models with discrete-time input parts).

    Returns
    -------
    ndarray, shape (nx,)
    """
    rule = data_rule_function(model, dt)
    return np.array(rule(float(y0), float(u0), np.asarray(p, dtype=float)), dtype=float).ravel()
