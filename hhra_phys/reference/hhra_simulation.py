"""The reference HHRA integrated over a record: :func:`simulate_reference`.

:func:`scipy.integrate.solve_ivp` at tight tolerances (:class:`SolverOptions`) over each
stretch of held input (an exact zero-order hold, or a first-order hold); with exact Coulomb
friction a hybrid integration that stops at every stick and breakaway, and with exact
backlash the ideal play operator applied to the integrated angle afterwards (see
:mod:`hhra_phys.reference.hhra`). The right-hand side is
:mod:`hhra_phys.reference.hhra_equations`'s; records with excitation and sensor are
:func:`hhra_phys.reference.hhra.reference_record`'s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from hhra_phys.reference.hhra_equations import RAD2DEG, _Spec, _spec, _xdot, _y

__all__ = ["SOLVE_IVP_METHODS", "SolverOptions", "simulate_reference"]


def _sticky(s: _Spec) -> bool:
    """Whether the simulation must track stick and slip (exact Coulomb friction)."""
    return not s.smooth and "coulomb_friction" in s.effects


def _push_and_level(x: np.ndarray, u_lags: np.ndarray, s: _Spec) -> tuple[float, float]:
    """Acceleration without friction at ``omega = 0`` and the static friction level."""
    xz = x.copy()
    xz[1] = 0.0
    v = s.effects["coulomb_friction"]
    level = v["g_coulomb"] + v.get("g_stribeck", 0.0)
    # At omega = 0 the sliding rate with direction +1 is push - level.
    return float(_xdot(xz, u_lags, s, mode=1)[1]) + level, level


def _initial_mode(x: np.ndarray, u_lags: np.ndarray, s: _Spec) -> int:
    if x[1] != 0.0:
        return 1 if x[1] > 0 else -1
    push, level = _push_and_level(x, u_lags, s)
    return 0 if abs(push) <= level else (1 if push > 0 else -1)


def _segment(
    x: np.ndarray, u_lags: np.ndarray, s: _Spec, t_eval: np.ndarray, method: str,
    rtol: float, atol: float, turns: list[tuple[float, float]] | None = None,
    slope: np.ndarray | None = None,
) -> np.ndarray:
    """States at ``t_eval`` (starting at 0) with the input held; shape (nx, len(t_eval)).

    ``slope``: the input lags move at this rate [input units/s] from ``u_lags`` at
    ``t = 0`` (a first-order hold over one sample) instead of being held.

    ``turns``: if given, ``(t, theta)`` of every point where ``omega`` reaches 0 in
    ``(0, t_eval[-1])`` is appended to it (the shaft's reversals, for the play operator).

    With exact Coulomb friction the integration is hybrid: while sliding in
    direction ``d`` an event stops it where ``d*omega`` falls to 0; there the shaft
    sticks if the rest of the acceleration is within the static level, or slides
    back; while stuck (``omega = 0`` held) an event stops it where that
    acceleration reaches the level (breakaway). Nothing chatters across 0.
    """
    ul = _input_path(u_lags, slope)
    if not _sticky(s):
        sol = solve_ivp(lambda t, xx: _xdot(xx, ul(t), s), (0.0, t_eval[-1]), x,
                        method=method, t_eval=t_eval, rtol=rtol, atol=atol,
                        events=None if turns is None else (lambda _t, xx: xx[1]))
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed: {sol.message}")
        if turns is not None and len(sol.t_events[0]):
            turns.extend((float(t), float(xe[0]))
                         for t, xe in zip(sol.t_events[0], sol.y_events[0], strict=True))
        return sol.y
    return _stick_slip_segment(x, u_lags, ul, s, t_eval, (method, rtol, atol), turns)


def _input_path(u_lags: np.ndarray, slope: np.ndarray | None) -> Any:
    """The input lags at time ``t`` into the sample: held, or moving at ``slope``."""
    def ul(t: float) -> np.ndarray:
        return u_lags if slope is None else u_lags + t * slope

    return ul


def _stick_slip_segment(
    x: np.ndarray, u_lags: np.ndarray, ul: Any, s: _Spec, t_eval: np.ndarray,
    solver: tuple[str, float, float], turns: list[tuple[float, float]] | None,
) -> np.ndarray:
    """:func:`_segment` with exact Coulomb friction: one integration per stick or slide
    phase, each ended by its switching event (:func:`_switch_event`)."""
    method, rtol, atol = solver
    out = np.empty((x.size, t_eval.size))
    out[:, 0] = x
    done, t0, mode = 1, 0.0, _initial_mode(x, u_lags, s)
    if mode == 0:
        x = x.copy()
        x[1] = 0.0
    for _ in range(10000):
        if done == t_eval.size:
            return out
        sol = solve_ivp(lambda t, xx, m=mode: _xdot(xx, ul(t), s, m), (t0, t_eval[-1]), x,
                        method=method, t_eval=t_eval[done:], rtol=rtol, atol=atol,
                        events=_switch_event(mode, ul, s))
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed: {sol.message}")
        k = len(sol.t)  # (an empty t_eval tail comes back as a list)
        if k:
            out[:, done:done + k] = sol.y
        done += k
        if sol.status != 1:
            continue
        t0, x = float(sol.t_events[0][0]), sol.y_events[0][0].copy()
        if turns is not None:  # a stop (omega = 0) or a breakaway from rest
            turns.append((t0, float(x[0])))
        mode = _mode_after_switch(mode, x, ul(t0), s)
        if t_eval[-1] - t0 <= 1e-12 * max(1.0, t_eval[-1]):
            # The event fell on the end of the segment: its state is the last sample's.
            out[:, done:] = x[:, None]
            return out
    raise RuntimeError("too many stick-slip switches in one held sample segment")


def _switch_event(mode: int, ul: Any, s: _Spec) -> Any:
    """The terminal event that ends a phase: breakaway while stuck (``mode = 0``: the
    push reaches the static level), the stop while sliding in direction ``mode``."""
    if mode == 0:
        def event(t: float, xx: np.ndarray) -> float:
            push, level = _push_and_level(xx, ul(t), s)
            return abs(push) - level
        event.direction = 1.0  # type: ignore[attr-defined]
    else:
        def event(_t: float, xx: np.ndarray, d: int = mode) -> float:
            return d * xx[1]
        event.direction = -1.0  # type: ignore[attr-defined]
    event.terminal = True  # type: ignore[attr-defined]
    return event


def _mode_after_switch(mode: int, x: np.ndarray, u_lags: np.ndarray, s: _Spec) -> int:
    """The phase after a switch at state ``x``: sliding in the push's direction after a
    breakaway; after a stop (``x``'s velocity set to exactly 0 in place) stuck if the push
    is within the static level, else sliding back."""
    if mode == 0:
        push, _ = _push_and_level(x, u_lags, s)
        return 1 if push > 0 else -1
    x[1] = 0.0
    push, level = _push_and_level(x, u_lags, s)
    return 0 if abs(push) <= level else (1 if push > 0 else -1)



#: Integrators of :func:`scipy.integrate.solve_ivp` by name.
SOLVE_IVP_METHODS: tuple[str, ...] = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")


@dataclass(frozen=True)
class SolverOptions:
    """How the reference is integrated (:func:`simulate_reference`, :func:`reference_record`).

    Every field is also a keyword of both functions (``rtol=1e-8``), overriding the
    options they are given.

    Attributes
    ----------
    method : str
        Integrator of :func:`~scipy.integrate.solve_ivp` (:data:`SOLVE_IVP_METHODS`):
        ``"LSODA"`` switches to a stiff method where needed; ``"Radau"`` for stiff sets;
        ``"DOP853"`` for smooth, non-stiff ones.
    rtol, atol : float
        Tolerances of :func:`~scipy.integrate.solve_ivp` (> 0).
    stick_band : float
        Velocity [rad/s] below which exact Coulomb friction may stick (``smooth=False``),
        ``>= 0``.
    """

    method: str = "LSODA"
    rtol: float = 1e-10
    atol: float = 1e-12
    stick_band: float = 1e-6

    def validate(self) -> SolverOptions:
        """Check every setting; returns ``self``.

        Raises
        ------
        ValueError
            Naming the setting and what is wrong with it.
        """
        if self.method not in SOLVE_IVP_METHODS:
            raise ValueError(f"method must be one of {', '.join(SOLVE_IVP_METHODS)} "
                                 f"(scipy's solve_ivp), got {self.method!r}")
        for name in ("rtol", "atol"):
            _check_number(name, getattr(self, name), "> 0", lambda v: v > 0)
        _check_number("stick_band", self.stick_band, ">= 0", lambda v: v >= 0)
        return self


def _check_number(name: str, value: Any, what: str, ok: Any) -> None:
    """``value`` a finite number for which ``ok`` holds, else an error naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int | float) \
            or not math.isfinite(value) or not ok(value):
        raise ValueError(f"{name} must be a finite number {what}, got {value!r}")


def _with_overrides(options: Any, overrides: Mapping[str, Any], what: str) -> Any:
    """``options`` (a frozen dataclass) with ``overrides`` of its fields applied.

    (:func:`hhra_phys.options.with_overrides` does this for the package; the reference
    imports nothing of the package but the data container and the excitation signals.)
    """
    names = {f.name for f in fields(options)}
    bad = sorted(set(overrides) - names)
    if bad:
        raise ValueError(f"unknown {what} setting(s) {', '.join(bad)}; settings: "
                         f"{', '.join(sorted(names))}")
    return replace(options, **overrides)


def _solver_options(solver: SolverOptions | None, settings: Mapping[str, Any]) -> SolverOptions:
    """``solver`` (default: the defaults) with ``settings`` applied, validated."""
    return _with_overrides(solver if solver is not None else SolverOptions(), settings,
                           "solver").validate()


def simulate_reference(
    u: Sequence[float] | np.ndarray,
    fs: float,
    params: Mapping[str, float],
    *,
    valve: str = "orifice",
    output: str = "angle",
    spool_lag: bool = False,
    effects: Mapping[str, Mapping[str, float]] | None = None,
    x0: Sequence[float] | np.ndarray | None = None,
    smooth: bool = True,
    states: bool = False,
    intersample: str = "zoh",
    solver: SolverOptions | None = None,
    **solver_settings: Any,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Simulate the sampled system with an exact zero-order (or first-order) hold.

    The input sample ``u[k]`` (and, for a delay, the samples before it) is held
    over ``[t_k, t_k + 1/fs)``; ``y[k]`` is the output of the state at ``t_k``, so
    ``y[0]`` is that of ``x0`` (the package's convention). Before the record the
    input is taken equal to ``u[0]``. Consecutive samples with the same held inputs
    are integrated in one :func:`~scipy.integrate.solve_ivp` call (the right-hand
    side is smooth there); every change of the input restarts the integrator, so
    no step crosses a jump. With ``intersample="foh"`` the input (and each lag)
    moves linearly from ``u[k]`` to ``u[k+1]`` over the sample, held after the last
    one, and every sample is its own call (the slope changes at each).

    Parameters
    ----------
    u : array, shape (N,)
        Input [mA].
    fs : float
        Sample rate [Hz].
    params : mapping
        Parameters by name (see :func:`reference_rhs`).
    valve, output, spool_lag, effects, smooth
        As in :func:`reference_rhs`.
    x0 : array, shape (nx,), optional
        Initial state (default: all zero, at rest).
    states : bool
        Also return the state at every sample.
    intersample : {"zoh", "foh"}
        What the input does between samples: held, or linear to the next sample.
    solver : SolverOptions, optional
        The integrator, its tolerances and exact friction's stick band (default
        :class:`SolverOptions`'s: LSODA, ``rtol=1e-10``, ``atol=1e-12``).
    **solver_settings
        Any field of :class:`SolverOptions` (``method``, ``rtol``, ``atol``,
        ``stick_band``), overriding ``solver``.

    Returns
    -------
    y : ndarray, shape (N,)
        Output (degrees for the angle).
    X : ndarray, shape (N, nx)
        States at the sample instants, only with ``states=True``.

    Raises
    ------
    ValueError
        A bad solver setting, naming it.
    RuntimeError
        When the integrator fails.
    """
    so = _solver_options(solver, solver_settings)
    u = np.asarray(u, dtype=float).ravel()
    if u.size < 1 or not np.isfinite(u).all():
        raise ValueError("u must be a non-empty finite 1-D array")
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sample rate in Hz, got {fs}")
    if intersample not in ("zoh", "foh"):
        raise ValueError(f"intersample must be 'zoh' or 'foh', got {intersample!r}")
    dt = 1.0 / fs
    s = _spec(params, valve, output, spool_lag, effects, dt, smooth, so.stick_band)
    nl = s.n_lags
    padded = np.concatenate([np.full(nl, u[0]), u])
    # Row k: u[k], u[k-1], ..., u[k-nl].
    lags = np.stack([padded[nl - j: nl - j + u.size] for j in range(nl + 1)], axis=1)
    x = np.zeros(len(s.state_names)) if x0 is None else np.asarray(x0, dtype=float).copy()
    if x.shape != (len(s.state_names),):
        raise ValueError(f"x0 must have shape ({len(s.state_names)},) for states {s.state_names}")
    play_after = not s.smooth and "backlash" in s.effects
    # Exact backlash: the shaft is integrated without the gap (the last state), the
    # play operator is applied afterwards (module docstring).
    core = replace(s, effects={k: v for k, v in s.effects.items() if k != "backlash"},
                   state_names=s.state_names[:-1]) if play_after else s
    nx = len(core.state_names)
    X = np.empty((u.size, x.size))
    turns: list[tuple[float, float]] | None = [] if play_after else None
    change = np.flatnonzero(np.any(np.diff(lags, axis=0) != 0, axis=1)) + 1
    slopes = np.zeros_like(lags)
    if intersample == "foh":  # every sample moving to the next is its own segment
        slopes[:-1] = np.diff(lags, axis=0) / dt
        change = np.flatnonzero(np.any(slopes[:-1] != 0, axis=1) | np.any(slopes[1:] != 0,
                                                                          axis=1)) + 1
    starts = np.concatenate([[0], change])
    stops = np.concatenate([change, [u.size]])
    xc = x[:nx]
    for a, b in zip(starts, stops, strict=True):
        ul = lags[a]
        t_eval = np.arange(b - a + 1) * dt
        seg: list[tuple[float, float]] | None = [] if play_after else None
        try:
            Y = _segment(xc, ul, core, t_eval, so.method, so.rtol, so.atol, seg,
                         slope=slopes[a] if slopes[a].any() else None)
        except RuntimeError as exc:
            raise RuntimeError(f"at sample {a}: {exc}") from exc
        X[a:b, :nx] = Y[:, :-1].T
        xc = Y[:, -1]
        if seg:
            turns.extend((a + t / dt, th) for t, th in seg)  # time in samples
    if play_after:
        X[:, -1] = _play_operator(X[:, 0], float(x[-1]),
                                  0.5 * s.effects["backlash"]["play"] / RAD2DEG, turns or [])
    y = np.array([_y(xk, s) for xk in X])
    return (y, X) if states else y


def _play_operator(theta: np.ndarray, gap0: float, half: float,
                   turns: list[tuple[float, float]]) -> np.ndarray:
    """Gap [rad] of the ideal play operator at the samples of the shaft angle ``theta``.

    ``turns``: ``(time in samples, theta)`` of the reversals between samples. The
    gap follows every change of angle, clipped to ``[-half, half]``; exact for an
    angle monotone between consecutive points (module docstring).
    """
    ts = np.concatenate([np.arange(theta.size, dtype=float), [t for t, _ in turns]])
    th = np.concatenate([theta, [v for _, v in turns]])
    is_sample = np.concatenate([np.ones(theta.size, bool), np.zeros(len(turns), bool)])
    order = np.argsort(ts, kind="stable")  # a sample before a reversal at the same time
    out = np.empty(theta.size)
    gap = min(max(gap0, -half), half)
    prev = th[order[0]]
    k = 0
    for i in order:
        gap = min(max(gap + th[i] - prev, -half), half)
        prev = th[i]
        if is_sample[i]:
            out[k] = gap
            k += 1
    return out
