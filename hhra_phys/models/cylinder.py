"""The valve-controlled double-acting linear cylinder (second bundled model).

Physics
-------
A 4-way critical-centre servo valve drives a symmetric (double-rod) cylinder:
both chambers have the same annulus area ``A_p``, so the piston force is
``A_p (p1 - p2) = A_p P_L`` and, at mid-stroke, both chambers hold half of the
total volume ``V_t``. The textbook equations (Merritt, *Hydraulic Control
Systems*, sections 2.6 and 5.2; the same form as the HHRA's) are::

    servo valve      Q_L = k_q x_v sqrt(p_s - sign(x_v) P_L),   x_v = k_x I
    continuity       Q_L = A_p dx/dt + C_tp P_L + V_t/(4 beta_e) dP_L/dt
    load balance     m d2x/dt2 = A_p P_L - B_p dx/dt - K x - F_L

with ``k_q = C_d w sqrt(1/rho)`` (discharge coefficient, area gradient, oil
density), ``C_tp`` the internal (cross-piston) leakage coefficient, ``B_p`` the
viscous friction of piston, rod seals and load guides, ``K`` a load spring and
``F_L`` a constant load force. The continuity equation is the sum of the two
chambers' equations ``Q1 = A_p v + C_tp P_L + V1/beta_e dp1/dt`` and
``Q2 = A_p v + C_tp P_L - V2/beta_e dp2/dt`` with ``V1 = V2 = V_t/2`` and
``Q_L = (Q1 + Q2)/2`` (the usual mid-stroke approximation; the chamber volumes
change with ``x`` by at most ``A_p * stroke/2``, which the constant ``V_t``
ignores, as does the HHRA model). Dividing the continuity equation by
``p_s V_t/(4 beta_e)`` and the load balance by ``m``, and normalising the load
pressure, ``p = P_L/p_s``, gives the three-state model simulated here::

    dx/dt = v
    dv/dt = c_force p - c_damping v - c_spring x - c_load
    dp/dt = c_valve I sqrt(1 - sign(I) p) - c_compress v - c_leak p

with the identifiable groups (all SI, ``I`` in mA)::

    c_force    = A_p p_s / m                         [m/s^2]    acceleration at full p_s
    c_damping  = B_p / m                             [1/s]      viscous damping rate
    c_spring   = K / m                               [1/s^2]    load stiffness (held 0)
    c_load     = F_L / m                             [m/s^2]    constant load (held 0)
    c_compress = 4 beta_e A_p / (V_t p_s)            [1/m]      pressure change per metre
    c_leak     = 4 beta_e C_tp / V_t                 [1/s]      leakage decay rate
    c_valve    = 4 beta_e k_q k_x / (V_t sqrt(p_s))  [1/(s mA)] valve flow gain
    c_kp       = 4 beta_e k_pa / V_t                 [1/s]      flow-pressure gain (linear valve)

The ``c_`` prefix keeps them apart from the HHRA's ``g_*`` groups, whose
meanings (angles, torques) differ. The linearised valve replaces the orifice law
by ``c_valve I - c_kp p``.

Linearisation and transfer function
-----------------------------------
At rest (``I = 0``, ``p = 0``) the orifice valve has flow gain ``c_valve`` and
flow-pressure gain 0; with ``k_p = c_kp`` for the linear valve (0 otherwise)
and ``L = c_leak + k_p``, eliminating ``v`` and ``p`` gives::

    x(s)/I(s) = c_force c_valve / (s^3 + (c_damping + L) s^2
                                   + (c_spring + c_damping L + c_force c_compress) s + c_spring L)

For ``c_spring = 0`` it is an integrator times a second-order lag: the poles are
0 and ``-(c_damping + L)/2 +- j sqrt(w^2 - ((c_damping + L)/2)^2)`` with
``w^2 = c_damping L + c_force c_compress``, the hydraulic natural frequency
``w_h = sqrt(c_force c_compress) = sqrt(4 beta_e A_p^2 / (V_t m))``, and the
steady velocity per mA is ``c_force c_valve / w^2 ~ c_valve / c_compress``
(valve flow over piston area). The output is the position in mm, so the
measured transfer function is 1000 times this one.

Nominal cylinder (:class:`CylinderPhysical`)
-------------------------------------------
An industrial servo axis: bore 80 mm, double rod 45 mm (``A_p`` = 34.4 cm^2),
stroke 500 mm, 0.5 L of oil in lines and manifold per side (``V_t`` = 2.72 L),
800 kg moving mass, ``B_p`` = 16 kN s/m, 16 MPa supply, effective bulk modulus
1.0 GPa (oil with hoses), cross-piston leakage 2.5e-12 m^3/(s Pa) (about
1.5 L/min at 100 bar: a worn seal), and a valve of about 60 L/min at 10 mA and
full supply pressure drop (``k_x`` = 60 um/mA on a 20 mm area gradient). This
gives ``w_h`` = 147 rad/s (23 Hz), damping ratio 0.08 and 29 mm/s per mA.

Identifiability from (current, position) is that of the HHRA (``docs/model.md``):
with the orifice valve the square root fixes the pressure scale, so all five
positive groups are identifiable when the record drives the load pressure to a
sizeable fraction of ``p_s``; ``c_damping`` and ``c_leak`` are told apart only
through their product (``c_damping c_leak`` against ``c_force c_compress`` in
the ``s`` coefficient) and the orifice law, so their intervals are the widest.
With the linearised valve only the transfer-function ratios are identifiable.

States: ``x`` [m], ``v`` [m/s], ``p`` [-]. Input: valve current [mA] (zero-order
hold). Output: piston position [mm] (``PositionOutput``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, ClassVar, Literal

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.errors import ModelError, ParameterError
from hhra_phys.excitation import irregular_steps, samples
from hhra_phys.model import DerivedQuantity, Model
from hhra_phys.models.hydraulics import orifice_flow, perturb_fields
from hhra_phys.parameters import Parameter
from hhra_phys.parts import Context, Part, State, register_part

__all__ = [
    "CylinderPhysical",
    "cylinder_parameter",
    "CylinderOrificeValve",
    "CylinderLinearValve",
    "CylinderChambers",
    "LinearMotion",
    "PositionOutput",
    "LinearCylinderModel",
    "CYLINDER_STAGES",
    "DEFAULT_FIXED",
    "DEFAULT_FREE",
    "position_estimate",
    "pressure_estimate",
    "cylinder_input",
    "perturbed_physical",
    "simulate_cylinder",
]

#: Metres to millimetres (the output unit).
MM_PER_M = 1000.0


# --- the physical view ------------------------------------------------------------


@dataclass(frozen=True)
class CylinderPhysical:
    """Physical symbols of the valve-controlled symmetric cylinder, SI units; ``I`` in mA.

    The defaults are the nominal industrial servo axis of the module docstring.

    Attributes
    ----------
    bore : piston diameter [m]
    rod : rod diameter (both sides, double-rod cylinder) [m]
    stroke : full stroke [m]; mid-stroke is ``x = 0``
    V_dead : oil volume of lines and manifold per side [m^3]
    m : moving mass (piston, rods, load) [kg]
    B_p : viscous friction coefficient [N*s/m]
    K : load spring stiffness [N/m]
    F_L : constant load force, opposing positive ``x`` [N]
    beta_e : effective bulk modulus [Pa]
    C_tp : internal leakage coefficient [m^3/(s*Pa)]
    p_s : supply pressure [Pa] (tank at 0)
    k_x : spool displacement per valve current [m/mA]
    C_d : discharge coefficient [-]
    w : area gradient of the spool [m]
    rho : oil density [kg/m^3]
    """

    bore: float = 0.080
    rod: float = 0.045
    stroke: float = 0.5
    V_dead: float = 0.5e-3
    m: float = 800.0
    B_p: float = 16000.0
    K: float = 0.0
    F_L: float = 0.0
    beta_e: float = 1.0e9
    C_tp: float = 2.5e-12
    p_s: float = 16.0e6
    k_x: float = 6.0e-5
    C_d: float = 0.61
    w: float = 0.02
    rho: float = 850.0

    def __post_init__(self) -> None:
        for f in fields(self):
            if not math.isfinite(getattr(self, f.name)):
                raise ParameterError(f"cylinder parameter {f.name!r} must be finite")
        for name in ("bore", "stroke", "m", "beta_e", "p_s", "k_x", "C_d", "w", "rho"):
            if getattr(self, name) <= 0:
                raise ParameterError(f"cylinder parameter {name!r} must be positive")
        for name in ("rod", "V_dead", "B_p", "C_tp"):
            if getattr(self, name) < 0:
                raise ParameterError(f"cylinder parameter {name!r} must be >= 0")
        if self.rod >= self.bore:
            raise ParameterError(
                f"rod ({self.rod} m) must be thinner than the bore ({self.bore} m)"
            )

    # -- derived quantities ------------------------------------------------------------
    @property
    def A_p(self) -> float:
        """Annulus area of each side ``pi/4 (bore^2 - rod^2)`` [m^2]."""
        return 0.25 * math.pi * (self.bore**2 - self.rod**2)

    @property
    def V_t(self) -> float:
        """Total oil volume of both chambers and lines ``A_p stroke + 2 V_dead`` [m^3]."""
        return self.A_p * self.stroke + 2.0 * self.V_dead

    @property
    def k_q(self) -> float:
        """Orifice flow gain ``C_d w sqrt(1/rho)`` [m^2/sqrt(kg/m^3)]."""
        return self.C_d * self.w * math.sqrt(1.0 / self.rho)

    @property
    def K_v(self) -> float:
        """Valve flow coefficient ``k_q k_x`` [m^3/(s*mA*Pa^0.5)]."""
        return self.k_q * self.k_x

    @property
    def compliance(self) -> float:
        """Hydraulic capacitance ``V_t / (4 beta_e)`` [m^3/Pa]."""
        return self.V_t / (4.0 * self.beta_e)

    def natural_frequency(self) -> float:
        """Hydraulic natural frequency ``sqrt(A_p^2 / (C_h m))`` [rad/s] (no spring)."""
        return math.sqrt(self.A_p**2 / (self.compliance * self.m))

    def velocity_gain(self) -> float:
        """Steady no-load velocity per valve current at rest, ``K_v sqrt(p_s)/A_p`` [m/(s*mA)]."""
        return self.K_v * math.sqrt(self.p_s) / self.A_p

    # -- the two views -------------------------------------------------------------------
    def groups(self, k_pa: float = 0.0) -> dict[str, float]:
        """The identifiable groups (module docstring) by name, in their units.

        Parameters
        ----------
        k_pa : float
            Flow-pressure gain of the linearised valve [m^3/(s*Pa)] (for ``c_kp``).
        """
        ch, ps = self.compliance, self.p_s
        return {
            "c_force": self.A_p * ps / self.m,
            "c_damping": self.B_p / self.m,
            "c_spring": self.K / self.m,
            "c_load": self.F_L / self.m,
            "c_compress": self.A_p / (ch * ps),
            "c_leak": self.C_tp / ch,
            "c_valve": self.K_v / (ch * math.sqrt(ps)),
            "c_kp": k_pa / ch,
        }

    def from_groups(self, groups: Mapping[str, float]) -> CylinderPhysical:
        """Physical parameters that reproduce ``groups``, one symbol solved per group.

        The geometry, supply pressure and valve orifice (``C_d``, ``w``, ``rho``)
        come from ``self`` (a datasheet); :data:`SOLVED_BY_GROUP` says which symbol
        each group determines. ``c_force`` (mass) and ``c_compress`` (bulk
        modulus) are solved first because the other groups depend on them.
        ``c_kp`` is not a physical constant (it depends on the operating point)
        and is ignored.
        """
        unknown = set(groups) - set(SOLVED_BY_GROUP) - {"c_kp"}
        if unknown:
            raise ParameterError(f"unknown cylinder groups {sorted(unknown)}")
        g = {**self.groups(), **{k: float(v) for k, v in groups.items()}}
        for name in ("c_force", "c_compress", "c_valve"):
            if not g[name] > 0:
                raise ParameterError(f"group {name} must be positive, got {g[name]}")
        m = self.A_p * self.p_s / g["c_force"]
        beta_e = g["c_compress"] * self.V_t * self.p_s / (4.0 * self.A_p)
        ch = self.V_t / (4.0 * beta_e)
        return replace(
            self,
            m=m,
            B_p=g["c_damping"] * m,
            K=g["c_spring"] * m,
            F_L=g["c_load"] * m,
            beta_e=beta_e,
            C_tp=g["c_leak"] * ch,
            k_x=g["c_valve"] * ch * math.sqrt(self.p_s) / self.k_q,
        )

    def plant(self) -> dict[str, float]:
        """SI values for :mod:`hhra_phys.reference.cylinder` (its ``PARAMETERS``)."""
        return {
            "A_p": self.A_p, "m": self.m, "B_p": self.B_p, "K": self.K, "F_L": self.F_L,
            "V_t": self.V_t, "beta_e": self.beta_e, "C_tp": self.C_tp, "p_s": self.p_s,
            "K_v": self.K_v,
        }

    def to_dict(self) -> dict[str, float]:
        """The symbols as a plain dict (JSON metadata)."""
        return asdict(self)


#: Which physical symbol :meth:`CylinderPhysical.from_groups` solves for, per group.
SOLVED_BY_GROUP: dict[str, str] = {
    "c_force": "m",
    "c_damping": "B_p",
    "c_spring": "K",
    "c_load": "F_L",
    "c_compress": "beta_e",
    "c_leak": "C_tp",
    "c_valve": "k_x",
}

#: Nominal identifiable groups: those of the nominal cylinder.
NOMINAL_GROUPS: dict[str, float] = CylinderPhysical().groups()
# The linearised valve's flow-pressure gain is 0 at rest; give it its value at
# 1 mA and rest (k_q k_x I / (2 sqrt(p_s)) in groups: c_valve * 1 mA / 2) so that
# its log-scaled box is meaningful.
NOMINAL_GROUPS["c_kp"] = 0.5 * NOMINAL_GROUPS["c_valve"]

#: Groups meant to be held fixed (at 0: no spring, no load) unless freed explicitly.
DEFAULT_FIXED: tuple[str, ...] = ("c_spring", "c_load")
#: The cylinder's stages, in the order they run (names of its own: stages are free).
CYLINDER_STAGES: tuple[str, ...] = ("valve", "chambers", "load", "sensor")
#: The positive groups a fit frees by default for the orifice valve.
DEFAULT_FREE: tuple[str, ...] = ("c_force", "c_damping", "c_compress", "c_leak", "c_valve")

_GROUP_SPECS: dict[str, tuple[str, str, str]] = {
    # name: (unit, scale, description)
    "c_force": ("m/s^2", "log", "A_p*p_s/m: acceleration at full supply pressure"),
    "c_damping": ("1/s", "log", "B_p/m: viscous damping rate"),
    "c_spring": ("1/s^2", "linear", "K/m: load stiffness (0 by default)"),
    "c_load": ("m/s^2", "linear", "F_L/m: constant load force (0 by default)"),
    "c_compress": ("1/m", "log", "4*beta_e*A_p/(V_t*p_s): normalised pressure per metre"),
    "c_leak": ("1/s", "log", "4*beta_e*C_tp/V_t: internal leakage rate"),
    "c_valve": ("1/(s*mA)", "log", "4*beta_e*k_q*k_x/(V_t*sqrt(p_s)): valve flow gain"),
    "c_kp": ("1/s", "log", "4*beta_e*k_pa/V_t: linearised flow-pressure gain"),
}

#: Bounds of each positive group as a factor around its nominal value.
GROUP_SPAN = 10.0
#: Symmetric absolute bounds of the signed groups: a spring up to a tenth of the
#: nominal hydraulic stiffness (w_h^2 / 10) and a load up to the supply-pressure force.
_SIGNED_BOUNDS: dict[str, float] = {
    "c_spring": 0.1 * NOMINAL_GROUPS["c_force"] * NOMINAL_GROUPS["c_compress"],
    "c_load": NOMINAL_GROUPS["c_force"],
}


def cylinder_parameter(name: str, nominal: float | None = None) -> Parameter:
    """The :class:`Parameter` of cylinder group ``name``.

    Positive (log-scaled) groups get the box nominal/10 .. nominal*10; the spring
    and load groups get symmetric absolute bounds (:data:`_SIGNED_BOUNDS`).
    """
    unit, scale, desc = _GROUP_SPECS[name]
    nom = NOMINAL_GROUPS[name] if nominal is None else float(nominal)
    if scale == "log":
        lo, hi = nom / GROUP_SPAN, nom * GROUP_SPAN
    else:
        lim = max(_SIGNED_BOUNDS[name], 2.0 * abs(nom))
        lo, hi = -lim, lim
    return Parameter(name, unit, nom, lo, hi, scale, desc)  # type: ignore[arg-type]


# --- the parts ------------------------------------------------------------------------


@dataclass(frozen=True)
class CylinderOrificeValve(Part):
    """4-way critical-centre valve, orifice law: ``q = c_valve I sqrt(1 - sign(I) p)``.

    In normalised pressure per second (``Q_L`` divided by ``p_s V_t/(4 beta_e)``).
    The sign and root are smoothed like the HHRA's valve (``sign_eps`` [mA],
    ``sqrt_delta`` [-]) so CasADi derivatives exist everywhere; beyond the supply
    pressure the signed root reverses the flow. Sets signal ``flow``.
    """

    sign_eps: float = 1e-3
    sqrt_delta: float = 1e-6
    stage: ClassVar[str] = "valve"
    name: ClassVar[str] = "cylinder_orifice_valve"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (cylinder_parameter("c_valve"),)

    def apply(self, ctx: Context) -> None:
        # the valve current, after any input-side effect
        ctx.signals["flow"] = orifice_flow(ctx.u, ctx.x["p"], ctx.p["c_valve"], self.sign_eps,
                                           self.sqrt_delta)


@dataclass(frozen=True)
class CylinderLinearValve(Part):
    """Linearised valve ``q = c_valve I - c_kp p`` (flow gain and flow-pressure gain)."""

    stage: ClassVar[str] = "valve"
    name: ClassVar[str] = "cylinder_linear_valve"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (cylinder_parameter("c_valve"), cylinder_parameter("c_kp"))

    def apply(self, ctx: Context) -> None:
        cmd = ctx.u  # the valve current, after any input-side effect
        ctx.signals["flow"] = ctx.p["c_valve"] * cmd - ctx.p["c_kp"] * ctx.x["p"]


@dataclass(frozen=True)
class CylinderChambers(Part):
    """Flow continuity of both chambers: ``dp/dt = flow - c_compress v - c_leak p``.

    ``c_compress v`` is the displacement flow of the moving piston, ``c_leak p``
    the cross-piston leakage (normalised pressure per second). Adds state ``p``.
    """

    stage: ClassVar[str] = "chambers"
    name: ClassVar[str] = "cylinder_chambers"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (cylinder_parameter("c_compress"), cylinder_parameter("c_leak"))

    @property
    def states(self) -> Sequence[State]:
        return (State("p", "-", 0.0, "load pressure (p1 - p2) / supply pressure p_s",
                      role="effort"),)

    def apply(self, ctx: Context) -> None:
        ctx.add_rate("p", ctx.signal("flow", self.name))
        ctx.add_rate("p", -ctx.p["c_compress"] * ctx.x["v"] - ctx.p["c_leak"] * ctx.x["p"])


@dataclass(frozen=True)
class LinearMotion(Part):
    """Load balance of piston and load: ``dv/dt = c_force p - c_damping v - c_spring x - c_load``.

    Adds states ``x`` [m] (0 at mid-stroke) and ``v`` [m/s]. The spring and load
    groups are parameters but meant to be held fixed (:data:`DEFAULT_FIXED`).
    """

    stage: ClassVar[str] = "load"
    name: ClassVar[str] = "linear_motion"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return tuple(cylinder_parameter(n)
                     for n in ("c_force", "c_damping", "c_spring", "c_load"))

    @property
    def states(self) -> Sequence[State]:
        return (
            State("x", "m", 0.0, "piston position from mid-stroke", scale=0.02,
                  role="position"),
            State("v", "m/s", 0.0, "piston velocity", role="velocity"),
        )

    def apply(self, ctx: Context) -> None:
        x, p = ctx.x, ctx.p
        ctx.add_rate("x", x["v"])
        ctx.add_rate(
            "v",
            p["c_force"] * x["p"] - p["c_damping"] * x["v"] - p["c_spring"] * x["x"] - p["c_load"],
        )


@dataclass(frozen=True)
class PositionOutput(Part):
    """Measured output: the piston position in millimetres."""

    stage: ClassVar[str] = "sensor"
    name: ClassVar[str] = "position_output"

    def apply(self, ctx: Context) -> None:
        ctx.signals["y"] = MM_PER_M * ctx.x["x"]


# Registered so that saved fits containing these parts load again (a loop, not a
# decorator, keeps the classes' own types for type checkers).
for _cls in (CylinderOrificeValve, CylinderLinearValve, CylinderChambers, LinearMotion,
             PositionOutput):
    register_part(_cls)


# --- the model ---------------------------------------------------------------------------


class LinearCylinderModel(Model):
    """Valve-controlled double-acting (symmetric) linear cylinder.

    Parameters
    ----------
    valve : {"orifice", "linear"}
        Valve law: the orifice law (default) or the linearised law.
    effects : iterable of Part
        Further parts (they must use the cylinder's states ``x``, ``v``, ``p``).
    nominal : dict, optional
        Nominal values to use instead of the nominal cylinder's, by parameter name.

    Notes
    -----
    States ``x`` [m], ``v`` [m/s], ``p`` [-]; input valve current [mA]
    (zero-order hold); output position [mm]. Parameters: the groups
    ``c_valve`` (and ``c_kp``), ``c_compress``, ``c_leak``, ``c_force``,
    ``c_damping``, ``c_spring``, ``c_load`` (module docstring); ``c_spring`` and
    ``c_load`` are held fixed by a fit unless freed (:data:`DEFAULT_FIXED`, the
    model's ``held``). Stages ``valve -> chambers -> load -> sensor``.

    Examples
    --------
    >>> from hhra_phys.models.cylinder import LinearCylinderModel
    >>> LinearCylinderModel().params.names[:3]
    ['c_valve', 'c_compress', 'c_leak']
    """

    def __init__(
        self,
        valve: Literal["orifice", "linear"] = "orifice",
        effects: Iterable[Part] = (),
        nominal: dict[str, float] | None = None,
    ) -> None:
        if valve not in ("orifice", "linear"):
            raise ModelError(f"valve must be 'orifice' or 'linear', got {valve!r}")
        # Listed load first so that the state vector reads x, v, p; the stages fix
        # the order the parts run in (the valve's flow before the chambers).
        parts: list[Part] = [
            LinearMotion(),
            CylinderChambers(),
            CylinderOrificeValve() if valve == "orifice" else CylinderLinearValve(),
            PositionOutput(),
            *effects,
        ]
        # Records start at rest: only the measured position's initial value is fitted.
        super().__init__(parts, stages=CYLINDER_STAGES, name="cylinder", pinned=("v", "p"),
                         held=DEFAULT_FIXED)
        if nominal:
            derived = self.with_nominal(nominal)
            self.params = derived.params
            self._overrides = derived._overrides

    @property
    def valve(self) -> str:
        """``"orifice"`` or ``"linear"``."""
        return "linear" if self.has_part("cylinder_linear_valve") else "orifice"

    def tf_coefficients_of(self, values: Mapping[str, float]) -> dict[str, float]:
        """:meth:`tf_coefficients` from fitted values by name (``{}`` if any is missing)."""
        try:
            return self.tf_coefficients(np.array([values[n] for n in self.params.names]))
        except (KeyError, ParameterError):
            return {}

    def tf_coefficients(self, p: np.ndarray | None = None) -> dict[str, float]:
        """Transfer function at rest ``x/I = kv / (s^3 + b s^2 + c s + d)`` (``a = 1``).

        Units: ``x`` in m (the output in mm is ``1000 x``), ``I`` in mA; ``b``
        [1/s], ``c`` [1/s^2], ``d`` [1/s^3], ``kv`` [m/(s^3 mA)]. See the module
        docstring for the derivation.

        Parameters
        ----------
        p : array, shape (n_params,), optional
            Parameter vector (nominal by default).
        """
        g = self.params.as_dict(self.nominal() if p is None else np.asarray(p, dtype=float))
        return {k: float(q.function(g)) for k, q in self.derived_quantities().items()}

    def derived_quantities(self) -> dict[str, DerivedQuantity]:
        """The transfer-function coefficients of :meth:`tf_coefficients` as functions of
        the groups, reported by a fit with 95 % intervals (the delta method)."""
        def leak(g: Mapping[str, Any]) -> Any:
            return g["c_leak"] + g.get("c_kp", 0.0)

        return {
            "a": DerivedQuantity("-", lambda g: 1.0,
                                 "s^3 coefficient of G(s), 1 by normalisation"),
            "b": DerivedQuantity("1/s", lambda g: g["c_damping"] + leak(g),
                                 "s^2 coefficient of G(s)", positive=True),
            "c": DerivedQuantity("1/s^2", lambda g: g["c_spring"] + g["c_damping"] * leak(g)
                                 + g["c_force"] * g["c_compress"], "s coefficient of G(s)",
                                 positive=True),
            "d": DerivedQuantity("1/s^3", lambda g: g["c_spring"] * leak(g),
                                 "s^0 coefficient of G(s)"),
            "kv": DerivedQuantity("m/(s^3*mA)", lambda g: g["c_force"] * g["c_valve"],
                                  "gain of G(s) (x in m, current in mA)", positive=True),
        }


# --- the simulated record ---------------------------------------------------------------

#: Default position noise (standard deviation) of the simulated record [mm]
#: (a magnetostrictive position sensor's noise is of this order).
DEFAULT_NOISE_MM = 0.05
#: Largest valve current of the default excitation [mA], before the stroke and
#: pressure limits below scale it down (estimated on the simulated plant).
DEFAULT_AMPLITUDE_MA = 8.0
#: Aimed hold length of the excitation's steps [s]: about two periods of the
#: hydraulic resonance, shorter than a settling time (0.3 s), so that the piston
#: travels little per step while every step shows the resonance.
DEFAULT_HOLD_S = 0.1
#: The input is scaled down if a linear estimate of the position leaves this
#: fraction of the half stroke (the rest is margin for the nonlinear plant).
STROKE_FRACTION = 0.6
#: ... or if a linear estimate of the load-pressure peak at a step exceeds this
#: fraction of the supply pressure: enough to make the orifice law (and so the
#: pressure scale) identifiable, without driving a chamber towards cavitation.
PRESSURE_FRACTION = 0.6


def position_estimate(
    u: np.ndarray, fs: float, physical: CylinderPhysical | None = None
) -> np.ndarray:
    """Linear estimate of the position [mm] a current record drives from mid-stroke.

    Steady no-load velocity per mA (:meth:`CylinderPhysical.velocity_gain`) times
    the running integral of the current; the orifice law only lowers the speed
    under load, so this bounds the travel of a step-like input well.
    """
    gain = (physical or CylinderPhysical()).velocity_gain()
    return MM_PER_M * gain * np.concatenate(([0.0], np.cumsum(u)[:-1])) / fs


def pressure_estimate(u: np.ndarray, physical: CylinderPhysical | None = None) -> float:
    """Linear estimate of the largest load-pressure swing ``|P_L|/p_s`` [-] of a step input.

    A step of the current changes the steady velocity by ``dv = velocity_gain * dI``;
    the undamped hydraulic resonance then carries a pressure swing of
    ``dv * sqrt(m/C_h) / p_s`` (kinetic energy of the mass into the oil spring).
    Damping makes the real peak smaller, so this bounds it.
    """
    phys = physical or CylinderPhysical()
    jump = float(np.max(np.abs(np.diff(u)))) if u.size > 1 else 0.0
    jump = max(jump, float(np.abs(u[0])) if u.size else 0.0)  # the start from rest
    return jump * phys.velocity_gain() * math.sqrt(phys.m / phys.compliance) / phys.p_s


def cylinder_input(
    duration: float = 20.0,
    fs: float = 250.0,
    seed: int | np.random.Generator | None = 0,
    amplitude: float = DEFAULT_AMPLITUDE_MA,
    levels: int = 4,
    hold: float = DEFAULT_HOLD_S,
    physical: CylinderPhysical | None = None,
) -> np.ndarray:
    """Valve current [mA] for the cylinder: zero-mean multi-level steps kept inside the stroke.

    A double-acting cylinder integrates the current, so the input must not drift
    the piston into its end stops. This uses a zero-mean input, no position
    feedback (the record stays an open-loop experiment, which the model
    describes without a controller): :func:`hhra_phys.excitation.irregular_steps`,
    the inverse-repeat M-sequence with several levels, whose second half of
    every period mirrors the first, so the travel returns near its start at the
    end of every period. Periods are chosen so the holds last about ``hold``
    seconds, and the whole signal is scaled down if the linear position estimate
    (:func:`position_estimate`) leaves ``STROKE_FRACTION`` of the half stroke or
    the pressure estimate (:func:`pressure_estimate`) exceeds
    ``PRESSURE_FRACTION`` of the supply pressure.

    Parameters
    ----------
    duration : float
        Record length [s] (at least 30 holds).
    fs : float
        Sample rate [Hz].
    seed : int, Generator or None
        Drives hold lengths and level order.
    amplitude : float
        Largest current [mA].
    levels : int
        Number of amplitude levels.
    hold : float
        Aimed mean hold length [s].
    physical : CylinderPhysical, optional
        Plant used for the position estimate (default: the nominal cylinder).

    Returns
    -------
    ndarray, shape (round(duration*fs),)
    """
    phys = physical or CylinderPhysical()
    n = samples(duration, fs)
    periods = max(1, int(round(duration / (30.0 * hold))))
    u = irregular_steps(n, levels=levels, amplitude=amplitude, n_periods=periods, seed=seed)
    reach = float(np.max(np.abs(position_estimate(u, fs, phys))))
    scale = min(1.0, STROKE_FRACTION * 0.5 * phys.stroke * MM_PER_M / reach,
                PRESSURE_FRACTION / pressure_estimate(u, phys))
    return u * scale


def perturbed_physical(
    seed: int | np.random.Generator | None = 0,
    spread: float = 2.0,
    min_factor: float = 1.3,
    base: CylinderPhysical | None = None,
) -> CylinderPhysical:
    """A cylinder whose groups lie away from the model's nominal values and box centre.

    Multiplies the mass ``m``, friction ``B_p``, bulk modulus ``beta_e``, valve
    gain ``k_x`` and leakage ``C_tp`` by log-uniform factors of magnitude in
    ``[min_factor, spread]``, each up or down at random (recovery tests with the truth at the
    nominal values or the box centre would flatter a search drawn to its coordinate origin:
    ``docs/benchmarks.md``, "What the tables show", point 6).
    """
    return perturb_fields(base or CylinderPhysical(), ("m", "B_p", "beta_e", "k_x", "C_tp"),
                          seed, spread, min_factor)


def simulate_cylinder(
    seed: int = 0,
    duration: float = 20.0,
    fs: float = 250.0,
    noise: float = DEFAULT_NOISE_MM,
    truth: CylinderPhysical | Mapping[str, float] | None = None,
    amplitude: float = DEFAULT_AMPLITUDE_MA,
    levels: int = 4,
    hold: float = DEFAULT_HOLD_S,
    u: np.ndarray | None = None,
    rtol: float = 1e-10,
    coulomb: float = 0.0,
    coulomb_width: float = 1e-3,
) -> Dataset:
    """A simulated record of the cylinder, from the independent reference implementation.

    The plant is integrated by :mod:`hhra_phys.reference.cylinder` (SciPy, exact
    zero-order hold, physical SI variables), not by the package model, so a fit
    to this record also checks the model's equations.

    Parameters
    ----------
    seed : int
        Seeds one ``numpy.random.default_rng``, which draws the excitation and
        then the noise.
    duration : float
        Record length [s].
    fs : float
        Sample rate [Hz].
    noise : float
        Standard deviation of the Gaussian position noise [mm].
    truth : CylinderPhysical or dict, optional
        The plant: physical symbols, or groups by name (solved into symbols with
        the nominal cylinder as datasheet, :meth:`CylinderPhysical.from_groups`).
        Default: the nominal cylinder.
    amplitude, levels, hold
        Excitation (:func:`cylinder_input`).
    u : array, optional
        Use this valve current [mA] instead.
    rtol : float
        Relative tolerance of the reference integration.
    coulomb : float
        Coulomb friction force of the seals [N], ``coulomb*tanh(v/coulomb_width)``
        against the motion (0: none). The model has no such part: a record with it is
        one the diagnosis should complete (``metadata["coulomb"]``).
    coulomb_width : float
        Its switching velocity [m/s].

    Returns
    -------
    Dataset
        ``t`` [s], ``u`` [mA], ``y`` [mm] from mid-stroke, starting at rest at
        ``x = 0``; ``metadata["truth"]``: the true groups by parameter name
        (``c_kp`` excluded: the plant has the orifice valve); also
        ``physical`` (SI symbols), ``noise_mm``, ``seed``, ``max_abs_position_mm``
        and ``max_abs_pressure`` (largest ``|P_L|/p_s``).
    """
    from hhra_phys.reference.cylinder import simulate_cylinder_reference

    if not (math.isfinite(noise) and noise >= 0):
        raise ParameterError(f"noise must be a non-negative standard deviation in mm, got {noise}")
    if not (math.isfinite(coulomb) and coulomb >= 0):
        raise ParameterError(f"coulomb must be a friction force >= 0 N, got {coulomb}")
    if not (math.isfinite(coulomb_width) and coulomb_width > 0):
        raise ParameterError(f"coulomb_width must be a velocity > 0 m/s, got {coulomb_width}")
    if truth is None:
        phys = CylinderPhysical()
    elif isinstance(truth, CylinderPhysical):
        phys = truth
    else:
        phys = CylinderPhysical().from_groups(truth)
    rng = np.random.default_rng(seed)
    if u is None:
        u = cylinder_input(duration, fs, rng, amplitude, levels, hold, phys)
    else:
        u = np.asarray(u, dtype=float)
    plant = dict(phys.plant(), **({"F_c": coulomb, "v_c": coulomb_width} if coulomb else {}))
    states = simulate_cylinder_reference(u, fs, plant, rtol=rtol)
    y_true = MM_PER_M * states[:, 0]
    if not np.isfinite(y_true).all():
        raise ParameterError("the cylinder could not be simulated; check the parameters")
    y = y_true + noise * rng.standard_normal(u.size)
    groups = {k: v for k, v in phys.groups().items() if k != "c_kp"}
    meta: dict[str, Any] = {
        "generator": "hhra_phys.models.cylinder.simulate_cylinder",
        "model": "LinearCylinderModel",
        "seed": seed,
        "noise_mm": noise,
        "truth": groups,
        "physical": phys.to_dict(),
        "max_abs_position_mm": float(np.max(np.abs(y_true))),
        "max_abs_pressure": float(np.max(np.abs(states[:, 2])) / phys.p_s),
        "x0": {"x": 0.0, "v": 0.0, "p": 0.0},
    }
    if coulomb:
        meta["coulomb"] = {"force_N": coulomb, "width_m_per_s": coulomb_width,
                           "accel_m_per_s2": coulomb / phys.m}
    return Dataset.from_arrays(
        u, y, fs=fs, metadata=meta, name=f"cylinder-seed{seed}",
        input_name="current", input_unit="mA", output_name="position", output_unit="mm",
    )
