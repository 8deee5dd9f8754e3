"""A fitting problem: model + data + cost + which parameters are free, and how scaled.

:class:`Problem` is what optimisers and refiners see. It maps between

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

On another record (validation, prediction) the ``"data"`` rule starts it and,
under ``"fit"``, the whole initial state is then re-estimated on that record
with the parameters fixed (:func:`estimate_initial_state`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Literal

import casadi as ca
import numpy as np

from hhra_phys.data import DataError, Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.model import Model
from hhra_phys.parameters import Parameter
from hhra_phys.simulate import Simulator, accuracy_tolerance

__all__ = [
    "COSTS",
    "Problem",
    "default_free",
    "data_rule_function",
    "estimate_initial_state",
    "initial_guess",
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


class Problem:
    """Model + estimation data + cost + free/fixed parameters and their scaling.

    Parameters
    ----------
    model : Model
        The model to fit (e.g. :class:`~hhra_phys.model.HHRAModel`).
    data : Dataset
        Estimation data (use :meth:`Dataset.split` first to keep validation data).
    cost : {"itae", "mse", "rmse", "ssr"}
        Cost minimised by the global search: ITAE (the paper's), mean or root mean
        squared error, or the sum of squared residuals. Local refiners always
        minimise the (smooth) sum of squares.
    free : sequence of str, optional
        Names of the free parameters (default: all except the model's ``held``
        ones, :func:`default_free`).
    fixed : dict, optional
        ``{name: value}``: parameters held at the given value (e.g. from a
        datasheet). A name both free and fixed is an error.
    bounds : dict, optional
        ``{name: (lower, upper)}`` overriding the model's bounds (physical units): the
        user's explicit boxes, never widened (:attr:`explicit_bounds`).
    initial_state : {"data", "zero", "fit"}
        How the initial state is set (module docstring).
    simulator : Simulator, optional
        A simulator of ``model`` at the data's sample rate to reuse (its sibling with the
        record's inter-sample behaviour, :meth:`Simulator.with_intersample`, if it differs).
    substeps : int or "auto"
        RK4 substeps if a simulator is built here.
    start : dict, optional
        Parameter values to use instead of the model's nominal values for the
        parameters that are neither free nor fixed, and as the start of the
        search (first population member, local refiners). ``x0_<state>`` names
        start a fitted initial state. A start value beyond a default box (not one of
        ``bounds``) of a log-scaled parameter widens that side by whole decades until
        it holds the value (at most :data:`MAX_WIDEN_DECADES`; :attr:`widened`).
    default_bounds : dict, optional
        ``{name: (lower, upper)}`` replacing the model's default boxes (e.g. the wider
        boxes of a record in sample units); like the model's, and unlike ``bounds``,
        they may be widened. Names that are not free are ignored.
    allow_outside_box : bool
        Accept ``fixed`` values of the right sign outside their parameter's box (the
        CLI's ``--allow-outside-box``); otherwise such a value is an error
        (:meth:`~hhra_phys.parameters.ParameterSet.check_values`, the check of
        ``--fix``). Notes about accepted values are in :attr:`notes`.

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
    ParameterError
        Unknown or contradictory parameter names, bad bounds, a fixed value that is
        not finite, of the wrong sign, or outside its box (without
        ``allow_outside_box``), each naming the parameter.
    DataError
        Data too short for the number of free parameters, or a sample rate that
        does not match the simulator.
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
        substeps: int | str = "auto",
        start: Mapping[str, float] | None = None,
        default_bounds: Mapping[str, tuple[float, float]] | None = None,
        allow_outside_box: bool = False,
    ) -> None:
        if cost not in COSTS:
            raise ParameterError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
        if initial_state not in ("data", "zero", "fit"):
            raise ParameterError(
                f"initial_state must be 'data', 'zero' or 'fit', got {initial_state!r}"
            )
        self.model = model
        self.data = data
        self.cost = cost
        self.initial_state = initial_state
        fixed = dict(fixed or {})
        names = model.params.names
        # The one check of held values (also the CLI's --fix): name, sign, box.
        self.notes: list[str] = model.params.check_values(
            fixed, allow_outside_box=allow_outside_box, what="fixed")
        if free is None:
            free = default_free(model, fixed)
        free = list(free)
        for name in free:
            model.params.index(name)
            if name in fixed:
                raise ParameterError(f"parameter {name!r} is both free and fixed")
        if len(set(free)) != len(free):
            raise ParameterError(f"free parameters listed twice: {free}")
        self.base = model.nominal()
        x0_start = {k: float(v) for k, v in (start or {}).items() if k.startswith("x0_")}
        for name, value in (start or {}).items():
            if not name.startswith("x0_"):
                self.base[model.params.index(name)] = float(value)
        for name, value in fixed.items():
            self.base[model.params.index(name)] = float(value)
        self.fixed = {n: float(self.base[model.params.index(n)]) for n in names if n not in free}

        # Free parameters (model parameters, then initial-state parameters).
        self.explicit_bounds: frozenset[str] = frozenset(bounds or {})
        self.default_boxes: dict[str, tuple[float, float]] = {}
        self.widened: list[dict[str, object]] = []
        params: list[Parameter] = []
        for name in free:
            par = model.params[name]
            box = (bounds or {}).get(name, (default_bounds or {}).get(name))
            if box is not None:
                lo, hi = (float(b) for b in box)
                nominal = min(max(par.nominal, lo), hi)
                par = par.with_(lower=lo, upper=hi, nominal=nominal)
            if name not in self.explicit_bounds:
                self.default_boxes[name] = (par.lower, par.upper)
                if par.scale == "log" and start and name in start:  # a given start, not a
                    # nominal off the box
                    par = self._box_for_start(par, float(start[name]))
            params.append(par)
        unknown = set(bounds or {}) - set(free)
        if unknown:
            raise ParameterError(
                f"bounds given for parameters that are not free: {sorted(unknown)}"
            )
        self._dt = 1.0 / data.fs
        self._x0_states: list[str] = list(model.fitted_states) if initial_state == "fit" else []
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
        self.free_params = params
        self.free_names = [p.name for p in params]
        self._model_free = [model.params.index(p.name) for p in params
                            if not p.name.startswith("x0_")]
        self.n_free = len(params)
        if self.n_free == 0:
            raise ParameterError("no free parameters: nothing to fit")
        if len(data) < 10 * self.n_free:
            raise DataError(
                f"{data.source or data.name or 'dataset'}: {len(data)} samples are too few to fit "
                f"{self.n_free} parameters (need at least {10 * self.n_free})"
            )
        self._scale = np.array([(p.upper - p.lower) / 2 if p.scale == "linear" else 1.0
                                for p in params])
        self._log = np.array([p.scale == "log" for p in params])

        # The record says what its input did between samples; a simulator given for
        # another behaviour is swapped for its sibling (same method and substeps).
        self.sim = (simulator.with_intersample(data.intersample) if simulator is not None
                    else Simulator(model, fs=data.fs, substeps=substeps,
                                   intersample=data.intersample))
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

    def with_boxes(self, boxes: Mapping[str, tuple[float, float]]) -> Problem:
        """The same problem with the default boxes of some parameters replaced (widened).

        Everything else is kept: free set, fixed values, explicit bounds, initial-state
        rule, simulator; :attr:`default_boxes` (the boxes before any widening) and
        :attr:`widened` carry over.

        Parameters
        ----------
        boxes : dict
            ``{name: (lower, upper)}`` of free model parameters whose box is not explicit.
        """
        explicit = {p.name: (p.lower, p.upper) for p in self.free_params
                    if p.name in self.explicit_bounds}
        defaults = {p.name: (p.lower, p.upper) for p in self.free_params
                    if not p.name.startswith("x0_") and p.name not in self.explicit_bounds}
        defaults.update(boxes)
        new = Problem(self.model, self.data, cost=self.cost,  # type: ignore[arg-type]
                      free=[n for n in self.free_names if not n.startswith("x0_")],
                      fixed=self.fixed, bounds=explicit, default_bounds=defaults,
                      initial_state=self.initial_state,  # type: ignore[arg-type]
                      simulator=self.sim, allow_outside_box=True)
        new.default_boxes = {**new.default_boxes, **self.default_boxes}
        new.widened = list(self.widened)
        new.notes = list(self.notes)
        return new

    # -- coordinates --------------------------------------------------------------------
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

        For another record (``data``, e.g. validation) the ``"data"`` rule is
        applied to it, and under ``"fit"`` the whole initial state is
        re-estimated on it (:meth:`fit_initial_state`): the fitted one belongs to
        the estimation record.
        """
        v = np.atleast_2d(np.asarray(values, dtype=float))
        if self.initial_state == "zero":
            return np.tile(self.model.x0(), (v.shape[0], 1))
        P = self.full(v)
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

        With ``data`` (e.g. the validation part) the simulation runs on its input,
        starting from its first measured output by the ``"data"`` rule.
        """
        single = np.ndim(values) == 1
        v = np.atleast_2d(np.asarray(values, dtype=float))
        P = self.full(v)
        if data is None:
            Y = self.sim.simulate(self.u, P, x0=self.initial_states(v))
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


