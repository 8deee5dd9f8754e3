"""Library of effects a physical model may lack, as model parts.

Each effect is a :class:`~hhra_phys.parts.Part` with named parameters (units,
bounds, fitting scale), a smooth formulation wherever derivatives are taken,
and a declared *signature*: the way it shows up in the residual of a model that
lacks it. :mod:`hhra_phys.diagnose` ranks effects by that signature and
:mod:`hhra_phys.loop` adds, refits and scores them.

Library names (stable, read by outside checks)::

    coulomb_friction  valve_deadzone  valve_saturation  input_delay  valve_dynamics
    gravity_load      backlash        sensor_offset     asymmetric_valve
    sensor_drift      input_offset    constant_force

Each effect declares what it needs: roles (:attr:`Effect.binds`) and names
(:attr:`Effect.reads`, :attr:`Effect.writes`), and :meth:`Effect.applicable` checks
exactly that, so the loop skips an effect a model cannot take and says why (for a
missing role, which one and how to declare it). Input-side effects
(``valve_deadzone``, ``valve_saturation``, ``input_delay``, ``valve_dynamics``,
``input_offset``) act on the model's input ``ctx.u`` and output-side ``sensor_offset``
and ``sensor_drift`` (a sensor's, not the physics') on the output ``y``: they attach to
any model. ``coulomb_friction``, ``constant_force`` and ``gravity_load`` bind by role:
they act on the rate of the model's velocity (:attr:`hhra_phys.model.Model.motion`, the
state with role ``"velocity"`` or ``"angular_velocity"``: ``omega`` on the HHRA, ``v`` on
the cylinder or a user's drive) and ``gravity_load`` reads its angle (role ``"angle"``);
``backlash`` needs an angle output in degrees, ``asymmetric_valve`` the ``"flow"`` and
``"command"`` signals of a valve model such as the HHRA (by name). A user's effect is
registered with :func:`hhra_phys.parts.register_effect`.

Scaling. Bounds of input-stage effects are relative to ``u_scale`` (typical input
magnitude, default 1 mA), of motion effects to ``accel_scale`` (the model's
``g_torque``, default the rig's; on another model the velocity's rate made by the full
input and the efforts, :func:`motion_scales`), of velocity widths to ``v_scale`` (the
velocity state's scale), of time constants to ``dt`` (sample period);
:func:`make_effect` sets them from a record, a fit and the model so the same library
works on the rig (mA, deg, 250 Hz), on a linear drive (V, m, m/s) and on records in raw
units and sample time.

First-order signature. :meth:`Effect.first_order` returns, for a probe size of
the effect, the change it makes at its entry point (``"input"``: the model's input,
the valve command; ``"rate:@velocity"``: the rate of the model's velocity state, the
angular acceleration ``rate:omega`` on the HHRA; ``"output"``: the output) given the
signals of a simulation without it. Propagated through the linearised model this
is the direction in which the effect moves the output, which the diagnosis
compares with the residual.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from hhra_phys.errors import ModelError, ParameterError
from hhra_phys.parameters import Parameter
from hhra_phys.parts import (
    EFFECTS,
    Context,
    Effect,
    Signals,
    State,
    corner_relu,
    register_effect,
    smooth_sign,
)

__all__ = ["EFFECTS", "EFFECT_ALIASES", "LIBRARY", "Effect", "Signals", "effect_name",
           "make_effect", "motion_scales", "register_effect", "RIG_ACCEL",
           "FRICTION_WIDTH", "BACKLASH_WIDTH", "CORNER_WIDTH", "corner_relu", "library_twins",
           "output_offsets", "output_slope", "SIGN_PROFILES"]

RAD2DEG = 180.0 / math.pi

#: The rig's g_torque [rad/s^2]: default scale of accelerations of motion effects.
RIG_ACCEL = 175.58


#: Smoothing settings of earlier versions, removed, with what replaces them.
REMOVED_SETTINGS: dict[str, str] = {
    "eps": "the smoothing tied to the sample period; set the physical 'width' instead "
           "(or fit_width=True where the effect offers it)",
    "eps_omega": "the soft backlash contact; set the contact 'width' [deg] instead "
                 "(or fit_width=True)",
}


#: Shapes of :class:`CoulombFriction`'s smooth sign (its ``profile``).
SIGN_PROFILES = ("algebraic", "tanh")


def _smooth_np(v: np.ndarray, eps: float) -> np.ndarray:
    return v / np.sqrt(v * v + eps * eps)


def _rate_unit(v_unit: str) -> str:
    """Unit of a velocity's rate: ``"rad/s"`` -> ``"rad/s^2"``, ``"m"`` -> ``"m/s"``."""
    return f"{v_unit}^2" if v_unit.endswith("/s") else f"{v_unit}/s"


# --- motion stage -----------------------------------------------------------------


#: Default switching width of the friction's smooth sign [rad/s]: seal friction
#: reverses within a few thousandths of a rad/s (``docs/model.md``). The stiffness it
#: adds at rest, ``level/width``, is what the simulator's ROS2 integrator is for.
FRICTION_WIDTH = 0.005


