"""The reference HHRA's equations: its right-hand side and output at one point.

The second, independent writing of the model and its effects that
:mod:`hhra_phys.reference.hhra` describes (the equations, the effects' formulas, the
smoothings and the exact switches): the documented groups :data:`REFERENCE_GROUPS`, the
effects it implements (:data:`EFFECT_NAMES`), the resolved specification of a model and the
rates and output of a state, :func:`reference_rhs`, :func:`reference_output` and
:func:`reference_state_names`. Plain Python and NumPy, one point at a time; integrating them
over a record is :mod:`hhra_phys.reference.hhra_simulation`'s business. It imports nothing
from the package.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["EFFECT_NAMES", "REFERENCE_GROUPS", "SIGN_EPS", "SQRT_DELTA", "reference_output",
           "reference_rhs", "reference_state_names"]

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
