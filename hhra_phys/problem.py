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

Where the code is: :class:`Problem` and the handling of several records here; one
record's problem and the fitting coordinates in :mod:`hhra_phys.record_problem`; the
initial-state rules in :mod:`hhra_phys.initial_state` (issue 34: short modules). Their
names are importable from here too.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar, Literal

import casadi as ca
import numpy as np

from hhra_phys.data import DataError, Dataset
from hhra_phys.errors import ParameterError

# One record's problem and the initial-state rules live in modules of their own (issue 34);
# their names stay importable from here.
from hhra_phys.initial_state import (  # noqa: F401  (re-exported)
    DATA_RULE_STEPS,
    _sensitivity,
    data_rule_function,
    estimate_initial_state,
    initial_guess,
)
from hhra_phys.model import Model
from hhra_phys.parameters import Parameter, as_number, record_name, split_record_name
from hhra_phys.record_problem import (  # noqa: F401  (re-exported)
    COSTS,
    HELD_OUT_STATE,
    LEAD_FRACTION,
    MAX_WIDEN_DECADES,
    CostName,
    RecordProblem,
    _check_choices,
    _Coordinates,
    default_free,
)
from hhra_phys.simulate import Simulator

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
                               allow_outside_box=allow_outside_box,
                               fit_states=self._fit_states_of(ds))
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

    #: Under ``"fit"``, fit the initial value of every state (not only the model's
    #: :attr:`~hhra_phys.model.Model.fitted_states`) on a record that starts after the first
    #: sample of the record it was cut from (:attr:`Dataset.origin
    #: <hhra_phys.data.Dataset.origin>`): a model that starts at rest (its velocity not
    #: fitted) is not at rest in the middle of a motion. Off here; the diagnosis loop's
    #: folds train on such pieces (:class:`hhra_phys.diagnosis.folds.LaterStartProblem`).
    fit_later_states: ClassVar[bool] = False

    def _fit_states_of(self, ds: Dataset) -> list[str] | None:
        """The states whose initial value is fitted on record ``ds`` (``None``: the model's
        own, :attr:`fit_later_states`)."""
        if not self.fit_later_states or ds.origin is None or ds.origin[1] <= 0:
            return None
        return [n for n in self.model.state_names if n not in self.model.pinned]

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
        new = type(self)(self.model, self.datasets, cost=self.cost, free=self._free_model,
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