@register_effect
@dataclass(frozen=True)
class CoulombFriction(Effect):
    """Friction torque: Coulomb, optionally Stribeck and viscous parts.

    ``domega/dt -= level * sgn(omega) + g_viscous*omega`` with ``level = g_coulomb +
    g_stribeck*exp(-(omega/v_stribeck)^2)`` and the smooth sign
    ``omega/sqrt(omega^2 + width^2)``, whose slope at rest is ``1/width``.
    Accelerations in rad/s^2 (friction torque over inertia).

    The switching width is physics, not numerics: ``width`` [rad/s] (default
    :data:`FRICTION_WIDTH`, 0.005 rad/s), or the fitted parameter ``v_switch``
    with ``fit_width=True``. A sharp friction makes the model stiff
    (``level/width`` per second at rest): :class:`~hhra_phys.simulate.Simulator`
    then integrates it with the L-stable ROS2 method. Within the width the
    smooth sign lets the shaft creep at ``width*f/sqrt(1 - f^2)`` under a push of
    ``f`` times the friction level, where real friction sticks.

    Parameters
    ----------
    stribeck : bool
        Add the Stribeck term (parameters ``g_stribeck`` [rad/s^2] and
        ``v_stribeck`` [rad/s]).
    viscous : bool
        Add a viscous term (parameter ``g_viscous`` [1/s]). Off by default: on a
        model with viscous damping of its own (the HHRA's ``g_damping``) the two
        cannot be told apart.
    width : float
        Switching width [rad/s] of the smooth sign (when not fitted).
    fit_width : bool
        Fit the switching width as parameter ``v_switch`` [rad/s] (log scale,
        0.0005 to 0.5 rad/s, nominal ``width``).
    profile : {"algebraic", "tanh"}
        Shape of the smooth sign: ``"algebraic"`` (default) ``omega/sqrt(omega^2 +
        width^2)``, or ``"tanh"`` ``tanh(omega/width)``. Both have the slope ``1/width``
        at rest (the same stiffness); away from rest the algebraic sign approaches its
        level as ``1 - width^2/(2 omega^2)``, the tanh exponentially, so a friction that
        switches fully within a few widths (a sharp seal, or a record made with a tanh
        law) is followed by the tanh where the algebraic leaves a slow tail (a 1 kHz drive:
        4e-6 m of selection error against its 1e-6 m noise, ``docs/diagnosis.md``).
        The loop's shape stage (``LoopOptions.fit_shapes``) tries both.
    accel_scale : float
        Typical acceleration [rad/s^2] (the model's ``g_torque``); sets the bounds.
    v_scale : float
        Typical velocity (the velocity's unit; 1 on the rig): scales the bounds of
        ``v_stribeck`` and ``v_switch``.
    v_unit : str
        Unit of the velocity (``"rad/s"`` on the rig, ``"m/s"`` on a linear drive):
        the parameters' units follow it.

    Binding. The friction acts on the rate of the model's velocity state and reads
    it (:attr:`hhra_phys.model.Model.motion`: the state with role ``"velocity"`` or
    ``"angular_velocity"``), whatever its name; :func:`make_effect` given the model
    sets ``accel_scale``, ``v_scale``, ``v_unit`` and ``width`` from it. Units above
    are the rig's; on a linear drive read m/s for rad/s.
    """

    stribeck: bool = False
    accel_scale: float = RIG_ACCEL
    viscous: bool = False
    width: float = FRICTION_WIDTH
    fit_width: bool = False
    v_scale: float = 1.0
    v_unit: str = "rad/s"
    profile: str = "algebraic"
    stage: ClassVar[str] = "motion"
    name: ClassVar[str] = "coulomb_friction"
    twin: ClassVar[tuple[str, ...]] = ("sign(@velocity)",)
    binds: ClassVar[tuple[str, ...]] = ("velocity",)
    entry: ClassVar[str] = "rate:@velocity"
    signature: ClassVar[str] = (
        "residual follows the sign of the simulated velocity; the error grows after "
        "each direction reversal and is largest at small inputs"
    )
    regressors: ClassVar[tuple[str, ...]] = ("sign_velocity", "reversals", "small_input")

    def __post_init__(self) -> None:
        for key in ("width", "v_scale"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"coulomb_friction {key} must be > 0 {self.v_unit}, "
                                     f"got {v!r}")
        if self.profile not in SIGN_PROFILES:
            raise ParameterError(f"coulomb_friction profile must be one of "
                                 f"{', '.join(map(repr, SIGN_PROFILES))}, got {self.profile!r}")

    @property
    def parameters(self) -> Sequence[Parameter]:
        a, vs, vu = self.accel_scale, self.v_scale, self.v_unit
        au = _rate_unit(vu)
        out = [Parameter("g_coulomb", au, 0.03 * a, 1e-4 * a, 0.6 * a, "log",
                         "Coulomb friction torque over inertia")]
        if self.stribeck:
            out += [
                Parameter("g_stribeck", au, 0.01 * a, 1e-4 * a, 0.6 * a, "log",
                          "extra breakaway (Stribeck) friction over inertia"),
                Parameter("v_stribeck", vu, 0.1 * vs, 1e-3 * vs, 2.0 * vs, "log",
                          "Stribeck velocity"),
            ]
        if self.viscous:
            out.append(Parameter("g_viscous", "1/s", 0.5, 0.0, 50.0, "linear",
                                 f"viscous friction torque over inertia per {vu}"))
        if self.fit_width:
            out.append(Parameter("v_switch", vu, self.width, 5e-4 * vs, 0.5 * vs, "log",
                                 "switching width of the Coulomb friction"))
        return tuple(out)

    def _width(self, level: Any, p: Mapping[str, Any] | None = None) -> Any:
        """Width of the smooth sign [rad/s] for friction ``level``."""
        if self.fit_width and p is not None:
            return p["v_switch"]
        return self.width

    def apply(self, ctx: Context) -> None:
        v = ctx.velocity(self.name)
        w = ctx.x[v]
        level = ctx.p["g_coulomb"]
        if self.stribeck:
            level = level + ctx.p["g_stribeck"] * ca.exp(-(w / ctx.p["v_stribeck"]) ** 2)
        width = self._width(level, ctx.p)
        rate = -level * (ca.tanh(w / width) if self.profile == "tanh"
                         else smooth_sign(w, width))
        if self.viscous:
            rate = rate - ctx.p["g_viscous"] * w
        ctx.add_rate(v, rate)

    def probe(self) -> dict[str, float]:
        return {p.name: p.nominal for p in self.parameters}

    def first_order(self, sig: Signals) -> np.ndarray:
        if sig.velocity is None:
            raise ModelError("coulomb_friction needs the simulated velocity")
        g = self.probe()["g_coulomb"]
        w = self._width(g)
        shape = (np.tanh(sig.velocity / w) if self.profile == "tanh"
                 else _smooth_np(sig.velocity, w))
        return -g * shape[:, None]


