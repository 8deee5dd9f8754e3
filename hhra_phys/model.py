"""Composed models and the helical hydraulic rotary actuator (HHRA).

The HHRA of the reference paper (PAPER_NOTES section 1) reduces to three states,
shaft angle ``theta`` [rad], angular velocity ``omega`` [rad/s] and the load
pressure normalised by the supply pressure, ``p = P_L / p_s`` [-]::

    dtheta/dt = omega
    domega/dt = g_torque*p - g_damping*omega - g_spring*theta - g_load
    dp/dt     = q(I, p) - g_compress*omega - g_leak*p

with the orifice valve ``q = g_valve * I * sqrt(1 - sign(I)*p)`` (or the linearised
valve ``q = g_valve*I - g_kp*p``). The ``g_*`` are the identifiable groups of the
physical symbols (see :mod:`hhra_phys.physical` for the mapping and
``docs/model.md`` for the derivation). Normalising the pressure by ``p_s`` keeps
every state O(1) and puts the orifice nonlinearity at ``|p| -> 1``.

A model is a list of :class:`~hhra_phys.parts.Part`; :class:`Model` assembles
them into CasADi functions. :class:`HHRAModel` is the HHRA built from the parts
defined here; :meth:`Model.with_parts` adds effects (friction, dead zone, ...).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar, Literal

import casadi as ca
import numpy as np

from hhra_phys.errors import ModelError
from hhra_phys.parameters import Parameter, ParameterSet
from hhra_phys.parts import (
    STAGES,
    Context,
    Part,
    State,
    smooth_sign,
    smooth_signed_sqrt,
)
from hhra_phys.physical import PhysicalParameters

RAD2DEG = 180.0 / math.pi

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
        p = ctx.x["p"]
        drop = 1 - smooth_sign(cmd, self.sign_eps) * p
        ctx.signals["flow"] = ctx.p["g_valve"] * cmd * smooth_signed_sqrt(drop, self.sqrt_delta)


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
        return (State("p", "-", 0.0, "load pressure P_L / supply pressure p_s"),)

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
            State("theta", "rad", 0.0, "shaft angle"),
            State("omega", "rad/s", 0.0, "shaft angular velocity"),
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
        return (State("xs", "mA", 0.0, "spool position in input units"),)

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
    ``p_offset`` is the sensor's zero. Both are linear-scale parameters.

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

#: Bounds of each group relative to its nominal value (log groups) or absolute.
GROUP_SPAN = 10.0


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


# --- the composed model -----------------------------------------------------------

#: Registry of part classes by class name, for JSON round trips.
PART_TYPES: dict[str, type[Part]] = {}


def register_part(cls: type[Part]) -> type[Part]:
    """Register a part class so models containing it can be saved and loaded."""
    PART_TYPES[cls.__name__] = cls
    return cls


for _cls in (CurrentCommand, OrificeValve, LinearValve, ChamberPressure, RotaryMotion,
             SpoolLag, AngleOutput, PressureOutput):
    register_part(_cls)


class Model:
    """A dynamic model composed of parts, assembled into CasADi functions.

    Parameters
    ----------
    parts : sequence of Part
        The parts; they run in stage order (:data:`~hhra_phys.parts.STAGES`), then
        in the given order within a stage.
    name : str
        A label used in reports.
    overrides : dict, optional
        ``{parameter: {"nominal": .., "lower": .., "upper": ..}}`` or
        ``{parameter: value}`` (sets the nominal value) applied on top of the
        parts' own parameter declarations.

    Notes
    -----
    The model is immutable: :meth:`with_parts`, :meth:`without` and
    :meth:`with_nominal` return new models.
    """

    def __init__(
        self,
        parts: Sequence[Part],
        name: str = "model",
        overrides: dict[str, Any] | None = None,
    ) -> None:
        self.parts: tuple[Part, ...] = tuple(parts)
        self.name = name
        self._overrides: dict[str, dict[str, Any]] = {}
        for pname, spec in (overrides or {}).items():
            self._overrides[pname] = dict(spec) if isinstance(spec, dict) else {"nominal": spec}
        for part in self.parts:
            if part.stage not in STAGES:
                raise ModelError(f"part {part.name!r} has unknown stage {part.stage!r}")
        ordered = sorted(enumerate(self.parts), key=lambda ip: (STAGES.index(ip[1].stage), ip[0]))
        self._ordered = [p for _, p in ordered]

        params: list[Parameter] = []
        for part in self._ordered:
            params.extend(part.parameters)
        base = ParameterSet(params)  # raises on duplicates
        for pname, changes in self._overrides.items():
            base = base.replace(pname, **changes)
        self.params = base

        states: list[State] = []
        for part in self._ordered:
            states.extend(part.states)
        names = [s.name for s in states]
        if len(set(names)) != len(names):
            raise ModelError(f"duplicate state names in model {name!r}: {names}")
        if not states:
            raise ModelError(f"model {name!r} has no states")
        # Keep the mechanical states first: theta, omega, p is the order users expect.
        order = {"theta": 0, "omega": 1, "p": 2}
        self.states: tuple[State, ...] = tuple(
            sorted(states, key=lambda s: (order.get(s.name, 3), names.index(s.name)))
        )
        self.n_lags = max((part.n_lags for part in self.parts), default=0)
        self._cache: dict[float, dict[str, ca.Function]] = {}

    # -- description -------------------------------------------------------------
    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(p.name for p in self._ordered)})"

    @property
    def state_names(self) -> list[str]:
        """State names in state-vector order."""
        return [s.name for s in self.states]

    @property
    def nx(self) -> int:
        """Number of states."""
        return len(self.states)

    @property
    def n_params(self) -> int:
        """Number of parameters."""
        return len(self.params)

    def nominal(self) -> np.ndarray:
        """Nominal parameter vector, shape (n_params,)."""
        return self.params.nominal()

    def x0(self) -> np.ndarray:
        """Default initial state vector, shape (nx,)."""
        return np.array([s.initial for s in self.states], dtype=float)

    def part_names(self) -> list[str]:
        """Names of the parts, in assembly order."""
        return [p.name for p in self._ordered]

    def has_part(self, name: str) -> bool:
        """Whether a part called ``name`` is in the model."""
        return name in self.part_names()

    # -- derived models ------------------------------------------------------------
    def _derive(self, parts: Sequence[Part], overrides: dict[str, Any]) -> Model:
        new = Model.__new__(type(self))
        Model.__init__(new, parts, self.name, overrides)
        return new

    def with_parts(self, *parts: Part) -> Model:
        """A new model with ``parts`` added (effects, extra loads ...)."""
        keep = {k: v for k, v in self._overrides.items()}
        return self._derive(self.parts + tuple(parts), keep)

    def without(self, name: str) -> Model:
        """A new model without the part called ``name``."""
        if not self.has_part(name):
            raise ModelError(f"model has no part {name!r}; parts: {', '.join(self.part_names())}")
        parts = [p for p in self.parts if p.name != name]
        remaining = {p.name for part in parts for p in part.parameters}
        keep = {k: v for k, v in self._overrides.items() if k in remaining}
        return self._derive(parts, keep)

    def with_nominal(self, values: dict[str, float] | None = None, **kw: float) -> Model:
        """A new model whose nominal parameter values are replaced by name.

        Bounds widen when a value falls outside them (log parameters keep a
        factor of 10 around the new value), so that any physically valid value can
        become a nominal.
        """
        overrides = {k: dict(v) for k, v in self._overrides.items()}
        for pname, value in {**(values or {}), **kw}.items():
            par = self.params[pname]
            change = overrides.setdefault(pname, {})
            change["nominal"] = float(value)
            if value < par.lower:
                change["lower"] = value / GROUP_SPAN if par.scale == "log" else value - abs(value)
            if value > par.upper:
                change["upper"] = value * GROUP_SPAN if par.scale == "log" else value + abs(value)
        return self._derive(self.parts, overrides)

    def time_scaled(self, factor: float, time_unit: str | None = None) -> Model:
        """A new model whose nominal values and bounds describe time in units of ``1/factor`` s.

        Parameters whose unit is a power of seconds are scaled accordingly
        (``1/s`` by ``factor``, ``1/s^2`` by ``factor**2``, ``s`` by ``1/factor``).
        Used to fit records in sample units: with ``factor = 1/250`` the rig's
        nominal values become values per 4 ms sample. ``time_unit`` (e.g.
        ``"sample"``) replaces ``s`` in those parameters' unit strings.
        """
        if not (np.isfinite(factor) and factor > 0):
            raise ModelError(f"time scale factor must be positive, got {factor}")
        overrides = {k: dict(v) for k, v in self._overrides.items()}
        for par in self.params:
            power = _time_power(par.unit)
            if power == 0:
                continue
            k = factor ** power
            lo, hi = sorted((par.lower * k, par.upper * k))
            overrides[par.name] = {"nominal": par.nominal * k, "lower": lo, "upper": hi}
            if time_unit:
                overrides[par.name]["unit"] = re.sub(r"\bs\b", time_unit, par.unit)
        return self._derive(self.parts, overrides)

    # -- symbolic assembly -----------------------------------------------------------
    def symbols(self) -> tuple[ca.SX, ca.SX, ca.SX]:
        """Fresh symbols ``(x, u_lags, p)`` of shapes (nx,), (n_lags+1,), (n_params,)."""
        return (
            ca.SX.sym("x", self.nx),
            ca.SX.sym("u", self.n_lags + 1),
            ca.SX.sym("p", self.n_params),
        )

    def assemble(self, x: ca.SX, u_lags: ca.SX, p: ca.SX, dt: float) -> tuple[ca.SX, ca.SX]:
        """Symbolic ``(xdot, y)`` of the model for given symbols or expressions.

        Parameters
        ----------
        x : casadi.SX, shape (nx,)
            State.
        u_lags : casadi.SX, shape (n_lags + 1,)
            Current and past input samples.
        p : casadi.SX, shape (n_params,)
            Parameter vector.
        dt : float
            Sample period [s] (used by discrete-time input parts).
        """
        ctx = Context(
            {s.name: x[i] for i, s in enumerate(self.states)},
            {name: p[i] for i, name in enumerate(self.params.names)},
            u_lags,
            dt,
        )
        for part in self._ordered:
            part.apply(ctx)
        if "y" not in ctx.signals:
            raise ModelError(f"model {self.name!r} has no output part (stage 'output')")
        xdot = ca.vertcat(*[ctx.rates[s.name] for s in self.states])
        return xdot, ctx.signals["y"]

    def functions(self, dt: float) -> dict[str, ca.Function]:
        """CasADi functions of the model for sample period ``dt`` (cached).

        Returns
        -------
        dict
            ``"f"``: (x, u_lags, p) -> xdot; ``"h"``: (x, u_lags, p) -> y;
            ``"jac"``: (x, u_lags, p) -> d xdot / d x (for stability checks).
        """
        key = float(dt)
        if key not in self._cache:
            x, u, p = self.symbols()
            xdot, y = self.assemble(x, u, p, dt)
            self._cache[key] = {
                "f": ca.Function("f", [x, u, p], [xdot], ["x", "u", "p"], ["xdot"]),
                "h": ca.Function("h", [x, u, p], [y], ["x", "u", "p"], ["y"]),
                "jac": ca.Function("state_jac", [x, u, p], [ca.densify(ca.jacobian(xdot, x))],
                                   ["x", "u", "p"], ["A"]),
            }
        return self._cache[key]

    def linearize(
        self,
        p: np.ndarray | None = None,
        x: np.ndarray | None = None,
        u: float = 0.0,
        dt: float = 0.004,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Exact Jacobians ``(A, B, C, D)`` of the model at an operating point.

        Parameters
        ----------
        p : array, optional
            Parameter vector (nominal by default).
        x : array, optional
            State at which to linearise (rest, :meth:`x0`, by default).
        u : float
            Input at which to linearise (input units, default 0).
        dt : float
            Sample period [s] passed to discrete-time input parts.

        Returns
        -------
        A, B, C, D : ndarray
            ``dxdot/dx`` (nx, nx), ``dxdot/du`` (nx, 1), ``dy/dx`` (1, nx),
            ``dy/du`` (1, 1). With input lags the derivative with respect to all
            lags is summed (the static gain of a delayed input).
        """
        xs, us, ps = self.symbols()
        xdot, y = self.assemble(xs, us, ps, dt)
        jac = ca.Function(
            "lin", [xs, us, ps],
            [ca.jacobian(xdot, xs), ca.jacobian(xdot, us), ca.jacobian(y, xs), ca.jacobian(y, us)],
        )
        pv = self.nominal() if p is None else np.asarray(p, dtype=float)
        xv = self.x0() if x is None else np.asarray(x, dtype=float)
        uv = np.full(self.n_lags + 1, float(u))
        A, B, C, D = (np.array(m) for m in jac(xv, uv, pv))
        return A, B.sum(axis=1, keepdims=True), C, D.sum(axis=1, keepdims=True)

    # -- persistence -------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """JSON-able specification from which :meth:`from_json` rebuilds the model."""
        parts = []
        for part in self.parts:
            args = {f.name: getattr(part, f.name) for f in fields(part)} if fields(part) else {}
            parts.append({"type": type(part).__name__, "args": _jsonable(args)})
        return {
            "class": type(self).__name__,
            "name": self.name,
            "parts": parts,
            "overrides": self._overrides,
        }

    @classmethod
    def from_json(cls, spec: dict[str, Any]) -> Model:
        """Rebuild a model saved with :meth:`to_json`."""
        try:  # the effect library registers its parts on import
            import hhra_phys.effects  # noqa: F401
        except ModuleNotFoundError as exc:
            if exc.name != "hhra_phys.effects":
                raise

        parts = []
        for entry in spec["parts"]:
            typ = PART_TYPES.get(entry["type"])
            if typ is None:
                raise ModelError(
                    f"unknown part type {entry['type']!r} in saved model; "
                    f"known: {', '.join(sorted(PART_TYPES))}"
                )
            args = {k: tuple(v) if isinstance(v, list) else v for k, v in entry["args"].items()}
            parts.append(typ(**args))
        target = HHRAModel if spec.get("class") == "HHRAModel" else Model
        new = Model.__new__(target)
        Model.__init__(new, parts, spec.get("name", "model"), spec.get("overrides"))
        return new


