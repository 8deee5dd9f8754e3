"""A second, independent implementation of the HHRA and its effects (NumPy/SciPy only).

The package's model (:mod:`hhra_phys.model`, :mod:`hhra_phys.parts`,
:mod:`hhra_phys.effects`) is assembled from CasADi parts and integrated with a
fixed-step RK4 (:mod:`hhra_phys.simulate`). A simulated rig built from that same
code cannot reveal an error in its equations: the data would carry the error too
(see ``docs/model.md``). This module writes the model a second time, from the
equations in ``docs/model.md`` and the documented formulas of the effects, and
integrates it with :func:`scipy.integrate.solve_ivp` at tight tolerances under an
exact zero-order hold. It imports nothing from the package's model code; only
:class:`hhra_phys.data.Dataset` (to return records) and
:mod:`hhra_phys.excitation` (input signals).

The model (``docs/model.md``; states ``theta`` [rad], ``omega`` [rad/s],
``p = P_L/p_s`` [-])::

    dtheta/dt = omega
    domega/dt = g_torque*p - g_damping*omega - g_spring*theta - g_load   (+ motion effects)
    dp/dt     = q - g_compress*omega - g_leak*p
    q         = g_valve*c*sqrt(1 - sign(c)*p)       (orifice valve)
              = g_valve*c - g_kp*p                  (linear valve)

with ``c`` the valve command: the input current [mA], after the optional spool
lag ``tau_v*dxs/dt = c - xs`` and the input-stage effects. Output: the angle in
degrees, or ``p_gain*p + p_offset``.

State vector: ``[theta, omega, p]``, then ``xs`` (``spool_lag=True``), then
``x_spool`` (effect ``valve_dynamics``), then ``gap`` (effect ``backlash``), then
``y_drift`` (effect ``sensor_drift``): the package's order for the same model.

Effects (argument ``effects``: a mapping from the library name to its parameter
values and optional settings; parameter values not given there are taken from
``params``)::

    coulomb_friction  domega/dt -= level*sgn(omega) [+ g_viscous*omega],
                      level = g_coulomb [+ g_stribeck*exp(-(omega/v_stribeck)^2)]
                      (Stribeck term when g_stribeck is given); settings width [rad/s]
                      (or the parameter v_switch)
    valve_deadzone    c -> max(c - i_dead, 0) - max(-c - i_dead, 0); settings u_scale,
                      width
    valve_saturation  c -> clip(c, -i_sat, i_sat); settings u_scale, width
    input_delay       c from u(t - delay*dt): (1-f)*u[n-k] + f*u[n-k-1], delay = k + f [samples]
    valve_dynamics    tau_spool*dx_spool/dt = c - x_spool, c -> x_spool
    gravity_load      domega/dt -= g_grav_cos*cos(theta) + g_grav_sin*sin(theta)
    backlash          gap [rad] = shaft minus encoder angle, |gap| <= play/2 [deg], y -= gap;
                      settings width [deg] (or the parameter w_contact)
    sensor_offset     y += y_offset
    sensor_drift      y += y_drift, dy_drift/dt = drift_rate [deg/s] (y_drift from 0)
    asymmetric_valve  q *= 1 + asym*sgn(c); settings u_scale, eps
    input_offset      c -> c + u_offset (in the input stage's order, after the delay)
    constant_force    domega/dt += g_const (before friction: part of what drives it)

Smoothing. With ``smooth=True`` (default) the documented smoothings of the
package are used, so that a comparison with it can be tight:
``sgn(v) ~ v/sqrt(v^2 + eps^2)``; the orifice's signed root
``sign(z)*(sqrt(|z| + delta) - sqrt(delta))/(sqrt(1 + delta) - sqrt(delta))``;
``max(v, 0)`` of the dead zone and saturation with a quadratic corner,
``(v + w)^2/(4w)`` for ``|v| < w`` and exact beyond, ``w = width*u_scale``; friction
width ``width`` (0.005 rad/s unless given, or ``v_switch``);
backlash ``dgap/dt = max(omega, 0)*f((h - gap)/w) + min(omega, 0)*f((h + gap)/w)``
with ``h = play/2``, ``f(z) = z`` up to 0.5, ``z - (z - 0.5)^2/2`` up to 1.5, then 1,
and the contact width ``w`` (``width``, 0.01 deg unless given, or
``w_contact``). With
``smooth=False`` every switch is exact (``sign``, ``sqrt``, ``clip``, ``max``, an ideal
play operator, and Coulomb friction that sticks: within ``stick_band`` of zero velocity
the friction cancels the rest of the acceleration up to its level, Karnopp's model, so
that the integrator does not chatter across ``omega = 0``).

Exact backlash (``smooth=False``). The encoder does not act back on the shaft, so
the ideal play operator is applied to the integrated shaft angle after the
integration rather than integrated as a discontinuous rate (which takes a stiff
solver minutes per record). The operator is rate independent: on a monotone
stretch of the angle the gap moves by the change of angle, clipped to ``+-h``
(``gap <- clip(gap + dtheta, -h, h)``). So it is exact when applied to the angle at
the sample instants and at every reversal in between; the reversals (``omega = 0``)
are located by :func:`~scipy.integrate.solve_ivp` events to the integration tolerance.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from scipy import signal as sps
from scipy.integrate import solve_ivp

from hhra_phys.data import Dataset
from hhra_phys.excitation import irregular_steps, samples

__all__ = [
    "reference_state_names",
    "reference_rhs",
    "reference_output",
    "simulate_reference",
    "velocity_gain",
    "reference_record",
    "RecordOptions",
    "SolverOptions",
    "SOLVE_IVP_METHODS",
    "REFERENCE_GROUPS",
    "EFFECT_NAMES",
]

RAD2DEG = 180.0 / math.pi

#: The built-in rig's identifiable groups as printed in ``docs/model.md`` (table
#: "The two parameter views"), and the linear valve's ``g_kp``. Taken from the
#: documentation, not from :mod:`hhra_phys.models.hhra.physical`, on purpose.
REFERENCE_GROUPS: dict[str, float] = {
    "g_torque": 175.6,
    "g_damping": 4.206,
    "g_spring": 0.0,
    "g_load": 0.0,
    "g_compress": 50.93,
    "g_leak": 6.4,
    "g_valve": 31.76,
    "g_kp": 2.0,
}

#: Library effect names this module implements, in the order their states appear.
EFFECT_NAMES: tuple[str, ...] = (
    "coulomb_friction", "valve_deadzone", "valve_saturation", "input_delay",
    "valve_dynamics", "gravity_load", "backlash", "sensor_offset", "asymmetric_valve",
    "sensor_drift", "input_offset", "constant_force",
)

_INPUT_EFFECTS = ("input_delay", "valve_deadzone", "valve_saturation", "valve_dynamics")

#: Default smoothing settings of each effect (the package's documented defaults).
_SETTINGS: dict[str, dict[str, float]] = {
    "coulomb_friction": {"width": 0.005},
    "valve_deadzone": {"u_scale": 1.0, "width": 0.01},
    "valve_saturation": {"u_scale": 1.0, "width": 0.01},
    "asymmetric_valve": {"u_scale": 1.0, "eps": 0.01},
    "backlash": {"width": 0.01},  # [deg]
    "input_delay": {},
    "valve_dynamics": {},
    "gravity_load": {},
    "sensor_offset": {},
    "sensor_drift": {},
    "input_offset": {},
    "constant_force": {},
}

#: Parameters each effect needs (``coulomb_friction`` also takes the optional
#: ``g_stribeck`` and ``v_stribeck``).
_EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    "coulomb_friction": ("g_coulomb",),
    "valve_deadzone": ("i_dead",),
    "valve_saturation": ("i_sat",),
    "input_delay": ("delay",),
    "valve_dynamics": ("tau_spool",),
    "gravity_load": ("g_grav_cos", "g_grav_sin"),
    "backlash": ("play",),
    "sensor_offset": ("y_offset",),
    "sensor_drift": ("drift_rate",),
    "asymmetric_valve": ("asym",),
    "input_offset": ("u_offset",),
    "constant_force": ("g_const",),
}

#: Optional parameters of an effect (taken from ``params`` too when given there).
_OPTIONAL_PARAMS: dict[str, tuple[str, ...]] = {
    "coulomb_friction": ("g_stribeck", "v_stribeck", "g_viscous", "v_switch"),
    "backlash": ("w_contact",),
}

#: Orifice smoothing of the package (``docs/model.md``, "Numerical choices").
SIGN_EPS = 1e-3  # [mA]
SQRT_DELTA = 1e-6  # [-]


# --- elementary switches, smooth or exact ----------------------------------------------


def _sgn(v: float, eps: float, smooth: bool) -> float:
    if smooth:
        return v / math.sqrt(v * v + eps * eps)
    return float(np.sign(v))


def _corner_relu(v: float, w: float, smooth: bool) -> float:
    if not smooth:
        return max(v, 0.0)
    if v <= -w:
        return 0.0
    return (v + w) ** 2 / (4.0 * w) if v < w else v


def _contact(z: float) -> float:
    """``min(z, 1)`` with the quadratic corner ``z - (z - 0.5)^2/2`` over ``(0.5, 1.5)``."""
    if z <= 0.5:
        return z
    return 1.0 if z >= 1.5 else z - 0.5 * (z - 0.5) ** 2


def _input_relu(v: float, settings: Mapping[str, float], smooth: bool) -> float:
    """The dead zone's and saturation's ``max(v, 0)``: a corner of ``width``."""
    return _corner_relu(v, settings["width"] * settings["u_scale"], smooth)


def _signed_sqrt(z: float, delta: float, smooth: bool) -> float:
    if smooth:
        norm = math.sqrt(1.0 + delta) - math.sqrt(delta)
        return math.copysign((math.sqrt(abs(z) + delta) - math.sqrt(delta)) / norm, z) if z else 0.0
    return math.copysign(math.sqrt(abs(z)), z) if z else 0.0


# --- the model specification -------------------------------------------------------------


@dataclass(frozen=True)
class _Spec:
    """Resolved model: valve, output, parameters, effects with their values."""

    valve: str
    output: str
    spool_lag: bool
    dt: float
    smooth: bool
    stick_band: float
    p: dict[str, float]
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    state_names: tuple[str, ...] = ()

    @property
    def n_lags(self) -> int:
        """Past input samples needed (the delay's interpolation reaches ``k+1``)."""
        if "input_delay" not in self.effects:
            return 0
        return int(math.floor(self.effects["input_delay"]["delay"])) + 1


def _spec(
    params: Mapping[str, float],
    valve: str,
    output: str,
    spool_lag: bool,
    effects: Mapping[str, Mapping[str, float]] | None,
    dt: float,
    smooth: bool,
    stick_band: float,
) -> _Spec:
    if valve not in ("orifice", "linear"):
        raise ValueError(f"valve must be 'orifice' or 'linear', got {valve!r}")
    if output not in ("angle", "pressure"):
        raise ValueError(f"output must be 'angle' or 'pressure', got {output!r}")
    p = _group_values(params, valve, output, spool_lag)
    eff = {name: _effect_values(name, given, p) for name, given in (effects or {}).items()}
    if output == "pressure" and "backlash" in eff:
        raise ValueError("backlash is seen by an angle encoder; use output='angle'")
    names = reference_state_names(spool_lag=spool_lag, effects=eff)
    return _Spec(valve, output, spool_lag, float(dt), smooth, float(stick_band), p, eff,
                 tuple(names))


def _group_values(params: Mapping[str, float], valve: str, output: str, spool_lag: bool
                  ) -> dict[str, float]:
    """``params`` as floats, with the groups the plant needs (``g_spring``, ``g_load``
    default to 0; the others must be given)."""
    p = {k: float(v) for k, v in params.items()}
    needed = ["g_torque", "g_damping", "g_compress", "g_leak", "g_valve"]
    needed += ["g_kp"] if valve == "linear" else []
    needed += ["tau_v"] if spool_lag else []
    needed += ["p_gain", "p_offset"] if output == "pressure" else []
    p.setdefault("g_spring", 0.0)
    p.setdefault("g_load", 0.0)
    missing = [k for k in needed if k not in p]
    if missing:
        raise ValueError(f"params lacks {missing}")
    return p


def _effect_values(name: str, given: Mapping[str, float], p: Mapping[str, float]
                   ) -> dict[str, float]:
    """An effect's settings and parameter values: its defaults, then ``p``'s values of its
    parameters, then ``given``; checked."""
    if name not in _EFFECT_PARAMS:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
    vals = dict(_SETTINGS[name])
    removed = sorted({"eps", "eps_omega", "dt"} & set(given) - set(vals))
    if removed:
        raise ValueError(f"{name}: settings {removed} were removed (set its width)")
    for key in _EFFECT_PARAMS[name] + _OPTIONAL_PARAMS.get(name, ()):
        if key in p:
            vals[key] = p[key]
    vals.update({k: float(v) for k, v in given.items()})
    lacking = [k for k in _EFFECT_PARAMS[name] if k not in vals]
    if lacking:
        raise ValueError(f"effect {name!r} needs parameter(s) {lacking}")
    if name == "coulomb_friction" and ("g_stribeck" in vals) != ("v_stribeck" in vals):
        raise ValueError("the Stribeck term needs both g_stribeck and v_stribeck")
    if name == "input_delay" and vals["delay"] < 0:
        raise ValueError("delay must be >= 0 samples")
    return vals


# --- right-hand side and output -------------------------------------------------------------


def _command(x: dict[str, float], u_lags: np.ndarray, s: _Spec, rates: dict[str, float]) -> float:
    """Valve command [input units] and the rates of the input-stage states."""
    e = s.effects
    if "input_delay" in e:
        # Linear interpolation of the held samples: hat weights max(0, 1 - |delay - k|).
        d = e["input_delay"]["delay"]
        c = sum(max(0.0, 1.0 - abs(d - k)) * float(u_lags[k]) for k in range(len(u_lags)))
    else:
        c = float(u_lags[0])
    if s.spool_lag:
        rates["xs"] = (c - x["xs"]) / s.p["tau_v"]
        c = x["xs"]
    # The package runs the input stage in the order the parts were added; the
    # mapping order of ``effects`` plays that role here (the delay always acts on
    # the measured input, as documented).
    for name, v in e.items():
        if name == "valve_deadzone":
            d = v["i_dead"]
            c = _input_relu(c - d, v, s.smooth) - _input_relu(-c - d, v, s.smooth)
        elif name == "valve_saturation":
            m = v["i_sat"]
            c = c - _input_relu(c - m, v, s.smooth) + _input_relu(-c - m, v, s.smooth)
        elif name == "valve_dynamics":
            rates["x_spool"] = (c - x["x_spool"]) / v["tau_spool"]
            c = x["x_spool"]
        elif name == "input_offset":
            c = c + v["u_offset"]
    return c


def _rates(
    x: dict[str, float], u_lags: np.ndarray, s: _Spec, mode: int | None = None
) -> dict[str, float]:
    """Rates of every state. ``mode`` (exact friction only): 0 stuck, +-1 sliding in
    that direction, None: decide from the state (Karnopp band, for single points)."""
    rates: dict[str, float] = {}
    P = s.p
    th, w, p = x["theta"], x["omega"], x["p"]
    c = _command(x, u_lags, s, rates)
    rates["p"] = _flow(c, p, s) - P["g_compress"] * w - P["g_leak"] * p
    acc = P["g_torque"] * p - P["g_damping"] * w - P["g_spring"] * th - P["g_load"]
    if "gravity_load" in s.effects:
        v = s.effects["gravity_load"]
        acc -= v["g_grav_cos"] * math.cos(th) + v["g_grav_sin"] * math.sin(th)
    if "constant_force" in s.effects:
        acc += s.effects["constant_force"]["g_const"]
    if "coulomb_friction" in s.effects:
        acc = _with_friction(acc, w, s, mode)
    rates["theta"] = w
    rates["omega"] = acc
    if "backlash" in s.effects:
        rates["gap"] = _gap_rate(w, x["gap"], s)
    if "sensor_drift" in s.effects:
        rates["y_drift"] = s.effects["sensor_drift"]["drift_rate"]
    return rates


def _flow(c: float, p: float, s: _Spec) -> float:
    """Valve flow for command ``c`` at load pressure ``p`` (and the asymmetric valve)."""
    P = s.p
    if s.valve == "orifice":
        # The orifice law: the pressure drop across the open edge is p_s - sign(x_v)*P_L,
        # i.e. 1 - sign(c)*p: the sign of the VALVE COMMAND, not of the pressure.
        drop = 1.0 - _sgn(c, SIGN_EPS, s.smooth) * p
        q = P["g_valve"] * c * _signed_sqrt(drop, SQRT_DELTA, s.smooth)
    else:
        q = P["g_valve"] * c - P["g_kp"] * p
    if "asymmetric_valve" in s.effects:
        v = s.effects["asymmetric_valve"]
        q *= 1.0 + v["asym"] * _sgn(c, v["eps"] * v["u_scale"], s.smooth)
    return q


def _with_friction(acc: float, w: float, s: _Spec, mode: int | None) -> float:
    """The acceleration ``acc`` (without friction) with Coulomb friction at velocity ``w``:
    smoothed, or exact with stick and slip (``mode`` as in :func:`_rates`)."""
    v = s.effects["coulomb_friction"]
    level = v["g_coulomb"]
    if "g_stribeck" in v:
        level += v["g_stribeck"] * math.exp(-((w / v["v_stribeck"]) ** 2))
    acc -= v.get("g_viscous", 0.0) * w
    if s.smooth:
        # The package's documented width: a physical v_switch (fitted) or width [rad/s].
        return acc - level * _sgn(w, v.get("v_switch", v["width"]), True)
    if mode == 0:
        return 0.0  # stuck: the simulation set omega = 0 exactly and holds it
    if mode is not None:
        return acc - level * mode  # sliding: the direction is fixed until omega reaches 0
    if abs(w) <= s.stick_band and abs(acc) <= level:
        # Stuck (Karnopp): friction holds the shaft; the residual velocity decays.
        return -w / max(s.dt, 1e-12)
    if abs(w) <= s.stick_band:
        return acc - level * math.copysign(1.0, acc)  # breaks away in the push's direction
    return acc - level * math.copysign(1.0, w)


def _gap_rate(w: float, gap: float, s: _Spec) -> float:
    """Rate of the backlash gap [rad/s] at shaft velocity ``w``."""
    v = s.effects["backlash"]
    half = 0.5 * v["play"] / RAD2DEG
    if not s.smooth:
        contact = 1.0 if math.copysign(1.0, w) * gap >= half else 0.0
        return w * (1.0 - contact)
    wid = v.get("w_contact", v["width"]) / RAD2DEG
    return (max(w, 0.0) * _contact((half - gap) / wid)
            + min(w, 0.0) * _contact((half + gap) / wid))


def _xdot(x: np.ndarray, u_lags: np.ndarray, s: _Spec, mode: int | None = None) -> np.ndarray:
    r = _rates(dict(zip(s.state_names, x, strict=True)), u_lags, s, mode)
    if mode == 0:
        r["theta"] = 0.0
    return np.array([r.get(n, 0.0) for n in s.state_names])


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


def _y(x: np.ndarray, s: _Spec) -> float:
    xs = dict(zip(s.state_names, x, strict=True))
    if s.output == "angle":
        y = RAD2DEG * xs["theta"]
    else:
        y = s.p["p_gain"] * xs["p"] + s.p["p_offset"]
    if "backlash" in s.effects:
        gap = xs["gap"]
        if not s.smooth:  # the ideal play operator keeps the gap inside the play
            half = 0.5 * s.effects["backlash"]["play"] / RAD2DEG
            gap = min(max(gap, -half), half)
        y -= RAD2DEG * gap
    if "sensor_offset" in s.effects:
        y += s.effects["sensor_offset"]["y_offset"]
    if "sensor_drift" in s.effects:
        y += xs["y_drift"]
    return float(y)


def reference_state_names(
    *,
    spool_lag: bool = False,
    effects: Mapping[str, Mapping[str, float]] | None = None,
) -> list[str]:
    """State names, in state-vector order, of the reference model with these options.

    Returns
    -------
    list of str
        ``["theta", "omega", "p"]`` then ``"xs"``, ``"x_spool"``, ``"gap"``, ``"y_drift"``
        as present.
    """
    names = ["theta", "omega", "p"]
    names += ["xs"] if spool_lag else []
    names += ["x_spool"] if effects and "valve_dynamics" in effects else []
    names += ["gap"] if effects and "backlash" in effects else []
    names += ["y_drift"] if effects and "sensor_drift" in effects else []
    return names


def reference_rhs(
    x: Sequence[float] | np.ndarray,
    u_lags: Sequence[float] | np.ndarray | float,
    params: Mapping[str, float],
    *,
    valve: str = "orifice",
    output: str = "angle",
    spool_lag: bool = False,
    effects: Mapping[str, Mapping[str, float]] | None = None,
    dt: float = 0.004,
    smooth: bool = True,
    stick_band: float = 1e-6,
) -> np.ndarray:
    """Time derivative of the state at one point.

    Parameters
    ----------
    x : array, shape (nx,)
        State ``[theta [rad], omega [rad/s], p [-], (xs [mA]), (x_spool [mA]), (gap [rad])]``
        (see :func:`reference_state_names`).
    u_lags : array, shape (n_lags + 1,), or float
        Current input [mA] and past samples ``u[n], u[n-1], ...`` (only the
        ``input_delay`` effect reads past samples; if fewer are given than the delay
        needs, the oldest given sample is repeated).
    params : mapping
        Group values by name: ``g_torque`` [rad/s^2], ``g_damping`` [1/s], ``g_spring``
        [1/s^2] and ``g_load`` [rad/s^2] (default 0), ``g_compress`` [1/rad],
        ``g_leak`` [1/s], ``g_valve`` [1/(s mA)], ``g_kp`` [1/s] (linear valve), ``tau_v``
        [s] (spool lag), ``p_gain``, ``p_offset`` (pressure output); effect parameters
        may be given here too.
    valve : {"orifice", "linear"}
        Valve law.
    output : {"angle", "pressure"}
        Measured output (only matters for which parameters are required).
    spool_lag : bool
        First-order spool lag ``tau_v*dxs/dt = c - xs`` before the valve.
    effects : mapping, optional
        Library effect name -> its parameter values and settings (module docstring).
    dt : float
        Sample period [s]: sets the friction smoothing width (``smooth=True``) and the
        decay of a residual velocity while stuck (``smooth=False``).
    smooth : bool
        The package's documented smoothings (True) or exact switching (False).
    stick_band : float
        Velocity [rad/s] below which exact Coulomb friction may stick (``smooth=False``).

    Returns
    -------
    ndarray, shape (nx,)
        ``dx/dt`` in state units per second.
    """
    s = _spec(params, valve, output, spool_lag, effects, dt, smooth, stick_band)
    return _xdot(np.asarray(x, dtype=float), _lags(u_lags, s.n_lags), s)


def reference_output(
    x: Sequence[float] | np.ndarray,
    params: Mapping[str, float],
    *,
    valve: str = "orifice",
    output: str = "angle",
    spool_lag: bool = False,
    effects: Mapping[str, Mapping[str, float]] | None = None,
    smooth: bool = True,
) -> float:
    """Measured output at one state.

    Parameters
    ----------
    x : array, shape (nx,)
        State (see :func:`reference_rhs`).
    params, valve, output, spool_lag, effects, smooth
        As in :func:`reference_rhs`.

    Returns
    -------
    float
        The angle [deg] (``output="angle"``, minus the backlash gap, plus a sensor
        offset) or ``p_gain*p + p_offset`` (``output="pressure"``).
    """
    s = _spec(params, valve, output, spool_lag, effects, 0.004, smooth, 1e-6)
    return _y(np.asarray(x, dtype=float), s)


def _lags(u_lags: Sequence[float] | np.ndarray | float, n_lags: int) -> np.ndarray:
    u = np.atleast_1d(np.asarray(u_lags, dtype=float))
    if u.size < n_lags + 1:  # before the record: the oldest sample given, held
        u = np.concatenate([u, np.full(n_lags + 1 - u.size, u[-1])])
    return u


# --- simulation ----------------------------------------------------------------------------


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


@dataclass(frozen=True)
class RecordOptions:
    """How :func:`reference_record` makes a record: its excitation, its sensor, its solver.

    Every field (and every field of :class:`SolverOptions`) is also a keyword of
    :func:`reference_record`, overriding the options it is given.

    Attributes
    ----------
    amplitude : float
        Largest current [mA] of the default excitation (> 0).
    levels : int
        Number of levels of the default excitation (>= 1).
    angle_limit_deg : float
        Half range [deg] the linear angle estimate may reach before the input is scaled.
    quantization : float, optional
        Encoder resolution [deg] (a 12-bit encoder: ``360 / 4096``).
    noise_ar : float
        Coefficient ``a`` of first-order autoregressive (coloured) sensor noise,
        ``n[k] = a n[k-1] + sqrt(1 - a^2) noise_deg w[k]`` with white ``w`` and a
        stationary start; 0 (default): white noise. ``|a| < 1``.
    drift_deg : float
        A slow sensor drift [deg]: the output moves by this much, linearly in time,
        over the record (0: none).
    solver : SolverOptions
        How the plant is integrated.
    """

    amplitude: float = 1.0
    levels: int = 4
    angle_limit_deg: float = 80.0
    quantization: float | None = None
    noise_ar: float = 0.0
    drift_deg: float = 0.0
    solver: SolverOptions = SolverOptions()

    def validate(self) -> RecordOptions:
        """Check every setting; returns ``self``.

        Raises
        ------
        ValueError
            Naming the setting and what is wrong with it.
        """
        _check_number("amplitude", self.amplitude, "> 0", lambda v: v > 0)
        if isinstance(self.levels, bool) or not isinstance(self.levels, int | np.integer) \
                or self.levels < 1:
            raise ValueError(f"levels must be an integer >= 1, got {self.levels!r}")
        _check_number("angle_limit_deg", self.angle_limit_deg, "> 0", lambda v: v > 0)
        if self.quantization is not None:
            _check_number("quantization", self.quantization, ">= 0", lambda v: v >= 0)
        _check_number("noise_ar", self.noise_ar, "in (-1, 1)", lambda v: abs(v) < 1)
        _check_number("drift_deg", self.drift_deg, "", lambda v: True)
        if not isinstance(self.solver, SolverOptions):
            raise ValueError(f"solver must be a SolverOptions, got {self.solver!r}")
        self.solver.validate()
        return self


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


def _record_options(options: RecordOptions | None, settings: Mapping[str, Any]
                    ) -> RecordOptions:
    """``options`` with ``settings`` (its fields and :class:`SolverOptions`'s) applied."""
    base = options if options is not None else RecordOptions()
    solver_names = {f.name for f in fields(SolverOptions)}
    record_names = {f.name for f in fields(RecordOptions)}
    unknown = sorted(set(settings) - solver_names - record_names)
    if unknown:
        raise ValueError(f"unknown reference record setting(s) {', '.join(unknown)}; "
                             f"settings: {', '.join(sorted(record_names | solver_names))}")
    solver = {k: v for k, v in settings.items() if k in solver_names}
    own = {k: v for k, v in settings.items() if k not in solver_names}
    if solver:
        own["solver"] = _solver_options(own.get("solver", base.solver), solver)
    return _with_overrides(base, own, "reference record").validate()



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


# --- records ---------------------------------------------------------------------------------


def velocity_gain(params: Mapping[str, float], valve: str = "orifice") -> float:
    """Steady angular velocity per valve current at rest [rad/s per mA].

    ``kv/c`` of the linearisation at rest, ``g_torque*g_valve / (g_damping*(g_leak +
    g_kp) + g_torque*g_compress)`` (``g_kp = 0`` for the orifice valve at zero current).
    """
    kp = params.get("g_kp", 0.0) if valve == "linear" else 0.0
    den = params["g_damping"] * (params["g_leak"] + kp) + params["g_torque"] * params["g_compress"]
    return params["g_torque"] * params["g_valve"] / den


def reference_record(
    seed: int = 0,
    duration: float = 20.0,
    fs: float = 250.0,
    noise_deg: float = 0.05,
    params: Mapping[str, float] | None = None,
    effects: Mapping[str, Mapping[str, float]] | None = None,
    *,
    valve: str = "orifice",
    spool_lag: bool = False,
    u: Sequence[float] | np.ndarray | None = None,
    smooth: bool = True,
    intersample: str = "zoh",
    options: RecordOptions | None = None,
    **settings: Any,
) -> Dataset:
    """A simulated rig record generated by the reference implementation.

    The counterpart of :func:`hhra_phys.models.hhra.rig.simulate_rig` written without the
    package's model: the same input family (the paper's irregular multi-level steps
    of :func:`hhra_phys.excitation.irregular_steps`, one M-sequence period per 20 s,
    scaled down if a linear estimate of the angle would leave +-``angle_limit_deg``),
    the shaft started so the linear estimate's stroke is centred on 0 deg, Gaussian
    angle noise (white, or coloured: first-order autoregressive), an optional slow
    drift of the sensor and optional quantisation.

    Parameters
    ----------
    seed : int
        Seeds the excitation and then the noise.
    duration : float
        Record length [s].
    fs : float
        Sample rate [Hz].
    noise_deg : float
        Standard deviation of the angle noise [deg] (of the noise process itself, also
        when it is coloured).
    params : mapping, optional
        Groups (and effect parameters) by name; missing groups take
        :data:`REFERENCE_GROUPS` (the rig's values as printed in ``docs/model.md``).
    effects : mapping, optional
        Effects in the plant (see :func:`simulate_reference`).
    valve : {"orifice", "linear"}
        Valve law.
    spool_lag : bool
        Spool lag (then ``params`` needs ``tau_v``).
    u : array, optional
        Valve current [mA] instead of the default excitation.
    smooth, intersample
        As in :func:`simulate_reference`; the record carries ``intersample`` (what its
        input did between samples).
    options : RecordOptions, optional
        The excitation, the sensor and the solver (default :class:`RecordOptions`'s).
    **settings
        Any field of :class:`RecordOptions` (``amplitude``, ``levels``,
        ``angle_limit_deg``, ``quantization``, ``noise_ar``, ``drift_deg``) or of
        :class:`SolverOptions` (``method``, ``rtol``, ``atol``, ``stick_band``), overriding
        ``options``.

    Returns
    -------
    Dataset
        ``t`` [s], ``u`` [mA], ``y`` [deg]. ``metadata``: ``generator`` (``"reference"``),
        ``seed``, ``noise_deg``, ``noise_ar``, ``drift_deg``, ``quantization_deg``, ``valve``,
        ``true_params``
        (every parameter by name), ``effects`` (names), ``x0`` (by state name), and
        ``truth``: everything :func:`simulate_reference` needs to reproduce the
        noise-free output (``params``, ``effects`` with settings, ``valve``,
        ``spool_lag``, ``smooth``, ``x0``, ``integrator``: the :class:`SolverOptions`).
        No ``physical`` entry: the reference works in groups only.

    Raises
    ------
    ValueError
        A bad setting (or a negative ``noise_deg``), naming it.
    """
    o = _record_options(options, settings)
    if not (math.isfinite(noise_deg) and noise_deg >= 0):
        raise ValueError(f"noise_deg must be >= 0, got {noise_deg}")
    p = dict(REFERENCE_GROUPS)
    if valve == "orifice":
        p.pop("g_kp")
    p.update({k: float(v) for k, v in (params or {}).items()})
    rng = np.random.default_rng(seed)
    gain = velocity_gain(p, valve)
    u = _excitation(duration, fs, gain, rng, o) if u is None else u
    u = np.asarray(u, dtype=float)
    names = reference_state_names(spool_lag=spool_lag, effects=effects)
    x0 = np.zeros(len(names))
    x0[0] = _centred_angle(u, fs, gain)
    y_true = simulate_reference(u, fs, p, valve=valve, spool_lag=spool_lag, effects=effects,
                                x0=x0, smooth=smooth, intersample=intersample, solver=o.solver)
    y = _sensor(y_true, noise_deg, rng, o)
    eff = {k: dict(v) for k, v in (effects or {}).items()}
    true_params = dict(p)
    for vals in eff.values():
        true_params.update({k: v for k, v in vals.items() if k in _ALL_EFFECT_PARAMS})
    meta: dict[str, Any] = {
        "generator": "reference",
        "seed": seed,
        "noise_deg": noise_deg,
        "noise_ar": o.noise_ar,
        "drift_deg": o.drift_deg,
        "quantization_deg": o.quantization,
        "valve": valve,
        "intersample": intersample,
        "true_params": true_params,
        "effects": list(eff),
        "x0": dict(zip(names, x0.tolist(), strict=True)),
        "truth": {
            "params": dict(p),
            "effects": eff,
            "valve": valve,
            "spool_lag": spool_lag,
            "smooth": smooth,
            "x0": x0.tolist(),
            "integrator": {f.name: getattr(o.solver, f.name) for f in fields(SolverOptions)},
        },
    }
    return Dataset.from_arrays(
        u, y, fs=fs, metadata=meta, name=f"reference-seed{seed}",
        input_name="current", input_unit="mA", output_name="angle", output_unit="deg",
    )


def _excitation(duration: float, fs: float, gain: float, rng: np.random.Generator,
                o: RecordOptions) -> np.ndarray:
    """The default input: irregular steps, scaled down if the linear estimate of the angle
    (``gain`` [rad/s per mA]) would span more than ``2 * angle_limit_deg``."""
    n = samples(duration, fs)
    periods = max(1, int(round(duration / 20.0)))
    u = irregular_steps(n, levels=o.levels, amplitude=o.amplitude, n_periods=periods, seed=rng)
    est = np.degrees(np.cumsum(u) / fs * gain)
    half = 0.5 * float(est.max() - est.min())
    return u * (o.angle_limit_deg / half) if half > o.angle_limit_deg else u


def _centred_angle(u: np.ndarray, fs: float, gain: float) -> float:
    """Initial angle [rad] that centres the linear estimate's stroke on 0."""
    est = np.degrees(np.cumsum(u) / fs * gain)
    est -= est[0]
    return -math.radians(0.5 * float(est.max() + est.min()))


def _sensor(y_true: np.ndarray, noise_deg: float, rng: np.random.Generator,
            o: RecordOptions) -> np.ndarray:
    """The measured angle: noise (white or AR(1)), drift and quantisation added."""
    w = noise_deg * rng.standard_normal(y_true.size)
    if o.noise_ar:
        # Stationary AR(1) with the standard deviation noise_deg: first sample at the
        # stationary spread, then innovations scaled by sqrt(1 - a^2).
        w[1:] *= math.sqrt(1.0 - o.noise_ar ** 2)
        w = sps.lfilter([1.0], [1.0, -o.noise_ar], w)
    y = y_true + w
    if o.drift_deg:
        y = y + o.drift_deg * np.arange(y.size) / max(y.size - 1, 1)
    if o.quantization:
        y = np.round(y / o.quantization) * o.quantization
    return y


_ALL_EFFECT_PARAMS = ({k for v in _EFFECT_PARAMS.values() for k in v}
                      | {k for v in _OPTIONAL_PARAMS.values() for k in v})