@register_effect
@dataclass(frozen=True)
class GravityLoad(Effect):
    """Angle-dependent load torque, such as an offset mass on the shaft.

    ``domega/dt -= g_grav_cos*cos(theta) + g_grav_sin*sin(theta)`` [rad/s^2]: a
    mass ``m`` at radius ``r`` whose lowest point is at angle ``theta_m`` gives
    ``m g r / J * sin(theta - theta_m)``, i.e. amplitude
    ``hypot(g_grav_cos, g_grav_sin)`` and phase ``atan2``. The two linear
    coefficients are used instead of amplitude and phase because they are
    identified without a phase ambiguity.

    Binding. It acts on the rate of the model's velocity and reads its position, which
    must be an angle (a state with role ``"angle"``, in rad): whatever their names. On a
    linear axis gravity is a constant force: :class:`ConstantForce`.

    Parameters
    ----------
    accel_scale : float
        Typical acceleration (the velocity's unit per second; the model's ``g_torque``):
        sets the bounds.
    v_unit : str
        Unit of the velocity: the parameters' units follow it.
    """

    accel_scale: float = RIG_ACCEL
    v_unit: str = "rad/s"
    stage: ClassVar[str] = "motion"
    name: ClassVar[str] = "gravity_load"
    twin: ClassVar[tuple[str, ...]] = ("sin(@angle)", "cos(@angle)")
    binds: ClassVar[tuple[str, ...]] = ("velocity", "angle")
    entry: ClassVar[str] = "rate:@velocity"
    signature: ClassVar[str] = (
        "residual drifts with the simulated angle (sin/cos of theta); it is absent "
        "where the shaft rests and may extrapolate badly outside the angles seen"
    )
    regressors: ClassVar[tuple[str, ...]] = ("angle",)
    position_dependent: ClassVar[bool] = True

    @property
    def parameters(self) -> Sequence[Parameter]:
        a = 0.6 * self.accel_scale
        au = _rate_unit(self.v_unit)
        return (
            Parameter("g_grav_cos", au, 0.0, -a, a, "linear",
                      "load torque over inertia at theta = 0"),
            Parameter("g_grav_sin", au, 0.0, -a, a, "linear",
                      "load torque over inertia at theta = 90 deg"),
        )

    def unbound(self, model: Any) -> str | None:
        why = super().unbound(model)
        if why and model.motion.velocity is not None and not model.motion.rotary:
            why += "; on a linear axis a constant load (gravity on an incline) is constant_force"
        return why

    def apply(self, ctx: Context) -> None:
        th = ctx.x[ctx.position(self.name)]
        ctx.add_rate(ctx.velocity(self.name), -(ctx.p["g_grav_cos"] * ca.cos(th)
                                                + ctx.p["g_grav_sin"] * ca.sin(th)))

    def probe(self) -> dict[str, float]:
        return {"g_grav_cos": 0.03 * self.accel_scale, "g_grav_sin": 0.03 * self.accel_scale}

    def first_order(self, sig: Signals) -> np.ndarray:
        if sig.position is None:
            raise ModelError("gravity_load needs the simulated angle")
        a = 0.03 * self.accel_scale
        return -a * np.column_stack([np.cos(sig.position), np.sin(sig.position)])


@dataclass(frozen=True)
class ConstantForce(Effect):
    """A constant force (torque) at the velocity's rate: ``dv/dt += g_const``.

    A load that does not depend on the motion: the weight on an inclined linear axis, a
    spring preload, a pressure on a rod's area, a motor's torque offset. ``g_const``
    is the force over the mass (torque over inertia), in the velocity's unit per second.
    It binds to the model's velocity (a state with role ``"velocity"`` or
    ``"angular_velocity"``) whatever its name. Physics first: a constant at the rate is
    what a trend in a position output needs before any sensor drift.

    Parameters
    ----------
    accel_scale : float
        Typical acceleration (the velocity's unit per second; the model's ``g_torque``):
        the bounds are ``+-0.6*accel_scale``, the probe ``0.03*accel_scale``.
    v_unit : str
        Unit of the velocity: the parameter's unit follows it.
    """

    accel_scale: float = RIG_ACCEL
    v_unit: str = "rad/s"
    stage: ClassVar[str] = "motion"
    name: ClassVar[str] = "constant_force"
    twin: ClassVar[tuple[str, ...]] = ("one()",)
    binds: ClassVar[tuple[str, ...]] = ("velocity",)
    entry: ClassVar[str] = "rate:@velocity"
    signature: ClassVar[str] = (
        "the velocity's rate is off by a constant: a position output drifts (a ramp that "
        "bends where damping or a spring holds it), a velocity output is offset"
    )
    regressors: ClassVar[tuple[str, ...]] = ("time",)

    @property
    def parameters(self) -> Sequence[Parameter]:
        a = 0.6 * self.accel_scale
        return (Parameter("g_const", _rate_unit(self.v_unit), 0.0, -a, a, "linear",
                          "constant force over mass (torque over inertia)"),)

    def applicable(self, model: Any) -> str | None:
        have = _rate_constants(model)
        if have:
            return (f"the model already has a free constant at the velocity's rate "
                    f"({', '.join(have)})")
        return super().applicable(model)

    def apply(self, ctx: Context) -> None:
        ctx.add_rate(ctx.velocity(self.name), ctx.p["g_const"])

    def probe(self) -> dict[str, float]:
        return {"g_const": 0.03 * self.accel_scale}

    def first_order(self, sig: Signals) -> np.ndarray:
        return np.full((sig.u.size, 1), 0.03 * self.accel_scale)


# --- input stage ------------------------------------------------------------------


#: Default corner width of the dead zone and the saturation, relative to ``u_scale``.
CORNER_WIDTH = 0.01


def _contact(z: Any) -> Any:
    """``min(z, 1)`` with a quadratic corner over ``0.5 < z < 1.5`` (backlash contact)."""
    return z - corner_relu(z - 1, 0.5)


class _InputCorner:
    """Corner width of an input-stage switch: ``width*u_scale``."""

    u_scale: float
    width: float

    def _check(self) -> None:
        for key in ("u_scale", "width"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"{self.name} {key} must be > 0, got {v!r}")  # type: ignore[attr-defined]

    def _relu(self, v: Any) -> Any:
        return corner_relu(v, self.width * self.u_scale)


