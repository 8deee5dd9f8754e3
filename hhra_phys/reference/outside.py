"""Records with a load the effect library does not have, from the reference model.

Truth for the discovery tests and study (:mod:`hhra_phys.diagnosis.discovery`): the
independent NumPy/SciPy HHRA of :mod:`hhra_phys.reference.hhra`
(:func:`~hhra_phys.reference.hhra.reference_rhs`) plus one term no library effect
can represent, integrated with :func:`scipy.integrate.solve_ivp` under an exact
zero-order hold. Nothing here imports the package's model code or the discovered
term's code, so a term found in such a record is not the generator's own formula
read back.

Terms (``OUTSIDE``; each a load torque over inertia or a leakage, with ``size`` its
coefficient)::

    quadratic_drag  domega/dt -= size*omega*|omega|   [rad/s^2], omega in rad/s  (unmeasured)
    cubic_spring    domega/dt -= size*theta^3          [rad/s^2], theta in rad
    pressure_leak   dp/dt     -= size*p*|p|            [1/s], p = P_L/p_s          (unmeasured)
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp

from hhra_phys.data import Dataset
from hhra_phys.reference.hhra import REFERENCE_GROUPS, reference_record, reference_rhs

__all__ = ["OUTSIDE", "outside_record", "integrate_held"]

#: Term name -> (state index whose rate it changes, change of that rate given the state).
OUTSIDE: dict[str, tuple[int, Callable[[np.ndarray], float]]] = {
    "quadratic_drag": (1, lambda x: -x[1] * abs(x[1])),
    "cubic_spring": (1, lambda x: -x[0] ** 3),
    "pressure_leak": (2, lambda x: -x[2] * abs(x[2])),
}


def integrate_held(rhs: Callable[[float, np.ndarray, float], np.ndarray], x0: np.ndarray,
                   u: np.ndarray, fs: float, what: str, intersample: str = "zoh") -> np.ndarray:
    """States at every sample under an exact zero-order (or first-order) hold of ``u``.

    Parameters
    ----------
    rhs : callable
        ``rhs(t, x, u_k) -> dx/dt`` with the held input ``u_k``.
    x0 : ndarray, shape (nx,)
        State at the first sample.
    u : ndarray, shape (N,)
        Sampled input, held between samples.
    fs : float
        Sample rate [Hz].
    what : str
        Name of the caller, for the error message.
    intersample : {"zoh", "foh"}
        Held over each sample, or linear from ``u[k]`` to ``u[k+1]`` (held after the last).

    Returns
    -------
    ndarray, shape (N, nx)
        One :func:`~scipy.integrate.solve_ivp` call (LSODA, rtol 1e-9, atol 1e-11) per run
        of equal inputs (under ``"foh"`` per moving sample).
    """
    if intersample not in ("zoh", "foh"):
        raise ValueError(f"intersample must be 'zoh' or 'foh', got {intersample!r}")
    dt = 1.0 / fs
    x = np.asarray(x0, dtype=float)
    X = np.empty((u.size, x.size))
    du = np.append(np.diff(u), 0.0) / dt if intersample == "foh" else np.zeros(u.size)
    moving = du != 0
    change = np.flatnonzero((np.diff(u) != 0) | moving[:-1] | moving[1:]) + 1
    for a, b in zip(np.concatenate([[0], change]), np.concatenate([change, [u.size]]),
                    strict=True):
        t_eval = np.arange(b - a + 1) * dt
        ua, slope = float(u[a]), float(du[a])
        sol = solve_ivp(lambda t, xx, ua=ua, slope=slope: rhs(t, xx, ua + slope * t),
                        (0.0, t_eval[-1]), x, t_eval=t_eval,
                        method="LSODA", rtol=1e-9, atol=1e-11)
        if not sol.success:
            raise RuntimeError(f"{what}: integration failed at sample {a}: {sol.message}")
        X[a:b] = sol.y[:, :-1].T
        x = sol.y[:, -1]
    return X


def outside_record(term: str, size: float, seed: int = 0, duration: float = 6.0,
                   fs: float = 250.0, noise_deg: float = 0.05, levels: int = 4,
                   intersample: str = "zoh") -> Dataset:
    """A rig record (angle [deg] from current [mA]) whose plant has an outside-library term.

    Parameters
    ----------
    term : str
        A name of :data:`OUTSIDE` (or ``"none"`` for a clean record).
    size : float
        Coefficient of the term (unit in the module docstring).
    seed : int
        Seeds the excitation (as :func:`~hhra_phys.reference.hhra.reference_record`)
        and the noise.
    duration, fs : float
        Length [s] and sample rate [Hz].
    noise_deg : float
        Standard deviation of the angle noise [deg].
    levels : int
        Amplitude levels of the excitation.
    intersample : {"zoh", "foh"}
        What the input does between samples (:func:`integrate_held`); the record says so.

    Returns
    -------
    Dataset
        ``metadata["truth"]`` holds ``term``, ``size`` and the groups.
    """
    if term != "none" and term not in OUTSIDE:
        raise ValueError(f"unknown outside term {term!r}; known: {', '.join(OUTSIDE)}, none")
    if not (math.isfinite(size) and math.isfinite(noise_deg) and noise_deg >= 0):
        raise ValueError(f"size and noise_deg must be finite (noise >= 0), got {size}, "
                         f"{noise_deg}")
    # The reference's own record gives the input and the centred start (noise-free).
    base = reference_record(seed=seed, duration=duration, fs=fs, noise_deg=0.0, levels=levels)
    u = base.u
    params = {k: v for k, v in REFERENCE_GROUPS.items() if k != "g_kp"}
    x = np.array([base.metadata["x0"][n] for n in ("theta", "omega", "p")], dtype=float)
    index, extra = OUTSIDE.get(term, (0, lambda x: 0.0))
    k = float(size) if term != "none" else 0.0

    def rhs(_t: float, xx: np.ndarray, uk: float) -> np.ndarray:
        d = reference_rhs(xx, uk, params)
        d[index] += k * extra(xx)
        return d

    X = integrate_held(rhs, x, u, fs, "outside_record", intersample)
    rng = np.random.default_rng([seed, 1])
    y = np.degrees(X[:, 0]) + noise_deg * rng.standard_normal(u.size)
    meta = {"generator": "hhra_phys.reference.outside", "seed": seed, "noise_deg": noise_deg,
            "intersample": intersample,
            "truth": {"term": term, "size": k, "params": params}}
    return Dataset.from_arrays(u, y, fs=fs, metadata=meta, name=f"outside-{term}-seed{seed}",
                               input_name="current", input_unit="mA", output_name="angle",
                               output_unit="deg")
