"""The valve-controlled helical hydraulic rotary actuator (HHRA) as a package of parts.

The HHRA of the reference paper (``docs/model.md``, "Equations") reduces to three states,
shaft angle ``theta`` [rad], angular velocity ``omega`` [rad/s] and the load
pressure normalised by the supply pressure, ``p = P_L / p_s`` [-]::

    dtheta/dt = omega
    domega/dt = g_torque*p - g_damping*omega - g_spring*theta - g_load
    dp/dt     = q(I, p) - g_compress*omega - g_leak*p

with the orifice valve ``q = g_valve * I * sqrt(1 - sign(I)*p)`` (or the linearised
valve ``q = g_valve*I - g_kp*p``). The ``g_*`` are the identifiable groups of the
physical symbols (see :mod:`hhra_phys.models.hhra.physical` for the mapping and
``docs/model.md`` for the derivation). Normalising the pressure by ``p_s`` keeps
every state O(1) and puts the orifice nonlinearity at ``|p| -> 1``.

Stages: ``input`` (valve command from the measured current) -> ``valve`` (flow)
-> ``flow`` (pressure equation) -> ``motion`` (angle and velocity) -> ``output``.
Signals: ``"command"`` (valve command, input units) and ``"flow"``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np

from hhra_phys.errors import ModelError, ParameterError
from hhra_phys.model import GROUP_SPAN, DerivedQuantity, Model
from hhra_phys.models.hhra.physical import PhysicalParameters
from hhra_phys.models.hydraulics import orifice_flow
from hhra_phys.parameters import Parameter
from hhra_phys.parts import (
    Context,
    Part,
    State,
    register_part,
)

__all__ = [
    "HHRAModel", "HHRA_STAGES", "NOMINAL_GROUPS", "RAD2DEG", "CurrentCommand", "OrificeValve",
    "LinearValve", "ChamberPressure", "RotaryMotion", "SpoolLag", "AngleOutput",
    "PressureOutput", "group_parameter",
]

RAD2DEG = 180.0 / math.pi

#: The HHRA's stages, in the order they run.
HHRA_STAGES: tuple[str, ...] = ("input", "valve", "flow", "motion", "output")

#: Nominal identifiable groups: those of the built-in simulated rig.
NOMINAL_GROUPS: dict[str, float] = PhysicalParameters().groups()
# The linearised valve's flow-pressure gain is 0 at rest; give it the value it
# has at a mid-range operating point so its log-scaled bounds are meaningful.
NOMINAL_GROUPS["g_kp"] = 2.0


# --- the HHRA parts -----------------------------------------------------------


@dataclass(frozen=True)
class CurrentCommand(Part):
    """Valve command equal to the measured input (valve current, input units).

    Effects of the ``input`` stage (dead zone, saturation, delay, spool lag)
    transform the ``command`` signal this part sets.
    """

    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "current_command"

    def apply(self, ctx: Context) -> None:
        ctx.signals["command"] = ctx.u


@dataclass(frozen=True)
class OrificeValve(Part):
    """Critical-centre servo valve with the orifice law.

    ``q = g_valve * I * sqrt(1 - sign(I) * p)`` in normalised pressure per second,
    i.e. the paper's ``q_L = k_q x_v sqrt(p_s - sign(x_v) P_L)`` divided by
    ``p_s * V_t / (4 beta_e)``. The sign and the square root are smoothed
    (:func:`~hhra_phys.parts.smooth_sign` with width ``sign_eps`` in input units,
    :func:`~hhra_phys.parts.smooth_signed_sqrt` with ``sqrt_delta``) so that CasADi
    derivatives exist everywhere; beyond the supply pressure (``sign(I)*p > 1``)
    the signed root reverses the flow, as a real orifice does.
    """

    sign_eps: float = 1e-3
    sqrt_delta: float = 1e-6
    stage: ClassVar[str] = "valve"
    name: ClassVar[str] = "orifice_valve"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (group_parameter("g_valve"),)

    def apply(self, ctx: Context) -> None:
        cmd = ctx.signal("command", self.name)
        ctx.signals["flow"] = orifice_flow(cmd, ctx.x["p"], ctx.p["g_valve"], self.sign_eps,
                                           self.sqrt_delta)


@dataclass(frozen=True)
class LinearValve(Part):
    """Linearised valve ``q = g_valve*I - g_kp*p`` (flow gain and flow-pressure gain)."""

    stage: ClassVar[str] = "valve"
    name: ClassVar[str] = "linear_valve"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (group_parameter("g_valve"), group_parameter("g_kp"))

    def apply(self, ctx: Context) -> None:
        cmd = ctx.signal("command", self.name)
        ctx.signals["flow"] = ctx.p["g_valve"] * cmd - ctx.p["g_kp"] * ctx.x["p"]


@dataclass(frozen=True)
class ChamberPressure(Part):
    """Flow continuity: ``dp/dt = flow - g_compress*omega - g_leak*p``.

    ``g_compress*omega`` is the displacement flow of the moving piston and
    ``g_leak*p`` the internal leakage, both in normalised pressure per second.
    """

    stage: ClassVar[str] = "flow"
    name: ClassVar[str] = "chamber_pressure"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (group_parameter("g_compress"), group_parameter("g_leak"))

    @property
    def states(self) -> Sequence[State]:
        return (State("p", "-", 0.0, "load pressure P_L / supply pressure p_s", scale=0.5,
                      role="effort"),)

    def apply(self, ctx: Context) -> None:
        ctx.add_rate("p", ctx.signal("flow", self.name))
        ctx.add_rate("p", -ctx.p["g_compress"] * ctx.x["omega"] - ctx.p["g_leak"] * ctx.x["p"])


@dataclass(frozen=True)
class RotaryMotion(Part):
    """Load and torque balance with the piston eliminated.

    ``domega/dt = g_torque*p - g_damping*omega - g_spring*theta - g_load``. The
    spring (``G``) and constant load (``T_L``) groups are parameters of the model
    but fixed at 0 by default (the paper's ``G = 0``; no load on the rig).
    """

    stage: ClassVar[str] = "motion"
    name: ClassVar[str] = "rotary_motion"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return tuple(group_parameter(n) for n in ("g_torque", "g_damping", "g_spring", "g_load"))

    @property
    def states(self) -> Sequence[State]:
        return (
            State("theta", "rad", 0.0, "shaft angle", scale=math.radians(10.0), role="angle"),
            State("omega", "rad/s", 0.0, "shaft angular velocity", role="angular_velocity"),
        )

    def apply(self, ctx: Context) -> None:
        x, p = ctx.x, ctx.p
        ctx.add_rate("theta", x["omega"])
        ctx.add_rate(
            "omega",
            p["g_torque"] * x["p"]
            - p["g_damping"] * x["omega"]
            - p["g_spring"] * x["theta"]
            - p["g_load"],
        )


@dataclass(frozen=True)
class SpoolLag(Part):
    """First-order lag of the valve spool: ``tau_v * dxs/dt = command - xs``.

    The valve then sees ``xs`` (input units) instead of the command. At 250 Hz
    angle data a lag of a few milliseconds is hardly identifiable (the angle
    integrates it away); pressure data shows it better.
    """

    tau_nominal: float = 0.01
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "spool_lag"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (
            Parameter(
                "tau_v", "s", self.tau_nominal, 1e-4, 0.2, "log", "valve spool time constant"
            ),
        )

    @property
    def states(self) -> Sequence[State]:
        return (State("xs", "mA", 0.0, "spool position in input units", fit_initial=False),)

    def apply(self, ctx: Context) -> None:
        cmd = ctx.signal("command", self.name)
        ctx.add_rate("xs", (cmd - ctx.x["xs"]) / ctx.p["tau_v"])
        ctx.signals["command"] = ctx.x["xs"]


@dataclass(frozen=True)
class AngleOutput(Part):
    """Measured output: the shaft angle in degrees."""

    stage: ClassVar[str] = "output"
    name: ClassVar[str] = "angle_output"

    def apply(self, ctx: Context) -> None:
        ctx.signals["y"] = RAD2DEG * ctx.x["theta"]


@dataclass(frozen=True)
class PressureOutput(Part):
    """Measured output: the load pressure, ``y = p_gain * p + p_offset``.

    ``p_gain`` is the supply pressure in the output's units (for a sensor in Pa,
    ``p_s``; for rescaled raw data, whatever scale the data has), signed: a
    negative gain means the sensor's positive direction is the other chamber's
    (so the model needs no assumption on the sign convention of the data).
    ``p_offset`` is the sensor's zero. Both are linear-scale parameters. The zero
    drifts between runs, so a fit of several records estimates ``p_offset`` once
    per record (``per_record``, :class:`~hhra_phys.problem.Problem`).

    With only a pressure measured, the angle's scale is not observable: scaling
    ``theta`` by ``b`` and dividing ``g_compress`` by ``b`` (and multiplying
    ``g_torque`` by ``b``) changes nothing measured, so fits keep ``g_compress``
    fixed for such models (:mod:`hhra_phys.problem`).
    """

    gain_nominal: float = 1.0
    gain_limit: float = 1e3
    offset_limit: float = 1e3
    stage: ClassVar[str] = "output"
    name: ClassVar[str] = "pressure_output"
    per_record: ClassVar[tuple[str, ...]] = ("p_offset",)

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (
            Parameter("p_gain", "out", self.gain_nominal, -self.gain_limit, self.gain_limit,
                      "linear", "supply pressure in output units (signed)"),
            Parameter("p_offset", "out", 0.0, -self.offset_limit, self.offset_limit, "linear",
                      "pressure sensor offset"),
        )

    def apply(self, ctx: Context) -> None:
        ctx.signals["y"] = ctx.p["p_gain"] * ctx.x["p"] + ctx.p["p_offset"]


# --- parameters of the groups ---------------------------------------------------

_GROUP_SPECS: dict[str, tuple[str, str, str]] = {
    # name: (unit, scale, description)
    "g_torque": ("rad/s^2", "log", "A*p_s/M_e: angular acceleration at full supply pressure"),
    "g_damping": ("1/s", "log", "B_e/M_e: viscous damping rate"),
    "g_spring": ("1/s^2", "linear", "2*varsigma*G/(d*M_e): angle stiffness (0 on the rig)"),
    "g_load": ("rad/s^2", "linear", "2*varsigma*T_L/(d*M_e): constant load torque (0 on the rig)"),
    "g_compress": ("1/rad", "log", "4*beta_e*A/(2*pi*zeta*V_t*p_s): displacement flow per rad"),
    "g_leak": ("1/s", "log", "4*beta_e*C_t/V_t: internal leakage rate"),
    "g_valve": ("1/(s*mA)", "log", "4*beta_e*k_q*k_x/(V_t*sqrt(p_s)): valve flow gain"),
    "g_kp": ("1/s", "log", "4*beta_e*k_pa/V_t: linearised flow-pressure gain"),
}

def group_parameter(name: str) -> Parameter:
    """The :class:`Parameter` of identifiable group ``name`` with the rig's nominal value.

    Log-scaled groups get bounds nominal/10 .. nominal*10; the spring and load
    groups (nominal 0) get symmetric absolute bounds.
    """
    unit, scale, desc = _GROUP_SPECS[name]
    nom = NOMINAL_GROUPS[name]
    if scale == "log":
        lo, hi = nom / GROUP_SPAN, nom * GROUP_SPAN
    else:
        lo, hi = (-400.0, 400.0) if name == "g_spring" else (-100.0, 100.0)
    return Parameter(name, unit, nom, lo, hi, scale, desc)  # type: ignore[arg-type]



for _cls in (CurrentCommand, OrificeValve, LinearValve, ChamberPressure, RotaryMotion,
             SpoolLag, AngleOutput, PressureOutput):
    register_part(_cls)


class HHRAModel(Model):
    """The valve-controlled helical hydraulic rotary actuator.

    Parameters
    ----------
    valve : {"orifice", "linear"}
        Valve law: the nonlinear orifice law (default) or the linearised law.
    output : {"angle", "pressure"}
        Measured output: shaft angle in degrees (default) or load pressure
        (``y = p_gain*p + p_offset``, for records such as the public
        hydraulic-actuator data whose output is oil pressure).
    spool_lag : bool
        Add a first-order valve spool lag (state ``xs``, parameter ``tau_v``).
    effects : iterable of Part
        Further parts, e.g. from :mod:`hhra_phys.effects`.
    nominal : dict, optional
        Nominal values to use instead of the simulated rig's, by parameter name.

    Notes
    -----
    States: ``theta`` [rad], ``omega`` [rad/s], ``p`` [-] (load pressure over
    supply pressure), plus ``xs`` [mA] with the spool lag. Input: valve current
    [mA] (zero-order hold). Default parameters: the identifiable groups
    ``g_torque, g_damping, g_spring, g_load, g_compress, g_leak, g_valve`` at the
    values of the built-in simulated rig
    (:class:`hhra_phys.models.hhra.physical.PhysicalParameters`).

    Examples
    --------
    >>> from hhra_phys import HHRAModel
    >>> model = HHRAModel()
    >>> model.params.names[:3]
    ['g_valve', 'g_compress', 'g_leak']
    """

    def __init__(
        self,
        valve: Literal["orifice", "linear"] = "orifice",
        output: Literal["angle", "pressure"] = "angle",
        spool_lag: bool = False,
        effects: Iterable[Part] = (),
        nominal: dict[str, float] | None = None,
    ) -> None:
        if valve not in ("orifice", "linear"):
            raise ModelError(f"valve must be 'orifice' or 'linear', got {valve!r}")
        if output not in ("angle", "pressure"):
            raise ModelError(f"output must be 'angle' or 'pressure', got {output!r}")
        # Parts listed motion first so that the state vector reads theta, omega, p
        # (then xs); the stages fix the order they run in.
        parts: list[Part] = [RotaryMotion(), ChamberPressure(), CurrentCommand()]
        if spool_lag:
            parts.append(SpoolLag())
        parts.append(OrificeValve() if valve == "orifice" else LinearValve())
        parts.append(AngleOutput() if output == "angle" else PressureOutput())
        parts += list(effects)
        # The rig starts at rest: only the measured state's initial value is fitted
        # (the angle; the pressure for a pressure output, which cannot see the angle).
        pinned = ("omega", "p") if output == "angle" else ("theta", "omega")
        # G = 0 and no load on the paper's rig; a pressure alone cannot see the
        # angle's scale, so the displacement group is held too.
        held = ("g_spring", "g_load") + (("g_compress",) if output == "pressure" else ())
        super().__init__(parts, stages=HHRA_STAGES, name="hhra", pinned=pinned, held=held)
        if nominal:
            derived = self.with_nominal(nominal)
            self.params = derived.params
            self._overrides = derived._overrides

    input_name: str = "current"

    @property
    def output_name(self) -> str:
        """``"angle"`` or ``"pressure"``."""
        return "pressure" if self.has_part("pressure_output") else "angle"

    def operating_state(self, x: np.ndarray, **named: float) -> np.ndarray:
        """The state at an operating point of the actuator.

        ``angle`` [deg], ``velocity`` [deg/s], ``pressure`` (``P_L/p_s`` in (-1, 1))
        and ``current`` [mA] (the spool-lag state follows the current).
        """
        pressure = float(named.get("pressure", 0.0))
        if not -1.0 < pressure < 1.0:
            raise ParameterError(
                f"operating_point.pressure is P_L/p_s and must lie in (-1, 1), got {pressure}")
        x = np.array(x, dtype=float)
        values = {"theta": math.radians(float(named.get("angle", 0.0))),
                  "omega": math.radians(float(named.get("velocity", 0.0))),
                  "p": pressure, "xs": float(named.get("current", 0.0))}
        for name, value in values.items():
            if name in self.state_names:
                x[self.state_names.index(name)] = value
        return x

    @classmethod
    def upgrade_spec(cls, spec: dict[str, Any]) -> dict[str, Any]:
        """A saved specification from before stages, pinned and held states were saved.

        Such files (hhra-phys 0.1 before the generic core) relied on the HHRA's
        fixed stage order and name-based rules; this restores them.
        """
        if "pinned" in spec:
            return spec
        spec = dict(spec)
        types = [p["type"] for p in spec["parts"]]
        pressure = "PressureOutput" in types
        spec["stages"] = list(HHRA_STAGES)
        spec["pinned"] = ["theta", "omega"] if pressure else ["omega", "p"]
        spec["held"] = ["g_spring", "g_load"] + (["g_compress"] if pressure else [])
        # State order theta, omega, p as the model builds it.
        first = [p for p in spec["parts"] if p["type"] in ("RotaryMotion", "ChamberPressure")]
        first.sort(key=lambda p: p["type"] != "RotaryMotion")
        spec["parts"] = first + [p for p in spec["parts"] if p not in first]
        return spec

    @property
    def valve(self) -> str:
        """``"orifice"`` or ``"linear"``."""
        return "linear" if self.has_part("linear_valve") else "orifice"

    def tf_coefficients(self, p: np.ndarray | None = None) -> dict[str, float]:
        """The paper's transfer function ``theta/I = kv / (a s^3 + b s^2 + c s)``.

        Computed from the groups and normalised to ``a = 1`` (only the ratios are
        identifiable from (current, angle) data). Units: ``theta`` in rad, ``I`` in
        mA; ``b`` [1/s], ``c`` [1/s^2], ``kv`` [rad/(s^3*mA)]. The linearised valve
        at rest has flow gain ``g_valve`` and flow-pressure gain ``g_kp`` (0 for the
        orifice valve at zero current).
        """
        d = self.params.as_dict(self.nominal() if p is None else np.asarray(p, dtype=float))
        return {k: float(q.function(d)) for k, q in self.derived_quantities().items()}

    def derived_quantities(self) -> dict[str, DerivedQuantity]:
        """The paper's transfer-function coefficients ``a``, ``b``, ``c``, ``kv``
        (:meth:`tf_coefficients`) as functions of the groups, so that a fit reports
        them with 95 % intervals (the delta method, docs/fitting.md)."""
        def leak(d: Mapping[str, Any]) -> Any:
            return d["g_leak"] + d.get("g_kp", 0.0)

        return {
            "a": DerivedQuantity("-", lambda d: 1.0,
                                 "s^3 coefficient of G(s), 1 by normalisation"),
            "b": DerivedQuantity("1/s", lambda d: d["g_damping"] + leak(d),
                                 "s^2 coefficient of G(s) = kv/(a s^3 + b s^2 + c s)",
                                 positive=True),
            "c": DerivedQuantity("1/s^2", lambda d: d["g_damping"] * leak(d)
                                 + d["g_torque"] * d["g_compress"],
                                 "s coefficient of G(s)", positive=True),
            "kv": DerivedQuantity("rad/(s^3*mA)", lambda d: d["g_torque"] * d["g_valve"],
                                  "gain of G(s) (theta in rad, current in mA)",
                                  positive=True),
        }

    def tf_coefficients_of(self, values: Mapping[str, float]) -> dict[str, float]:
        """:meth:`tf_coefficients` from fitted values by name (``{}`` if any group is missing)."""
        try:
            return self.tf_coefficients(np.array([values[n] for n in self.params.names]))
        except (KeyError, ParameterError):
            return {}

    def physical_view(
        self, values: Mapping[str, float], datasheet: Any = None,
        metadata: Mapping[str, Any] | None = None,
    ) -> tuple[dict[str, float] | None, str | None]:
        """Physical symbols from the fitted groups and a datasheet.

        ``datasheet`` is a :class:`~hhra_phys.models.hhra.physical.PhysicalParameters`
        holding the known symbols; without one, a record's ``metadata["physical"]``
        (simulated rig data carries its own) is used. Returns ``(symbols, None)``,
        ``(None, None)`` without a datasheet, or ``(None, warning)`` when the groups
        do not determine the symbols.
        """
        sheet = datasheet
        meta = metadata or {}
        if sheet is None and isinstance(meta.get("physical"), dict):
            try:
                sheet = PhysicalParameters(**meta["physical"])
            except (TypeError, ParameterError):
                sheet = None
        if sheet is None:
            return None, None
        groups = {k: v for k, v in values.items() if k.startswith("g_") and k != "g_kp"}
        try:
            return sheet.from_groups(groups).to_dict(), None
        except ParameterError as exc:
            return None, f"physical symbols not recoverable with the datasheet: {exc}"
