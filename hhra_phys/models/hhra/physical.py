"""The paper's physical parameters and their identifiable groups.

The helical hydraulic rotary actuator is described in the reference paper by
about twenty physical symbols (``docs/model.md``, "Equations"). From valve current and
shaft angle only a few groups of them can be identified. With the load pressure
normalised by the supply pressure, ``p = P_L/p_s``, the model becomes::

    dtheta/dt = omega
    domega/dt = g_torque*p - g_damping*omega - g_spring*theta - g_load
    dp/dt     = g_valve*I*sqrt(1 - sign(I)*p) - g_compress*omega - g_leak*p

with the groups (``M_e = m/(2 pi zeta) + 2 varsigma J/d`` and
``B_e = B_c/(2 pi zeta) + 2 varsigma B_m/d``)::

    g_torque   = A p_s / M_e                              [rad/s^2]
    g_damping  = B_e / M_e                                [1/s]
    g_spring   = 2 varsigma G / (d M_e)                   [1/s^2]
    g_load     = 2 varsigma T_L / (d M_e)                 [rad/s^2]
    g_compress = 4 beta_e A / (2 pi zeta V_t p_s)         [1/rad]
    g_leak     = 4 beta_e C_t / V_t                       [1/s]
    g_valve    = 4 beta_e k_q k_x / (V_t sqrt(p_s))       [1/(s mA)]
    g_kp       = 4 beta_e k_pa / V_t                      [1/s]  (linearised valve only)

Identifiability: the orifice law fixes the pressure scale, so with excitation
that drives the load pressure to a sizeable fraction of ``p_s`` all five
positive groups are identifiable from (current, angle). With the linearised
valve only the three transfer-function ratios ``b/a``, ``c/a``, ``kv/a`` are, and
``g_leak`` and ``g_damping`` trade against each other. The physical symbols
themselves need a datasheet: :meth:`PhysicalParameters.from_groups` recovers one
unknown per group (``J``, ``B_m``, ``beta_e``, ``k_x``, ``C_t``) given the rest.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

from hhra_phys.errors import ParameterError

__all__ = [
    "PhysicalParameters",
]

#: Which physical symbol :meth:`PhysicalParameters.from_groups` solves for, per group.
SOLVED_BY_GROUP: dict[str, str] = {
    "g_torque": "J",
    "g_damping": "B_m",
    "g_compress": "beta_e",
    "g_valve": "k_x",
    "g_leak": "C_t",
    "g_spring": "G",
    "g_load": "T_L",
}

_UNITS: dict[str, str] = {
    "A": "m^2", "S1": "m", "S2": "m", "beta1": "rad", "beta2": "rad", "gamma": "rad",
    "d": "m", "m": "kg", "J": "kg*m^2", "B_c": "N*s/m", "B_m": "N*m*s/rad", "G": "N*m/rad",
    "T_L": "N*m", "V_t": "m^3", "beta_e": "Pa", "C_t": "m^3/(s*Pa)", "p_s": "Pa",
    "k_x": "m/mA", "C_d": "-", "w": "m", "rho": "kg/m^3",
}


def _helix_angle(d: float, lead: float) -> float:
    """Helix angle [rad] from the axis of a thread of diameter ``d`` and lead ``lead``."""
    return math.atan(math.pi * d / lead)


@dataclass(frozen=True)
class PhysicalParameters:
    """Physical symbols of the HHRA (paper section 2), SI units; ``I`` in mA.

    The defaults describe the built-in simulated rig: a mid-size helical
    actuator (2000 mm^2 piston, 0.2 m leads, about 650 N*m at 10 MPa) driving an
    inertial load of 1.5 kg*m^2 through a servo valve of about 6 L/min per mA at
    full supply pressure, with 250 cm^3 of oil.

    Attributes
    ----------
    A : piston area [m^2]
    S1, S2 : leads of the two helical pairs [m]
    beta1, beta2 : helix angles [rad] (default: from ``d`` and the leads)
    gamma : friction angle of the helical pairs [rad]
    d : reference diameter of the helical pairs [m]
    m : moving piston mass [kg]
    J : shaft and load inertia [kg*m^2]
    B_c : viscous coefficient on the piston [N*s/m]
    B_m : rotary viscous coefficient [N*m*s/rad]
    G : angle stiffness of the load [N*m/rad]
    T_L : constant load torque [N*m]
    V_t : total control volume [m^3]
    beta_e : effective bulk modulus [Pa]
    C_t : internal leakage coefficient [m^3/(s*Pa)]
    p_s : supply pressure [Pa]
    k_x : spool displacement per valve current [m/mA]
    C_d : discharge coefficient [-]
    w : area gradient of the spool [m]
    rho : oil density [kg/m^3]
    """

    A: float = 2.0e-3
    S1: float = 0.2
    S2: float = 0.2
    beta1: float = _helix_angle(0.06, 0.2)
    beta2: float = _helix_angle(0.06, 0.2)
    gamma: float = math.radians(2.0)
    d: float = 0.06
    m: float = 6.0
    J: float = 1.5
    B_c: float = 1500.0
    B_m: float = 6.0
    G: float = 0.0
    T_L: float = 0.0
    V_t: float = 2.5e-4
    beta_e: float = 1.0e9
    C_t: float = 4.0e-13
    p_s: float = 10.0e6
    k_x: float = 2.0e-5
    C_d: float = 0.61
    w: float = 0.015
    rho: float = 850.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not math.isfinite(value):
                raise ParameterError(f"physical parameter {f.name!r} must be finite, got {value}")
        for name in ("A", "S1", "S2", "d", "m", "V_t", "beta_e", "p_s", "k_x", "C_d", "w", "rho"):
            if getattr(self, name) <= 0:
                raise ParameterError(
                    f"physical parameter {name!r} must be positive, got {getattr(self, name)}"
                )
        for name in ("J", "B_c", "B_m", "C_t"):
            if getattr(self, name) < 0:
                raise ParameterError(f"physical parameter {name!r} must be >= 0")
        if min(self.beta1, self.beta2) <= self.gamma:
            raise ParameterError("helix angles beta1, beta2 must exceed the friction angle gamma")

    # -- derived quantities -----------------------------------------------------------
    @property
    def zeta(self) -> float:
        """``(S1 + S2) / (S1*S2)`` [1/m]: ``Y = theta / (2 pi zeta)``."""
        return (self.S1 + self.S2) / (self.S1 * self.S2)

    @property
    def varsigma(self) -> float:
        """``1/tan(beta1 - gamma) + 1/tan(beta2 - gamma)`` [-]."""
        return 1 / math.tan(self.beta1 - self.gamma) + 1 / math.tan(self.beta2 - self.gamma)

    @property
    def torque_ratio(self) -> float:
        """``2*varsigma/d`` [1/m]: axial force per unit shaft torque (T = F d/(2 varsigma))."""
        return 2 * self.varsigma / self.d

    @property
    def M_e(self) -> float:
        """Equivalent mass ``m/(2 pi zeta) + 2 varsigma J / d`` [kg*m]."""
        return self.m / (2 * math.pi * self.zeta) + self.torque_ratio * self.J

    @property
    def B_e(self) -> float:
        """Equivalent damping ``B_c/(2 pi zeta) + 2 varsigma B_m / d`` [N*s]."""
        return self.B_c / (2 * math.pi * self.zeta) + self.torque_ratio * self.B_m

    @property
    def k_q(self) -> float:
        """Orifice flow gain ``C_d * w * sqrt(1/rho)`` [m^2/sqrt(kg/m^3)]."""
        return self.C_d * self.w * math.sqrt(1 / self.rho)

    @property
    def displacement(self) -> float:
        """Volume displaced per radian ``A / (2 pi zeta)`` [m^3/rad]."""
        return self.A / (2 * math.pi * self.zeta)

    @property
    def compliance(self) -> float:
        """Hydraulic capacitance ``V_t / (4 beta_e)`` [m^3/Pa]."""
        return self.V_t / (4 * self.beta_e)

    def k_xa(self, P_L: float = 0.0, x_v: float = 0.0) -> float:
        """Linearised valve flow gain ``dq/dx_v`` at ``(x_v, P_L)`` [m^2/s]."""
        s = 1.0 if x_v >= 0 else -1.0
        return self.k_q * math.sqrt(self.p_s - s * P_L)

    def k_pa(self, P_L: float = 0.0, x_v: float = 0.0) -> float:
        """Linearised flow-pressure gain ``-dq/dP_L`` at ``(x_v, P_L)`` [m^3/(s*Pa)]."""
        s = 1.0 if x_v >= 0 else -1.0
        return self.k_q * abs(x_v) / (2 * math.sqrt(self.p_s - s * P_L))

    def natural_frequency(self) -> float:
        """Hydraulic natural frequency ``sqrt(A*A/(2 pi zeta) / (C_h*M_e))`` [rad/s]."""
        return math.sqrt(self.A * self.displacement / (self.compliance * self.M_e))

    # -- the two views ------------------------------------------------------------------
    def groups(self, k_pa: float = 0.0) -> dict[str, float]:
        """The identifiable groups (see the module docstring), by name, in their units."""
        ch, me, ps = self.compliance, self.M_e, self.p_s
        return {
            "g_torque": self.A * ps / me,
            "g_damping": self.B_e / me,
            "g_spring": self.torque_ratio * self.G / me,
            "g_load": self.torque_ratio * self.T_L / me,
            "g_compress": self.displacement / (ch * ps),
            "g_leak": self.C_t / ch,
            "g_valve": self.k_q * self.k_x / (ch * math.sqrt(ps)),
            "g_kp": k_pa / ch,
        }

    def from_groups(self, groups: dict[str, float]) -> PhysicalParameters:
        """Physical parameters that reproduce ``groups``, solving one symbol per group.

        The other symbols are taken from ``self`` (a datasheet). Which symbol each
        group determines is listed in :data:`SOLVED_BY_GROUP` (``J``, ``B_m``,
        ``beta_e``, ``k_x``, ``C_t``, ``G``, ``T_L``). ``g_compress`` is solved first
        because it fixes ``beta_e``, which the valve and leakage groups depend on.

        Raises
        ------
        ParameterError
            When a group cannot be matched with a non-negative symbol (e.g. an
            inertia below the piston's own share).
        """
        unknown = set(groups) - set(SOLVED_BY_GROUP) - {"g_kp"}
        if unknown:
            raise ParameterError(f"unknown groups {sorted(unknown)}")
        new = self
        if "g_compress" in groups:
            # g_compress = 4 beta_e A / (2 pi zeta V_t p_s)
            new = replace(new, beta_e=groups["g_compress"] * new.V_t * new.p_s
                          / (4 * new.displacement))
        ch = new.compliance
        if "g_torque" in groups:
            new = new._with_g_torque(groups["g_torque"])
        me = new.M_e
        if "g_damping" in groups:
            new = new._with_g_damping(groups["g_damping"])
        if "g_spring" in groups:
            new = replace(new, G=groups["g_spring"] * me / new.torque_ratio)
        if "g_load" in groups:
            new = replace(new, T_L=groups["g_load"] * me / new.torque_ratio)
        if "g_leak" in groups:
            new = replace(new, C_t=groups["g_leak"] * ch)
        if "g_valve" in groups:
            new = replace(new, k_x=groups["g_valve"] * ch * math.sqrt(new.p_s) / new.k_q)
        return new

    def _with_g_torque(self, g_torque: float) -> PhysicalParameters:
        """The motor inertia ``J`` that gives ``g_torque`` [rad/s^2] (refused below zero)."""
        me = self.A * self.p_s / g_torque
        J = (me - self.m / (2 * math.pi * self.zeta)) / self.torque_ratio
        if J < 0:
            raise ParameterError(
                f"g_torque={g_torque:.6g} implies M_e={me:.6g} kg*m, below the "
                "piston mass share m/(2 pi zeta): J would be negative"
            )
        return replace(self, J=J)

    def _with_g_damping(self, g_damping: float) -> PhysicalParameters:
        """The motor's viscous coefficient ``B_m`` that gives ``g_damping`` [1/s] (refused
        below zero)."""
        B_m = (g_damping * self.M_e - self.B_c / (2 * math.pi * self.zeta)) / self.torque_ratio
        if B_m < 0:
            raise ParameterError(
                f"g_damping={g_damping:.6g} is below the piston's own viscous "
                "share B_c/(2 pi zeta M_e): B_m would be negative"
            )
        return replace(self, B_m=B_m)

    def tf_coefficients(self, k_pa: float | None = None) -> dict[str, float]:
        """The paper's ``G(s) = k_v / (a s^3 + b s^2 + c s)`` in physical units.

        ``a = V_t/(4 beta_e) M_e``, ``b = V_t/(4 beta_e) B_e + (C_t + k_pa) M_e``,
        ``c = (C_t + k_pa) B_e + A^2/(2 pi zeta)``, ``k_v = A k_x k_xa``, with the
        valve linearised at rest (``k_xa = k_q sqrt(p_s)``, ``k_pa = 0`` unless given).
        ``theta`` in rad, ``I`` in mA. Valid for ``G = 0`` (the paper's case).
        """
        kpa = 0.0 if k_pa is None else k_pa
        kce = self.C_t + kpa
        ch = self.compliance
        return {
            "a": ch * self.M_e,
            "b": ch * self.B_e + kce * self.M_e,
            "c": kce * self.B_e + self.A * self.displacement,
            "kv": self.A * self.k_x * self.k_xa(),
        }

    def to_dict(self) -> dict[str, float]:
        """All symbols by name (SI units)."""
        return asdict(self)

    @staticmethod
    def units() -> dict[str, str]:
        """Unit of every symbol."""
        return dict(_UNITS)
