"""A dynamic model composed of parts: the generic core of hhra-phys.

A :class:`Model` is a list of :class:`~hhra_phys.parts.Part` objects assembled
into CasADi functions ``xdot = f(x, u_lags, p)`` and ``y = h(x, u_lags, p)``.
It knows no state, signal or part name of any particular system: the bundled
models (:mod:`hhra_phys.models`) and a user's own are packages of parts, and
effects (:mod:`hhra_phys.effects`, or a user's, see
:func:`~hhra_phys.parts.register_effect`) are further parts added with
:meth:`Model.with_parts`.

Order of assembly. Input-side effects (an :class:`~hhra_phys.parts.Effect` of
stage ``"input"``) first, in list order; then the model's stages, in the order
given (``stages=``) or of first appearance in the part list, each stage's parts
in list order; a stage the model does not name (``"output"`` of an output-side
effect) after those, in order of first appearance. States are ordered as their
parts appear in the list.

Example: a user's two-tank process::

    from hhra_phys import Model, Part, State, Parameter, register_part

    @register_part
    @dataclass(frozen=True)
    class Tank(Part):
        name = "tank"
        stage = "tank"
        ...

    model = Model([Inflow(), Tank(), LevelSensor()])   # stages: inflow, tank, sensor
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields, is_dataclass
from typing import Any

import casadi as ca
import numpy as np

from hhra_phys.errors import HHRAError, ModelError
from hhra_phys.outputs import jsonable
from hhra_phys.parameters import ParameterSet
from hhra_phys.parts import (
    INPUT_STAGE,
    PART_TYPES,
    Context,
    Effect,
    Motion,
    Part,
    State,
    part_type_name,
    register_part,
    resolve_motion,
)

__all__ = ["DerivedQuantity", "Model", "register_part", "MODEL_TYPES"]

@dataclass(frozen=True)
class DerivedQuantity:
    """A quantity a model derives from its parameters (a transfer-function coefficient,
    a natural frequency), reported with a 95 % interval by the fit.

    Attributes
    ----------
    unit : str
        Its unit.
    function : callable
        ``function(values) -> value`` with ``values`` the model's parameters by name. It
        must use only arithmetic and CasADi-compatible functions (``+ - * / **``,
        ``casadi.sqrt``, ...): the fit calls it with CasADi symbols for the free
        parameters to get its exact gradient (the delta method,
        :func:`hhra_phys.result.derived_estimates`).
    description : str
        What it is, in words.
    positive : bool
        The quantity is positive by construction: its interval is taken on its
        logarithm (asymmetric, never crossing zero, as the log-scaled parameters').
    """

    unit: str
    function: Callable[[Mapping[str, Any]], Any]
    description: str = ""
    positive: bool = False


#: Factor of 10 around a new nominal value for log-scaled bounds (:meth:`Model.with_nominal`).
GROUP_SPAN = 10.0

#: Model classes by class name, for JSON round trips (filled by subclassing).
MODEL_TYPES: dict[str, type[Model]] = {}


def _check_parts(parts: Sequence[Part]) -> None:
    """Refuse anything but :class:`Part` objects, and a part without a stage name."""
    for part in parts:
        if not isinstance(part, Part):
            raise ModelError(f"a model is made of Part objects, got {part!r}")
        if not isinstance(part.stage, str) or not part.stage:
            raise ModelError(f"part {part.name!r} has no stage name (a non-empty string)")


def _model_states(parts: Sequence[Part], name: str, pinned: Sequence[str]) -> list[State]:
    """The parts' states in part order: at least one, each name once, ``pinned`` among them."""
    states: list[State] = []
    for part in parts:
        states.extend(part.states)
    names = [s.name for s in states]
    if len(set(names)) != len(names):
        raise ModelError(f"duplicate state names in model {name!r}: {names}")
    if not states:
        raise ModelError(f"model {name!r} has no states")
    unknown = sorted(set(pinned) - set(names))
    if unknown:
        raise ModelError(f"pinned states {unknown} are not states of the model ({names})")
    return states


class Model:
    """A dynamic model composed of parts, assembled into CasADi functions.

    Parameters
    ----------
    parts : sequence of Part
        The parts (module docstring for the order they run in).
    stages : sequence of str, optional
        Order of the stages; default: order of first appearance in ``parts``.
        A stage of a part not listed here runs after the listed ones (input-side
        effects before everything).
    name : str
        A label used in reports.
    overrides : dict, optional
        ``{parameter: {"nominal": .., "lower": .., "upper": ..}}`` or
        ``{parameter: value}`` (sets the nominal value) applied on top of the
        parts' own parameter declarations.
    pinned : sequence of str, optional
        States whose initial value is never fitted (held at
        :attr:`State.initial <hhra_phys.parts.State.initial>`), in addition to
        those declared with ``fit_initial=False``.
    held : sequence of str, optional
        Parameters a fit holds at their nominal value unless they are freed
        explicitly (e.g. a spring that is absent on the usual rig).
    velocity, position : str, optional
        The velocity state whose rate forces act on and its position, by name, where
        the states' roles do not say it (several states with a velocity role). By
        default the state with role ``"velocity"`` (or ``"angular_velocity"``) and the
        one with role ``"position"`` (or ``"angle"``): :attr:`motion`.
    feedthrough : bool
        The input acts on the measured output directly (not only through the states):
        only then may a discovered output term use the input
        (:func:`hhra_phys.diagnosis.screening.input_followers`). Default ``False``.

    Notes
    -----
    The model is immutable: :meth:`with_parts`, :meth:`without` and
    :meth:`with_nominal` return new models.
    """

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        MODEL_TYPES[cls.__name__] = cls

    def __init__(
        self,
        parts: Sequence[Part],
        stages: Sequence[str] | None = None,
        name: str = "model",
        overrides: Mapping[str, Any] | None = None,
        pinned: Sequence[str] = (),
        held: Sequence[str] = (),
        velocity: str | None = None,
        position: str | None = None,
        feedthrough: bool = False,
    ) -> None:
        if isinstance(stages, str):
            raise ModelError(
                f"stages must be a sequence of stage names, got the string {stages!r} "
                "(the model's name is the keyword name=)"
            )
        self.parts: tuple[Part, ...] = tuple(parts)
        _check_parts(self.parts)
        self.name = name
        self._overrides: dict[str, dict[str, Any]] = {}
        for pname, spec in (overrides or {}).items():
            self._overrides[pname] = dict(spec) if isinstance(spec, dict) else {"nominal": spec}
        self._stages_given = tuple(stages) if stages is not None else None
        self._ordered = self._order()
        self.params = self._parameter_set()
        states = _model_states(self.parts, name, pinned)
        self.pinned: tuple[str, ...] = tuple(pinned)
        unknown = sorted(set(held) - set(self.params.names))
        if unknown:
            raise ModelError(f"held parameters {unknown} are not parameters of the model")
        self.held: tuple[str, ...] = tuple(held)
        self.states: tuple[State, ...] = tuple(states)
        self._motion_given = (velocity, position)
        #: Whether the input acts on the output directly (declared; see ``feedthrough``).
        self.feedthrough = bool(feedthrough)
        #: The velocity whose rate forces act on and its position (bound by role).
        self.motion: Motion = resolve_motion(self.states, velocity, position)
        self.n_lags = max((part.n_lags for part in self.parts), default=0)
        self._cache: dict[float, dict[str, ca.Function]] = {}
        self._signal_names: tuple[str, ...] | None = None

    def _parameter_set(self) -> ParameterSet:
        """The parts' parameters in assembly order, with the overrides applied."""
        params = []
        for part in self._ordered:
            params.extend(part.parameters)
        base = ParameterSet(params)  # raises on duplicates
        for pname, changes in self._overrides.items():
            base = base.replace(pname, **changes)
        return base

    def _order(self) -> list[Part]:
        """Parts in assembly order (module docstring)."""
        first = [p for p in self.parts if isinstance(p, Effect) and p.stage == INPUT_STAGE]
        rest = [p for p in self.parts if not any(p is q for q in first)]
        order = list(self._stages_given or ())
        for part in rest:
            if part.stage not in order:
                order.append(part.stage)
        self.stages: tuple[str, ...] = tuple(order)
        ranked = sorted(enumerate(rest), key=lambda ip: (order.index(ip[1].stage), ip[0]))
        return first + [p for _, p in ranked]

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

    # -- model-specific views (overridden by models that have them) ------------------
    #: Name of the input in linear systems and reports.
    input_name: str = "u"

    @property
    def output_name(self) -> str:
        """Name of the output in linear systems and reports."""
        return "y"

    def operating_state(self, x: np.ndarray, **named: float) -> np.ndarray:
        """State vector ``x`` moved to an operating point given by model-specific names.

        The generic model knows no such names: any non-zero value is an error
        (give states by name instead). The HHRA reads ``current``, ``angle``,
        ``pressure`` and ``velocity``.
        """
        extra = {k: v for k, v in named.items() if v and k != "current"}
        if extra:
            raise ModelError(
                f"operating point {sorted(extra)} is not defined for model {self.name!r}; "
                f"give its states by name ({', '.join(self.state_names)})")
        return x

    def tf_coefficients_of(self, values: Mapping[str, float]) -> dict[str, float]:
        """A transfer function of the model from fitted values, if it defines one (else ``{}``)."""
        return {}

    def derived_quantities(self) -> dict[str, DerivedQuantity]:
        """Quantities derived from the parameters that a fit reports with intervals.

        The generic model declares none (``{}``); a model overrides this (the HHRA:
        the paper's transfer-function coefficients ``a``, ``b``, ``c``, ``kv``).
        """
        return {}

    def physical_view(
        self, values: Mapping[str, float], datasheet: Any = None,
        metadata: Mapping[str, Any] | None = None,
    ) -> tuple[dict[str, float] | None, str | None]:
        """Physical symbols from fitted parameters and a datasheet, and a warning if any.

        The generic model has no physical view: ``(None, None)``.
        """
        return None, None

    # -- derived models ------------------------------------------------------------
    @property
    def fitted_states(self) -> list[str]:
        """States whose initial value a fit estimates (``fit_initial`` and not pinned)."""
        return [s.name for s in self.states if s.fit_initial and s.name not in self.pinned]

    def role_of(self, state: str) -> str | None:
        """The declared role of ``state`` (:data:`hhra_phys.parts.ROLES`), or ``None``."""
        return self.states[self.state_names.index(state)].role

    def sensor_states(self) -> list[str]:
        """States of sensor effects (:attr:`hhra_phys.parts.Effect.sensor`, a drift's
        ``y_drift``): the measurement's, never read inside the dynamics."""
        return [s.name for part in self.parts if getattr(part, "sensor", False)
                for s in part.states]

    def signal_names(self) -> list[str]:
        """Names of the signals the assembled model provides (``"y"`` among them)."""
        if self._signal_names is None:
            x, u, p = self.symbols()
            ctx = self._context(x, u, p, 0.004)
            self._signal_names = tuple(ctx.signals)
        return list(self._signal_names)

    def _derive(self, parts: Sequence[Part], overrides: dict[str, Any]) -> Model:
        new = Model.__new__(type(self))
        keep_stages = self._stages_given
        names = {s.name for q in parts for s in q.states}
        pinned = [s for s in self.pinned if s in names]
        pnames = {par.name for q in parts for par in q.parameters}
        held = [n for n in self.held if n in pnames]
        velocity, position = (n if n in names else None for n in self._motion_given)
        Model.__init__(new, parts, keep_stages, self.name, overrides, pinned, held,
                       velocity, position, self.feedthrough)
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
        ctx = self._context(x, u_lags, p, dt)
        xdot = ca.vertcat(*[ctx.rates[s.name] for s in self.states])
        return xdot, ctx.signals["y"]

    def _context(self, x: ca.SX, u_lags: ca.SX, p: ca.SX, dt: float) -> Context:
        """Run every part on a fresh context; raise if no part sets the output ``y``."""
        ctx = Context(
            {s.name: x[i] for i, s in enumerate(self.states)},
            {name: p[i] for i, name in enumerate(self.params.names)},
            u_lags,
            dt,
            self.motion,
        )
        for part in self._ordered:
            try:
                part.apply(ctx)
            except HHRAError:
                raise
            except Exception as exc:  # a user's part: say which one failed, and where
                raise ModelError(_apply_failed(part, exc)) from exc
        if "y" not in ctx.signals:
            raise ModelError(
                f"model {self.name!r} has no output part: no part sets ctx.signals['y']")
        return ctx

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
            parts.append({"type": part_type_name(type(part)), "args": jsonable(args)})
        return {
            "class": type(self).__name__,
            "name": self.name,
            "parts": parts,
            "overrides": self._overrides,
            "stages": list(self._stages_given) if self._stages_given is not None else None,
            "pinned": list(self.pinned),
            "held": list(self.held),
            # Only where declared: a model bound by its states' roles saves as before.
            **{k: v for k, v in zip(("velocity", "position"), self._motion_given,
                                     strict=True) if v is not None},
            **({"feedthrough": True} if self.feedthrough else {}),
        }

    @classmethod
    def from_json(cls, spec: dict[str, Any]) -> Model:
        """Rebuild a model saved with :meth:`to_json`.

        Every part class must be registered (:func:`~hhra_phys.parts.register_part`):
        the package's own are when :mod:`hhra_phys` is imported; a user's when
        the module defining them is imported.
        """
        target = MODEL_TYPES.get(str(spec.get("class")), Model)
        upgrade = getattr(target, "upgrade_spec", None)
        if upgrade is not None:
            spec = upgrade(spec)
        parts = []
        for entry in spec["parts"]:
            typ = PART_TYPES.get(entry["type"])
            if typ is None:
                raise ModelError(
                    f"unknown part type {entry['type']!r} in saved model: import the "
                    "module that defines and registers it (register_part) before "
                    f"loading; known: {', '.join(sorted(PART_TYPES))}"
                )
            args = {k: tuple(v) if isinstance(v, list) else v for k, v in entry["args"].items()}
            known = {f.name for f in fields(typ)} if is_dataclass(typ) else set(args)
            if set(args) - known:
                raise ModelError(
                    f"saved model part {entry['type']!r} has settings this version does not "
                    f"know: {sorted(set(args) - known)} (known: {sorted(known)}); earlier "
                    "versions' smoothing settings (eps, eps_omega) were removed")
            parts.append(typ(**args))
        new = Model.__new__(target)
        stages = spec.get("stages")
        Model.__init__(new, parts, stages, spec.get("name", "model"), spec.get("overrides"),
                       spec.get("pinned", ()), spec.get("held", ()), spec.get("velocity"),
                       spec.get("position"), bool(spec.get("feedthrough", False)))
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


def _apply_failed(part: Part, exc: Exception) -> str:
    """Which part's ``apply`` raised what, with the file and line of the raise."""
    import inspect
    import traceback

    cls = type(part)
    try:
        where = inspect.getsourcefile(cls) or cls.__module__
    except TypeError:
        where = cls.__module__
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if f.name == "apply"]
    line = f", line {frames[-1].lineno}: {frames[-1].line}" if frames else ""
    return (f"part {part.name!r} ({cls.__name__} in {where}{line}) failed while building the "
            f"model: its apply(ctx) raised {type(exc).__name__}: {exc} (ctx.p holds the "
            "parameters the model declares, ctx.x its states, ctx.signals the signals set by "
            "earlier stages)")
