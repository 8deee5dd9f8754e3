"""Several records at once: one model, shared parameters, per-record initial states.

Users record more than one run of a plant (different amplitudes, loads, days).
:class:`MultiProblem` stacks one-record :class:`~hhra_phys.problem.Problem`
objects into one fitting problem, the way MATLAB's multi-experiment ``nlgreyest``
or PyBOP's multi-fitting problem do:

* the model parameters are **shared** by every record (one coordinate each);
* every record has its own **initial state** (under ``initial_state="fit"`` its
  ``x0_<state>`` parameters, named ``x0_<state>_rec<k>`` for record ``k``,
  counted from 1) and its own value of the model's **per-record parameters**
  (parts declare them in a ``per_record`` attribute, e.g. the zero of a pressure
  sensor, ``p_offset``, which drifts from day to day), named ``<name>_rec<k>``;
* records may differ in length and sample rate: one compiled simulator per sample
  rate is shared by the records at that rate.

The cost of the global search is the sum of the records' costs (one population
call per record); the least-squares residual of the refiners and of the
uncertainty is the records' residuals stacked, with the exact Jacobian assembled
block by block (:class:`~hhra_phys.refine.CompiledLeastSquares`, ``blocks()``).
So intervals come from all records together.

:func:`fit_records` is what :func:`hhra_phys.fit.fit` runs for a list of records::

    res = fit([ds1, ds2])                  # shared groups, x0_theta_rec1, x0_theta_rec2
    res.records[0]["val"]["rmse"]          # metrics per record, pooled in res.metrics
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import casadi as ca
import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.metrics import score
from hhra_phys.model import Model
from hhra_phys.parameters import Parameter, record_name, split_record_name
from hhra_phys.problem import COSTS, Problem, default_free
from hhra_phys.simulate import Simulator

__all__ = [
    "MultiProblem",
    "RecordSet",
    "check_records",
    "per_record_params",
    "pooled_score",
    "record_name",
    "split_record_name",
    "split_records",
]

def _per_record_split(values: Mapping[str, float] | None, n: int, what: str
                      ) -> tuple[dict[str, float], list[dict[str, float]]]:
    """``{name or name_rec<k>: value}`` -> (shared values, one dict per record)."""
    shared: dict[str, float] = {}
    own: list[dict[str, float]] = [{} for _ in range(n)]
    for name, value in (values or {}).items():
        base, k = split_record_name(name)
        if k is None:
            shared[name] = float(value)
        elif k > n:
            raise ParameterError(f"{what} {name!r}: there are only {n} records")
        else:
            own[k - 1][base] = float(value)
    return shared, own


def per_record_params(model: Model) -> list[str]:
    """Model parameters estimated once per record: those its parts list in ``per_record``."""
    out: list[str] = []
    for part in model.parts:
        out += [n for n in getattr(part, "per_record", ()) if n in model.params.names]
    return out


class MultiProblem:
    """One model fitted to several records (module docstring).

    Offers what the optimisers, refiners and the uncertainty step use of a
    :class:`~hhra_phys.problem.Problem`: the coordinate maps, box, start,
    vectorised cost, stacked output ``y`` and ``blocks()``.

    Parameters
    ----------
    model : Model
        The model shared by all records.
    records : sequence of Dataset
        Estimation records (at least one; lengths and sample rates may differ).
    cost, free, fixed, bounds, initial_state, substeps, default_bounds, allow_outside_box
        As for :class:`~hhra_phys.problem.Problem`; ``free`` names model
        parameters (the per-record copies are made here).
    start : dict, optional
        Start values: a shared name starts every record, ``<name>_rec<k>``
        (e.g. ``x0_theta_rec2``) one record.
    per_record : sequence of str, optional
        Free model parameters estimated once per record (default:
        :func:`per_record_params` of the model that are free).
    names : sequence of str, optional
        Labels of the records in reports (default: their names or sources).
    simulators : dict, optional
        ``{fs: Simulator}``: simulators of ``model`` to reuse, by sample rate [Hz]
        (the diagnosis loop's short-block candidate simulators); rates missing
        here get one built as usual.

    ``fixed`` may hold one record's value of a per-record parameter,
    ``<name>_rec<k>`` (the loop holds each record's sensor zero while it searches
    a candidate's new parameters); a shared name holds every record.

    Raises
    ------
    ParameterError
        No records, unknown per-record names, a start for a record that does
        not exist.
    DataError
        A record too short for its free parameters.
    """

    def __init__(
        self,
        model: Model,
        records: Sequence[Dataset],
        cost: str = "itae",
        free: Sequence[str] | None = None,
        fixed: Mapping[str, float] | None = None,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        initial_state: str = "data",
        substeps: int | str = "auto",
        start: Mapping[str, float] | None = None,
        per_record: Sequence[str] | None = None,
        names: Sequence[str] | None = None,
        simulators: Mapping[float, Simulator] | None = None,
        default_bounds: Mapping[str, tuple[float, float]] | None = None,
        allow_outside_box: bool = False,
        simulator: Simulator | None = None,
    ) -> None:
        records = list(records)
        if not records:
            raise ParameterError("a multi-record problem needs at least one record")
        if cost not in COSTS:
            raise ParameterError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
        free = list(free) if free is not None else default_free(model, fixed)
        if per_record is None:
            per_record = [n for n in per_record_params(model) if n in free]
        per_record = list(per_record)
        missing = sorted(set(per_record) - set(free))
        if missing:
            raise ParameterError(f"per-record parameters {missing} are not free ({free})")
        shared_start, own_start = _per_record_split(start, len(records), "start value")
        shared_fixed, own_fixed = _per_record_split(fixed, len(records), "fixed value")
        sims: dict[float, Simulator] = {float(k): v for k, v in (simulators or {}).items()}
        if simulator is not None:  # the earlier one-simulator argument
            sims.setdefault(float(simulator.fs), simulator)
        self.records: list[Problem] = []
        for i, ds in enumerate(records):
            sim = sims.get(float(ds.fs))
            fixed_k = {**shared_fixed, **own_fixed[i]} or None
            pr = Problem(model, ds, cost=cost, free=free, fixed=fixed_k,  # type: ignore[arg-type]
                         bounds=bounds, initial_state=initial_state,  # type: ignore[arg-type]
                         simulator=sim, substeps=substeps,
                         start={**shared_start, **own_start[i]},
                         default_bounds=default_bounds, allow_outside_box=allow_outside_box)
            sims.setdefault(float(ds.fs), pr.sim)
            self.records.append(pr)
        self.model = model
        self.cost = cost
        self.initial_state = initial_state
        self.per_record = per_record
        first = self.records[0]
        self.fixed = first.fixed
        # As given (per-record names kept), so that with_boxes rebuilds the same problem.
        self._fixed_given = dict(fixed or {})
        self.sim = first.sim
        self.simulators = sims
        # Boxes are per model parameter, the same in every record (see Problem).
        self.explicit_bounds = first.explicit_bounds
        self.default_boxes = {k: v for pr in self.records for k, v in pr.default_boxes.items()}
        self.widened = [w for pr in self.records for w in pr.widened]
        self.notes = list(first.notes)
        self._model_free = free

        # Stacked layout: the shared model parameters, then record by record its own.
        own = set(per_record)
        params: list[Parameter] = []
        log: list[bool] = []
        scale: list[float] = []
        index_of: dict[str, int] = {}
        self._index: list[np.ndarray] = []
        for k, pr in enumerate(self.records, start=1):
            idx = []
            for j, par in enumerate(pr.free_params):
                specific = par.name in own or par.name.startswith("x0_")
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
        self.names = (list(names) if names is not None else
                      [ds.name or ds.source or f"record {k}" for k, ds in
                       enumerate(records, start=1)])

    def with_boxes(self, boxes: Mapping[str, tuple[float, float]]) -> MultiProblem:
        """The same problem with the default boxes of some model parameters replaced.

        As :meth:`Problem.with_boxes <hhra_phys.problem.Problem.with_boxes>`; ``boxes``
        are keyed by model parameter names (a per-record parameter's box is every
        record's).
        """
        first = self.records[0]
        explicit = {p.name: (p.lower, p.upper) for p in first.free_params
                    if p.name in self.explicit_bounds}
        defaults = {p.name: (p.lower, p.upper) for p in first.free_params
                    if not p.name.startswith("x0_") and p.name not in self.explicit_bounds}
        defaults.update(boxes)
        new = MultiProblem(self.model, self.data, cost=self.cost, free=self._model_free,
                           fixed=self._fixed_given, bounds=explicit, default_bounds=defaults,
                           initial_state=self.initial_state, per_record=self.per_record,
                           names=self.names, allow_outside_box=True,
                           simulators=self.simulators)
        new.default_boxes = {**new.default_boxes, **self.default_boxes}
        new.widened = list(self.widened)
        return new

    # The coordinate maps and the box are the one-record problem's, on the stacked arrays.
    to_z = Problem.to_z
    from_z = Problem.from_z
    bounds_z = Problem.bounds_z

    @property
    def data(self) -> list[Dataset]:
        """The estimation records."""
        return [pr.data for pr in self.records]

    def blocks(self) -> list[tuple[Problem, np.ndarray]]:
        """``(one-record problem, indices of its coordinates in the stacked ones)`` per record."""
        return list(zip(self.records, self._index, strict=True))

    def record_values(self, values: np.ndarray, k: int) -> np.ndarray:
        """Free values of record ``k`` (from 0) in its own problem's order, shape (..., n)."""
        return np.asarray(values, dtype=float)[..., self._index[k]]

    def start_values(self) -> np.ndarray:
        """Starting values of the stacked free parameters (physical units)."""
        out = np.empty(self.n_free)
        for pr, idx in self.blocks():
            out[idx] = pr.start_values()
        return out

    def full(self, values: np.ndarray) -> np.ndarray:
        """Full model parameter vector(s) of the first record (shared parameters)."""
        return self.records[0].full(self.record_values(values, 0))

    def initial_states(self, values: np.ndarray) -> np.ndarray:
        """Initial states of the first record, shape (n_pop, nx)."""
        return self.records[0].initial_states(self.record_values(values, 0))

    def __call__(self, Z: np.ndarray) -> np.ndarray:
        """Vectorised objective: the sum of the records' costs, (n, n_free) -> (n,)."""
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        total = np.zeros(Z.shape[0])
        for pr, idx in self.blocks():
            total = total + pr(Z[:, idx])
        return np.where(np.isfinite(total), total, np.inf)

    def simulate_values(self, values: np.ndarray) -> np.ndarray:
        """Stacked simulated outputs of the records, (n_free,) -> (sum N,) or (n, .) -> (n, .)."""
        parts = [pr.simulate_values(self.record_values(values, k))
                 for k, pr in enumerate(self.records)]
        return np.concatenate(parts, axis=-1)

    def residual_function(self) -> ca.Function:
        """CasADi ``r(z)``: the records' symbolic residuals stacked (exact Hessian)."""
        if getattr(self, "_residual_fn", None) is None:
            z = ca.MX.sym("z", self.n_free)
            parts = [pr.residual_function()(ca.vertcat(*[z[int(i)] for i in idx]))
                     for pr, idx in self.blocks()]
            self._residual_fn = ca.Function("residual", [z], [ca.vertcat(*parts)], ["z"], ["r"])
        return self._residual_fn


def pooled_score(records: Sequence[Dataset], outputs: Sequence[np.ndarray]) -> dict[str, float]:
    """Metrics of several records together.

    MSE, RMSE, VAF, fit and the largest error over all samples pooled; ITAE is
    the sum of the records' own ITAE (each on its own time axis).
    """
    y = np.concatenate([ds.y for ds in records])
    yhat = np.concatenate([np.asarray(o, dtype=float) for o in outputs])
    out = {k: float(v) for k, v in score(y, yhat).items()}
    out["itae"] = float(sum(score(ds.y, o, ds.t)["itae"]
                            for ds, o in zip(records, outputs, strict=True)))
    return out


def _label(ds: Dataset, k: int) -> str:
    return ds.name or ds.source or f"record {k}"


def check_records(records: Sequence[Dataset], what: str = "record") -> None:
    """Several records of one plant must agree on their signals' names and units.

    Raises
    ------
    DataError
        A record whose input or output name or unit differs from the first
        record's (the message names both records, by file where they came from one).
    """
    from hhra_phys.errors import DataError

    records = list(records)
    if not records:
        return
    first = records[0]

    def where(ds: Dataset, k: int) -> str:  # the file, where the record came from one
        return str(ds.source or ds.name or f"{what} {k}")

    for k, ds in enumerate(records[1:], start=2):
        for attr, label in (("output_unit", "output unit"), ("output_name", "output"),
                            ("input_unit", "input unit"), ("input_name", "input")):
            a, b = getattr(first, attr), getattr(ds, attr)
            if a != b:
                raise DataError(
                    f"{where(ds, k)}: {label} {b!r}, but {where(first, 1)} has {a!r}: "
                    f"{what}s fitted together must measure the same signals in the same "
                    "units (convert the file, or fit them apart)")


class RecordSet(tuple):  # type: ignore[type-arg]
    """Several records (parts of records) that play the role of one in the loop.

    A tuple of :class:`~hhra_phys.data.Dataset` with the few attributes the
    diagnosis loop reads of a record: ``n`` (all samples), ``name``, the signals'
    names and units (the records agree on them, :func:`check_records`), and, for
    scaling an effect to the data (:func:`~hhra_phys.effects.make_effect`), ``u``
    and ``y`` (the records' samples one after another; never simulated as one
    record), ``dt`` (the largest sample period [s]: smoothing widths tied to it
    stay integrable at every record's rate) and ``fs`` (the first record's).
    """

    #: Whole validation records (scored with the first record's per-record values),
    #: not parts of the estimation records.
    whole = False

    @property
    def n(self) -> int:
        """Samples of all records."""
        return int(sum(ds.n for ds in self))

    @property
    def name(self) -> str:
        """The records' names joined by ``" + "``."""
        return " + ".join(_label(ds, k) for k, ds in enumerate(self, start=1))

    @property
    def names(self) -> list[str]:
        """One label per record."""
        return [_label(ds, k) for k, ds in enumerate(self, start=1)]

    @property
    def u(self) -> np.ndarray:
        """Inputs one after another, shape (n,)."""
        return np.concatenate([ds.u for ds in self])

    @property
    def y(self) -> np.ndarray:
        """Outputs one after another, shape (n,)."""
        return np.concatenate([ds.y for ds in self])

    @property
    def dt(self) -> float:
        """Largest sample period [s or samples]."""
        return float(max(ds.dt for ds in self))

    @property
    def fs(self) -> float:
        """Sample rate of the first record [Hz]."""
        return float(self[0].fs)

    def __getattr__(self, attr: str) -> Any:
        # Signal names, units and the time unit are common (check_records).
        if attr in ("output_unit", "output_name", "input_unit", "input_name", "time_unit"):
            return getattr(self[0], attr)
        raise AttributeError(attr)


def split_records(
    records: Sequence[Dataset], split: float, test: float,
    validation: Sequence[Dataset] | None = None,
) -> tuple[RecordSet, RecordSet, RecordSet | None]:
    """The diagnosis loop's estimation, selection and test parts of several records.

    Every record is split the loop's way (:func:`hhra_phys.loop.split_record`);
    with ``validation`` the records split into estimation and selection only
    (``test`` ignored) and the whole validation records are the test part.
    """
    from hhra_phys.selection import split_record

    records = list(records)
    check_records(records + list(validation or []))
    parts = [split_record(ds, split, 0.0 if validation else test) for ds in records]
    est = RecordSet(p[0] for p in parts)
    sel = RecordSet(p[1] for p in parts)
    if validation:
        held_whole = RecordSet(validation)
        held_whole.whole = True
        return est, sel, held_whole
    held = [p[2] for p in parts]
    return est, sel, (RecordSet(held) if held[0] is not None else None)