def estimate_initial_state(
    sim: Simulator,
    u: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    x0: np.ndarray,
    iterations: int = 4,
) -> np.ndarray:
    """Least-squares estimate of the whole initial state of a record, parameters fixed.

    Like initial-condition estimation when comparing models on validation data
    (MATLAB's ``compare``): a record cut from the middle of a motion starts with
    unknown velocity and pressure, and its first noisy sample would set a
    constant offset that a free-run angle never forgets. A few Gauss-Newton
    steps with central differences through the compiled simulator
    (``2*nx + 1`` trajectories per step, one population call); the model
    parameters are untouched.

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
        Gauss-Newton steps.

    Returns
    -------
    ndarray, shape (nx,)
        The estimate (the guess itself if a step fails).
    """
    nx = x0.size
    step = 1e-4
    x = np.asarray(x0, dtype=float).copy()
    best = np.inf
    for _ in range(iterations):
        X = np.tile(x, (2 * nx + 1, 1))
        for i in range(nx):
            X[1 + 2 * i, i] -= step
            X[2 + 2 * i, i] += step
        Y = sim.simulate(u, np.tile(p, (2 * nx + 1, 1)), x0=X)
        if not np.isfinite(Y).all():
            break
        r = Y[0] - y
        best = min(best, float(r @ r))
        J = (Y[2::2] - Y[1::2]).T / (2 * step)
        delta, *_ = np.linalg.lstsq(J, -r, rcond=1e-10)
        # Damped step: halve until the cost falls (a stiff extra state can make the
        # linearisation a poor guide far from the guess).
        for _ in range(8):
            trial = x + delta
            y_trial = sim.simulate(u, p, x0=trial)
            cost = float((y_trial - y) @ (y_trial - y)) if np.isfinite(y_trial).all() else np.inf
            if cost < best:
                break
            delta = delta / 2
        else:
            break  # no step lowers the cost: keep x
        x, best = trial, cost
        if np.all(np.abs(delta) < 1e-8):
            break
    return x


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