def _time_power(unit: str) -> int:
    """Power of 1/s in a unit string: ``"1/s"`` -> 1, ``"rad/s^2"`` -> 2, ``"s"`` -> -1."""
    u = unit.replace(" ", "")
    if u == "s":
        return -1
    if re.search(r"/\(?s\^2\b", u):
        return 2
    if re.search(r"/\(?s\b", u):
        return 1
    return 0


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if hasattr(obj, "__dataclass_fields__"):
        return _jsonable(asdict(obj))
    return obj


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
    values of the built-in simulated rig (:class:`hhra_phys.physical.PhysicalParameters`).

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
        parts: list[Part] = [CurrentCommand()]
        if spool_lag:
            parts.append(SpoolLag())
        parts.append(OrificeValve() if valve == "orifice" else LinearValve())
        parts += [ChamberPressure(), RotaryMotion()]
        parts.append(AngleOutput() if output == "angle" else PressureOutput())
        parts += list(effects)
        super().__init__(parts, name="hhra")
        if nominal:
            derived = self.with_nominal(nominal)
            self.params = derived.params
            self._overrides = derived._overrides

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
        kp = d.get("g_kp", 0.0)
        leak = d["g_leak"] + kp
        return {
            "a": 1.0,
            "b": d["g_damping"] + leak,
            "c": d["g_damping"] * leak + d["g_torque"] * d["g_compress"],
            "kv": d["g_torque"] * d["g_valve"],
        }
