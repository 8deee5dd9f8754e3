"""A fitting problem: model + records + cost + which parameters are free, and how scaled.

:class:`Problem` is what optimisers and refiners see, for one record or several (one
record is a set of one; each record's part is a :class:`RecordProblem`). It maps between

* the model's full parameter vector ``p`` (physical units, ``model.params`` order), and
* the *fitting coordinates* ``z`` of the free parameters only, in which the
  search box is given and the optimisers move.

Fitting coordinates. Positive groups spanning decades use ``z = log10(value in
SI units)``; signed parameters (offsets, loads) use ``z = value / s`` with ``s``
half the width of their box. The coordinates are absolute on purpose: H-GWO's
mutation ``lam * X_alpha`` pulls toward ``z = 0`` (``docs/benchmarks.md``), and
coordinates centred on the nominal values or the box centre would turn that pull
into a bias toward them whatever the data say. Here ``z = 0`` is one SI unit,
unrelated to either (and the fitting pipeline uses ``lam = 1`` by default,
see :mod:`hhra_phys.fit`).

Initial state: one rule for every model, from the states' declarations
(:class:`~hhra_phys.parts.State` ``fit_initial`` and ``scale``, and the model's
``pinned`` states); no part or state name is special.

``"zero"``
    every state at its declared ``initial`` value;
``"data"``
    as ``"zero"``, then the *fitted states* (``fit_initial`` and not pinned) moved
    by the least-norm change that makes the model's output equal the first
    measured sample (Newton steps on ``y = h(x)``; exact in one step for an
    output linear in the states, such as an angle in degrees or a pressure with
    gain and offset);
``"fit"``
    every fitted state's initial value is a free parameter ``x0_<state>``,
    started at its ``"data"`` value and searched within ``+- scale`` of it.

A later part of a record (the loop's selection and test parts, a fit's validation part:
a :class:`~hhra_phys.data.Dataset` that knows its place, ``origin``) starts through a
*leading window*, the samples just before it in its record (:meth:`RecordProblem.lead_window`,
issue 33): its input memory (the model's input lags and the inter-sample rule's
neighbours), so that a delay holds the inputs before the part and a lag (a filter state)
runs into it. The state at the window's start is set by the ``"data"`` rule there and,
under ``"fit"``, re-estimated on the part's outputs through the window
(:data:`HELD_OUT_STATE` ``"part"``, the convention of comparing models on validation
data), or on an unscored window of :data:`LEAD_FRACTION` of the part before it
(``"window"``: measured, not the default; on the public record it scores the same final
fit 0.396 on test where the state fitted on the part gives 0.371, docs/diagnosis.md).
Before, each part started at its own first sample with the input before it held at its
first value (under ``"fit"`` with the state re-estimated on the part itself).
On another record (a separate validation record, prediction) the ``"data"`` rule starts
it and, under ``"fit"``, the whole initial state is then re-estimated on that record
with the parameters fixed (:func:`estimate_initial_state`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Literal

import casadi as ca
import numpy as np
from scipy.optimize import least_squares

from hhra_phys.data import DataError, Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.model import Model
from hhra_phys.parameters import Parameter, as_number, record_name, split_record_name
from hhra_phys.simulate import Simulator, accuracy_tolerance

__all__ = [
    "COSTS",
    "LEAD_FRACTION",
    "Problem",
    "RecordProblem",
    "as_records",
    "default_free",
    "data_rule_function",
    "estimate_initial_state",
    "initial_guess",
    "per_record_params",
    "record_label",
]

CostName = Literal["itae", "mse", "rmse", "ssr"]
COSTS: tuple[str, ...] = ("itae", "mse", "rmse", "ssr")

#: Newton steps of the ``"data"`` rule (one is exact for an output linear in the states).
DATA_RULE_STEPS = 3

#: Decades a default box side may be widened in all (:func:`hhra_phys.fit.fit` widens one
#: per refit; a start value beyond it widens as many as it needs up to this). Three decades
#: beyond the factor-10 default box (a factor 10^4 from nominal) is the most a group of a
#: working actuator can plausibly differ from the rig's; further out a group at its edge is
#: a model or unit error, which the edge warning reports.
MAX_WIDEN_DECADES = 3


#: Under :data:`HELD_OUT_STATE` ``"window"``: a held-out part's leading window beyond the
#: model's input memory, as a fraction of the part's length (never scored).
LEAD_FRACTION = 0.25
#: Where a held-out part's state under ``"fit"`` is estimated (:meth:`RecordProblem.lead_window`):
#: ``"window"`` on a leading window that the part's score never sees (its input memory and
#: then :data:`LEAD_FRACTION` of the part), ``"part"`` on the part's own outputs through
#: a window of its input memory only (the convention of comparing models on validation data,
#: with the inputs a delay or a filter needs from before the part).
HELD_OUT_STATE = "part"


def default_free(model: Model, fixed: Mapping[str, float] | None = None) -> list[str]:
    """Parameters a fit frees by default: all but the model's ``held`` ones and ``fixed``.

    (The HHRA holds its spring and constant-load groups, and for a pressure
    output alone the displacement group, whose scale a pressure cannot see.)
    """
    held = set(model.held) | set(fixed or {})
    return [n for n in model.params.names if n not in held]


def data_rule_function(model: Model, dt: float) -> ca.Function:
    """CasADi function ``(y0, u0, p) -> x0`` of the ``"data"`` rule (module docstring).

    Symbolic in every argument, so the rule is differentiated exactly where the
    initial state depends on parameters (a pressure sensor's gain and offset).
    """
    cache = model.__dict__.setdefault("_data_rule_cache", {})
    key = float(dt)
    if key in cache:
        return cache[key]
    xs, us, ps = model.symbols()
    y0 = ca.SX.sym("y0")
    u0 = ca.SX.sym("u0")
    _, h = model.assemble(xs, us, ps, dt)
    fitted = [model.state_names.index(n) for n in model.fitted_states]
    x = ca.SX(model.x0())
    if fitted:
        xf = ca.vertcat(*[xs[i] for i in fitted])
        hu = ca.substitute(h, us, ca.repmat(u0, us.numel(), 1))
        J = ca.jacobian(hu, xf)
        jj = ca.mtimes(J, J.T)
        step = ca.Function("newton", [xs, y0, u0, ps],
                           [ca.if_else(jj > 0, J.T * (y0 - hu) / jj, ca.SX.zeros(len(fitted)))])
        for _ in range(DATA_RULE_STEPS):
            dxf = step(x, y0, u0, ps)
            x = ca.vertcat(*[x[i] + dxf[fitted.index(i)] if i in fitted else x[i]
                             for i in range(model.nx)])
    fn = ca.Function("x0_data_rule", [y0, u0, ps], [x], ["y0", "u0", "p"], ["x0"])
    cache[key] = fn
    return fn


def _check_choices(cost: str, initial_state: str) -> None:
    """The cost and the initial-state rule are known ones."""
    if cost not in COSTS:
        raise ParameterError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
    if initial_state not in ("data", "zero", "fit"):
        raise ParameterError(
            f"initial_state must be 'data', 'zero' or 'fit', got {initial_state!r}"
        )


def as_records(data: Dataset | Sequence[Dataset]) -> list[Dataset]:
    """One record or several as a list of records (one record: a list of one).

    Raises
    ------
    ParameterError
        No record, or an item that is not a :class:`~hhra_phys.data.Dataset`.
    """
    if isinstance(data, Dataset):
        records = [data]
    elif isinstance(data, str | bytes) or not isinstance(data, Sequence | tuple | list):
        raise ParameterError(
            f"data must be a Dataset or a sequence of Dataset objects, got "
            f"{type(data).__name__} {data!r:.60}; load a file with hhra_phys.data.load(path)")
    else:
        records = list(data)
    if not records:
        raise ParameterError("a fitting problem needs at least one record")
    for ds in records:
        if not isinstance(ds, Dataset):
            raise ParameterError(f"records must be Dataset objects, got {type(ds).__name__}")
    return records


def record_label(ds: Dataset, k: int) -> str:
    """A record's label in reports: its name, or its source, or ``"record <k>"`` (from 1)."""
    return ds.name or ds.source or f"record {k}"


def per_record_params(model: Model) -> list[str]:
    """Model parameters estimated once per record: those its parts list in ``per_record``."""
    out: list[str] = []
    for part in model.parts:
        out += [n for n in getattr(part, "per_record", ()) if n in model.params.names]
    return out


def _per_record_split(values: Mapping[str, float] | None, n: int, what: str
                      ) -> tuple[dict[str, float], list[dict[str, float]]]:
    """``{name or name_rec<k>: value}`` -> (shared values, one dict per record)."""
    shared: dict[str, float] = {}
    own: list[dict[str, float]] = [{} for _ in range(n)]
    if values is not None and not isinstance(values, Mapping):
        raise ParameterError(f"{what}s must be a mapping {{name: value}}, got "
                             f"{type(values).__name__} {values!r:.60}")
    for name, value in (values or {}).items():
        base, k = split_record_name(name)
        v = as_number(value, f"{what} {name}={value!r}")
        if k is None:
            shared[name] = v
        elif k > n:
            raise ParameterError(f"{what} {name!r}: there are only {n} records")
        else:
            own[k - 1][base] = v
    return shared, own


def _simulators_by_rate(simulator: Simulator | Mapping[float, Simulator] | None,
                        records: Sequence[Dataset]) -> dict[float, Simulator]:
    """``{fs: Simulator}`` of the simulators given (one, by rate, or none)."""
    if simulator is None:
        return {}
    if isinstance(simulator, Mapping):
        return {float(k): v for k, v in simulator.items()}
    if not any(abs(simulator.fs - ds.fs) <= 1e-9 * ds.fs for ds in records):
        raise DataError(f"dataset sample rate {records[0].fs} Hz differs from the "
                        f"simulator's {simulator.fs} Hz")
    return {float(ds.fs): simulator for ds in records
            if abs(simulator.fs - ds.fs) <= 1e-9 * ds.fs}


class _Coordinates:
    """The map between free-parameter values and fitting coordinates, shared by a record's
    problem and the problem of a record set: ``log10`` for log-scaled parameters, the
    value over half its box width for linear ones (``_log``, ``_scale``, ``free_params``
    are the subclass's)."""

    _log: np.ndarray
    _scale: np.ndarray
    free_params: list[Parameter]

    def to_z(self, values: np.ndarray) -> np.ndarray:
        """Fitting coordinates of free-parameter values (physical units), shape (..., n_free)."""
        v = np.asarray(values, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self._log, np.log10(np.abs(v)), v / self._scale)

    def from_z(self, z: np.ndarray) -> np.ndarray:
        """Free-parameter values (physical units) of fitting coordinates, shape (..., n_free)."""
        zz = np.asarray(z, dtype=float)
        with np.errstate(over="ignore"):  # an extreme coordinate gives inf, flagged later
            return np.where(self._log, 10.0 ** zz, zz * self._scale)

    def bounds_z(self) -> np.ndarray:
        """Search box in fitting coordinates, shape (n_free, 2)."""
        lo = np.array([p.lower for p in self.free_params])
        hi = np.array([p.upper for p in self.free_params])
        return np.stack([self.to_z(lo), self.to_z(hi)], axis=1)


class RecordProblem(_Coordinates):
    """One record's part of a :class:`Problem`: model + record + cost + free parameters.

    A :class:`Problem` holds one per record (:attr:`Problem.records`); it is what the
    compiled sensitivities, the record-by-record analyses and the multiple-shooting
    refiner see. Build a :class:`Problem` (one record or several) to fit; its
    parameters are those of :class:`Problem`, for this record alone (its free
    parameters are named without a record suffix).

    Parameters
    ----------
    model : Model
    data : Dataset
        The record (estimation part).
    cost, free, fixed, bounds, initial_state, start, default_bounds, allow_outside_box
        As for :class:`Problem`, for this record.
    simulator : Simulator, optional
        A simulator of ``model`` at the record's sample rate to reuse (its sibling with
        the record's inter-sample behaviour, :meth:`Simulator.with_intersample`, if it
        differs); default: one built here with accuracy-chosen substeps.

    Attributes
    ----------
    explicit_bounds : frozenset of str
        Free parameters whose box was given in ``bounds`` (never widened).
    default_boxes : dict
        ``{name: (lower, upper)}``: the default box, before any widening, of every free
        log-scaled model parameter whose box may be widened.
    widened : list of dict
        Box sides widened here for a start value beyond them: ``name``, ``side``,
        ``round`` (0), ``from``, ``to``, ``reason`` (``"start"``).
    notes : list of str
        Fixed values accepted outside their box.

    Raises
    ------
    ParameterError, DataError
        As :class:`Problem`.
    """

    def __init__(
        self,
        model: Model,
        data: Dataset,
        cost: CostName = "itae",
        free: Sequence[str] | None = None,
        fixed: Mapping[str, float] | None = None,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        initial_state: Literal["data", "zero", "fit"] = "data",
        simulator: Simulator | None = None,
        start: Mapping[str, float] | None = None,
        default_bounds: Mapping[str, tuple[float, float]] | None = None,
        allow_outside_box: bool = False,
    ) -> None:
        _check_choices(cost, initial_state)
        self.model = model
        self.data = data
        self.cost = cost
        self.initial_state = initial_state
        start = self._checked_start(model, start)
        free = self._set_values(free, fixed, start, allow_outside_box)
        params = self._model_params(free, bounds, default_bounds, start)
        self._dt = 1.0 / data.fs
        params += self._initial_state_params(start)
        self.free_params = params
        self.free_names = [p.name for p in params]
        self._model_free = [model.params.index(p.name) for p in params
                            if not p.name.startswith("x0_")]
        self.n_free = len(params)
        self._check_size()
        self._scale = np.array([(p.upper - p.lower) / 2 if p.scale == "linear" else 1.0
                                for p in params])
        self._log = np.array([p.scale == "log" for p in params])
        self._set_simulator(simulator)

    @staticmethod
    def _checked_start(model: Model, start: Mapping[str, float] | None) -> dict[str, float]:
        """``start`` as ``{name: float}``: every name a parameter of the model or an
        ``x0_<state>``, every value a finite number (positive for a log-scaled one)."""
        if start is None:
            return {}
        if not isinstance(start, Mapping):
            raise ParameterError(f"start must be a mapping {{name: value}}, got "
                                 f"{type(start).__name__} {start!r:.60}")
        out: dict[str, float] = {}
        for name, value in start.items():
            v = as_number(value, f"start {name}={value!r}")
            if not math.isfinite(v):
                raise ParameterError(f"start {name}={value!r}: the value must be finite")
            if not str(name).startswith("x0_"):
                try:
                    par = model.params[model.params.index(name)]
                except ParameterError as exc:
                    raise ParameterError(f"start {name}={value!r}: {exc}") from None
                if par.scale == "log" and v <= 0:
                    raise ParameterError(f"start {name}={value!r}: {name} is a positive "
                                         "quantity (log scale); give a value > 0")
            out[name] = v
        return out

    def _set_values(self, free: Sequence[str] | None, fixed: Mapping[str, float] | None,
                    start: Mapping[str, float], allow_outside_box: bool) -> list[str]:
        """Check the free and fixed names; set :attr:`base`, :attr:`fixed`, :attr:`notes`."""
        model = self.model
        fixed = dict(fixed or {})
        # The one check of held values (also the CLI's --fix): name, sign, box.
        self.notes: list[str] = model.params.check_values(
            fixed, allow_outside_box=allow_outside_box, what="fixed")
        free = list(default_free(model, fixed) if free is None else free)
        for name in free:
            model.params.index(name)
            if name in fixed:
                raise ParameterError(f"parameter {name!r} is both free and fixed")
        if len(set(free)) != len(free):
            raise ParameterError(f"free parameters listed twice: {free}")
        self.base = model.nominal()
        for name, value in start.items():
            if not name.startswith("x0_"):
                self.base[model.params.index(name)] = float(value)
        for name, value in fixed.items():
            self.base[model.params.index(name)] = float(value)
        self.fixed = {n: float(self.base[model.params.index(n)])
                      for n in model.params.names if n not in free}
        return free

    def _model_params(self, free: list[str], bounds: Mapping[str, tuple[float, float]] | None,
                      default_bounds: Mapping[str, tuple[float, float]] | None,
                      start: Mapping[str, float]) -> list[Parameter]:
        """The free model parameters with their boxes (explicit, default, widened for a start)."""
        self.explicit_bounds: frozenset[str] = frozenset(bounds or {})
        self.default_boxes: dict[str, tuple[float, float]] = {}
        self.widened: list[dict[str, object]] = []
        unknown = set(bounds or {}) - set(free)
        if unknown:
            raise ParameterError(
                f"bounds given for parameters that are not free: {sorted(unknown)}"
            )
        params: list[Parameter] = []
        for name in free:
            par = self.model.params[name]
            box = (bounds or {}).get(name, (default_bounds or {}).get(name))
            if box is not None:
                lo, hi = (float(b) for b in box)
                nominal = min(max(par.nominal, lo), hi)
                par = par.with_(lower=lo, upper=hi, nominal=nominal)
            if name not in self.explicit_bounds:
                self.default_boxes[name] = (par.lower, par.upper)
                if par.scale == "log" and name in start:  # a given start, not a
                    # nominal off the box
                    par = self._box_for_start(par, float(start[name]))
            params.append(par)
        return params

    def _initial_state_params(self, start: Mapping[str, float]) -> list[Parameter]:
        """The ``x0_<state>`` parameters of the ``"fit"`` rule, started at ``start`` or the
        ``"data"`` rule's value."""
        model = self.model
        x0_start = {k: float(v) for k, v in start.items() if k.startswith("x0_")}
        self._x0_states: list[str] = (list(model.fitted_states)
                                      if self.initial_state == "fit" else [])
        params: list[Parameter] = []
        if self._x0_states:
            guess = self._x0_from_data(self.base[None, :])[0]
            for state in self._x0_states:
                st = model.states[model.state_names.index(state)]
                value = float(guess[model.state_names.index(state)])
                if not math.isfinite(value):
                    value = float(st.initial)
                name = f"x0_{state}"
                start_value = x0_start.pop(name, value)
                lo = min(value, start_value) - st.scale
                hi = max(value, start_value) + st.scale
                params.append(Parameter(name, st.unit, start_value, lo, hi, "linear",
                                        f"initial value of state {state!r}"))
        if x0_start:
            raise ParameterError(
                f"start values {sorted(x0_start)} name initial states that are not fitted "
                f"(fitted with initial_state='fit': {', '.join(model.fitted_states) or 'none'})"
            )
        return params

    def _check_size(self) -> None:
        """Something to fit, and at least ten samples per free parameter."""
        data = self.data
        if self.n_free == 0:
            raise ParameterError("no free parameters: nothing to fit")
        if len(data) < 10 * self.n_free:
            raise DataError(
                f"{data.source or data.name or 'dataset'}: {len(data)} samples are too few to fit "
                f"{self.n_free} parameters (need at least {10 * self.n_free})"
            )

    def _set_simulator(self, simulator: Simulator | None) -> None:
        """The record's simulator, with accuracy-chosen substeps when it chooses them."""
        data = self.data
        # The record says what its input did between samples; a simulator given for
        # another behaviour is swapped for its sibling (same method and substeps).
        self.sim = (simulator.with_intersample(data.intersample) if simulator is not None
                    else Simulator(self.model, fs=data.fs, intersample=data.intersample))
        if abs(self.sim.fs - data.fs) > 1e-9 * data.fs:
            raise DataError(
                f"dataset sample rate {data.fs} Hz differs from the simulator's {self.sim.fs} Hz"
            )
        self.u = data.u
        self.y = data.y
        self.t = data.t - data.t[0]
        if self.sim.substeps_auto:
            # Accuracy, not only stability, sets the substeps: at the start values the
            # estimated integration error stays below 10 % of the record's noise level
            # (Simulator.accurate); population search, IPOPT and predictions share them.
            v = self.start_values()
            self.sim = self.sim.accurate(self.u, self.full(v), accuracy_tolerance(self.y),
                                         x0=self.initial_states(v)[0])

    def _box_for_start(self, par: Parameter, value: float) -> Parameter:
        """``par`` with its default box widened by whole decades to hold a start ``value``."""
        lo, hi = par.lower, par.upper
        if not (math.isfinite(value) and value > 0) or lo <= value <= hi:
            return par
        side = "lower" if value < lo else "upper"
        decades = math.ceil(abs(math.log10(value / (lo if side == "lower" else hi))) - 1e-9)
        decades = min(decades, MAX_WIDEN_DECADES)
        new = (lo / 10**decades, hi) if side == "lower" else (lo, hi * 10**decades)
        self.widened.append({"name": par.name, "side": side, "round": 0, "from": [lo, hi],
                             "to": list(new), "reason": "start", "decades": decades})
        return par.with_(lower=new[0], upper=new[1])

    def start_values(self) -> np.ndarray:
        """Starting values of the free parameters (physical units)."""
        out = []
        for p in self.free_params:
            if p.name.startswith("x0_"):
                out.append(p.nominal)
            else:
                out.append(self.base[self.model.params.index(p.name)])
        return np.array(out)

    @property
    def x0_states(self) -> list[str]:
        """States whose initial value is a free parameter ``x0_<state>`` (``"fit"`` rule)."""
        return list(self._x0_states)

    def blocks(self) -> list[tuple[RecordProblem, np.ndarray]]:
        """This record as the one block of its coordinates (:meth:`Problem.blocks`)."""
        return [(self, np.arange(self.n_free))]

    def full(self, values: np.ndarray) -> np.ndarray:
        """Full model parameter vectors from free values, shape (..., n_params)."""
        v = np.atleast_2d(np.asarray(values, dtype=float))
        P = np.tile(self.base, (v.shape[0], 1))
        nm = len(self._model_free)
        P[:, self._model_free] = v[:, :nm]
        return P if np.ndim(values) > 1 else P[0]

    # -- initial state --------------------------------------------------------------------
    def _x0_from_data(self, P: np.ndarray, data: Dataset | None = None) -> np.ndarray:
        """Initial states (n_pop, nx) under the ``"data"`` rule for parameter rows ``P``."""
        d = self.data if data is None else data
        rule = data_rule_function(self.model, 1.0 / d.fs)
        n = P.shape[0]
        fn = rule if n == 1 else rule.map(n)
        X0 = np.array(fn(float(d.y[0]), float(d.u[0]), P.T), dtype=float)
        return X0.reshape(self.model.nx, n).T

    def initial_states(self, values: np.ndarray, data: Dataset | None = None) -> np.ndarray:
        """Initial states (n_pop, nx) for free-parameter values (n_pop, n_free).

        For a later part of a record (``data`` with a :meth:`lead_window`: the loop's
        selection and test parts, a fit's validation part) the state the model reaches
        at its first sample through the window. For another record (``data``, e.g. a
        separate validation record) the ``"data"`` rule is applied to it, and under
        ``"fit"`` the whole initial state is re-estimated on it
        (:meth:`fit_initial_state`): the fitted one belongs to the estimation record.
        """
        v = np.atleast_2d(np.asarray(values, dtype=float))
        if self.initial_state == "zero":
            return np.tile(self.model.x0(), (v.shape[0], 1))
        P = self.full(v)
        lead = None if data is None else self.lead_window(data)
        if lead is not None:  # through the leading window to the part's first sample
            u_w, _, _ = lead
            _, X = self.simulator_for(data).simulate(
                np.concatenate([u_w, data.u[:1]]), P, x0=self._window_states(P, data, lead),
                states=True)
            return X[:, u_w.size]
        if data is not None:
            X0 = self._x0_from_data(P, data)
            if self.initial_state == "fit":
                X0 = np.array([self.fit_initial_state(data, P[i], X0[i]) for i in range(len(P))])
            return X0
        if self.initial_state == "data":
            return self._x0_from_data(P)
        X0 = np.tile(self.model.x0(), (v.shape[0], 1))
        nm = len(self._model_free)
        for k, state in enumerate(self._x0_states):
            X0[:, self.model.state_names.index(state)] = v[:, nm + k]
        return X0

    def symbolic(self, z: ca.MX) -> tuple[ca.MX, ca.MX]:
        """Full parameter vector and initial state as CasADi expressions of coordinates ``z``.

        The same coordinates and initial-state rule as :meth:`from_z`,
        :meth:`full` and :meth:`initial_states`, for exact derivatives (IPOPT,
        sensitivities, profiles).
        """
        vals = [10 ** z[i] if p.scale == "log" else z[i] * self._scale[i]
                for i, p in enumerate(self.free_params)]
        pieces = [ca.MX(float(b)) for b in self.base]
        for k, j in enumerate(self._model_free):
            pieces[j] = vals[k]
        p_full = ca.vertcat(*pieces)
        if self.initial_state == "zero":
            return p_full, ca.MX(ca.DM(self.model.x0()))
        if self.initial_state == "data":
            rule = data_rule_function(self.model, self._dt)
            return p_full, rule(float(self.data.y[0]), float(self.data.u[0]), p_full)
        nm = len(self._model_free)
        x0 = [ca.MX(float(v)) for v in self.model.x0()]
        for k, state in enumerate(self._x0_states):
            x0[self.model.state_names.index(state)] = vals[nm + k]
        return p_full, ca.vertcat(*x0)

    def lead_window(self, data: Dataset) -> tuple[np.ndarray, np.ndarray, int] | None:
        """The samples just before ``data`` in its record: ``(u, y, skip)`` or ``None``.

        Defined when ``data`` was cut from a record (:attr:`Dataset.origin
        <hhra_phys.data.Dataset.origin>`: the loop's selection and test parts, a fit's
        validation part) after that record's first sample, at the problem's sample rate,
        and the rule is ``"data"`` or ``"fit"``. The window holds the model's input memory,
        ``n_lags + 2`` samples (what a delay or an interpolation reads before a sample),
        as far as the record reaches back, and under :data:`HELD_OUT_STATE` ``"window"``
        then :data:`LEAD_FRACTION` of the part's length (at least the memory again).
        ``skip``: the window's samples the state's fit leaves out (all of them under
        ``"part"``: the state is fitted on the part's outputs; the memory under
        ``"window"``). The part's score never includes the window.
        ``None`` otherwise (a separate record: its initial state by the rule on itself).
        """
        if self.initial_state == "zero" or data.origin is None:
            return None
        root, a = data.origin
        if a <= 0 or abs(data.fs - self.data.fs) > 1e-9 * data.fs:
            return None
        memory = self.model.n_lags + 2
        n = min(a, memory + (0 if HELD_OUT_STATE == "part" else
                             max(memory, int(round(LEAD_FRACTION * data.n)))))
        if HELD_OUT_STATE == "part":
            return (np.asarray(root.u[a - n:a], dtype=float),
                    np.asarray(root.y[a - n:a], dtype=float), n)
        return (np.asarray(root.u[a - n:a], dtype=float), np.asarray(root.y[a - n:a],
                                                                        dtype=float),
                min(memory, n - 1))

    def _window_states(self, P: np.ndarray, data: Dataset,
                       lead: tuple[np.ndarray, np.ndarray, int]) -> np.ndarray:
        """States (n_pop, nx) at the start of ``data``'s leading window: the ``"data"``
        rule on its first sample, under ``"fit"`` re-estimated through the window on the
        outputs after its first ``skip`` samples (the part's, under ``"part"``)."""
        u_w, y_w, memory = lead
        rule = data_rule_function(self.model, 1.0 / data.fs)
        n = P.shape[0]
        fn = rule if n == 1 else rule.map(n)
        X0 = np.array(fn(float(y_w[0]), float(u_w[0]), P.T), dtype=float)
        X0 = X0.reshape(self.model.nx, n).T
        if self.initial_state == "fit":
            sim = self.simulator_for(data)
            if HELD_OUT_STATE == "part":  # the part's outputs, through the window
                u_w, y_w = np.concatenate([u_w, data.u]), np.concatenate([y_w, data.y])
            X0 = np.array([estimate_initial_state(sim, u_w, y_w, P[i], X0[i], skip=memory)
                           for i in range(n)])
        return X0

    def fit_initial_state(
        self, data: Dataset, p: np.ndarray, x0: np.ndarray, iterations: int = 4
    ) -> np.ndarray:
        """Estimate the whole initial state on ``data`` (see :func:`estimate_initial_state`)."""
        return estimate_initial_state(self.simulator_for(data), data.u, data.y, p, x0, iterations)

    def simulator_for(self, data: Dataset) -> Simulator:
        """The problem's simulator, or one at ``data``'s sample rate and inter-sample
        behaviour if they differ."""
        if abs(data.fs - self.sim.fs) <= 1e-9 * data.fs:
            return self.sim.with_intersample(data.intersample)
        return Simulator(self.model, fs=data.fs, substeps=self.sim.substeps,
                         method=self.sim.method, intersample=data.intersample)

    # -- evaluation ------------------------------------------------------------------------
    def simulate_values(self, values: np.ndarray, data: Dataset | None = None) -> np.ndarray:
        """Simulated output for free-parameter values, (n_free,) -> (N,) or (n, n_free) -> (n, N).

        With ``data`` (e.g. the validation part) the simulation runs on its input: a
        later part of a record through its leading window (:meth:`lead_window`, not
        scored, cut off here), another record from the initial state the problem's rule
        gives it (:meth:`initial_states`).
        """
        single = np.ndim(values) == 1
        v = np.atleast_2d(np.asarray(values, dtype=float))
        P = self.full(v)
        lead = None if data is None or self.initial_state == "zero" else self.lead_window(data)
        if data is None:
            Y = self.sim.simulate(self.u, P, x0=self.initial_states(v))
        elif lead is not None:
            Y = self.simulator_for(data).simulate(
                np.concatenate([lead[0], data.u]), P,
                x0=self._window_states(P, data, lead))[:, lead[0].size:]
        else:
            Y = self.simulator_for(data).simulate(data.u, P, x0=self.initial_states(v, data))
        return Y[0] if single else Y

    def cost_of(self, Y: np.ndarray) -> np.ndarray:
        """Cost of simulated outputs (n, N) against the estimation data; non-finite -> inf.

        The same definition as the fused cost of :meth:`__call__` (one weighted
        sum, :meth:`_cost_weights`), evaluated in NumPy on given trajectories.
        """
        loss, weights, post = self._cost_weights()
        e = np.atleast_2d(np.asarray(Y, dtype=float)) - self.y[None, :]
        per = np.abs(e) if loss == "abs" else e * e
        c = per.sum(axis=1) if weights is None else per @ weights
        c = np.asarray(post(c), dtype=float)
        c = np.where(np.isfinite(c), c, np.inf)
        return c if np.ndim(Y) > 1 else c[0]

    def __call__(self, Z: np.ndarray) -> np.ndarray:
        """Vectorised objective in fitting coordinates: (n, n_free) -> (n,) costs.

        Candidates whose simulation is flagged (unstable, diverging) cost ``inf``.
        """
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        v = self.from_z(Z)
        # The cost is summed inside the compiled simulator (same value as
        # cost_of(simulate_values(v)) up to summation order, without moving
        # whole trajectories through NumPy).
        loss, weights, post = self._cost_weights()
        c = self.sim.simulate_cost(self.u, self.full(v), self.y, weights, loss,
                                   x0=self.initial_states(v))
        c = post(np.asarray(c, dtype=float))
        return np.where(np.isfinite(c), c, np.inf)

    def _cost_weights(
        self,
    ) -> tuple[str, np.ndarray | None, Callable[[np.ndarray], np.ndarray]]:
        """(loss, per-sample weights, final map) giving the cost from a weighted sum."""
        n = self.y.size
        if self.cost == "itae":
            t = self.t
            step = (t[-1] - t[0]) / (n - 1) if n > 1 else 0.0
            return "abs", (t - t[0]) * step, lambda c: c
        if self.cost == "ssr":
            return "sq", None, lambda c: c
        weights = np.full(n, 1.0 / n)
        return "sq", weights, (np.sqrt if self.cost == "rmse" else lambda c: c)

    # -- symbolic (for IPOPT / gradients) ----------------------------------------------------
    def residual_function(self) -> ca.Function:
        """CasADi function ``r(z) = y_sim(z) - y`` on the estimation record (MX, differentiable)."""
        if getattr(self, "_residual_fn", None) is not None:
            return self._residual_fn
        z = ca.MX.sym("z", self.n_free)
        p_full, x0 = self.symbolic(z)
        traj = self.sim.trajectory_function(self.y.size)
        U = self.sim.input_matrix(self.u)
        y_sim = traj(x0, p_full, ca.DM(U))
        r = ca.vec(y_sim[: self.y.size]) - ca.DM(self.y)
        self._residual_fn = ca.Function("residual", [z], [r], ["z"], ["r"])
        return self._residual_fn



class Problem(_Coordinates):
    """Model + one or several estimation records + cost + free/fixed parameters and scaling.

    The one fitting problem of the package: the fit, the diagnosis loop, discovery, the
    backward step and design see only it, whatever the number of records (one record is
    a set of one). Records are fitted together the way MATLAB's multi-experiment
    ``nlgreyest`` or PyBOP's multi-fitting problem do:

    * the model parameters are **shared** by every record (one coordinate each);
    * every record has its own **initial state** and its own value of the model's
      **per-record parameters** (parts list them in a ``per_record`` attribute, e.g. the
      zero of a pressure sensor, ``p_offset``, which drifts from day to day). With
      several records these are named ``<name>_rec<k>`` (``x0_theta_rec2``, record
      ``k`` counted from 1); with one record they keep their plain names
      (``x0_theta``);
    * records may differ in length and sample rate: one compiled simulator per sample
      rate is shared by the records at that rate.

    The cost of the global search is the sum of the records' costs (one population call
    per record); the least-squares residual of the refiners and of the uncertainty is
    the records' residuals stacked, with the exact Jacobian assembled record by record
    (:class:`~hhra_phys.refine.CompiledLeastSquares`, :meth:`blocks`), so intervals come
    from all records together. Each record's part is a :class:`RecordProblem`
    (:attr:`records`).

    Parameters
    ----------
    model : Model
        The model to fit (e.g. :class:`~hhra_phys.model.HHRAModel`), shared by all records.
    data : Dataset or sequence of Dataset
        Estimation record(s) (use :meth:`Dataset.split` first to keep validation data).
    cost : {"itae", "mse", "rmse", "ssr"}
        Cost minimised by the global search (each record's, summed): ITAE (the paper's),
        mean or root mean squared error, or the sum of squared residuals. Local
        refiners always minimise the (smooth) sum of squares.
    free : sequence of str, optional
        Names of the free model parameters (default: all except the model's ``held``
        ones, :func:`default_free`); the per-record copies are made here.
    fixed : dict, optional
        ``{name: value}``: parameters held at the given value (e.g. from a datasheet).
        A name both free and fixed is an error. ``<name>_rec<k>`` holds one record's
        value of a per-record parameter (the loop holds each record's sensor zero while
        it searches a candidate's new parameters); a plain name holds every record's.
    bounds : dict, optional
        ``{name: (lower, upper)}`` overriding the model's bounds (physical units): the
        user's explicit boxes, never widened (:attr:`explicit_bounds`).
    initial_state : {"data", "zero", "fit"}
        How each record's initial state is set (module docstring).
    simulator : Simulator or dict, optional
        A simulator of ``model`` to reuse, or ``{fs: Simulator}`` by sample rate [Hz]
        (the diagnosis loop's short-block candidate simulators); records at other rates
        get one built with accuracy-chosen substeps. Each record uses the sibling with
        its inter-sample behaviour (:meth:`Simulator.with_intersample`).
    start : dict, optional
        Parameter values to use instead of the model's nominal values for the
        parameters that are neither free nor fixed, and as the start of the search
        (first population member, local refiners). ``x0_<state>`` names start a fitted
        initial state; a plain name starts every record, ``<name>_rec<k>`` one record.
        A start value beyond a default box (not one of ``bounds``) of a log-scaled
        parameter widens that side by whole decades until it holds the value (at most
        :data:`MAX_WIDEN_DECADES`; :attr:`widened`).
    default_bounds : dict, optional
        ``{name: (lower, upper)}`` replacing the model's default boxes (e.g. the wider
        boxes of a record in sample units); like the model's, and unlike ``bounds``,
        they may be widened. Names that are not free are ignored.
    allow_outside_box : bool
        Accept ``fixed`` values of the right sign outside their parameter's box (the
        CLI's ``--allow-outside-box``); otherwise such a value is an error
        (:meth:`~hhra_phys.parameters.ParameterSet.check_values`, the check of
        ``--fix``). Notes about accepted values are in :attr:`notes`.
    per_record : sequence of str, optional
        Free model parameters estimated once per record (default: those of
        :func:`per_record_params` that are free).

    Attributes
    ----------
    records : list of RecordProblem
        Each record's part, in the order given.
    explicit_bounds : frozenset of str
        Free parameters whose box was given in ``bounds`` (never widened).
    default_boxes : dict
        ``{name: (lower, upper)}``: the default box, before any widening, of every free
        log-scaled model parameter whose box may be widened.
    widened : list of dict
        Box sides widened here for a start value beyond them: ``name``, ``side``,
        ``round`` (0), ``from``, ``to``, ``reason`` (``"start"``).
    notes : list of str
        Fixed values accepted outside their box.

    Raises
    ------
    ParameterError
        No records; unknown or contradictory parameter names, bad bounds, a fixed value
        that is not finite, of the wrong sign, or outside its box (without
        ``allow_outside_box``), each naming the parameter; unknown per-record names; a
        start or fixed value for a record that does not exist.
    DataError
        A record too short for the number of its free parameters, or a simulator whose
        sample rate matches no record.
    """

    def __init__(
        self,
        model: Model,
        data: Dataset | Sequence[Dataset],
        cost: CostName = "itae",
        free: Sequence[str] | None = None,
        fixed: Mapping[str, float] | None = None,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        initial_state: Literal["data", "zero", "fit"] = "data",
        simulator: Simulator | Mapping[float, Simulator] | None = None,
        start: Mapping[str, float] | None = None,
        default_bounds: Mapping[str, tuple[float, float]] | None = None,
        allow_outside_box: bool = False,
        per_record: Sequence[str] | None = None,
    ) -> None:
        datasets = as_records(data)
        _check_choices(cost, initial_state)
        free = (list(free) if free is not None
                else default_free(model, {split_record_name(n)[0]: 0.0 for n in fixed or {}}))
        if per_record is None:
            per_record = [n for n in per_record_params(model) if n in free]
        missing = sorted(set(per_record) - set(free))
        if missing:
            raise ParameterError(f"per-record parameters {missing} are not free ({free})")
        self.model = model
        self.cost = cost
        self.initial_state = initial_state
        self.per_record = list(per_record)
        self._free_model = free
        # As given (per-record names kept), so that with_boxes rebuilds the same problem.
        self._fixed_given = dict(fixed or {})
        self.simulators = _simulators_by_rate(simulator, datasets)
        shared_start, own_start = _per_record_split(start, len(datasets), "start")
        shared_fixed, own_fixed = _per_record_split(fixed, len(datasets), "fixed")
        self.records: list[RecordProblem] = []
        for i, ds in enumerate(datasets):
            pr = RecordProblem(model, ds, cost=cost, free=free,
                               fixed={**shared_fixed, **own_fixed[i]} or None, bounds=bounds,
                               initial_state=initial_state,
                               simulator=self.simulators.get(float(ds.fs)),
                               start={**shared_start, **own_start[i]},
                               default_bounds=default_bounds,
                               allow_outside_box=allow_outside_box)
            self.simulators.setdefault(float(ds.fs), pr.sim)
            self.records.append(pr)
        first = self.records[0]
        self.fixed = first.fixed
        # Boxes are per model parameter, the same in every record.
        self.explicit_bounds = first.explicit_bounds
        self.default_boxes = {k: v for pr in self.records for k, v in pr.default_boxes.items()}
        self.widened = [w for pr in self.records for w in pr.widened]
        self.notes = list(first.notes)
        self._stack()

    def _stack(self) -> None:
        """The stacked coordinates: the shared model parameters, then each record's own."""
        own = set(self.per_record)
        several = len(self.records) > 1
        params: list[Parameter] = []
        log: list[bool] = []
        scale: list[float] = []
        index_of: dict[str, int] = {}
        self._index: list[np.ndarray] = []
        for k, pr in enumerate(self.records, start=1):
            idx = []
            for j, par in enumerate(pr.free_params):
                specific = several and (par.name in own or par.name.startswith("x0_"))
                name = record_name(par.name, k) if specific else par.name
                if name not in index_of:
                    index_of[name] = len(params)
                    params.append(par.with_(name=name) if specific else par)
                    log.append(bool(pr._log[j]))
                    scale.append(float(pr._scale[j]))
                idx.append(index_of[name])
            self._index.append(np.array(idx, dtype=int))
        self.free_params = params
        self.free_names = [p.name for p in params]
        self.n_free = len(params)
        self._log = np.array(log)
        self._scale = np.array(scale)
        self.y = np.concatenate([pr.y for pr in self.records])

    def with_boxes(self, boxes: Mapping[str, tuple[float, float]]) -> Problem:
        """The same problem with the default boxes of some model parameters replaced (widened).

        Everything else is kept: records, free set, fixed values (also the start values
        of parameters that are neither free nor fixed), the free parameters' start values
        (initial states and per-record values included), explicit bounds, initial-state
        rule, simulators; :attr:`default_boxes` (the boxes before any widening),
        :attr:`widened` and :attr:`notes` carry over. Why the start values: a problem
        given finer substeps (:meth:`with_simulator`) is refined from where it starts;
        rebuilt at the model's nominal values, an accepted drive model's polish started
        where its simulation diverged and ended there.

        Parameters
        ----------
        boxes : dict
            ``{name: (lower, upper)}`` of free model parameters whose box is not explicit
            (a per-record parameter's box is every record's).
        """
        first = self.records[0]
        explicit = {p.name: (p.lower, p.upper) for p in first.free_params
                    if p.name in self.explicit_bounds}
        defaults = {p.name: (p.lower, p.upper) for p in first.free_params
                    if not p.name.startswith("x0_") and p.name not in self.explicit_bounds}
        defaults.update(boxes)
        new = Problem(self.model, self.datasets, cost=self.cost, free=self._free_model,
                      fixed={**self.fixed, **self._fixed_given}, bounds=explicit,
                      default_bounds=defaults, initial_state=self.initial_state,
                      simulator=self.simulators, allow_outside_box=True,
                      per_record=self.per_record,
                      start=dict(zip(self.free_names, self.start_values().tolist(),
                                     strict=True)))
        new.default_boxes = {**new.default_boxes, **self.default_boxes}
        new.widened = list(self.widened)
        new.notes = list(self.notes)
        return new

    def with_simulator(self, sim: Simulator) -> Problem:
        """The same problem (:meth:`with_boxes`) with the records at ``sim``'s sample rate
        simulated by ``sim`` (e.g. finer substeps)."""
        new = self.with_boxes({})
        for pr in new.records:
            if abs(pr.data.fs - sim.fs) <= 1e-9 * sim.fs:
                pr.sim = sim.with_intersample(pr.data.intersample)
        new.simulators[float(sim.fs)] = sim
        return new

    # -- records --------------------------------------------------------------------------
    @property
    def datasets(self) -> list[Dataset]:
        """The estimation records."""
        return [pr.data for pr in self.records]

    @property
    def names(self) -> list[str]:
        """One label per record: its name, or its source, or ``"record <k>"``."""
        return [record_label(pr.data, k) for k, pr in enumerate(self.records, start=1)]

    def blocks(self) -> list[tuple[RecordProblem, np.ndarray]]:
        """``(record's problem, indices of its coordinates in the stacked ones)`` per record."""
        return list(zip(self.records, self._index, strict=True))

    def record_values(self, values: np.ndarray, k: int) -> np.ndarray:
        """Free values of record ``k`` (from 0) in its own problem's order, shape (..., n)."""
        return np.asarray(values, dtype=float)[..., self._index[k]]

    def per_record_values(self, values: np.ndarray) -> list[tuple[RecordProblem, np.ndarray]]:
        """``(record's problem, its free values)`` for every record (:meth:`record_values`)."""
        return [(pr, self.record_values(values, k)) for k, pr in enumerate(self.records)]

    # -- the first record (the record of a one-record problem) -------------------------------
    @property
    def data(self) -> Dataset:
        """The first estimation record (a one-record problem's record; all: :attr:`datasets`)."""
        return self.records[0].data

    @property
    def sim(self) -> Simulator:
        """The first record's simulator (all, by sample rate: :attr:`simulators`)."""
        return self.records[0].sim

    @property
    def u(self) -> np.ndarray:
        """The first record's input."""
        return self.records[0].u

    @property
    def t(self) -> np.ndarray:
        """The first record's time from 0."""
        return self.records[0].t

    @property
    def base(self) -> np.ndarray:
        """The first record's full parameter vector before fitting."""
        return self.records[0].base

    @property
    def x0_states(self) -> list[str]:
        """States whose initial value is a free parameter ``x0_<state>`` (``"fit"`` rule)."""
        return self.records[0].x0_states

    def start_values(self) -> np.ndarray:
        """Starting values of the free parameters (physical units)."""
        out = np.empty(self.n_free)
        for pr, idx in self.blocks():
            out[idx] = pr.start_values()
        return out

    def full(self, values: np.ndarray) -> np.ndarray:
        """Full model parameter vector(s) of the first record, shape (..., n_params)."""
        return self.records[0].full(self.record_values(values, 0))

    def initial_states(self, values: np.ndarray, data: Dataset | None = None) -> np.ndarray:
        """Initial states of the first record (or, with ``data``, of that record under the
        first record's values), shape (n_pop, nx) (:meth:`RecordProblem.initial_states`)."""
        return self.records[0].initial_states(self.record_values(values, 0), data)

    def simulator_for(self, data: Dataset) -> Simulator:
        """A simulator at ``data``'s sample rate and inter-sample behaviour."""
        return self.records[0].simulator_for(data)

    # -- evaluation ------------------------------------------------------------------------
    def __call__(self, Z: np.ndarray) -> np.ndarray:
        """Vectorised objective in fitting coordinates: the sum of the records' costs,
        (n, n_free) -> (n,).

        Candidates whose simulation is flagged (unstable, diverging) cost ``inf``.
        """
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        total = np.zeros(Z.shape[0])
        for pr, idx in self.blocks():
            total = total + pr(Z[:, idx])
        return np.where(np.isfinite(total), total, np.inf)

    def simulate_values(self, values: np.ndarray, data: Dataset | None = None) -> np.ndarray:
        """Simulated outputs, (n_free,) -> (N,) or (n, n_free) -> (n, N).

        Without ``data`` the records' outputs one after another (``N`` all their
        samples); with ``data`` (e.g. a whole validation record) the simulation runs on
        its input with the first record's values, starting from its first measured
        output by the ``"data"`` rule.
        """
        if data is not None:
            return self.records[0].simulate_values(self.record_values(values, 0), data=data)
        parts = [pr.simulate_values(vk) for pr, vk in self.per_record_values(values)]
        return np.concatenate(parts, axis=-1)

    def cost_of(self, Y: np.ndarray) -> np.ndarray:
        """Cost of stacked simulated outputs (n, N) against the records: the sum of theirs."""
        Y2 = np.atleast_2d(np.asarray(Y, dtype=float))
        total = np.zeros(Y2.shape[0])
        a = 0
        for pr in self.records:
            total = total + pr.cost_of(Y2[:, a:a + pr.y.size])
            a += pr.y.size
        total = np.where(np.isfinite(total), total, np.inf)
        return total if np.ndim(Y) > 1 else total[0]

    def simulate_parts(self, values: np.ndarray,
                       parts: Sequence[Dataset | None] | None = None) -> list[np.ndarray]:
        """Each record's simulated output with its own values, shape (N_k,) each.

        ``parts[k]`` (e.g. record ``k``'s selection part; ``None``: its estimation
        record) is simulated from its first measured output by the ``"data"`` rule.
        """
        parts = [None] * len(self.records) if parts is None else list(parts)
        return [pr.simulate_values(vk, data=ds)
                for (pr, vk), ds in zip(self.per_record_values(values), parts, strict=True)]

    def residual_function(self) -> ca.Function:
        """CasADi ``r(z) = y_sim(z) - y``: the records' symbolic residuals stacked."""
        if len(self.records) == 1:  # the stacked coordinates are the record's own
            return self.records[0].residual_function()
        if getattr(self, "_residual_fn", None) is None:
            z = ca.MX.sym("z", self.n_free)
            parts = [pr.residual_function()(ca.vertcat(*[z[int(i)] for i in idx]))
                     for pr, idx in self.blocks()]
            self._residual_fn = ca.Function("residual", [z], [ca.vertcat(*parts)], ["z"], ["r"])
        return self._residual_fn


def _sensitivity(sim: Simulator):
    """The simulator's compiled forward sensitivities (shared with the refiners), or None.

    Its first ``nx`` columns are the exact Jacobian of the outputs with respect to the
    initial state: one trajectory, and the code every refined model compiles anyway, where
    central differences need a population function of their own (a compile per model
    variant, 0.6 s, most of what a loop's cold start paid per candidate)."""
    from hhra_phys.sensitivity import TrajectorySensitivity

    try:
        return TrajectorySensitivity.of(sim)
    except Exception:  # a model CasADi cannot differentiate: central differences
        return None


def estimate_initial_state(
    sim: Simulator,
    u: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    x0: np.ndarray,
    iterations: int = 4,
    skip: int = 0,
) -> np.ndarray:
    """Least-squares estimate of the whole initial state of a record, parameters fixed.

    Like initial-condition estimation when comparing models on validation data
    (MATLAB's ``compare``): a record cut from the middle of a motion starts with
    unknown velocity and pressure, and its first noisy sample would set a
    constant offset that a free-run angle never forgets. SciPy's trust-region
    least squares (``least_squares``, ``"trf"``, scaled by the Jacobian's columns)
    with the exact Jacobian from the compiled forward sensitivities the refiners use
    (:class:`~hhra_phys.sensitivity.TrajectorySensitivity`; by central differences through
    the population simulator where they are not finite); the model parameters are untouched.
    A trust region, not plain Gauss-Newton steps: a discovered stiff or non-smooth term
    (``omega^3`` with a large coefficient, ``|theta|``) makes the linearisation a poor
    guide far from the guess, where undamped or halved Gauss-Newton steps stall (on such
    a held-out part they stopped at 0.080 deg where the state's optimum gives 0.052).

    Parameters
    ----------
    sim : Simulator
        Simulator of the model at the record's sample rate.
    u, y : ndarray, shape (N,)
        Input and measured output of the record.
    p : ndarray, shape (n_params,)
        Model parameters.
    x0 : ndarray, shape (nx,)
        Initial guess.
    iterations : int
        Budget: at most ``4 * iterations + 4`` simulations of the trajectory (each
        iteration of the trust region takes one or, after a rejected step, a few).
    skip : int
        Samples at the start left out of the fit (simulated, not compared: a leading
        window's first samples, whose delayed inputs lie before it).

    Returns
    -------
    ndarray, shape (nx,)
        The estimate (the guess itself if its trajectory is not finite, or if no
        state lowers the cost).
    """
    nx = x0.size
    step = 1e-4
    x = np.asarray(x0, dtype=float).copy()
    y_cmp = np.asarray(y, dtype=float)[skip:]
    P = np.tile(p, (2 * nx, 1))

    def residual(xk: np.ndarray) -> np.ndarray:
        return sim.simulate(u, p, x0=xk)[skip:] - y_cmp

    sens = _sensitivity(sim)

    def jacobian(xk: np.ndarray) -> np.ndarray:
        if sens is not None:
            with np.errstate(all="ignore"):
                J = sens(u, p, xk)[1][skip:, :nx]
            if np.isfinite(J).all():
                return J
        X = np.tile(xk, (2 * nx, 1))
        for i in range(nx):
            X[2 * i, i] -= step
            X[2 * i + 1, i] += step
        Y = sim.simulate(u, P, x0=X)[:, skip:]
        J = (Y[1::2] - Y[0::2]).T / (2 * step)
        return np.where(np.isfinite(J), J, 0.0)

    if y_cmp.size == 0:
        return x
    try:
        # A guess whose trajectory is not finite raises ValueError; the trust region only
        # accepts steps that lower the cost, so its answer is never worse than the guess.
        sol = least_squares(residual, x, jac=jacobian, method="trf", x_scale="jac",
                            max_nfev=4 * iterations + 4, xtol=1e-6, ftol=1e-4)
    except (ValueError, np.linalg.LinAlgError):
        return x
    return np.asarray(sol.x, dtype=float) if np.isfinite(sol.fun).all() else x


def initial_guess(model: Model, y0: float, p: np.ndarray, u0: float = 0.0,
                  dt: float = 0.004) -> np.ndarray:
    """Initial state of the ``"data"`` rule (module docstring) for a first output sample ``y0``.

    Parameters
    ----------
    model : Model
    y0 : float
        First measured output sample (output units).
    p : ndarray, shape (n_params,)
        Model parameters.
    u0 : float
        First input sample (input units).
    dt : float
        Sample period [s] (for models with discrete-time input parts).

    Returns
    -------
    ndarray, shape (nx,)
    """
    rule = data_rule_function(model, dt)
    return np.array(rule(float(y0), float(u0), np.asarray(p, dtype=float)), dtype=float).ravel()
