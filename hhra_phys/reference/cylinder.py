"""Independent reference of the valve-controlled double-acting linear cylinder.

Plain NumPy/SciPy, in physical SI variables, written from the textbook equations
(Merritt, *Hydraulic Control Systems*, ch. 5) and deliberately sharing no code
with :mod:`hhra_phys.models.cylinder`: no normalisation, no groups, no
smoothing, no CasADi. Test data generated here therefore cannot inherit a
mistake of the package model (a wrong sign in the valve law, a wrong group
mapping), which data simulated by the package model itself would hide.

Plant (symmetric double-rod cylinder, 4-way critical-centre valve)::

    Q_L     = K_v * I * sign(p_s - sign(I) P_L) * sqrt(|p_s - sign(I) P_L|)
    dx/dt   = v
    m dv/dt = A_p P_L - B_p v - K x - F_L - F_c tanh(v / v_c)
    V_t/(4 beta_e) dP_L/dt = Q_L - A_p v - C_tp P_L

State ``(x, v, P_L)``: piston position [m], velocity [m/s], load pressure
``p1 - p2`` [Pa]. Input: valve current ``I`` [mA], held constant over each sample
(exact zero-order hold: the ODE is integrated separately over every interval in
which the input is constant, so no step ever falls across an input jump).

``params`` is a mapping with the SI values (see :data:`PARAMETERS`), optionally with a
Coulomb friction of the seals (:data:`OPTIONAL`: ``F_c`` [N], switching over ``v_c``
[m/s]; none by default), which the package's cylinder model lacks: records with it test
whether the diagnosis names the friction on this model (``experiments/cylinder_friction.py``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from scipy.integrate import solve_ivp

__all__ = [
    "cylinder_rhs",
    "simulate_cylinder_reference",
]

#: Required entries of ``params`` and their units.
PARAMETERS: dict[str, str] = {
    "A_p": "m^2",  # annulus area of each side (symmetric cylinder)
    "m": "kg",  # moving mass (piston, rod, load)
    "B_p": "N*s/m",  # viscous friction coefficient
    "K": "N/m",  # load spring stiffness
    "F_L": "N",  # constant external load force (opposing positive x)
    "V_t": "m^3",  # total oil volume of both chambers and lines
    "beta_e": "Pa",  # effective bulk modulus
    "C_tp": "m^3/(s*Pa)",  # internal (cross-piston) leakage coefficient
    "p_s": "Pa",  # supply pressure (return at 0)
    "K_v": "m^3/(s*mA*Pa^0.5)",  # valve flow coefficient C_d*w*k_x*sqrt(1/rho)
}


#: Optional entries of ``params``, their units and defaults: a Coulomb friction force
#: ``F_c*tanh(v/v_c)`` opposing the motion (0: none).
OPTIONAL: dict[str, tuple[str, float]] = {
    "F_c": ("N", 0.0),
    "v_c": ("m/s", 1e-3),
}


def _unpack(params: Mapping[str, float]) -> tuple[float, ...]:
    missing = [k for k in PARAMETERS if k not in params]
    if missing:
        raise KeyError(f"reference cylinder parameters missing: {missing}")
    return tuple(float(params[k]) for k in PARAMETERS)


def cylinder_rhs(
    t: float, state: Sequence[float] | np.ndarray, current: float, params: Mapping[str, float]
) -> np.ndarray:
    """Time derivative of the physical state.

    Parameters
    ----------
    t : float
        Time [s] (unused: the plant is time-invariant; kept for ``solve_ivp``).
    state : array_like, shape (3,)
        ``(x [m], v [m/s], P_L [Pa])``.
    current : float
        Valve current [mA].
    params : mapping
        SI parameters (:data:`PARAMETERS`, and any of :data:`OPTIONAL`).

    Returns
    -------
    ndarray, shape (3,)
        ``(dx/dt [m/s], dv/dt [m/s^2], dP_L/dt [Pa/s])``.
    """
    A_p, m, B_p, K, F_L, V_t, beta_e, C_tp, p_s, K_v = _unpack(params)
    F_c = float(params.get("F_c", OPTIONAL["F_c"][1]))
    v_c = float(params.get("v_c", OPTIONAL["v_c"][1]))
    x, v, P_L = (float(s) for s in state)
    # Pressure drop across the metering edges that are open for this current sign;
    # beyond the supply pressure the drop reverses and so does the flow.
    drop = p_s - np.sign(current) * P_L
    Q_L = K_v * current * np.sign(drop) * np.sqrt(abs(drop))
    dx = v
    friction = F_c * np.tanh(v / v_c) if F_c else 0.0
    dv = (A_p * P_L - B_p * v - K * x - F_L - friction) / m
    dP = 4.0 * beta_e / V_t * (Q_L - A_p * v - C_tp * P_L)
    return np.array([dx, dv, dP])


def simulate_cylinder_reference(
    u: Sequence[float] | np.ndarray,
    fs: float,
    params: Mapping[str, float],
    x0: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
    rtol: float = 1e-10,
    atol: Sequence[float] | np.ndarray | None = None,
    method: str = "DOP853",
) -> np.ndarray:
    """Simulate the cylinder with an exact zero-order hold of the current.

    Parameters
    ----------
    u : array_like, shape (N,)
        Valve current [mA]; ``u[k]`` is held over ``[k/fs, (k+1)/fs)``.
    fs : float
        Sample rate [Hz].
    params : mapping
        SI parameters (:data:`PARAMETERS`, and any of :data:`OPTIONAL`).
    x0 : array_like, shape (3,)
        Initial ``(x [m], v [m/s], P_L [Pa])``.
    rtol : float
        Relative tolerance of :func:`scipy.integrate.solve_ivp`.
    atol : array_like, shape (3,), optional
        Absolute tolerances; default ``rtol * (1e-2 m, 1e-2 m/s, 1e-2 p_s)``, i.e.
        relative to a small fraction of each state's scale.
    method : str
        Integrator of :func:`scipy.integrate.solve_ivp` (an explicit high-order
        one: the plant is not stiff at the pressures a servo cylinder sees).

    Returns
    -------
    ndarray, shape (N, 3)
        States at the sample instants ``t_k = k/fs`` (row 0 is ``x0``).

    Raises
    ------
    RuntimeError
        If the integrator fails on some interval.
    """
    u = np.asarray(u, dtype=float)
    n = u.size
    p_s = float(params["p_s"])
    tol = rtol * np.array([1e-2, 1e-2, 1e-2 * p_s]) if atol is None else np.asarray(atol)
    out = np.empty((n, 3))
    state = np.asarray(x0, dtype=float).copy()
    out[0] = state
    # Runs of equal input: integrating each run in one call is still an exact
    # zero-order hold (the input is constant over it) and much cheaper than a call
    # per sample for step-like excitation.
    change = np.flatnonzero(np.diff(u) != 0.0) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [n]))
    for k0, k1 in zip(starts, ends, strict=True):
        # Samples k0+1 .. k1 are reached with input u[k0]; the last sample needs no
        # integration past it.
        k_last = min(k1, n - 1)
        if k_last <= k0:
            continue
        t_eval = np.arange(k0 + 1, k_last + 1) / fs
        sol = solve_ivp(
            cylinder_rhs, (k0 / fs, k_last / fs), state, method=method, t_eval=t_eval,
            rtol=rtol, atol=tol, args=(float(u[k0]), params),
        )
        if not sol.success:
            raise RuntimeError(f"reference integration failed at t = {k0 / fs:g} s: "
                               f"{sol.message}")
        out[k0 + 1: k_last + 1] = sol.y.T
        state = sol.y[:, -1]
    return out