@register_effect
@dataclass(frozen=True)
class ValveDeadzone(_InputCorner, Effect):
    """No flow for ``|command| < i_dead``: ``c -> relu(c - d) - relu(-c - d)``.

    ``relu`` is :func:`corner_relu`: exact beyond ``width*u_scale`` of the edges,
    a quadratic (C1) corner within.

    Parameters
    ----------
    u_scale : float
        Typical input magnitude (input units; 1 mA on the rig); sets the bounds.
    width : float
        Half width of the corners relative to ``u_scale`` (default
        :data:`CORNER_WIDTH`, 0.01).
    """

    u_scale: float = 1.0
    width: float = CORNER_WIDTH
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "valve_deadzone"
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "residual grows during small inputs (no motion where the model moves) and the "
        "apparent gain depends on the input level"
    )
    regressors: ClassVar[tuple[str, ...]] = ("small_input", "input_level")

    def __post_init__(self) -> None:
        self._check()

    @property
    def parameters(self) -> Sequence[Parameter]:
        s = self.u_scale
        return (Parameter("i_dead", "input", 0.05 * s, 1e-3 * s, 0.9 * s, "log",
                          "half width of the valve dead zone"),)

    def apply(self, ctx: Context) -> None:
        c = ctx.u
        d = ctx.p["i_dead"]
        ctx.u = self._relu(c - d) - self._relu(-c - d)

    def first_order(self, sig: Signals) -> np.ndarray:
        d = self.probe()["i_dead"]
        return -np.clip(sig.u, -d, d)[:, None]


@register_effect
@dataclass(frozen=True)
class ValveSaturation(_InputCorner, Effect):
    """Spool or current limit: ``c -> clip(c, -i_sat, i_sat)``.

    Written ``c - relu(c - s) + relu(-c - s)`` with :func:`corner_relu`: exact
    beyond ``width*u_scale`` of the limits. Parameters as :class:`ValveDeadzone`.
    """

    u_scale: float = 1.0
    width: float = CORNER_WIDTH
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "valve_saturation"
    twin: ClassVar[tuple[str, ...]] = ("sat(u)",)
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "the apparent gain falls at the largest inputs (the residual follows the input "
        "level at its extremes only)"
    )
    regressors: ClassVar[tuple[str, ...]] = ("input_level",)

    def __post_init__(self) -> None:
        self._check()

    @property
    def parameters(self) -> Sequence[Parameter]:
        s = self.u_scale
        return (Parameter("i_sat", "input", 0.8 * s, 0.05 * s, 3.0 * s, "log",
                          "largest effective valve command"),)

    def apply(self, ctx: Context) -> None:
        c = ctx.u
        s = ctx.p["i_sat"]
        ctx.u = c - self._relu(c - s) + self._relu(-c - s)

    def first_order(self, sig: Signals) -> np.ndarray:
        s = 0.8 * float(np.max(np.abs(sig.u)))
        return (np.clip(sig.u, -s, s) - sig.u)[:, None]


@dataclass(frozen=True)
class InputOffset(Effect):
    """A constant bias of the input: ``u -> u + u_offset`` (input units).

    A servo valve's null bias (the spool passes flow at zero current), a motor driver's
    command offset, a pump's zero. It acts on the model's input, so it attaches to any
    model; under an integrating output it leaves a trend in the output, which is physics
    before it is a sensor's drift.

    Parameters
    ----------
    u_scale : float
        Typical input magnitude (input units; 1 mA on the rig): the bounds are
        ``+-0.5*u_scale``, the probe ``0.05*u_scale``.
    """

    u_scale: float = 1.0
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "input_offset"
    twin: ClassVar[tuple[str, ...]] = ("one()",)
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "the model is driven by a constant input it does not see: a trend (integrating "
        "output) or an offset that follows the input's gain"
    )
    regressors: ClassVar[tuple[str, ...]] = ("time",)

    def __post_init__(self) -> None:
        if not (isinstance(self.u_scale, (int, float)) and math.isfinite(self.u_scale)
                and self.u_scale > 0):
            raise ParameterError(f"input_offset u_scale must be > 0, got {self.u_scale!r}")

    @property
    def parameters(self) -> Sequence[Parameter]:
        s = 0.5 * self.u_scale
        return (Parameter("u_offset", "input", 0.0, -s, s, "linear",
                          "constant bias of the input (valve null bias, command offset)"),)

    def apply(self, ctx: Context) -> None:
        ctx.u = ctx.u + ctx.p["u_offset"]

    def probe(self) -> dict[str, float]:
        return {"u_offset": 0.05 * self.u_scale}

    def first_order(self, sig: Signals) -> np.ndarray:
        return np.full((sig.u.size, 1), 0.05 * self.u_scale)


@register_effect
@dataclass(frozen=True)
class InputDelay(Effect):
    """Transport delay of the command, fractional, in samples.

    ``command(t) = u(t - delay*dt)`` with the held input samples interpolated
    linearly between neighbouring lags (``u_lags``): for ``delay = k + f`` the
    command is ``(1-f)*u[n-k] + f*u[n-k-1]``. The weights are the hat functions
    ``max(0, 1 - |delay - k|)``: continuous in ``delay``, with kinks at integers.

    Parameters
    ----------
    max_delay : int
        Upper bound of the delay's box [samples]. The part holds twice as many lags
        (``n_lags = 2*max_delay + 1``), so a box widened at its edge (the loop's, a
        fit's) can reach a delay up to ``2*max_delay + 1``; within the box the extra lags
        weigh exactly zero (issue 33: with ``n_lags = max_delay + 1`` a 10-sample delay
        ended at 9.00 and a stand-in made up the rest).
    """

    max_delay: int = 8
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "input_delay"
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "the measured response lags the simulated one: the cross-correlation of measured "
        "and simulated output changes peaks at a positive lag; residual follows the "
        "input's changes"
    )
    regressors: ClassVar[tuple[str, ...]] = ("input_change",)

    def __post_init__(self) -> None:
        if int(self.max_delay) != self.max_delay or self.max_delay < 1:
            raise ParameterError(f"max_delay must be a positive integer, got {self.max_delay}")

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (Parameter("delay", "samples", 1.0, 0.0, float(self.max_delay), "linear",
                          "transport delay of the valve command"),)

    @property
    def n_lags(self) -> int:
        return 2 * int(self.max_delay) + 1

    def apply(self, ctx: Context) -> None:
        d = ctx.p["delay"]
        out = ca.SX(0)
        for k in range(self.n_lags + 1):
            out = out + ca.fmax(0, 1 - ca.fabs(d - k)) * ctx.u_lags[k]
        # The delay acts on the measured input, wherever it sits among the input-side
        # effects: earlier ones (dead zone, saturation, lag) see the delayed input,
        # so substitute it for the current input in what they built.
        u0 = ctx.u_lags[0]
        ctx.u = ca.substitute(ctx.u, u0, out)
        for key, expr in ctx.signals.items():
            ctx.signals[key] = ca.substitute(expr, u0, out)
        for key, expr in ctx.rates.items():
            ctx.rates[key] = ca.substitute(expr, u0, out)

    def first_order(self, sig: Signals) -> np.ndarray:
        u = sig.u
        return (np.concatenate([u[:1], u[:-1]]) - u)[:, None]


