"""Effects on what the sensor sees: backlash before the encoder, sensor offset and drift.

They change the measured output ``y``, not the physics of the motion: :class:`Backlash`
(play between the drive and the position sensor: it needs a velocity and a position, rotary
or linear, and an output affine in the position), :class:`SensorOffset` (a constant bias)
and :class:`SensorDrift` (a zero that moves linearly in time). They are registered as
library effects by :mod:`hhra_phys.effects.library`, in the library's order.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from hhra_phys.effects.common import RAD2DEG, _smooth_np
from hhra_phys.effects.structure import output_offsets, output_slope
from hhra_phys.errors import ModelError, ParameterError
from hhra_phys.parameters import Parameter
from hhra_phys.parts import Context, Effect, Signals, State, corner_relu

__all__ = ["BACKLASH_SPEED", "BACKLASH_WIDTH", "Backlash", "SensorDrift", "SensorOffset"]


#: Default contact width of the backlash [deg]: the angle over which the carried
#: side takes up the load at contact (tooth and spline compliance), far below the
#: encoder noise of the rig (0.05 deg). The stiffness it adds while carried,
#: ``|omega|/width``, is what the simulator's ROS4 integrator is for.
BACKLASH_WIDTH = 0.01

#: Shaft speed [rad/s] at which the backlash's stiffness is judged by default
#: (:meth:`Backlash.stiff_states`): of the order of the rig's speed at 1 mA.
BACKLASH_SPEED = 0.5


def _contact(z: Any) -> Any:
    """``min(z, 1)`` with a quadratic corner over ``0.5 < z < 1.5`` (backlash contact)."""
    return z - corner_relu(z - 1, 0.5)



@dataclass(frozen=True)
class Backlash(Effect):
    """Play between the drive and the position sensor, as the sensor sees it.

    State ``gap`` (in the position's unit: rad on the HHRA) = driven position minus sensed
    position, starting at 0 (centred in the play of total ``play`` [output units: deg on
    the HHRA], half ``h = play/2`` in position units)::

        dgap/dt = max(v, 0)*f((h - gap)/w) + min(v, 0)*f((h + gap)/w)

    with ``v`` the model's velocity and ``f(z) = min(z, 1)`` given a quadratic corner over
    ``0.5 < z < 1.5`` (:func:`corner_relu`): ``f = 1`` farther than ``1.5 w`` from the
    contact, so the gap follows the drive exactly there (the sensor rests); ``f = z``
    within ``0.5 w`` of it, so the gap reaches the contact (``gap = +-h`` in the direction
    of motion) exponentially, within ``0.5 w*exp(-s/w)`` after ``s`` of carried motion,
    and is pushed back if beyond: the sensor is carried along and the effective play is
    ``play`` whatever the length of the motion (the ideal play operator as ``w -> 0``;
    about ``0.5 w`` behind it at each new contact). ``w`` is the contact width. The
    direction is read exactly (``max``/``min`` of ``v``): nothing moves at rest. Only
    ``min``, ``max`` and products: vector instructions in the simulator's SIMD code.
    Output ``y -= slope*gap``.

    Bound by role: the model's velocity and position (:attr:`~hhra_phys.model.Model.
    motion`), rotary or linear, with an output affine in the position (an encoder);
    ``slope`` is that output's change per unit of position (``dy/dposition``, 57.3 deg/rad
    on the HHRA, 1000 mm/m on a drive measured in mm). The defaults are the HHRA's (an
    angle encoder in degrees); :func:`~hhra_phys.effects.make_effect` with a model sets
    ``slope``, the units and the scales from the model (``play_scale``: 2 % of the
    position state's scale in output units; ``speed``: the velocity's scale), so a linear
    drive gets a play in its output's unit.

    The width is physics, not numerics: ``width`` (default :data:`BACKLASH_WIDTH` times
    ``play_scale``: 0.01 deg on the HHRA), or the fitted parameter ``w_contact`` with
    ``fit_width=True``. While carried the gap relaxes at ``|v|/w`` per second (about
    3000 1/s at 0.5 rad/s on the HHRA): a stiff model, which
    :class:`~hhra_phys.simulate.Simulator` sees through :meth:`stiff_states` and
    integrates with ROS4.

    Parameters
    ----------
    width : float
        Contact width [output units] (when not fitted).
    fit_width : bool
        Fit the contact width as parameter ``w_contact`` [output units] (log scale, 0.001
        to 0.5 times ``play_scale``, nominal ``width``).
    speed : float
        Velocity [position units/s] at which :meth:`stiff_states` puts the contact (the
        stiffness check only; the dynamics do not use it).
    slope : float
        ``dy/dposition`` of the model's output (output units per position unit).
    play_scale : float
        Output units per unit of the play's box: ``play`` nominal 0.5, box 0.02 to 10
        (times this).
    unit : str
        The output's unit (the parameters' unit).
    position_unit : str
        The position's unit (the ``gap`` state's).
    """

    width: float = BACKLASH_WIDTH
    fit_width: bool = False
    speed: float = BACKLASH_SPEED
    slope: float = RAD2DEG
    play_scale: float = 1.0
    unit: str = "deg"
    position_unit: str = "rad"
    stage: ClassVar[str] = "output"
    name: ClassVar[str] = "backlash"
    binds: ClassVar[tuple[str, ...]] = ("velocity", "position")
    writes: ClassVar[tuple[str, ...]] = ("y",)
    entry: ClassVar[str] = "output"
    signature: ClassVar[str] = (
        "output residual jumps by about the play at each direction reversal and stays "
        "constant while the direction holds (follows the sign of the velocity)"
    )
    regressors: ClassVar[tuple[str, ...]] = ("sign_velocity", "reversals")

    def __post_init__(self) -> None:
        for field_name in ("width", "speed", "play_scale"):
            v = getattr(self, field_name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"backlash {field_name} must be > 0, got {v!r}")
        if not (isinstance(self.slope, (int, float)) and math.isfinite(self.slope)
                and self.slope != 0):
            raise ParameterError(f"backlash slope must be a finite non-zero number, "
                                 f"got {self.slope!r}")

    @classmethod
    def scaled_fields(cls, auto: Mapping[str, Any], model: Any) -> dict[str, Any]:
        """:func:`~hhra_phys.effects.make_effect`'s fields for ``model``: none on the HHRA
        (the defaults are its own), else the output's slope and the motion's scales
        (``auto``: the record's and the motion's scales, :func:`motion_scales`)."""
        if model is None or "v_scale" not in auto:
            return {}
        position = model.motion.position
        slope = output_slope(model, position) if position is not None else None
        if not slope:
            return {}  # not applicable: applicable() says why
        st = model.states[model.state_names.index(position)]
        play_scale = 0.02 * float(st.scale) * abs(slope)
        return {"slope": float(slope), "play_scale": play_scale,
                "width": BACKLASH_WIDTH * play_scale, "speed": float(auto["v_scale"]),
                "unit": str(auto.get("y_unit") or "output units"),
                "position_unit": st.unit or ""}

    @classmethod
    def unasked(cls, model: Any) -> str | None:
        """Tried unasked on an angle (the HHRA's encoder, as always); on a linear position
        only when asked: there its stiff contact made each refit of the 25 s drive cost
        9-17 s and its diagnosis about a quarter longer (docs/diagnosis.md)."""
        motion = model.motion
        if motion.position is None or motion.rotary:
            return None
        return ("tried on a linear position only when asked (--effects ...,backlash or "
                "LoopOptions.candidates): its stiff contact costs a long refit each round")

    @property
    def parameters(self) -> Sequence[Parameter]:
        k = self.play_scale
        out = [Parameter("play", self.unit, 0.5 * k, 0.02 * k, 10.0 * k, "log",
                         "total play between the drive and the position sensor")]
        if self.fit_width:
            out.append(Parameter("w_contact", self.unit, self.width, 1e-3 * k, 0.5 * k,
                                 "log", "contact width of the backlash"))
        return tuple(out)

    @property
    def states(self) -> Sequence[State]:
        return (State("gap", self.position_unit, 0.0,
                      "driven position minus sensed position", fit_initial=False),)

    def applicable(self, model: Any) -> str | None:
        why = super().applicable(model)
        if why:
            return why
        position = model.motion.position
        slope = output_slope(model, position)
        if not slope:
            return ("backlash is seen by a position sensor: the model's output is not "
                    f"affine in its position {position!r}")
        if abs(slope - self.slope) > 1e-9 * abs(slope):
            return (f"this backlash was built for an output of {self.slope:g} per unit of "
                    f"position, the model's output changes by {slope:g}: build it with "
                    "make_effect('backlash', model=...)")
        return None

    def apply(self, ctx: Context) -> None:
        w, gap = ctx.x[ctx.velocity(self.name)], ctx.x["gap"]
        half = 0.5 * ctx.p["play"] / self.slope
        width = (ctx.p["w_contact"] if self.fit_width else self.width) / abs(self.slope)
        # The exact direction (max/min): a smooth sign would let the gap creep at
        # rest and, at speeds within its width, drag it past the contact.
        rate = (ca.fmax(w, 0) * _contact((half - gap) / width)
                + ca.fmin(w, 0) * _contact((half + gap) / width))
        ctx.add_rate("gap", rate)
        ctx.signals["y"] = ctx.signal("y", self.name) - self.slope * gap

    def stiff_states(self, values: Mapping[str, float]) -> list[dict[str, float]]:
        """States at which the backlash is stiffest, for the simulator's method choice.

        Parameters
        ----------
        values : mapping
            Parameter values by name (``play``, ``w_contact`` if fitted; output units).

        Returns
        -------
        list of dict
            Carried at contact on either side at :attr:`speed`: ``{"@velocity": +-speed,
            "gap": +-play/2}`` (position units per second, position units), where the gap
            relaxes at ``speed/width``; ``"@velocity"`` names the model's velocity state
            (``omega`` on the HHRA).
        """
        half = 0.5 * float(values["play"]) / self.slope
        return [{"@velocity": s * self.speed, "gap": s * half} for s in (1.0, -1.0)]

    def probe(self) -> dict[str, float]:
        return {"play": 0.5 * self.play_scale}

    def first_order(self, sig: Signals) -> np.ndarray:
        if sig.velocity is None:
            raise ModelError("backlash needs the simulated velocity")
        # Half the probe play against the motion; the direction's sign smoothed over
        # 2 % of the stiffness speed (0.01 rad/s on the HHRA) so that a velocity crossing
        # zero between samples is not a jump.
        return (-0.25 * self.play_scale
                * _smooth_np(sig.velocity, 0.02 * self.speed)[:, None])


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
