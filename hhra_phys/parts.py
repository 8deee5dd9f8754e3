"""Composable model parts, the part registry and the effect base class.

A model in hhra-phys is an ordered list of :class:`Part` objects (see
:class:`hhra_phys.model.Model`). Assembling the model hands every part, in stage
order, one symbolic :class:`Context`; each part reads states, parameters, the
input and named signals, and contributes

* time derivatives of states (``ctx.add_rate``),
* named signals for later parts (``ctx.signals``), and
* the measured output (``ctx.signals["y"]``).

Stages. A part's :attr:`Part.stage` is any string naming where it runs. A model
runs its stages in the order it is given, or in the order of their first
appearance in its part list, and the parts of one stage in list order. Two stage
names have a meaning for every model, because effects attach there to models
they know nothing about:

* ``"input"``: an :class:`Effect` of this stage acts on the model's input
  ``ctx.u`` and runs before every part of the model (dead zone, saturation,
  delay, lag of the input);
* ``"output"``: a stage the model does not name runs after all of the model's
  stages, so an output-side effect (offset, backlash) sees the finished
  ``ctx.signals["y"]``.

Registries. :func:`register_part` records a part class by name so that saved
models (JSON) can be rebuilt; :func:`register_effect` also makes an
:class:`Effect` a candidate of the diagnosis loop (:data:`EFFECTS`). They live
here, with the base classes, so that models and effect libraries import this
module and never each other.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from hhra_phys.errors import ModelError
from hhra_phys.parameters import Parameter

__all__ = [
    "State",
    "ROLES",
    "VELOCITY_ROLES",
    "POSITION_ROLES",
    "Motion",
    "resolve_motion",
    "Context",
    "Part",
    "PART_TYPES",
    "register_part",
    "part_type_name",
    "Signals",
    "Effect",
    "EFFECTS",
    "register_effect",
    "INPUT_STAGE",
    "OUTPUT_STAGE",
    "smooth_sign",
    "smooth_signed_sqrt",
    "smooth_abs",
    "smooth_relu",
    "corner_relu",
]

#: Stage whose effects act on the model's input, before every part of the model.
INPUT_STAGE = "input"
#: Conventional last stage: where output-side effects attach.
OUTPUT_STAGE = "output"

#: Physical roles a state may declare (``State(..., role=...)``), and what each means.
#: Library effects bind to a model by role, not by name (:class:`Motion`).
ROLES: dict[str, str] = {
    "position": "a linear position (any length unit: m, mm, or the output's unit)",
    "velocity": "the rate of a linear position (its unit per second): forces act on its rate",
    "angle": "a rotary position [rad]",
    "angular_velocity": "the rate of an angle [rad/s]: torques act on its rate",
    "effort": "what drives the motion: a pressure, force, torque or motor current",
    "level": "a stored quantity: a tank level, a volume, a charge, a temperature",
    "flow": "a flow into or out of a store",
}
#: Roles of a velocity whose rate forces (torques) act on.
VELOCITY_ROLES: tuple[str, ...] = ("velocity", "angular_velocity")
#: Roles of a position (the integral of a velocity).
POSITION_ROLES: tuple[str, ...] = ("position", "angle")


@dataclass(frozen=True)
class State:
    """A continuous state of a model.

    Parameters
    ----------
    name : str
        Identifier (``theta``, ``level``, ...), unique in a model.
    unit : str
        Unit of the state.
    initial : float
        Default initial value at the start of a simulation.
    description : str
        What the state means.
    fit_initial : bool
        Whether a fit estimates the state's initial value from the data
        (``initial_state="fit"``, the default of :func:`hhra_phys.fit.fit`).
        ``False`` pins it at ``initial`` (a state known to start at rest, or
        one the output cannot see). A model can also pin states by name
        (:class:`hhra_phys.model.Model`, ``pinned``).
    scale : float
        Typical size of the state (its unit): a fitted initial value is searched
        within ``+- scale`` of its estimate from the first output sample. For a
        velocity it also scales the library's velocity widths (friction switching
        and Stribeck velocities, :func:`hhra_phys.effects.make_effect`).
    role : str, optional
        Physical role, one of :data:`ROLES`: ``"position"``, ``"velocity"``,
        ``"angle"`` [rad], ``"angular_velocity"`` [rad/s], ``"effort"``,
        ``"level"``, ``"flow"``. Library effects bind by role: friction, a
        constant force and gravity act on the rate of the model's velocity
        (:class:`Motion`) whatever its name. ``None`` (default): no role.

    Raises
    ------
    ModelError
        ``role`` is not one of :data:`ROLES`.
    """

    name: str
    unit: str
    initial: float = 0.0
    description: str = ""
    fit_initial: bool = True
    scale: float = 1.0
    role: str | None = None

    def __post_init__(self) -> None:
        if self.role is not None and self.role not in ROLES:
            raise ModelError(f"state {self.name!r}: unknown role {self.role!r}; roles: "
                             f"{', '.join(ROLES)}")


@dataclass(frozen=True)
class Motion:
    """The velocity whose rate forces act on, and its position, of a model.

    Attributes
    ----------
    velocity : str or None
        Name of the velocity state (``None``: the model has none; see ``why``).
    position : str or None
        Name of the matching position state, if the model has one.
    rotary : bool
        Whether the motion is rotary (angle [rad], angular velocity [rad/s]).
    why : str
        Why ``velocity`` or ``position`` is ``None`` and how to declare it.
    """

    velocity: str | None = None
    position: str | None = None
    rotary: bool = False
    why: str = ""


_DECLARE_VELOCITY = ("declare State(..., role='velocity') (or role='angular_velocity' "
                     "for a rotary one) on the state whose rate forces act on")
_DECLARE_POSITION = ("declare State(..., role='position') (or role='angle' [rad] for a "
                     "rotary one) on the state whose rate is the velocity")


def _by_role(states: Sequence[State], roles: Sequence[str]) -> list[State]:
    return [s for s in states if s.role in roles]


def _pick_velocity(states: Sequence[State], given: str | None) -> tuple[State | None, str]:
    """The velocity state: declared by name, else the one with a velocity role, else a
    state named ``omega`` (models written before roles)."""
    names = {s.name: s for s in states}
    if given is not None:
        return names[given], ""
    found = _by_role(states, VELOCITY_ROLES)
    if len(found) > 1:
        return None, (f"several states have a velocity role ({', '.join(s.name for s in found)}):"
                      f" name the one forces act on with Model(..., velocity='{found[0].name}')")
    if found:
        return found[0], ""
    if "omega" in names and names["omega"].role is None:
        return names["omega"], ""
    return None, f"the model has no state with role 'velocity'; {_DECLARE_VELOCITY}"


def _pick_position(states: Sequence[State], velocity: State | None, rotary: bool,
                   given: str | None) -> tuple[State | None, str]:
    """The position state: declared, else the one position role of the velocity's kind
    (or the only one), else ``theta`` beside a legacy ``omega``."""
    names = {s.name: s for s in states}
    if given is not None:
        return names[given], ""
    found = _by_role(states, POSITION_ROLES)
    same = [s for s in found if (s.role == "angle") == rotary] if velocity is not None else []
    pick = same if len(same) == 1 else found
    if len(pick) > 1:
        return None, (f"several states have a position role ({', '.join(s.name for s in pick)}):"
                      f" name the velocity's with Model(..., position='{pick[0].name}')")
    if pick:
        return pick[0], ""
    if velocity is not None and velocity.name == "omega" and "theta" in names \
            and names["theta"].role is None:
        return names["theta"], ""
    return None, f"the model has no state with role 'position'; {_DECLARE_POSITION}"


def resolve_motion(states: Sequence[State], velocity: str | None = None,
                   position: str | None = None) -> Motion:
    """The :class:`Motion` of a model with ``states``.

    Parameters
    ----------
    states : sequence of State
        The model's states.
    velocity, position : str, optional
        Names declared by the model (:class:`hhra_phys.model.Model`, ``velocity=``,
        ``position=``); by default the states with a velocity role
        (:data:`VELOCITY_ROLES`) and a position role (:data:`POSITION_ROLES`), one of
        each. A model written before roles with states ``omega`` and ``theta`` (and no
        roles on them) binds those as a rotary motion.

    Returns
    -------
    Motion

    Raises
    ------
    ModelError
        A declared name is not a state.
    """
    names = [s.name for s in states]
    for what, given in (("velocity", velocity), ("position", position)):
        if given is not None and given not in names:
            raise ModelError(f"declared {what} {given!r} is not a state of the model "
                             f"({', '.join(names)})")
    v, why_v = _pick_velocity(states, velocity)
    rotary = v is not None and (v.role == "angular_velocity"
                                or (v.role is None and v.name == "omega"))
    q, why_q = _pick_position(states, v, rotary, position)
    if v is None and q is not None:
        rotary = q.role == "angle"
    elif v is not None and v.role is None and q is not None and q.role is not None:
        rotary = q.role == "angle"
    return Motion(v.name if v else None, q.name if q else None, rotary,
                  "; ".join(w for w in (why_v, why_q) if w))


class Context:
    """Symbolic workspace shared by the parts while a model is assembled.

    Attributes
    ----------
    x : dict of str to casadi.SX
        State symbols by name.
    p : dict of str to casadi.SX
        Parameter symbols by name.
    u_lags : casadi.SX
        Measured input at the current sample and the previous ``n_lags`` samples
        (``u_lags[0]`` is the current input, zero-order hold over the sample).
    u : casadi.SX
        The input as the model's parts see it: ``u_lags[0]`` unless an
        input-side effect (stage ``"input"``) replaced it, e.g. by a dead zone.
    dt : float
        Sample period [s] (needed by discrete-time input parts such as a delay).
    signals : dict of str to casadi.SX
        Named intermediate expressions. ``"y"`` is the measured output; other
        names are the model's own (the HHRA's are ``"command"``, the valve
        command in input units, and ``"flow"``).
    """

    def __init__(
        self,
        x: dict[str, ca.SX],
        p: dict[str, ca.SX],
        u_lags: ca.SX,
        dt: float,
        motion: Motion | None = None,
    ) -> None:
        self.x = x
        self.p = p
        self.u_lags = u_lags
        self.u: ca.SX = u_lags[0]
        self.dt = dt
        self.signals: dict[str, ca.SX] = {}
        self.rates: dict[str, ca.SX] = {name: ca.SX(0) for name in x}
        #: The model's velocity and position (:class:`Motion`); without one, a context of
        #: states named ``omega`` and ``theta`` binds those (models before roles).
        self.motion = motion if motion is not None else resolve_motion(
            [State(n, "") for n in x])

    def velocity(self, part: str = "") -> str:
        """Name of the model's velocity state (:class:`Motion`), or a clear error."""
        if self.motion.velocity is None or self.motion.velocity not in self.x:
            who = f"{part} " if part else ""
            raise ModelError(f"{who}needs a state with role 'velocity': {self.motion.why}")
        return self.motion.velocity

    def position(self, part: str = "") -> str:
        """Name of the model's position state (:class:`Motion`), or a clear error."""
        if self.motion.position is None or self.motion.position not in self.x:
            who = f"{part} " if part else ""
            raise ModelError(f"{who}needs a state with role 'position': {self.motion.why}")
        return self.motion.position

    def add_rate(self, state: str, expr: ca.SX) -> None:
        """Add ``expr`` to the time derivative of ``state``."""
        if state not in self.rates:
            raise ModelError(
                f"a part adds to the derivative of unknown state {state!r}; "
                f"states are {', '.join(self.rates)}"
            )
        self.rates[state] = self.rates[state] + expr

    def signal(self, name: str, part: str = "") -> ca.SX:
        """Return signal ``name`` or raise a clear error naming the part that needs it."""
        if name not in self.signals:
            who = f"part {part!r} " if part else ""
            raise ModelError(
                f"{who}needs signal {name!r}, which no earlier part provides "
                f"(available: {', '.join(self.signals) or 'none'})"
            )
        return self.signals[name]


