"""The loop's fits: one problem, simulator and run for every stage (base fit, candidates,
polish, backward step), sharing the settings of one loop (:class:`_Settings`).

Apart from the engine so that candidate refits, which travel to worker processes, carry
only these functions and their picklable settings.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.fit import (
    FitOptions,
    at_edges,
    fit_problem,
    widened_box,
)
from hhra_phys.metrics import score
from hhra_phys.model import Model
from hhra_phys.multi import pooled_score
from hhra_phys.parameters import record_name, split_record_name
from hhra_phys.problem import Problem, as_records, per_record_params
from hhra_phys.refine import STALL_ITER, CompiledLeastSquares
from hhra_phys.result import FitResult
from hhra_phys.simulate import MAX_ACCURACY_SUBSTEPS, Simulator, accuracy_tolerance

__all__ = []


@dataclass(frozen=True)
class _Settings:
    """What every fit of one loop shares (picklable: it travels to the workers)."""

    est: Dataset
    sel: Dataset
    data: Dataset
    bounds: dict[str, tuple[float, float]]
    backend: str
    seed: int
    ipopt_iter: int
    initial_state: str
    #: Substeps of the base simulators, ``((fs, substeps), ...)`` (one per sample rate).
    substeps: tuple[tuple[float, int], ...] | None
    split: float
    criterion: str
    #: Default boxes (widened like the model's when a group ends at an edge).
    default_bounds: dict[str, tuple[float, float]] = field(default_factory=dict)


#: Samples per compiled step of candidate simulators. The default of a plain fit
#: (10) unrolls more code: it pays for 100 x 200 searches, not for a candidate's
#: few hundred evaluations, while compiling it takes longer (docs/performance.md).
CANDIDATE_BLOCK = 2


def _simulator(cfg: _Settings, model: Model) -> dict[float, Simulator]:
    """The simulators of a candidate (or accepted) model, ``{fs: Simulator}`` (one per
    sample rate of the records): base substeps, a short block."""
    subs = dict(cfg.substeps or ())
    return {fs: Simulator(model, fs=fs, backend=cfg.backend, substeps=subs.get(fs, "auto"),
                          block=CANDIDATE_BLOCK)
            for fs in dict.fromkeys(float(ds.fs) for ds in as_records(cfg.est))}




def _stiff_substeps(problem: Problem) -> Problem:
    """A stiff candidate's problem with its substeps by the accuracy rule at its start values.

    A candidate keeps the base fit's substeps, which for a stiff model (ROS4) the
    stability rule raises to at least ``ROS4_MIN_STIFF``; the step-doubling error estimate
    from the coarsest count (:meth:`Simulator.accurate`) often allows fewer (a sharp
    backlash on the rig's record: ROS4 x 4 within a tenth of the noise, at half the cost
    of x 8). The fit checks the estimate again at the fitted values and refines with
    more substeps if they need them. Models integrated with RK4, several records, and
    candidates whose estimate does not meet the tolerance (or does not stay finite) keep
    the problem as it is.
    """
    if len(problem.records) > 1 or problem.sim.method == "rk4":
        return problem
    rec = problem.records[0]
    v = problem.start_values()
    sim = problem.sim.accurate(rec.u, problem.full(v), accuracy_tolerance(rec.y),
                               x0=problem.initial_states(v)[0], coarsest=True)
    if sim.accuracy.get("within"):
        return problem.with_simulator(sim)
    if sim is problem.sim:
        sim.accuracy = {}  # as before: substeps inherited, not estimated
    return problem


def _as_refitted(problem: Problem, integration: Mapping[str, Any] | None) -> Problem:
    """An accepted model's problem for its polish, simulated at least as finely as its
    refit ended (``integration``: the refit's ``settings["integration"]``).

    The polish keeps the base fit's substeps (as the loop's models always had) unless the
    refit ended with more (the fit's accuracy check at its fitted values refines them):
    then the refit's method and count, with its accuracy record, so the polish checks them
    again. Why: a drive's friction sharpened to 1e-4 m/s was refitted at ROS4 x 16
    (selection 2.0e-6 m) and, polished at the base fit's x 8, ended at 9.2e-6 m, from
    which the next round chose a stand-in. Not coarser than the base: polished at the
    accuracy rule's coarser count, the one-loop study's dead zone beside an exact friction
    (seed 1) lost its next round to a discovered stand-in.
    """
    integration = integration or {}
    n = integration.get("substeps")
    if (len(problem.records) > 1 or not isinstance(n, int) or n <= problem.sim.substeps
            or integration.get("method") != problem.sim.method):
        return problem
    sim = problem.sim.with_substeps(n)
    sim.accuracy = {k: integration[k] for k in ("method", "substeps", "error_estimate",
                                                 "tolerance", "within") if k in integration}
    return problem.with_simulator(sim)


def _accuracy_checked(problem: Problem) -> Problem:
    """An accepted model's polish problem with its substeps checked at its start values
    (the accepted refit's), up to :data:`~hhra_phys.simulate.MAX_ACCURACY_SUBSTEPS`.

    A refit that inherited the base fit's substeps carries no error estimate, so the fit's
    accuracy check at its fitted values never ran for it; here the step-doubling estimate
    (:meth:`~hhra_phys.simulate.Simulator.accurate`, the simulator's own method) runs at
    the values the polish starts from, the polish runs at the substeps it asks for, and its
    record lets the polish's own check refine again at the polished values. Why: a drive's
    Coulomb friction sharpened to 1e-4 m/s was accepted at the base fit's RK4 x 2 and
    polished there (test 2.4x the noise; the next round took a discovered rate term and a
    resonant mode as stand-ins for the discretisation error). A refit whose record has an
    estimate keeps it (the polish's check starts from it); several records keep their
    substeps, as :func:`_stiff_substeps`.
    """
    acc = problem.sim.accuracy or {}
    if len(problem.records) > 1 or acc.get("error_estimate") is not None:
        return problem
    rec = problem.records[0]
    v = problem.start_values()
    try:
        sim = problem.sim.accurate(rec.u, problem.full(v), accuracy_tolerance(rec.y),
                                   x0=problem.initial_states(v)[0],
                                   finest=MAX_ACCURACY_SUBSTEPS)
    except Exception:  # noqa: BLE001 - no estimate: the polish runs as before
        return problem
    return problem if sim is problem.sim else problem.with_simulator(sim)


def _problem(cfg: _Settings, model: Model, free: Sequence[str], fixed: Mapping[str, float],
             start: Mapping[str, float], x0: Mapping[str, float] | None = None,
             simulator: Simulator | Mapping[float, Simulator] | None = None,
             kind: type[Problem] = Problem) -> Problem:
    """A problem on the estimation part(s) (warm-started at ``start`` and ``x0``), of
    class ``kind`` (a fold's: :class:`~hhra_phys.diagnosis.folds.LaterStartProblem`).

    Candidates keep the base model's substeps: "auto" would size them at the
    effect's nominal (a stiff friction sign can ask for 8x more) and the
    simulator's stability check already rejects candidates too stiff for them.
    One simulator per sample rate serves every problem of one model (its compiled
    code is per model structure, not per free set).

    ``start`` may hold per-record values (``x0_theta_rec2``, ``p_offset_rec2``, from
    :func:`_values`); a per-record parameter held in ``fixed`` is held at each record's
    own value. ``simulator`` is ``{fs: Simulator}``, or one simulator (the base fit's,
    default block) beside which the other rates get the same kind.
    """
    records = as_records(cfg.est)
    if simulator is None:
        sims = _simulator(cfg, model)
    elif isinstance(simulator, Mapping):
        sims = dict(simulator)
    else:
        sims = {float(simulator.fs): simulator}
        for ds in records:
            sims.setdefault(float(ds.fs), Simulator(model, fs=ds.fs, backend=cfg.backend))
    own = set(per_record_params(model))
    held: dict[str, float] = {}
    for name, value in fixed.items():
        if name in own:  # each record keeps its own value
            held.update({record_name(name, k): float(start.get(record_name(name, k), value))
                         for k in range(1, len(records) + 1)})
        else:
            held[name] = float(value)
    st = {k: v for k, v in start.items()
          if (k in model.params or split_record_name(k)[1] is not None)
          and k not in held and split_record_name(k)[0] not in fixed}
    if cfg.initial_state == "fit":
        for state in model.fitted_states:  # warm start of the fitted initial state too
            if x0 and state in x0:
                st.setdefault(f"x0_{state}", float(x0[state]))
    bnd = {k: v for k, v in cfg.bounds.items() if k in free}
    dflt = {k: v for k, v in cfg.default_bounds.items() if k in free and k not in bnd}
    return kind(model, records, free=list(free), fixed=held, bounds=bnd,
                   initial_state=cfg.initial_state, start=st,  # type: ignore[arg-type]
                   simulator=sims, default_bounds=dflt or None,
                   allow_outside_box=True)  # fixed values come from the loop's fits


def _values(res: FitResult) -> dict[str, float]:
    """A fit's values to warm-start the next: the model's, and each record's own.

    One record: :attr:`FitResult.values`. Several: also ``<name>_rec<k>`` of every
    per-record free parameter and initial state.
    """
    out = dict(res.values)
    if res.records:
        out.update({n: res.x0_param(n) for n in res.free
                    if split_record_name(n)[1] is not None})
    return out


def _judged_options(cfg: _Settings, optimizer: str, pop: int, iters: int,
                    refine: str = "ipopt", warm: bool = True, ipopt_iter: int | None = None,
                    stall: bool = True) -> FitOptions:
    """The fit options of a loop's refit (:func:`_run`)."""
    # A warm start seeds the first population with the problem's start values
    # (the previous fit); the base fit is not seeded. A refit that is judged (capped at
    # ipopt_iter) stops where IPOPT's iterate stalls (refine.STALL_ITER); a polish
    # (stall=False) runs on.
    return FitOptions(optimizer=optimizer, refine=refine, pop_size=pop, max_iter=iters,
                      seed=cfg.seed, seed_population=warm, split=cfg.split,
                      refine_options={"max_iter": ipopt_iter or cfg.ipopt_iter,
                                      "stall_iter": STALL_ITER if stall else 0})


def _run(cfg: _Settings, problem: Problem, optimizer: str, pop: int, iters: int,
         refine: str = "ipopt", warm: bool = True, ipopt_iter: int | None = None,
         stall: bool = True) -> FitResult:
    """A loop's refit of ``problem`` (:func:`_judged_options`), each record scored on its
    own selection part."""
    opts = _judged_options(cfg, optimizer, pop, iters, refine, warm, ipopt_iter, stall)
    return fit_problem(problem, as_records(cfg.sel), options=opts,
                       records=as_records(cfg.data))


def _base_fit(cfg: _Settings, problem: Problem, pop: int, iters: int) -> FitResult:
    """The base fit: a plain fit (H-GWO ``pop`` x ``iters`` + IPOPT at its own limit)."""
    opts = FitOptions(optimizer="hgwo", pop_size=pop, max_iter=iters, seed=cfg.seed,
                      seed_population=False, split=cfg.split)
    return fit_problem(problem, as_records(cfg.sel), options=opts,
                       records=as_records(cfg.data))


def _test_score(problem: Problem, res: FitResult, test: Dataset | None) -> dict[str, float]:
    """Free-run scores on the test part (initial state re-estimated on it, as for selection).

    Pooled over the records; with several records each one's is written into
    ``res.records`` (``"test"``). Each record's test part is simulated with its own
    per-record values; whole validation records (``test.whole``) with the first
    record's, as :func:`~hhra_phys.fit.fit` scores them, and are appended to
    ``res.records`` (``n_est`` 0) with their name.
    """
    if test is None:
        return {}
    whole = bool(getattr(test, "whole", False))
    parts = as_records(test)
    v = _free_values(problem, res)
    ys = ([problem.simulate_values(v, data=ds) for ds in parts] if whole
          else problem.simulate_parts(v, parts))
    if res.records:  # several records: each one's test scores beside its others
        entries = [dict(r) for r in res.records if r.get("n_est")]
        for k, (ds, y) in enumerate(zip(parts, ys, strict=True)):
            sc = {kk: float(vv) for kk, vv in score(ds.y, y, ds.t).items()}
            if whole:
                entries.append({"name": test.names[k], "source": ds.source,
                                "fs": float(ds.fs), "n_est": 0, "n_val": 0, "n_test": ds.n,
                                "est": {}, "val": {}, "test": sc})
            else:
                entries[k]["test"] = sc
                entries[k]["n_test"] = ds.n
        res.records = entries
    return pooled_score(parts, ys)


def _free_values(problem: Problem, res: FitResult) -> np.ndarray:
    # Model parameters by name; fitted initial states (and, with several records,
    # per-record parameters) from the result's own record of them.
    return np.array([res.values[n] if n in res.values else res.x0_param(n)
                     for n in problem.free_names])


def _unidentified(res: FitResult, names: Sequence[str], model: Model) -> list[str]:
    """Effect parameters whose 95 % CI spans a decade (log) or includes 0 (linear)."""
    out = []
    for n in names:
        lo, hi = res.ci95.get(n, (math.nan, math.nan))
        par = model.params[n]
        if not (math.isfinite(lo) and math.isfinite(hi)):
            out.append(n)
        elif par.scale == "log" and (lo <= 0 or hi / lo > 10):
            out.append(n)
        elif par.scale == "linear" and lo <= 0 <= hi and n != "delay":
            out.append(n)
        elif n == "delay" and hi - lo > 2:
            out.append(n)
    return out


def _output_range(problem: Problem, values: np.ndarray, data: Any) -> tuple[float, float]:
    """Range of the simulated output (free run), output units: on the estimation records
    (``data`` None), or on parts of them (``data``, one per record, each simulated with
    its record's own values)."""
    parts = None if data is None else as_records(data)
    y = np.concatenate(problem.simulate_parts(values, parts))
    return float(np.nanmin(y)), float(np.nanmax(y))


def _edge_boxes(problem: Problem, res: FitResult, names: Sequence[str]
                ) -> dict[str, tuple[float, float]]:
    """Widened boxes of the parameters ``names`` that end at a box edge: that side a decade
    further (log scale) or ten times as far from zero (linear; a side at zero is a sign and
    stays). Boxes the user gave (explicit bounds) are never widened, nor those of
    parameters the record does not see across the widening (:func:`_half_widths`)."""
    z = problem.to_z(_free_values(problem, res))
    out: dict[str, tuple[float, float]] = {}
    half: np.ndarray | None = None
    for i, side in at_edges(problem, z):
        par = problem.free_params[i]
        if par.name not in names or par.name in getattr(problem, "explicit_bounds", ()):
            continue
        new = widened_box(par, side)  # the fit's widening step (hhra_phys.fit)
        if new is None:
            continue
        k = 0 if side == "lower" else 1
        edges = np.full(problem.n_free, np.nan)
        edges[i] = new[k]
        step = abs(float(problem.to_z(edges)[i]) - float(problem.bounds_z()[i, k]))
        if half is None:
            half = _half_widths(problem, z)
        if half[i] < step:
            out[par.name] = new
    return out


def _half_widths(problem: Problem, z: np.ndarray) -> np.ndarray:
    """Half-widths of the conditional 95 % intervals at ``z``, in fitting coordinates:
    ``1.96 s / |J_i|`` (each parameter alone, the others held; ``J`` the residual
    Jacobian, ``s`` the residual's RMS). One evaluation of the sensitivities.

    A parameter at a box edge is widened only where the record sees it across the
    widening step (half-width below the step): moving it that far changes the sum of
    squares by more than the noise. One the record does not see there sits on a flat
    profile (a play or a dead band shrunk towards zero on a record without one); a
    wider box would only buy another search and refinement that moves it by decades
    and the estimation cost by rounding. Each parameter is taken alone (its conditional,
    not its marginal interval) so that a group the box pins while a correlated one
    makes up for it still counts as seen (the torque gain at its upper edge on the
    record of ``benchmarks/bench_candidates.py``: 0.02-0.06 decades), as does one the
    data pull out of its box (a gravity load stopped at a third of its size,
    docs/diagnosis.md). Without finite derivatives every half-width is 0 (widen as
    before).
    """
    r, J = CompiledLeastSquares(problem)(z)
    if not (np.isfinite(r).all() and np.isfinite(J).all()):
        return np.zeros(problem.n_free)
    s = math.sqrt(float(r @ r) / max(r.size - problem.n_free, 1))
    with np.errstate(divide="ignore"):
        return 1.96 * s / np.linalg.norm(J, axis=0)


def _warm_compile(cfg: _Settings, model: Model, n_pop: int) -> None:
    """Build the compiled code a candidate model will need (disk cache), results unused.

    Runs in a background thread while the loop refits earlier candidates: the C
    compiler works outside the GIL, so compiling candidate ``k+1`` overlaps the
    compiled simulations and IPOPT of candidate ``k``. Builds what a refit calls:
    the population cost for H-GWO's batch of ``n_pop`` points, a single
    simulation and the sensitivity function of the refiners. Failures are left for
    the refit itself to report.
    """
    from hhra_phys.sensitivity import TrajectorySensitivity

    try:
        sims = _simulator(cfg, model)
        for sim in sims.values():
            est = next(ds for ds in as_records(cfg.est) if float(ds.fs) == float(sim.fs))
            if sim.method != "rk4":  # as _stiff_substeps will choose (at the nominal)
                sim = sim.accurate(est.u, model.nominal(), accuracy_tolerance(est.y),
                                   coarsest=True)
            n = min(est.n, sim.chunk)
            u, p = est.u[:n], model.nominal()
            with np.errstate(all="ignore"):
                sim.simulate_cost(u, np.tile(p, (n_pop, 1)), est.y[:n], np.ones(n), "abs")
                sim.simulate(u, p)
            TrajectorySensitivity.of(sim).outputs_function()  # the refiners call both
    except Exception:  # noqa: BLE001, S110 - the refit reports its own failure
        pass


def _effect_params(model: Model, effect: str) -> list[str]:
    """Names of the parameters of the part called ``effect`` in ``model``."""
    part = next(p for p in model.parts if p.name == effect)
    return [p.name for p in part.parameters]


class _DiscoveryFits:
    """What :class:`hhra_phys.diagnosis.discovery.Discovery` needs of the loop's fits."""

    def __init__(self, cfg: _Settings) -> None:
        self.cfg = cfg
        self.data = cfg.data
        self.val = cfg.sel  # terms are chosen on the selection part, like effects

    @staticmethod
    def values(res: FitResult) -> dict[str, float]:
        return _values(res)

    def problem(self, model: Model, free: Sequence[str], fixed: Mapping[str, float],
                start: Mapping[str, float], x0: Mapping[str, float] | None = None) -> Problem:
        return _problem(self.cfg, model, free, fixed, start, x0)

    def run(self, problem: Problem, optimizer: str, pop: int, iters: int,
            refine: str = "ipopt", warm: bool = True) -> FitResult:
        return _run(self.cfg, problem, optimizer, pop, iters, refine=refine, warm=warm)




def _substeps(problem: Problem) -> tuple[tuple[float, int], ...]:
    """The base fit's substeps per sample rate, which candidates keep."""
    return tuple((float(fs), int(sim.substeps)) for fs, sim in problem.simulators.items())
