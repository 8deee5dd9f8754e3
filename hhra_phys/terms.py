"""Parts that discovery builds: sparse terms and resonant modes (registered parts).

:class:`DiscoveredTerm` holds a few terms of a library of shapes (module
:mod:`hhra_phys.diagnosis.discovery`) at one entry point of a model (``input``, ``output`` or the
rate of a state); :class:`DiscoveredMode` adds two states: a resonant mode mixed into the output
or the input, or a load on a compliant coupling of a velocity state. Both are ordinary
registered parts, so a saved :class:`~hhra_phys.result.FitResult` holding one loads back
with ``import hhra_phys`` alone; how they are found (screening, sparse fits through the
simulator, the loop's rule) is :mod:`hhra_phys.diagnosis.discovery`'s.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import casadi as ca
import numpy as np

from hhra_phys.errors import ModelError
from hhra_phys.model import Model
from hhra_phys.parameters import Parameter
from hhra_phys.parts import (
    INPUT_STAGE,
    OUTPUT_STAGE,
    Context,
    Effect,
    State,
    register_part,
)

__all__ = [
    "FAMILIES",
    "DiscoveredTerm",
    "DiscoveredMode",
    "MODE_ENTRIES",
    "MODE_SEPARATION",
    "mode_entries",
    "velocity_pairs",
    "velocity_states",
]

#: Families of one-variable terms (module docstring).
FAMILIES: tuple[str, ...] = ("lin", "sq", "cube", "odd2", "abs", "sign", "hinge+", "hinge-",
                             "sat")
#: Width of the smooth sign, |.| and relu on the scaled variable (2 % of its range).
SMOOTH = 0.02

_NP = SimpleNamespace(sqrt=np.sqrt, fabs=np.abs, tanh=np.tanh, sin=np.sin, cos=np.cos)
_CA = SimpleNamespace(sqrt=ca.sqrt, fabs=ca.fabs, tanh=ca.tanh, sin=ca.sin, cos=ca.cos)
_SPEC = re.compile(r"^([a-z0-9+\-]+)\(([^)]*)\)$")


def _parse(spec: str) -> tuple[str, list[str]]:
    """``"prod(theta,omega)"`` -> ``("prod", ["theta", "omega"])``."""
    m = _SPEC.match(spec)
    if not m:
        raise ModelError(f"bad discovered-term specification {spec!r}")
    args = [a for a in m.group(2).split(",") if a]
    return m.group(1), args


def _basis(family: str, q: Sequence[Any], knot: Any, lib: SimpleNamespace) -> Any:
    """Value of a term family on scaled arguments ``q`` (NumPy or CasADi, ``lib``)."""
    if family == "one":
        return 1.0 + 0.0 * knot
    if family in ("sin", "cos"):
        return getattr(lib, family)(q[0])
    if family == "prod":
        return q[0] * q[1]
    if family in ("hinge+", "hinge-"):
        e = SMOOTH
        v = (q[0] if family == "hinge+" else -q[0]) - knot
        return 0.5 * (v + lib.sqrt(v * v + e * e))
    return _shape(family, q[0], lib)


def _shape(family: str, x: Any, lib: SimpleNamespace) -> Any:
    """Value of a one-variable family without a knot on the scaled variable ``x``."""
    e = SMOOTH
    if family == "lin":
        return x
    if family == "sq":
        return x * x
    if family == "cube":
        return x * x * x
    if family == "odd2":
        return x * lib.fabs(x)
    if family == "abs":
        return lib.sqrt(x * x + e * e) - e
    if family == "sign":
        return x / lib.sqrt(x * x + e * e)
    if family == "sat":
        return lib.tanh(2.0 * x)
    raise ModelError(f"unknown term family {family!r}")


def _entry_tag(entry: str) -> str:
    return entry.replace(":", "_")


# --- the discovered part ------------------------------------------------------------------


class _AtEntry(Effect):
    """Stage and entry of a discovered part from its ``target`` (a dataclass field of the
    subclass): the input entry runs before every part; the others after all the model's
    stages, so that every signal and rate they read is complete."""

    target: str

    @property  # type: ignore[override]
    def stage(self) -> str:  # noqa: D102
        return INPUT_STAGE if self.target == "input" else OUTPUT_STAGE

    @property  # type: ignore[override]
    def entry(self) -> str:  # noqa: D102
        return self.target


@register_part
@dataclass(frozen=True)
class DiscoveredTerm(_AtEntry):
    """A sparse sum of terms found from the residual, added at one entry point.

    ``target`` += ``sum_j a_j * f_j(v/s)`` where each ``f_j`` is a family of
    :data:`FAMILIES` (or ``prod``, ``sin``, ``cos``, ``one``) of model variables
    ``v`` (states, the measured input ``u``, signals) scaled by ``s``. The
    coefficients ``a_j`` carry the entry's unit; hinge terms also have a fitted
    knot (in the variable's unit).

    Parameters
    ----------
    target : str
        ``"input"``, ``"output"`` or ``"rate:<state>"``.
    index : int
        Running number ``k`` of the discovered terms of a model (unique names).
    terms : tuple of str
        Term specifications, e.g. ``("odd2(omega)", "prod(theta,p)")``.
    variables, scales : tuple
        Every variable the terms use and its scale ``s`` (its unit).
    start : tuple of float
        Starting (nominal) coefficient of each term (entry unit).
    bound : tuple of float
        Half width of each coefficient's box (entry unit).
    knots : tuple of float
        Starting knot of each hinge term (the variable's unit; ignored for others).
    knot_max : tuple of float
        Upper bound of each hinge knot (the variable's unit).
    unit : str
        Unit of the entry (``rad/s^2`` for ``rate:omega`` of the HHRA).
    var_units : tuple of str
        Unit of each variable (for the printed expression).
    """

    target: str = "output"
    index: int = 1
    terms: tuple[str, ...] = ()
    variables: tuple[str, ...] = ()
    scales: tuple[float, ...] = ()
    start: tuple[float, ...] = ()
    bound: tuple[float, ...] = ()
    knots: tuple[float, ...] = ()
    knot_max: tuple[float, ...] = ()
    unit: str = ""
    var_units: tuple[str, ...] = ()
    signature = "a term outside the library, built from the residual"

    def __post_init__(self) -> None:
        n = len(self.terms)
        for label, seq in (("start", self.start), ("bound", self.bound), ("knots", self.knots),
                           ("knot_max", self.knot_max)):
            if len(seq) != n:
                raise ModelError(f"discovered term: {label} has {len(seq)} values for {n} terms")
        if len(self.scales) != len(self.variables):
            raise ModelError("discovered term: one scale per variable is needed")
        for spec in self.terms:
            for a in _parse(spec)[1]:
                if a not in self.variables:
                    raise ModelError(f"discovered term {spec!r} uses unknown variable {a!r}")
        if not (self.target in ("input", "output") or self.target.startswith("rate:")):
            raise ModelError(f"discovered term entry must be input, output or rate:<state>, "
                             f"got {self.target!r}")

    # Names and declared reads/writes depend on the instance (not class attributes).
    @property  # type: ignore[override]
    def name(self) -> str:  # noqa: D102
        return f"discovered_{_entry_tag(self.target)}_{self.index}"

    @property
    def uses(self) -> list[str]:
        """State, signal or input names the term depends on (``"u"``: the input)."""
        out: list[str] = []
        for spec in self.terms:
            for a in _parse(spec)[1]:
                if a not in out:
                    out.append(a)
        return out

    @property  # type: ignore[override]
    def reads(self) -> tuple[str, ...]:  # noqa: D102
        return tuple(v for v in self.uses if v != "u")

    @property  # type: ignore[override]
    def writes(self) -> tuple[str, ...]:  # noqa: D102
        if self.target.startswith("rate:"):
            return (self.target[5:],)
        return ("y",) if self.target == "output" else ()

    @property  # type: ignore[override]
    def position_dependent(self) -> bool:  # noqa: D102
        return any(_parse(s)[0] in ("sin", "cos") for s in self.terms)

    def coefficient_name(self, j: int) -> str:
        """Name of term ``j``'s coefficient (0-based ``j``)."""
        return f"disc{self.index}_a{j + 1}"

    def knot_name(self, j: int) -> str:
        """Name of hinge term ``j``'s knot."""
        return f"disc{self.index}_c{j + 1}"

    @property
    def parameters(self) -> Sequence[Parameter]:
        out = []
        for j, spec in enumerate(self.terms):
            b = float(self.bound[j])
            a0 = min(max(float(self.start[j]), -b), b)
            out.append(Parameter(self.coefficient_name(j), self.unit, a0, -b, b, "linear",
                                 f"coefficient of {spec} (discovered)"))
            fam, args = _parse(spec)
            if fam.startswith("hinge"):
                v = args[0]
                unit = self.var_units[self.variables.index(v)] if self.var_units else ""
                hi = float(self.knot_max[j])
                out.append(Parameter(self.knot_name(j), unit,
                                     min(max(float(self.knots[j]), 0.0), hi), 0.0, hi,
                                     "linear", f"knot of {spec} (discovered)"))
        return tuple(out)

    def _value(self, ctx: Context, name: str) -> Any:
        if name == "u":
            return ctx.u_lags[0]
        if name in ctx.x:
            return ctx.x[name]
        return ctx.signal(name, self.name)

    def contribution(self, get: Callable[[str], Any], p: Mapping[str, Any],
                     lib: SimpleNamespace = _CA) -> Any:
        """``sum_j a_j f_j`` given variable values ``get(name)`` and parameters ``p``."""
        total: Any = 0.0
        for j, spec in enumerate(self.terms):
            fam, args = _parse(spec)
            # sin and cos take the angle itself, as the screened column and the printed
            # expression do (scaling it by max|angle| would change the function).
            q = [get(a) if fam in ("sin", "cos") else get(a) / self.scales[self.variables.index(a)]
                 for a in args]
            knot: Any = 0.0
            if fam.startswith("hinge"):
                knot = p[self.knot_name(j)] / self.scales[self.variables.index(args[0])]
            total = total + p[self.coefficient_name(j)] * _basis(fam, q, knot, lib)
        return total

    def apply(self, ctx: Context) -> None:
        term = self.contribution(lambda n: self._value(ctx, n), ctx.p)
        if self.target == "input":
            ctx.u = ctx.u + term
        elif self.target == "output":
            ctx.signals["y"] = ctx.signal("y", self.name) + term
        else:
            ctx.add_rate(self.target[5:], term)

    def expression(self, values: Mapping[str, float], digits: int = 3) -> str:
        """The term in the model's names and units, e.g. ``d omega/dt += -0.31*omega*|omega|``."""
        lhs = {"input": "u +=", "output": "y +="}.get(self.target, f"d {self.target[5:]}/dt +=")
        parts = []
        for j, spec in enumerate(self.terms):
            fam, args = _parse(spec)
            a = float(values.get(self.coefficient_name(j), self.start[j]))
            s = [self.scales[self.variables.index(v)] for v in args]
            c = values.get(self.knot_name(j), self.knots[j])
            g = f"{{:.{digits}g}}"
            text = {
                "one": (a, ""),
                "lin": (a / s[0], f"{args[0]}") if args else (a, ""),
                "sq": (a / s[0] ** 2, f"{args[0]}^2") if args else (a, ""),
                "cube": (a / s[0] ** 3, f"{args[0]}^3") if args else (a, ""),
                "odd2": (a / s[0] ** 2, f"{args[0]}*|{args[0]}|") if args else (a, ""),
                "abs": (a / s[0], f"|{args[0]}|") if args else (a, ""),
                "sign": (a, f"sgn({args[0]})") if args else (a, ""),
                "hinge+": ((a / s[0], f"relu({args[0]} - {g.format(float(c))})")
                           if args else (a, "")),
                "hinge-": ((a / s[0], f"relu(-{args[0]} - {g.format(float(c))})")
                           if args else (a, "")),
                "sat": (a, f"tanh({args[0]}/{g.format(s[0] / 2)})") if args else (a, ""),
                "sin": (a, f"sin({args[0]})") if args else (a, ""),
                "cos": (a, f"cos({args[0]})") if args else (a, ""),
                "prod": ((a / (s[0] * s[1]), f"{args[0]}*{args[1]}")
                         if len(args) == 2 else (a, "")),
            }[fam]
            coef, what = text
            term = g.format(coef) + (f"*{what}" if what else "")
            parts.append(term)
        body = " + ".join(parts).replace("+ -", "- ")
        return f"{lhs} {body} [{self.unit}]".strip()


# --- variables, entry points and the term library -------------------------------------------


#: Entry points of a mode (:class:`DiscoveredMode`) every model has, as named in ``entries``;
#: a model with velocity states also has ``"mode:rate:<v>"`` (:func:`mode_entries`).
MODE_ENTRIES: tuple[str, ...] = ("mode:output", "mode:input")
#: Resonance periods screened, in samples (log grid between the two).
MODE_PERIOD_RANGE: tuple[float, float] = (4.0, 300.0)
#: Number of periods of the screening grid.
MODE_N_PERIODS = 48
#: Damping ratios screened (and the box of the fitted one). A resonance has a peak in
#: ``|H|``: damping below ``1/sqrt(2)``. A better-damped second-order filter is a lag,
#: which the library's ``valve_dynamics`` and ``input_delay`` represent (without the cap
#: such a filter stood in for a hidden delay on 3 of 3 reference records).
MODE_DAMPINGS: tuple[float, ...] = (0.03, 0.07, 0.15, 0.3, 0.5)
MODE_DAMPING_BOX: tuple[float, float] = (0.005, 0.7)
#: Half width of the mix's box [-] (1: a pure second-order filter of the output).
MODE_MIX_BOUND = 3.0
#: Starts of the IPOPT refit: the best screened grid points with distinct periods.
MODE_STARTS = 2
#: Box of a load mode's inertia ratio (load over the inertia behind the velocity state).
MODE_LOAD_RATIO_BOX: tuple[float, float] = (1e-3, 10.0)
#: Least starting ratio of a load mode's refit (docs/diagnosis.md, public record).
MODE_LOAD_START = 0.3
#: Least ratio between a claimed mode's frequency and each of the refitted model's own
#: resonances (docs/diagnosis.md: stand-ins at 1.05-1.2x; hidden resonance tested at 3.8x).
MODE_SEPARATION = 1.5


@register_part
@dataclass(frozen=True)
class DiscoveredMode(_AtEntry):
    """A resonant mode at the output, the input or a velocity state: a new state pair.

    ``target="output"`` (a compliant coupling or a resonant sensor between the
    model's output and the measurement): the measured output is the model's
    output ``y`` passed through a mix of itself and a second-order filter,
    ``y_s = y + k*(H(s) - 1) y`` with ``H(s) = w^2/(s^2 + 2*z*w*s + w^2)``,
    a compliant coupling or a resonant sensor (``k = 1``: the sensor reads the
    filtered output; other ``k``: a mode that shows part of itself). ``H - 1 =
    -(s + 2 z w) s / (s^2 + 2 z w s + w^2)`` is driven by the output's rate
    ``dy/dt = (dy/dx) f(x, u)``, taken symbolically from the model, so the two
    new states are the mode's deviation from the output and start at rest (0) on
    every record: no initial value to fit::

        a' = b
        b' = -w^2 a - 2 z w b + dy/dt
        y_s = y - k (2 z w a + b)

    ``target="input"`` (a resonant actuator stage, e.g. a second-order valve
    spool): the parts see ``u + k*(m - u)`` with ``m'' = w^2 (u - m) - 2 z w m'``.
    The held input jumps, so the mode is kept in absolute form: ``m`` starts at
    ``u_start`` (the estimation record's first input) and its initial value is
    fitted with the other initial states (``x0_mode<k>_m``; re-estimated on every
    other record), ``m'`` starts at rest.

    ``target="rate:<v>"`` (a load on a compliant coupling, e.g. an arm or a second
    inertia on a shaft): ``v`` is a velocity state (another state's rate is ``v``,
    :func:`velocity_states`, such as ``omega`` of ``d theta/dt = omega``). A load of
    ``k`` times the inertia behind ``v`` is coupled to it by a spring and a damper
    with natural frequency ``w`` and damping ratio ``z`` (of the load alone, on a
    fixed base); the states are the coupling's twist ``a`` and the relative velocity
    ``b = v - v_load``, both starting at rest (the load moves with ``v``)::

        f_c = w^2 a + 2 z w b          (the load's acceleration)
        dv/dt += -k f_c                (the coupling's reaction)
        a' = b
        b' = dv/dt|rest - (1 + k) f_c  (``dv/dt|rest``: every other part's rate of v)

    At low frequency the load follows and the inertia behind ``v`` grows by
    ``1 + k``; near ``w`` the two inertias swing against each other (two modes).

    No term of the present states and signals can make such an oscillation: it
    needs the new states. Not a library effect (:data:`hhra_phys.effects.EFFECTS`):
    it is a discovery candidate, tried after the library rounds and accepted by
    the same rule (``docs/diagnosis.md``).

    Parameters
    ----------
    target : str
        ``"output"``, ``"input"`` or ``"rate:<v>"`` (``v`` a velocity state).
    index : int
        Running number ``k`` of discovered modes (unique names).
    w, zeta, mix : float
        Starting natural frequency [rad per time unit], damping ratio [-] and mix [-]
        (for ``"rate:<v>"`` the load's inertia ratio, > 0).
    w_min, w_max : float
        Box of the natural frequency [rad per time unit].
    unit : str
        Unit of the entry (output, input or the velocity state; for the states' units).
    twist_unit : str
        Load mode only: unit of the position whose rate is the velocity (the twist's);
        default ``<unit>*<time unit>``.
    time_unit : str
        ``"s"`` or ``"sample"``.
    u_start, u_scale : float
        Input mode only: initial value and typical size of ``m`` (input units).
    """

    target: str = "output"
    index: int = 1
    w: float = 1.0
    zeta: float = 0.2
    mix: float = 1.0
    w_min: float = 0.01
    w_max: float = 100.0
    unit: str = ""
    time_unit: str = "s"
    twist_unit: str = ""
    u_start: float = 0.0
    u_scale: float = 1.0
    signature = ("a damped oscillation at one frequency in the residual, which no function "
                 "of the present states represents")

    def __post_init__(self) -> None:
        if self.target not in ("output", "input") and not (
                self.target.startswith("rate:") and len(self.target) > 5):
            raise ModelError(f"a discovered mode enters at the output, the input or the rate "
                             f"of a velocity state ('rate:<v>'), got {self.target!r}")
        if not (0 < self.w_min < self.w_max and math.isfinite(self.w_max)):
            raise ModelError(f"discovered mode: need 0 < w_min < w_max, got {self.w_min}, "
                             f"{self.w_max}")

    @property  # type: ignore[override]
    def name(self) -> str:  # noqa: D102
        return f"discovered_mode_{self.target.replace(':', '_')}_{self.index}"

    def applicable(self, model: Any) -> str | None:  # noqa: D102 - Effect.applicable
        if self.velocity and self.velocity not in velocity_states(model):
            return (f"a load mode needs a velocity state (another state's rate); "
                    f"{self.velocity!r} is not one (velocity states: "
                    f"{', '.join(velocity_states(model)) or 'none'})")
        return super().applicable(model)

    @property
    def velocity(self) -> str:
        """The velocity state of a load mode (``"rate:<v>"``), else ``""``."""
        return self.target[5:] if self.target.startswith("rate:") else ""

    @property  # type: ignore[override]
    def reads(self) -> tuple[str, ...]:  # noqa: D102
        return ("y",) if self.target == "output" else (self.velocity,) if self.velocity else ()

    @property  # type: ignore[override]
    def writes(self) -> tuple[str, ...]:  # noqa: D102
        return self.reads

    @property
    def uses(self) -> list[str]:
        """The model's variables the mode depends on: the velocity state of a load mode
        (linear in it: nothing is extrapolated), none for the others."""
        return [self.velocity] if self.velocity else []

    @property
    def pname(self) -> dict[str, str]:
        """Parameter names by role: ``w``, ``z``, ``k``."""
        return {r: f"mode{self.index}_{r}" for r in ("w", "z", "k")}

    @property
    def parameters(self) -> Sequence[Parameter]:
        n, tu = self.pname, self.time_unit
        w0 = min(max(self.w, self.w_min), self.w_max)
        z0 = min(max(self.zeta, MODE_DAMPING_BOX[0]), MODE_DAMPING_BOX[1])
        k0 = min(max(self.mix, -MODE_MIX_BOUND), MODE_MIX_BOUND)
        if self.velocity:
            lo, hi = MODE_LOAD_RATIO_BOX
            k = Parameter(n["k"], "-", min(max(self.mix, lo), hi), lo, hi, "log",
                          f"load inertia over the inertia behind {self.velocity}")
        else:
            k = Parameter(n["k"], "-", k0, -MODE_MIX_BOUND, MODE_MIX_BOUND, "linear",
                          "mix of the mode in the measured output (1: filtered output)")
        return (Parameter(n["w"], f"rad/{tu}", w0, self.w_min, self.w_max, "log",
                          "natural frequency of the discovered mode"),
                Parameter(n["z"], "-", z0, *MODE_DAMPING_BOX, "log",
                          "damping ratio of the discovered mode"), k)

    @property
    def states(self) -> Sequence[State]:
        i, tu, u = self.index, self.time_unit, self.unit or "out"
        if self.velocity:
            return (State(f"mode{i}_a", self.twist_unit or f"{u}*{tu}", 0.0,
                          "load coupling's twist", fit_initial=False),
                    State(f"mode{i}_b", u, 0.0, f"{self.velocity} minus the load's velocity",
                          fit_initial=False))
        if self.target == "input":
            return (State(f"mode{i}_m", u, float(self.u_start), "input mode's position",
                          fit_initial=True, scale=float(self.u_scale)),
                    State(f"mode{i}_v", f"{u}/{tu}", 0.0, "input mode's rate",
                          fit_initial=False))
        return (State(f"mode{i}_a", f"{u}*{tu}", 0.0, "mode's integrated deviation",
                      fit_initial=False),
                State(f"mode{i}_b", u, 0.0, "mode's deviation from the output rate filter",
                      fit_initial=False))

    def apply(self, ctx: Context) -> None:
        i = self.index
        n = self.pname
        w, z, k = ctx.p[n["w"]], ctx.p[n["z"]], ctx.p[n["k"]]
        if self.velocity:
            a, b = ctx.x[f"mode{i}_a"], ctx.x[f"mode{i}_b"]
            rest = ctx.rates[self.velocity]  # every other part's rate of v
            f_c = w * w * a + 2 * z * w * b
            ctx.add_rate(self.velocity, -k * f_c)
            ctx.add_rate(f"mode{i}_a", b)
            ctx.add_rate(f"mode{i}_b", rest - (1 + k) * f_c)
            return
        if self.target == "input":
            m, v = ctx.x[f"mode{i}_m"], ctx.x[f"mode{i}_v"]
            ctx.add_rate(f"mode{i}_m", v)
            ctx.add_rate(f"mode{i}_v", w * w * (ctx.u - m) - 2 * z * w * v)
            ctx.u = ctx.u + k * (m - ctx.u)
            return
        y = ctx.signal("y", self.name)
        ydot: Any = 0.0
        for n, xs in ctx.x.items():
            if ca.depends_on(y, xs):
                ydot = ydot + ca.jacobian(y, xs) * ctx.rates[n]
        a, b = ctx.x[f"mode{i}_a"], ctx.x[f"mode{i}_b"]
        ctx.add_rate(f"mode{i}_a", b)
        ctx.add_rate(f"mode{i}_b", -w * w * a - 2 * z * w * b + ydot)
        ctx.signals["y"] = y - k * (2 * z * w * a + b)

    def period(self, w: float) -> float:
        """Period ``2 pi / w`` [time unit] of natural frequency ``w``."""
        return 2 * math.pi / w

    def expression(self, values: Mapping[str, float], digits: int = 3) -> str:
        """The mode in words and numbers: mix, natural frequency, period and damping."""
        n, g = self.pname, f"{{:.{digits}g}}"
        w = float(values.get(n["w"], self.w))
        z = float(values.get(n["z"], self.zeta))
        k = float(values.get(n["k"], self.mix))
        wz = (f"w = {g.format(w)} rad/{self.time_unit} (period {g.format(self.period(w))} "
              f"{self.time_unit}), z = {g.format(z)}")
        if self.velocity:
            v = self.velocity
            return (f"d {v}/dt += -{g.format(k)}*(w^2*a + 2 z w*({v} - {v}_load)), a' = {v} - "
                    f"{v}_load: a load of {g.format(k)} times the inertia behind {v} on a "
                    f"compliant coupling, {wz}")
        v = "y" if self.target == "output" else "u"
        return f"{v} += {g.format(k)}*(H - 1) {v}, H = w^2/(s^2 + 2 z w s + w^2), {wz}"


def velocity_pairs(model: Model) -> dict[str, str]:
    """``{velocity: position}``: states that are another state's rate, and that state
    (``d theta/dt = omega``: ``{"omega": "theta"}``), found symbolically from the
    assembled model (the rate of the position equals the velocity exactly)."""
    x, u, p = model.symbols()
    ctx = model._context(x, u, p, 1.0)
    out: dict[str, str] = {}
    for q in model.state_names:
        for v in model.state_names:
            if v != q and v not in out and ca.simplify(ctx.rates[q] - ctx.x[v]).is_zero():
                out[v] = q
    return out


def velocity_states(model: Model) -> list[str]:
    """States that are another state's rate (``d theta/dt = omega``: ``omega``).

    Such a velocity can carry a load on a compliant coupling (:class:`DiscoveredMode`
    with ``target="rate:<v>"``); :func:`velocity_pairs` also names the position.
    """
    return list(velocity_pairs(model))


def mode_entries(model: Model) -> list[str]:
    """Entry points of a resonant mode of ``model``: ``mode:output``, ``mode:input`` and
    ``mode:rate:<v>`` for each of its :func:`velocity_states`."""
    return [*MODE_ENTRIES, *[f"mode:rate:{v}" for v in velocity_states(model)]]