@register_effect
@dataclass(frozen=True)
class ValveDynamics(Effect):
    """First-order lag of the valve spool: ``tau_spool * dx_spool/dt = command - x_spool``.

    Parameters
    ----------
    dt : float
        Sample period [s]; the bounds are ``0.3*dt .. 50*dt`` (faster lags are
        invisible at this sampling and too stiff for the integrator).
    """

    dt: float = 0.004
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "valve_dynamics"
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "the response to each input step starts late and rounded; high-frequency residual "
        "after input changes (an integrating output hides it)"
    )
    regressors: ClassVar[tuple[str, ...]] = ("input_change",)

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (Parameter("tau_spool", "s", 2.5 * self.dt, 0.3 * self.dt, 50 * self.dt, "log",
                          "valve spool time constant"),)

    @property
    def states(self) -> Sequence[State]:
        return (State("x_spool", "input", 0.0, "spool position in input units",
                      fit_initial=False),)

    def apply(self, ctx: Context) -> None:
        ctx.add_rate("x_spool", (ctx.u - ctx.x["x_spool"]) / ctx.p["tau_spool"])
        ctx.u = ctx.x["x_spool"]

    def first_order(self, sig: Signals) -> np.ndarray:
        tau = self.probe()["tau_spool"]
        a = math.exp(-sig.dt / tau)
        # The spool at sample k has seen the held inputs up to k-1 (zero-order hold),
        # starting at rest on u[0].
        b, den = [0.0, 1 - a], [1.0, -a]
        from scipy import signal as sps  # here, not at import: most of `import hhra_phys`

        lagged = sps.lfilter(b, den, sig.u, zi=sps.lfilter_zi(b, den) * sig.u[0])[0]
        return (lagged - sig.u)[:, None]


# --- valve stage --------------------------------------------------------------------


@register_effect
@dataclass(frozen=True)
class AsymmetricValve(Effect):
    """Different flow gains for the two directions: ``flow *= 1 + asym*sgn(command)``.

    ``asym`` [-] is half the relative difference of the gains (+0.1: 10 % more flow
    for a positive command, 10 % less for a negative one). Runs in the ``valve``
    stage after the valve part, on its ``"flow"`` signal.
    """

    u_scale: float = 1.0
    eps: float = 0.01
    stage: ClassVar[str] = "valve"
    name: ClassVar[str] = "asymmetric_valve"
    reads: ClassVar[tuple[str, ...]] = ("command", "flow")
    writes: ClassVar[tuple[str, ...]] = ("flow",)
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "residual drifts in proportion to the integral of |input| (time-growing drift "
        "whatever the direction)"
    )
    regressors: ClassVar[tuple[str, ...]] = ("time", "abs_input")

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (Parameter("asym", "-", 0.0, -0.8, 0.8, "linear",
                          "relative flow-gain difference between directions (half)"),)

    def apply(self, ctx: Context) -> None:
        c = ctx.signal("command", self.name)
        flow = ctx.signal("flow", self.name)
        ctx.signals["flow"] = flow * (1 + ctx.p["asym"] * smooth_sign(c, self.eps * self.u_scale))

    def probe(self) -> dict[str, float]:
        return {"asym": 0.05}

    def first_order(self, sig: Signals) -> np.ndarray:
        return 0.05 * np.abs(sig.u)[:, None]


# --- output stage -------------------------------------------------------------------


#: Default contact width of the backlash [deg]: the angle over which the carried
#: side takes up the load at contact (tooth and spline compliance), far below the
#: encoder noise of the rig (0.05 deg). The stiffness it adds while carried,
#: ``|omega|/width``, is what the simulator's ROS4 integrator is for.
BACKLASH_WIDTH = 0.01

#: Shaft speed [rad/s] at which the backlash's stiffness is judged by default
#: (:meth:`Backlash.stiff_states`): of the order of the rig's speed at 1 mA.
BACKLASH_SPEED = 0.5


