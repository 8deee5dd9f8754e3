"""Effects on the motion: friction, an angle-dependent load and a constant force.

Each acts on the rate of the model's velocity state (role ``"velocity"`` or
``"angular_velocity"``: ``omega`` on the HHRA, ``v`` on a linear drive), whatever its name:
:class:`CoulombFriction` (Coulomb, optionally Stribeck and viscous), :class:`GravityLoad`
(reads the angle, role ``"angle"``) and :class:`ConstantForce`. Their bounds scale with the
model's acceleration (``accel_scale``) and velocity (``v_scale``). They are registered as
library effects by :mod:`hhra_phys.effects.library`, in the library's order.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from hhra_phys.effects.common import RIG_ACCEL, _rate_unit, _smooth_np
from hhra_phys.effects.structure import _rate_constants
from hhra_phys.errors import ModelError, ParameterError
from hhra_phys.parameters import Parameter
from hhra_phys.parts import Context, Effect, Signals, smooth_sign

__all__ = ["FRICTION_WIDTH", "SIGN_PROFILES", "ConstantForce", "CoulombFriction",
           "GravityLoad"]

#: Shapes of :class:`CoulombFriction`'s smooth sign (its ``profile``).
SIGN_PROFILES = ("algebraic", "tanh")


#: Default switching width of the friction's smooth sign [rad/s]: seal friction
#: reverses within a few thousandths of a rad/s (``docs/model.md``). The stiffness it
#: adds at rest, ``level/width``, is what the simulator's ROS2 integrator is for.
FRICTION_WIDTH = 0.005


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

    @classmethod
    def scaled_fields(cls, auto: Mapping[str, Any], model: Any) -> dict[str, Any]:
        """The generic fields, and ``width`` from the motion's ``friction_width``
        (:data:`FRICTION_WIDTH` times the velocity's scale) on a model other than the HHRA."""
        out = super().scaled_fields(auto, model)
        if "friction_width" in auto:
            out["width"] = float(auto["friction_width"])
        return out

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