@dataclass(frozen=True)
class Part:
    """Base class of model parts.

    Subclasses set :attr:`name` and :attr:`stage`, may declare
    :attr:`parameters`, :attr:`states` and :attr:`n_lags` (how many past input
    samples they need), and implement :meth:`apply`. Options of a part are
    dataclass fields (they are saved with the model).
    """

    #: Stage the part runs in: any string (module docstring).
    stage: ClassVar[str] = "motion"
    #: Short name used in reports; effects use their library name.
    name: ClassVar[str] = "part"

    @property
    def parameters(self) -> Sequence[Parameter]:
        """Parameters this part adds to the model."""
        return ()

    @property
    def states(self) -> Sequence[State]:
        """States this part adds to the model."""
        return ()

    @property
    def n_lags(self) -> int:
        """Number of past input samples the part needs (0: only the current one)."""
        return 0

    def apply(self, ctx: Context) -> None:  # pragma: no cover - abstract
        """Contribute rates and signals to ``ctx``."""
        raise NotImplementedError

    def stiff_states(self, values: Mapping[str, float]) -> list[dict[str, float]]:
        """Operating points where this part is stiffest and rest does not show it.

        The simulator's method choice (:meth:`hhra_phys.simulate.Simulator.plan`)
        evaluates the model's Jacobian at rest and at these points: a stiffness
        that only appears in motion (a sharp backlash carried at contact) must set
        the integrator too. Default: none.

        Parameters
        ----------
        values : mapping
            Parameter values by name (model units).

        Returns
        -------
        list of dict
            ``{state name: value}`` per point; states not named stay at rest.
        """
        return []