@register_effect
@dataclass(frozen=True)
class Backlash(Effect):
    """Play between piston and shaft as seen by the encoder.

    State ``gap`` [rad] = shaft angle minus encoder angle, starting at 0 (centred in
    the play of total ``play`` [deg], half ``h = play/2``)::

        dgap/dt = max(omega, 0)*f((h - gap)/w) + min(omega, 0)*f((h + gap)/w)

    with ``f(z) = min(z, 1)`` given a quadratic corner over ``0.5 < z < 1.5``
    (:func:`corner_relu`): ``f = 1`` farther than ``1.5 w`` from the contact, so the
    gap follows the shaft exactly there (the encoder rests); ``f = z`` within
    ``0.5 w`` of it, so the gap reaches the contact (``gap = +-h`` in the direction
    of motion) exponentially, within ``0.5 w*exp(-s/w)`` after ``s`` of carried
    motion, and is pushed back if beyond: the encoder is carried along and the
    effective play is ``play`` whatever the length of the motion (the ideal play
    operator as ``w -> 0``; about ``0.5 w`` behind it at each new contact). ``w``
    [deg] is the contact width. The direction is read exactly (``max``/``min`` of
    ``omega``): nothing moves at rest. Only ``min``, ``max`` and products: vector
    instructions in the simulator's SIMD code. Output ``y -= gap`` in degrees.

    The width is physics, not numerics: ``width`` (default :data:`BACKLASH_WIDTH`,
    0.01 deg), or the fitted parameter ``w_contact`` with ``fit_width=True``.
    While carried the gap relaxes at ``|omega|/w`` per second (about 3000 1/s at
    0.5 rad/s): a stiff model, which :class:`~hhra_phys.simulate.Simulator` sees
    through :meth:`stiff_states` and integrates with ROS4.

    Parameters
    ----------
    width : float
        Contact width [deg] (when not fitted).
    fit_width : bool
        Fit the contact width as parameter ``w_contact`` [deg] (log scale, 0.001 to
        0.5 deg, nominal ``width``).
    speed : float
        Shaft speed [rad/s] at which :meth:`stiff_states` puts the contact (the
        stiffness check only; the dynamics do not use it).
    """

    width: float = BACKLASH_WIDTH
    fit_width: bool = False
    speed: float = BACKLASH_SPEED
    stage: ClassVar[str] = "output"
    name: ClassVar[str] = "backlash"
    binds: ClassVar[tuple[str, ...]] = ("velocity", "angle")
    writes: ClassVar[tuple[str, ...]] = ("y",)
    entry: ClassVar[str] = "output"
    signature: ClassVar[str] = (
        "output residual jumps by about the play at each direction reversal and stays "
        "constant while the direction holds (follows the sign of the velocity)"
    )
    regressors: ClassVar[tuple[str, ...]] = ("sign_velocity", "reversals")

    def __post_init__(self) -> None:
        for field_name in ("width", "speed"):
            v = getattr(self, field_name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"backlash {field_name} must be > 0, got {v!r}")

    @property
    def parameters(self) -> Sequence[Parameter]:
        out = [Parameter("play", "deg", 0.5, 0.02, 10.0, "log",
                         "total play between piston and shaft")]
        if self.fit_width:
            out.append(Parameter("w_contact", "deg", self.width, 1e-3, 0.5, "log",
                                 "contact width of the backlash"))
        return tuple(out)

    @property
    def states(self) -> Sequence[State]:
        return (State("gap", "rad", 0.0, "shaft angle minus encoder angle",
                      fit_initial=False),)

    def applicable(self, model: Any) -> str | None:
        why = super().applicable(model)
        if why:
            return why
        angle = model.motion.position
        slope = output_slope(model, angle)
        if slope is None or abs(slope - RAD2DEG) > 1e-9 * RAD2DEG:
            return ("backlash is seen by an angle encoder: the model has no angle output "
                    f"(its output is not the angle {angle!r} in degrees)")
        return None

    def apply(self, ctx: Context) -> None:
        w, gap = ctx.x[ctx.velocity(self.name)], ctx.x["gap"]
        half = 0.5 * ctx.p["play"] / RAD2DEG
        width = (ctx.p["w_contact"] if self.fit_width else self.width) / RAD2DEG
        # The exact direction (max/min): a smooth sign would let the gap creep at
        # rest and, at speeds within its width, drag it past the contact.
        rate = (ca.fmax(w, 0) * _contact((half - gap) / width)
                + ca.fmin(w, 0) * _contact((half + gap) / width))
        ctx.add_rate("gap", rate)
        ctx.signals["y"] = ctx.signal("y", self.name) - RAD2DEG * gap

    def stiff_states(self, values: Mapping[str, float]) -> list[dict[str, float]]:
        """States at which the backlash is stiffest, for the simulator's method choice.

        Parameters
        ----------
        values : mapping
            Parameter values by name (``play`` [deg], ``w_contact`` [deg] if fitted).

        Returns
        -------
        list of dict
            Carried at contact on either side at :attr:`speed`: ``{"@velocity": +-speed,
            "gap": +-play/2}`` (rad/s, rad), where the gap relaxes at ``speed/width``;
            ``"@velocity"`` names the model's velocity state (``omega`` on the HHRA).
        """
        half = 0.5 * float(values["play"]) / RAD2DEG
        return [{"@velocity": s * self.speed, "gap": s * half} for s in (1.0, -1.0)]

    def probe(self) -> dict[str, float]:
        return {"play": 0.5}

    def first_order(self, sig: Signals) -> np.ndarray:
        if sig.velocity is None:
            raise ModelError("backlash needs the simulated velocity")
        # Half the probe play against the motion; the direction's sign smoothed over
        # 0.01 rad/s so that a velocity crossing zero between samples is not a jump.
        return -0.25 * _smooth_np(sig.velocity, 0.01)[:, None]


@register_effect
@dataclass(frozen=True)
class SensorOffset(Effect):
    """Constant bias of the measured output: ``y += y_offset`` (output units).

    With an integrating output (the HHRA angle without spring or load) it cannot be
    told from the initial angle: the diagnosis reports it as not identifiable.
    """

    y_scale: float = 1.0
    stage: ClassVar[str] = "output"
    name: ClassVar[str] = "sensor_offset"
    twin: ClassVar[tuple[str, ...]] = ("one()",)
    sensor: ClassVar[bool] = True
    writes: ClassVar[tuple[str, ...]] = ("y",)
    entry: ClassVar[str] = "output"
    signature: ClassVar[str] = "constant residual mean"
    regressors: ClassVar[tuple[str, ...]] = ("constant",)

    @property
    def parameters(self) -> Sequence[Parameter]:
        a = 10 * self.y_scale
        return (Parameter("y_offset", "out", 0.0, -a, a, "linear", "sensor zero offset"),)

    def applicable(self, model: Any) -> str | None:
        have = output_offsets(model)
        if have:
            return f"the model's output already has an offset parameter ({', '.join(have)})"
        return super().applicable(model)

    def apply(self, ctx: Context) -> None:
        ctx.signals["y"] = ctx.signal("y", self.name) + ctx.p["y_offset"]

    def probe(self) -> dict[str, float]:
        return {"y_offset": 0.1 * self.y_scale}

    def first_order(self, sig: Signals) -> np.ndarray:
        return np.full((sig.u.size, 1), 0.1 * self.y_scale)


