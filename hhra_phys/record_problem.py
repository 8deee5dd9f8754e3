"""One record's fitting problem: :class:`RecordProblem`, and the fitting coordinates.

A :class:`~hhra_phys.problem.Problem` of one record or several is made of one
:class:`RecordProblem` per record: its model, free parameters and their boxes (widened for
a start value beyond a default box, at most :data:`MAX_WIDEN_DECADES`), the map to the
fitting coordinates (:class:`_Coordinates`, shared with the problem of a record set), its
simulator, initial state (with a held-out part's leading window, :data:`HELD_OUT_STATE`),
cost and residual. Separate from :mod:`hhra_phys.problem` so that the single record's
problem and the set's stacking read one at a time; every name here is also importable
from :mod:`hhra_phys.problem`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Literal

import casadi as ca
import numpy as np

from hhra_phys.data import DataError, Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.initial_state import data_rule_function, estimate_initial_state
from hhra_phys.model import Model
from hhra_phys.parameters import Parameter, as_number
from hhra_phys.simulate import Simulator, accuracy_tolerance

__all__ = [
    "COSTS",
    "LEAD_FRACTION",
    "RecordProblem",
    "default_free",
]


CostName = Literal["itae", "mse", "rmse", "ssr"]
COSTS: tuple[str, ...] = ("itae", "mse", "rmse", "ssr")


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


def _check_choices(cost: str, initial_state: str) -> None:
    """The cost and the initial-state rule are known ones."""
    if cost not in COSTS:
        raise ParameterError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
    if initial_state not in ("data", "zero", "fit"):
        raise ParameterError(
            f"initial_state must be 'data', 'zero' or 'fit', got {initial_state!r}"
        )


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
    fit_states : sequence of str, optional
        Under ``"fit"``, the states whose initial value is fitted (default: the model's
        :attr:`~hhra_phys.model.Model.fitted_states`). :class:`Problem` passes every state
        for a record that starts after its record's first sample
        (:attr:`Problem.fit_later_states`).

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
        fit_states: Sequence[str] | None = None,
    ) -> None:
        _check_choices(cost, initial_state)
        self.model = model
        self.data = data
        self.cost = cost
        self.initial_state = initial_state
        self._fit_states = None if fit_states is None else list(fit_states)
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
        chosen = model.fitted_states if self._fit_states is None else self._fit_states
        self._x0_states: list[str] = list(chosen) if self.initial_state == "fit" else []
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
                f"(fitted with initial_state='fit': {', '.join(chosen) or 'none'})"
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