#: Registry of part classes by class name, for JSON round trips.
PART_TYPES: dict[str, type[Part]] = {}


def _qualified(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def register_part(cls: type[Part]) -> type[Part]:
    """Register a part class so that models containing it can be saved and loaded.

    Usable as a class decorator. The class is registered under its qualified name
    (``module.Class``) and, unless another class already holds it, under its bare
    class name (the name saved files use). A user's class that shares a bare name
    with a registered one (a ``GravityLoad`` part beside the library's
    ``GravityLoad`` effect) therefore never replaces it; models containing it are
    saved under the qualified name (:func:`part_type_name`). Registering the same
    class again (a reloaded module) replaces the earlier registration.

    Raises :class:`~hhra_phys.errors.ModelError` if ``cls`` is not a :class:`Part`
    subclass.
    """
    if not (isinstance(cls, type) and issubclass(cls, Part)):
        raise ModelError(f"register_part expects a Part subclass, got {cls!r}")
    PART_TYPES[_qualified(cls)] = cls
    holder = PART_TYPES.get(cls.__name__)
    if holder is None or _qualified(holder) == _qualified(cls):
        PART_TYPES[cls.__name__] = cls
    return cls


def part_type_name(cls: type[Part]) -> str:
    """Name under which a model's saved form records a part class.

    The bare class name when it maps to ``cls`` in :data:`PART_TYPES` (files stay
    readable by earlier versions), otherwise the qualified ``module.Class`` name.
    """
    return cls.__name__ if PART_TYPES.get(cls.__name__) is cls else _qualified(cls)


# --- effects ------------------------------------------------------------------------


@dataclass(frozen=True)
class Signals:
    """Signals of a simulation without an effect, for first-order signatures.

    Attributes
    ----------
    u : ndarray, shape (N,)
        Input (input units).
    dt : float
        Sample period [s] (or samples for records in sample time).
    theta, omega : ndarray or None
        Shortcuts for ``states["theta"]`` and ``states["omega"]`` (rotary
        mechanics), kept for effects written against them.
    output : str
        Unit or kind of the output (informative).
    states : dict of str to ndarray
        Simulated states by name, each shape (N,).
    y : ndarray or None
        Simulated output, shape (N,).
    velocity, position : ndarray or None
        The model's velocity and position states (:class:`Motion`, bound by role),
        each shape (N,); by default ``omega`` and ``theta``.
    """

    u: np.ndarray
    dt: float
    theta: np.ndarray | None = None
    omega: np.ndarray | None = None
    output: str = ""
    states: Mapping[str, np.ndarray] = field(default_factory=dict)
    y: np.ndarray | None = None
    velocity: np.ndarray | None = None
    position: np.ndarray | None = None

    def __post_init__(self) -> None:
        merged = dict(self.states)
        for name in ("theta", "omega"):
            given = getattr(self, name)
            if given is not None:
                merged.setdefault(name, given)
            elif name in merged:
                object.__setattr__(self, name, merged[name])
        object.__setattr__(self, "states", merged)
        for bound, legacy in (("velocity", "omega"), ("position", "theta")):
            if getattr(self, bound) is None and getattr(self, legacy) is not None:
                object.__setattr__(self, bound, getattr(self, legacy))


@dataclass(frozen=True)
class Effect(Part):
    """Base class of effects: a part the diagnosis loop can add to a model.

    A user's effect needs only what a part needs (``name``, ``stage``,
    ``parameters``, ``apply``) and the :func:`register_effect` decorator. The
    rest has defaults:

    Class attributes
    ----------------
    reads : tuple of str
        States and signals the effect reads (``"u"`` is always there; ``"y"``
        is the output). :meth:`applicable` checks that the model has them.
    writes : tuple of str
        States whose rate the effect changes and signals it sets.
    binds : tuple of str
        Roles the effect binds to (:class:`Motion`): ``"velocity"`` (the model's
        velocity, linear or rotary), ``"position"`` (its position) or ``"angle"``
        (a rotary position [rad]). :meth:`applicable` checks them and says how to
        declare a missing one.
    entry : str
        Where the effect enters, for its first-order signature: ``"input"``
        (the model's input), ``"output"``, ``"rate:<state>"`` (the time derivative
        of a state) or ``"rate:@velocity"`` (the rate of the model's velocity,
        whatever its name: :meth:`entry_at`).
    signature : str
        What the effect leaves in the residual of a model without it.
    regressors : tuple of str
        Generic regressors of :mod:`hhra_phys.diagnosis.residual` it relates to.
    position_dependent : bool
        Whether it depends on a position-like state (it may extrapolate badly).
    sensor : bool
        Whether it describes the measurement, not the dynamics (a sensor's offset or
        drift): the loop judges such effects as their own kind of candidate, so a
        physics candidate that settles a round does not skip them (a drift and a
        biased valve leave the same trend; both explanations must meet in the tie
        rule).
    twin : tuple of str
        Discovered-term pieces that have the effect's own shape at its :attr:`entry`
        (``"sign(@velocity)"`` for a Coulomb friction; ``@velocity``, ``@position`` and
        ``@angle`` stand for the model's states of those roles): a discovered term holding
        one of them is named as this physics in its discovered form
        (:func:`~hhra_phys.effects.library_twins`). Empty: none.
    """

    stage: ClassVar[str] = INPUT_STAGE
    reads: ClassVar[tuple[str, ...]] = ()
    writes: ClassVar[tuple[str, ...]] = ()
    binds: ClassVar[tuple[str, ...]] = ()
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = ""
    regressors: ClassVar[tuple[str, ...]] = ()
    position_dependent: ClassVar[bool] = False
    sensor: ClassVar[bool] = False
    twin: ClassVar[tuple[str, ...]] = ()

    def applicable(self, model: Any) -> str | None:
        """``None`` if the effect can be added to ``model``, else the reason why not.

        Checks the parameter and state names against the model's, the roles in
        :attr:`binds` against the model's :attr:`~hhra_phys.model.Model.motion`
        (:meth:`unbound`), every name in :attr:`reads` and :attr:`writes` against the
        model's states and signals, and then that the model with the effect
        assembles. Never raises.
        """
        if self.name in model.part_names():
            return "already in the model"
        clash = set(model.params.names) & {p.name for p in self.parameters}
        if clash:
            return f"model already has parameters {sorted(clash)}"
        clash = set(model.state_names) & {s.name for s in self.states}
        if clash:
            return f"model already has states {sorted(clash)}"
        why = self.unbound(model)
        if why:
            return why
        have = set(model.state_names) | set(model.signal_names()) | {"u", "y"}
        missing = [n for n in dict.fromkeys((*self.reads, *self.writes)) if n not in have]
        if missing:
            return (f"needs {', '.join(repr(n) for n in missing)}, which the model has neither "
                    f"as a state nor as a signal (states: {', '.join(model.state_names)}; "
                    f"signals: {', '.join(model.signal_names()) or 'none'})")
        try:
            model.with_parts(self).functions(float(getattr(self, "dt", 0.004) or 0.004))
        except Exception as exc:  # noqa: BLE001 - any failure means "cannot be added"
            return f"the model with it does not assemble: {exc}"
        return None

    def unbound(self, model: Any) -> str | None:
        """``None`` if the model has every role in :attr:`binds`, else which one it lacks
        and how to declare it."""
        motion: Motion = model.motion
        for role in self.binds:
            if role == "velocity" and motion.velocity is None:
                return (f"{self.name} needs a state with role 'velocity' (or "
                        f"'angular_velocity'); {_why(motion, 'velocity', _DECLARE_VELOCITY)}")
            if role in ("position", "angle") and motion.position is None:
                return (f"{self.name} needs a state with role '{role}'; "
                        f"{_why(motion, 'position', _DECLARE_POSITION)}")
            if role == "angle" and not motion.rotary:
                return (f"{self.name} needs a rotary position (a state with role 'angle' "
                        f"[rad]); the model's position {motion.position!r} is linear: "
                        "declare State(..., role='angle') if it is an angle in rad")
        return None

    @classmethod
    def entry_at(cls, model: Any) -> str:
        """:attr:`entry` on ``model``: ``"rate:@velocity"`` becomes ``"rate:<name>"`` of
        the model's velocity state (:attr:`Model.motion`); other entries as declared (a
        class attribute: callable on the class, as :func:`~hhra_phys.effects.library_twins`
        does)."""
        if cls.entry == "rate:@velocity" and model.motion.velocity is not None:
            return f"rate:{model.motion.velocity}"
        return cls.entry

    @classmethod
    def unasked(cls, model: Any) -> str | None:
        """Why the diagnosis loop does not try this effect on ``model`` unless asked
        (``LoopOptions.candidates``, CLI ``--effects``), or ``None`` (the default: every
        applicable effect is tried). For an effect whose refit costs much on a kind of model
        where it was not offered before (the backlash on a linear position)."""
        return None

    @classmethod
    def scaled_fields(cls, auto: Mapping[str, Any], model: Any) -> dict[str, Any]:
        """The fields :func:`~hhra_phys.effects.make_effect` sets from a record, a fit and
        the model (``auto``: ``u_scale``, ``dt``, ``y_scale``, ``y_unit``, and the motion's
        ``accel_scale``, ``v_scale``, ``v_unit``, ``friction_width``): by default those of ``auto``
        that are fields of the class. An effect whose fields mean something else in
        another model's units (the backlash's widths are in output units) overrides it."""
        fields = getattr(cls, "__dataclass_fields__", {})
        return {k: v for k, v in auto.items() if k in fields}

    def probe(self) -> dict[str, float]:
        """Parameter values of a small but relevant size of the effect."""
        return {p.name: p.nominal for p in self.parameters}

    def first_order(self, sig: Signals) -> np.ndarray | None:
        """Change at :attr:`entry` made by the effect at its probe size, shape (N, k).

        ``None`` (the default) when the effect declares no first-order
        signature: the loop then refits it without a ranking score.
        """
        return None


def _why(motion: Motion, what: str, how: str) -> str:
    """The model's own reason for a missing role (several candidates...) or ``how``."""
    for part in motion.why.split("; "):
        if what in part and "several" in part:
            return part
    return how


#: Registry: effect name -> effect class (candidates of the diagnosis loop).
EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Register an effect class as a candidate of the diagnosis loop (class decorator).

    The class is also registered as a part (:func:`register_part`), so models
    containing it can be saved and loaded. A later registration under the same
    :attr:`Effect.name` replaces the earlier one.

    Raises
    ------
    ModelError
        ``cls`` is not an :class:`Effect` subclass, or has no name of its own.
    """
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise ModelError(f"register_effect expects an Effect subclass, got {cls!r}")
    if cls.name in ("part", "") or not isinstance(cls.name, str):
        raise ModelError(f"effect class {cls.__name__} needs a class attribute 'name'")
    register_part(cls)
    EFFECTS[cls.name] = cls
    return cls


# --- smooth helpers --------------------------------------------------------


def smooth_sign(v: ca.SX, eps: float) -> ca.SX:
    """Smooth sign ``v / sqrt(v^2 + eps^2)``: exact far from 0, differentiable at 0.

    ``eps`` has the unit of ``v``; the transition width is about ``2*eps``.
    """
    return v / ca.sqrt(v * v + eps * eps)


def smooth_signed_sqrt(z: ca.SX, delta: float) -> ca.SX:
    """Smooth ``sign(z)*sqrt(|z|)``, normalised to be exact at ``z = 1``.

    ``sign(z) * (sqrt(|z| + delta) - sqrt(delta)) / (sqrt(1 + delta) - sqrt(delta))``.
    It is continuously differentiable, with the finite slope
    ``1/(2 sqrt(delta))`` (over the normaliser) at ``z = 0``, which bounds the
    stiffness of the orifice equation at the supply pressure; its value at the
    rest operating point ``z = 1`` is exact, so the linearisation at rest equals
    the paper's linearised valve. For ``delta = 1e-6`` it is within 0.1 % of
    ``sqrt(z)`` for ``z >= 0.25`` and within 1 % for ``z >= 0.01``. One square
    root and no division: the valve law dominates the cost of a simulation and
    square roots and divisions are its slow operations.
    """
    norm = 1.0 / (math.sqrt(1.0 + delta) - math.sqrt(delta))
    mag = (ca.sqrt(ca.fabs(z) + delta) - math.sqrt(delta)) * norm
    return ca.sign(z) * mag


def smooth_abs(v: ca.SX, eps: float) -> ca.SX:
    """Smooth ``|v|`` as ``sqrt(v^2 + eps^2) - eps`` (exact at 0, error below ``eps``)."""
    return ca.sqrt(v * v + eps * eps) - eps


def smooth_relu(v: ca.SX, eps: float) -> ca.SX:
    """Smooth ``max(v, 0)`` as ``(v + sqrt(v^2 + eps^2)) / 2``."""
    return 0.5 * (v + ca.sqrt(v * v + eps * eps))


def corner_relu(v: Any, w: float) -> Any:
    """``max(v, 0)`` with a quadratic corner: exact for ``|v| >= w``, C1 everywhere.

    ``(v + w)^2/(4w)`` for ``|v| < w`` (value ``w/4`` at 0, slope from 0 to 1).
    Unlike ``(v + sqrt(v^2 + w^2))/2`` it leaves no residual away from the corner:
    a command held a little off a dead-zone or saturation edge is passed exactly,
    where the square-root form's error ``w^2/(4|v|)``, integrated by the angle,
    drifts (``docs/model.md``, numerical choices). Works on CasADi and NumPy values.

    Parameters
    ----------
    v : SX or ndarray
        Argument (input units).
    w : float
        Half width of the corner (input units), > 0.
    """
    fmin, fmax = (ca.fmin, ca.fmax) if isinstance(v, (ca.SX, ca.MX)) else (np.minimum, np.maximum)
    r = fmin(fmax(v + w, 0), 2 * w)
    return r * r / (4 * w) + fmax(v - w, 0)