@register_effect
@dataclass(frozen=True)
class SensorDrift(Effect):
    """Slow drift of the sensor's zero: ``y += y_drift``, ``d y_drift/dt = drift_rate``.

    A sensor effect, not physics: an encoder or strain gauge whose zero moves with
    temperature adds a trend to the measured output that no input explains. The drift
    state starts at 0 on every record (a record's own offset is its initial state's
    business), so on a part of a record the drift is ``drift_rate * (t - t0)``. Under an
    integrating output a constant bias at the input (an asymmetric valve) also makes a
    trend; a trend the model reproduces as the sensor's keeps the physics free of it.

    Parameters
    ----------
    y_scale : float
        Typical output magnitude (output units): the bound of ``drift_rate`` is
        ``y_scale / (100 dt)``.
    dt : float
        Sample period [s] (or samples for records in sample time).
    """

    y_scale: float = 1.0
    dt: float = 0.004
    stage: ClassVar[str] = "output"
    name: ClassVar[str] = "sensor_drift"
    sensor: ClassVar[bool] = True
    writes: ClassVar[tuple[str, ...]] = ("y",)
    entry: ClassVar[str] = "output"
    signature: ClassVar[str] = "residual trend linear in time (the sensor's zero drifts)"
    regressors: ClassVar[tuple[str, ...]] = ("time",)

    @property
    def parameters(self) -> Sequence[Parameter]:
        a = self.y_scale / (100.0 * self.dt)
        return (Parameter("drift_rate", "out/s", 0.0, -a, a, "linear",
                          "drift of the sensor's zero per second"),)

    @property
    def states(self) -> Sequence[State]:
        return (State("y_drift", "out", 0.0, "drift of the sensor's zero since the record's start",
                      fit_initial=False, scale=float(self.y_scale)),)

    def apply(self, ctx: Context) -> None:
        ctx.add_rate("y_drift", ctx.p["drift_rate"])
        ctx.signals["y"] = ctx.signal("y", self.name) + ctx.x["y_drift"]

    def probe(self) -> dict[str, float]:
        # 0.1 y_scale over 1000 samples.
        return {"drift_rate": 1e-4 * self.y_scale / self.dt}

    def first_order(self, sig: Signals) -> np.ndarray:
        return (np.arange(sig.u.size) * sig.dt * self.probe()["drift_rate"])[:, None]


# The offsets, physics first, registered after the earlier library so that the order of
# the earlier candidates (the loop's order where scores tie) stays as it was.
register_effect(InputOffset)
register_effect(ConstantForce)

#: Names of the library's own effects (:data:`EFFECTS` also holds a user's registered ones).
LIBRARY: tuple[str, ...] = tuple(EFFECTS)

#: Generic names of the input effects, for any model's input (a pump voltage, a DAC
#: command), beside the valve names the HHRA keeps: the same parts, not new candidates.
EFFECT_ALIASES: dict[str, str] = {
    "input_deadzone": "valve_deadzone",
    "input_saturation": "valve_saturation",
    "input_lag": "valve_dynamics",
}


def effect_name(name: str) -> str:
    """The registered name of an effect given by its name or a generic alias
    (:data:`EFFECT_ALIASES`); a registered effect of the alias's name wins."""
    return name if name in EFFECTS else EFFECT_ALIASES.get(name, name)


# --- structural checks ----------------------------------------------------------------


def output_slope(model: Any, state: str) -> float | None:
    """``dy/d state`` if the output is affine in ``state`` with a constant slope, else None.

    Read from the model's symbolic output, not from part names (so any model
    whose output is, say, the angle in degrees is recognised).
    """
    if state not in model.state_names:
        return None
    x, u, p = model.symbols()
    _, y = model.assemble(x, u, p, 0.004)
    d = ca.jacobian(y, x[model.state_names.index(state)])
    if not d.is_constant():
        return None
    return float(ca.DM(ca.evalf(d)))


def _rate_constants(model: Any) -> list[str]:
    """Free parameters that add a constant to the velocity's rate by themselves: a
    constant slope there, absent from every other rate and from the output."""
    v = model.motion.velocity
    if v is None:
        return []
    x, u, p = model.symbols()
    xdot, y = model.assemble(x, u, p, 0.004)
    iv = model.state_names.index(v)
    dx = ca.jacobian(xdot, p)
    dy = ca.jacobian(y, p)
    out = []
    for i, name in enumerate(model.params.names):
        if name in model.held:
            continue
        di = dx[iv, i]
        others = [dx[k, i] for k in range(model.nx) if k != iv]
        if (di.is_constant() and float(ca.evalf(di)) != 0.0 and dy[0, i].nnz() == 0
                and all(o.nnz() == 0 for o in others)):
            out.append(name)
    return out


def motion_scales(model: Any, values: Mapping[str, float] | None = None,
                  u_scale: float = 1.0) -> dict[str, Any]:
    """Scales of the model's motion for the library's motion effects.

    Parameters
    ----------
    model : Model
        A model with a velocity (:attr:`~hhra_phys.model.Model.motion`).
    values : mapping, optional
        Parameter values by name (a fit's); the nominal values elsewhere.
    u_scale : float
        Typical input magnitude (input units).

    Returns
    -------
    dict
        ``accel_scale``: typical acceleration [velocity unit/s], the change of the
        velocity's rate made by ``u_scale`` at the input and by every state with role
        ``"effort"`` at its :attr:`~hhra_phys.parts.State.scale` (the model linearised at
        rest; by the other states' scales if those give none); ``v_scale`` (the velocity
        state's scale) and ``v_unit`` (its unit). Empty for a model without a velocity.
    """
    v = model.motion.velocity
    if v is None:
        return {}
    st = model.states[model.state_names.index(v)]
    out: dict[str, Any] = {"v_scale": float(st.scale), "v_unit": st.unit or "1/s"}
    P = model.nominal()
    for i, name in enumerate(model.params.names):
        if values and name in values:
            P[i] = float(values[name])
    try:
        A, B, _, _ = model.linearize(p=P)
    except Exception:  # noqa: BLE001 - no scale rather than no effect
        return out
    iv = model.state_names.index(v)
    scales = [s.scale for s in model.states]
    effort = [k for k, s in enumerate(model.states) if s.role == "effort"]
    a = abs(float(B[iv, 0])) * u_scale + sum(abs(float(A[iv, k])) * scales[k] for k in effort)
    if not (math.isfinite(a) and a > 0):
        a = max((abs(float(A[iv, k])) * scales[k] for k in range(model.nx) if k != iv),
                default=0.0)
    if math.isfinite(a) and a > 0:
        out["accel_scale"] = a
    return out


def output_offsets(model: Any) -> list[str]:
    """Parameters that shift the output by themselves: ``dy/dq == 1`` and absent from ``f``."""
    x, u, p = model.symbols()
    xdot, y = model.assemble(x, u, p, 0.004)
    dy = ca.jacobian(y, p)
    dx = ca.jacobian(xdot, p)
    out = []
    for i, name in enumerate(model.params.names):
        di = dy[0, i]
        if di.is_constant() and float(ca.evalf(di)) == 1.0 and dx[:, i].nnz() == 0:
            out.append(name)
    return out


def library_twins(entry: str, terms: Sequence[str], model: Any) -> list[str]:
    """Library effects whose own shape a discovered term holds at the same entry.

    A discovered term at ``entry`` whose pieces include an effect's :attr:`~hhra_phys.
    parts.Effect.twin` (``d v/dt += -0.3*sgn(v)`` at the velocity's rate: Coulomb
    friction; a constant at the input: an input offset) is that physics in its
    discovered form, whatever else it holds. The report and the diagnose JSON name it
    so (``steps[].same_as``): a reader sees the friction, not "a term outside the
    library". Roles resolve on ``model`` (:attr:`~hhra_phys.model.Model.motion`); an
    effect whose role the model lacks is no twin. Registered user effects that declare
    their own ``twin`` count as well (one inherited from a library class does not). It
    decides nothing.

    Parameters
    ----------
    entry : str
        The discovered term's entry (``"input"``, ``"output"``, ``"rate:<state>"``).
    terms : sequence of str
        Its pieces (:attr:`~hhra_phys.terms.DiscoveredTerm.terms`, e.g. ``"sign(v)"``).
    model : Model
        The model it was discovered on.

    Returns
    -------
    list of str
        Library effect names, in library order (empty: none).
    """
    motion = model.motion
    roles = {"@velocity": motion.velocity, "@position": motion.position,
             "@angle": motion.position if motion.rotary else None}
    have = set(terms)
    out = []
    for name, cls in EFFECTS.items():
        # Each effect's own declaration: a user's subclass of the friction is not named
        # the friction unless it says so.
        if not cls.__dict__.get("twin") or cls.entry_at(model) != entry:
            continue
        for piece in cls.twin:
            for role, state in roles.items():
                if role in piece:
                    piece = piece.replace(role, state or "\0")
            if piece in have:
                out.append(name)
                break
    return out


# --- construction -------------------------------------------------------------------


def _model_scales(model: Any, values: Mapping[str, float] | None,
                  u_scale: float) -> dict[str, Any]:
    """:func:`make_effect`'s settings from the model: its motion's scales and units."""
    if "g_torque" in model.params.names:
        return {}  # the HHRA: g_torque (or the rig's) and the rig's units, as before roles
    out = motion_scales(model, values, u_scale)
    if "v_scale" in out:
        out["width"] = FRICTION_WIDTH * out["v_scale"]
    return out


def make_effect(
    name: str,
    *,
    data: Any | None = None,
    values: Mapping[str, float] | None = None,
    model: Any | None = None,
    **kw: Any,
) -> Effect:
    """Build library effect ``name``, scaled to a record and a fit.

    Parameters
    ----------
    name : str
        Library name (see :data:`EFFECTS`).
    data : Dataset, optional
        Record the effect will be fitted to: sets ``u_scale`` (largest
        ``|input|``), ``dt`` (sample period) and ``y_scale`` (output st. dev.).
    values : dict, optional
        Fitted values of the model it is added to: ``g_torque`` sets ``accel_scale``.
    model : Model, optional
        The model it is added to: where ``values`` has no ``g_torque`` (any model but
        the HHRA), :func:`motion_scales` sets ``accel_scale``, and the velocity state
        sets ``v_scale``, ``v_unit`` and the friction's ``width``
        (:data:`FRICTION_WIDTH` times ``v_scale``), so that the motion effects work in
        the model's own units (a linear drive in m, m/s).
    **kw
        Fields of the effect class (explicit ones win).

    Raises
    ------
    ModelError
        Unknown name or field.
    """
    cls = EFFECTS.get(effect_name(name))
    if cls is None:
        raise ModelError(f"unknown effect {name!r}; library: {', '.join(sorted(EFFECTS))} "
                         f"(generic names: {', '.join(EFFECT_ALIASES)})")
    fields = set(cls.__dataclass_fields__)
    auto: dict[str, Any] = {}
    if data is not None:
        auto["u_scale"] = float(np.max(np.abs(data.u))) or 1.0
        auto["dt"] = float(data.dt)
        auto["y_scale"] = float(np.std(data.y)) or 1.0
    if model is not None:
        auto.update(_model_scales(model, values, auto.get("u_scale", 1.0)))
    if values and values.get("g_torque", 0) > 0:
        auto["accel_scale"] = float(values["g_torque"])
    args = {k: v for k, v in auto.items() if k in fields}
    removed = sorted(set(kw) & set(REMOVED_SETTINGS) - fields)
    if removed:
        raise ModelError(f"effect {name!r}: " + "; ".join(
            f"{k} was removed ({REMOVED_SETTINGS[k]})" for k in removed))
    unknown = set(kw) - fields
    if unknown:
        raise ModelError(
            f"effect {name!r} has no field(s) {sorted(unknown)}; fields: {sorted(fields)}"
        )
    args.update(kw)
    return cls(**args)

