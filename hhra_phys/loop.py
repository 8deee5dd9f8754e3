"""The closed loop: fit, diagnose, add an effect, refit, keep it only if it pays.

The record is split in time order into three parts (default 50/25/25 %):
**estimation** (every fit), **selection** (chooses among candidates) and **test**
(chooses nothing; reports the base and final models' error). :func:`augment` runs::

    fit the base model on estimation (as a plain fit: H-GWO 100 x 200 + IPOPT), or reuse one
    repeat:
        stop if the selection residual and the estimation residual are both at the
            noise level (RMSE <= (1 + noise_tol) * noise level, or white by Ljung-Box)
        rank, in one list by first-order score, the library effects not yet in the
            model (hhra_phys.diagnose.analyse) and the discovered terms and modes
            (hhra_phys.discover.Discovery)
        refit them in that order (library effects anywhere, an Executor, or here:
            global search over the new parameters with the previous fit held, then
            IPOPT over all free parameters; discovered ones by IPOPT through the
            simulator), score each on selection, judge it by the one rule
            (hhra_phys.selection.acceptance), and skip the rest of a kind (library or
            discovered) once one of its candidates leaves both parts at the noise level
            (round_settled)
        add the winner among the acceptable ones (hhra_phys.selection.choose: lowest
            selection RMSE, near-ties within the noise allowance by the information
            criterion); polish it; backward step over what came before
    until nothing is accepted or max_effects additions are in
    score base and final on the test part

Every candidate tried is a :class:`Step` with its evidence, fitted parameters,
95 % CIs, estimation and selection scores and why it was (not) accepted. A fitted
effect whose CI spans more than a decade (log parameters) or includes "absent"
(linear ones) is flagged as not identifiable from the record. When a
position-dependent effect is tried and the selection part drives the output
outside the range seen in estimation, the step says so (such terms extrapolate).

Speed. Candidates run compiled native code (``backend="auto"``): the compiled-code
cache (:mod:`hhra_phys.compile`) is keyed by the generated code, so every model
structure compiles once per machine, and while one candidate is refitted the next
candidates' simulators compile in a background thread. A candidate's global search
is sized to its new parameters. Candidate refits are plain picklable jobs
(:func:`refit_candidate`), so a round can run on any
:class:`concurrent.futures.Executor` with the same results as here.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor, ThreadPoolExecutor
from copy import copy
from dataclasses import dataclass, field, fields, replace
from types import SimpleNamespace
from typing import Any

import numpy as np
from scipy.stats import chi2

from hhra_phys.data import Dataset
from hhra_phys.diagnose import Diagnosis, analyse, noise_level, whiteness
from hhra_phys.discover import DiscoveredStep, Discovery
from hhra_phys.effects import EFFECTS, SIGN_PROFILES, effect_name, make_effect
from hhra_phys.errors import ParameterError
from hhra_phys.fit import (
    MAX_WIDEN_DECADES,
    WIDEN_CLEAR_GAIN,
    WIDEN_MIN_GAIN,
    FitOptions,
    at_edges,
    fit_problem,
    widened_box,
)
from hhra_phys.interrupt import map_stopping
from hhra_phys.intersample import (
    HoldCandidate,
    hold_signature,
    hold_suspected,
    other_holds,
    refit_with_hold,
)
from hhra_phys.metrics import score
from hhra_phys.model import Model
from hhra_phys.multi import RecordSet, pooled_score, split_records
from hhra_phys.options import with_overrides
from hhra_phys.outputs import jsonable
from hhra_phys.parameters import record_name, split_record_name
from hhra_phys.problem import Problem, as_records, default_free, per_record_params
from hhra_phys.refine import STALL_ITER, CompiledLeastSquares
from hhra_phys.regime import change_coverage, regime_coverage
from hhra_phys.result import FitResult, format_metric
from hhra_phys.selection import (
    COLOURED_P,
    METRIC_KEYS,
    NOISE_TOL,
    Step,
    acceptance,
    at_noise_level,
    backward_decision,
    choose,
    information_criterion,
    judge,
    needs_rotation,
    noise_tolerance,
    pooled_rmse,
    rotated_verdict,
    round_settled,
    split_record,
    stops_at_noise,
    thin_part,
    tie_break,
    votes,
)
from hhra_phys.simulate import MAX_ACCURACY_SUBSTEPS, Simulator, accuracy_tolerance

__all__ = [
    "LoopOptions",
    "LoopResult",
    "augment",
    "base_model_for",
    "selection_noise",
    "noise_stop",
    "refit_candidate",
    "SHAPE_MODES",
]

#: Where the loop fits a smooth-edged library effect's shape (``LoopOptions.fit_shapes``):
#: the round's chosen effect, every contender's refit, or nowhere.
SHAPE_MODES = ("chosen", "contenders", "off")

#: IPOPT iteration limit of an accepted candidate's polish (the old loop's limit for
#: every candidate); the base fit keeps the plain fit's limit.
POLISH_ITER = 60



@dataclass
class LoopResult:
    """Outcome of :func:`augment`.

    :meth:`to_json` is the diagnose JSON (and :meth:`from_json` reads it back);
    :meth:`report` writes the Markdown report and its figures.
    """

    base: FitResult
    final: FitResult
    steps: list[Step]
    chosen: list[str]
    diagnoses: list[Diagnosis]
    final_diagnosis: Diagnosis | None
    settings: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    #: Candidates that could not be tried on this model, with the reason.
    skipped: dict[str, str] = field(default_factory=dict)
    #: Scores on the test part, which chose nothing: ``{"base": {...}, "final": {...}}``
    #: (empty dictionaries with ``test=0``).
    test_scores: dict[str, dict[str, float]] = field(default_factory=dict)
    #: The record(s) the loop ran on (:func:`augment`'s ``data``), for :meth:`report`'s
    #: figures; ``None`` for a result read with :meth:`from_json`. Not saved.
    data: Any = field(default=None, repr=False, compare=False)
    #: The diagnoses' JSON summaries of a result read with :meth:`from_json` (the live
    #: :class:`~hhra_phys.diagnose.Diagnosis` objects, with their arrays, are not saved).
    saved_diagnoses: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def test(self) -> dict[str, float]:
        """The final model's scores on the untouched test part (``rmse``, ``vaf``, ...)."""
        return dict(self.test_scores.get("final", {}))

    def summary(self) -> str:
        """What ``hhra-phys diagnose`` prints after the loop: the chosen effects, the RMSE
        and VAF of each part before -> after (``est``, ``val`` the selection part, ``test``),
        each record's with several, and the final fit's derived quantities with their 95 %
        intervals. Units are the records'; warnings are :attr:`warnings` and the final
        fit's (not repeated here)."""
        return "\n".join(summary_lines(self, self.to_json()))

    def report(self, path: str | Any, data: Any = None, overwrite: bool = False) -> Any:
        """Write the Markdown report and its residual figures (``hhra-phys diagnose
        --report``'s; :func:`hhra_phys.report.loop_report`).

        Parameters
        ----------
        path : str or path-like
            The report (``.md``); figures ``<stem>_before.png``, ``<stem>_after.png``
            and, when discovery built terms, ``<stem>_discovery.png`` go beside it.
        data : Dataset or sequence of Dataset, optional
            The loop's record(s) (default: the ones :func:`augment` kept).
        overwrite : bool
            Replace existing files.

        Returns
        -------
        pathlib.Path
        """
        from hhra_phys.report import loop_report

        return loop_report(self, path, data=data, overwrite=overwrite)

    def to_json(self) -> dict[str, Any]:
        """The diagnose JSON.

        ``base`` and ``final`` hold ``est`` (estimation), ``val`` (the selection part,
        which chose the effects; the key keeps its old name) and ``test`` (the
        untouched test part) scores; ``test`` at top level is the final model's test
        score, ``steps``, ``chosen``, ``skipped`` as before; ``stopped_by_budget``
        whether :attr:`LoopOptions.budget` ended the loop early. ``fits`` holds the base
        and final fits whole (:meth:`FitResult.to_json <hhra_phys.result.FitResult.to_json>`,
        with the derived quantities), ``test_scores`` and ``loop_warnings`` what
        :meth:`from_json` needs besides.
        """
        def part(res: FitResult, key: str) -> dict[str, Any]:
            out = {k: {m: res.metrics[k].get(m) for m in METRIC_KEYS}
                   for k in ("est", "val") if res.metrics.get(k)}
            if self.test_scores.get(key):
                out["test"] = {m: self.test_scores[key].get(m) for m in METRIC_KEYS}
            if res.records:  # several records: each one's scores ("sel": its selection part)
                out["records"] = [
                    {"name": r["name"], **{k: {m: r.get(src, {}).get(m) for m in METRIC_KEYS}
                                           for k, src in (("est", "est"), ("sel", "val"),
                                                          ("test", "test"))}}
                    for r in res.records]
            return {**out, **{k: v for k, v in res.settings.items() if k == "widened"}}

        final = part(self.final, "final")
        final["params"] = self.final.values
        final["ci95"] = {k: list(v) for k, v in self.final.ci95.items()}
        # The final fit's own warnings (identifiability, bounds, extrapolation) and how
        # its intervals were had (the directions the data cannot determine, with why).
        final["warnings"] = list(self.final.warnings)
        final["intervals"] = self.final.intervals
        saved = self.saved_diagnoses
        return jsonable({
            "base": part(self.base, "base"),
            "test": ({m: self.test_scores["final"].get(m) for m in METRIC_KEYS}
                     if self.test_scores.get("final") else None),
            "steps": [s.to_json() for s in self.steps],
            "chosen": list(self.chosen),
            "final": final,
            "diagnosis_before": (self.diagnoses[0].to_json() if self.diagnoses
                                 else saved.get("diagnosis_before")),
            "diagnosis_after": (self.final_diagnosis.to_json()
                                if self.final_diagnosis is not None
                                else saved.get("diagnosis_after")),
            "warnings": self.warnings + [w for w in self.final.warnings
                                         if w not in self.warnings],
            "skipped": dict(self.skipped),
            "settings": self.settings,
            "stopped_by_budget": bool(self.settings.get("stopped_by_budget", False)),
            "fits": {"base": self.base.to_json(), "final": self.final.to_json()},
            "test_scores": self.test_scores,
            "loop_warnings": list(self.warnings),
        })

    @classmethod
    def from_json(cls, d: Mapping[str, Any], source: str = "diagnose result") -> LoopResult:
        """The result of :meth:`to_json`'s dictionary.

        The fits, steps, choices, settings and scores come back; the diagnoses only as
        their JSON summaries (:attr:`saved_diagnoses`), so :meth:`report` of a read
        result has no evidence section and no figures.

        Raises
        ------
        ParameterError
            A dictionary without the whole fits (written before ``fits`` was kept).
        """
        if not isinstance(d.get("fits"), Mapping):
            raise ParameterError(f"{source}: no 'fits' (a diagnose JSON written before the "
                                 "fits were kept cannot be read back)")
        return cls(
            base=FitResult.from_json(d["fits"]["base"], source=f"{source} base fit"),
            final=FitResult.from_json(d["fits"]["final"], source=f"{source} final fit"),
            steps=[_step_from_json(s) for s in d.get("steps", [])],
            chosen=list(d.get("chosen", [])),
            diagnoses=[], final_diagnosis=None,
            settings=dict(d.get("settings", {})),
            warnings=list(d.get("loop_warnings", [])),
            skipped=dict(d.get("skipped", {})),
            test_scores={k: dict(v) for k, v in (d.get("test_scores") or {}).items()},
            saved_diagnoses={k: d[k] for k in ("diagnosis_before", "diagnosis_after")
                             if d.get(k) is not None},
        )


def _twins_text(step: Step) -> str:
    """`` (the discovered form of coulomb_friction)`` for a discovered step that holds a
    library effect's shape (:func:`~hhra_phys.effects.library_twins`), else empty."""
    same = getattr(step, "same_as", ())
    return f" (the discovered form of {' and '.join(same)})" if same else ""


def _step_from_json(d: Mapping[str, Any]) -> Step:
    """A :class:`Step` (or discovered one) of :meth:`Step.to_json`'s dictionary."""
    own = {f.name for f in fields(Step)}
    kw = {k: v for k, v in d.items() if k in own}
    kw["ci95"] = {n: [math.nan if c is None else c for c in v]
                  for n, v in (d.get("ci95") or {}).items()}
    for k in ("criterion", "criterion_before", "val_rmse_before"):  # null: NaN when written
        kw[k] = math.nan if kw.get(k) is None else kw[k]
    if not d.get("discovered"):
        return Step(**kw)
    extra = ("expression", "uses", "method", "screening", "extrapolated", "same_as")
    return DiscoveredStep(**kw, **{k: d[k] for k in extra if k in d})


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


#: Queue kinds refitted by :func:`refit_candidate` (the rest are discovered candidates).
_LIBRARY_KINDS = ("effect", "sensor")
#: The order of a round's kinds of candidate (then by first-order score within each):
#: library effects and sensor effects, discovered terms, resonant modes. Why: the named
#: physics before its stand-ins (a discovered twin of a dead zone took a round from the
#: library's by 0.6 BIC units), and in order of cost: a library refit is one search of a
#: few new parameters (10-16 s on a 5000-sample rig record), a discovered entry several
#: refits of every free parameter, one per form and dropped term (37-42 s on the same
#: record), and a settled round spares what comes after (:data:`_SETTLES`).
_KIND_ORDER = {"effect": 0, "sensor": 0, "discovered": 1, "mode": 2}
#: A round's refits in units of the base fit's wall time, for the estimate said before
#: each round (:meth:`_Loop._estimate`): a library refit (shared among the workers), the
#: discovery screen, a discovered entry (several refits of every free parameter) and a
#: resonant mode, with the number of term and mode entries a round usually proposes.
#: Measured on 5000-sample reference-rig records (a base fit of 6-16 s, a library refit
#: 0.2-0.3 of it, a mode fit 0.5-0.8, a term entry 1.5-2.7): an upper bound by design.
_ROUND_COST = {"library": 0.3, "screen": 0.3, "term": 2.5, "mode": 0.8, "entries": 3,
               "modes": 3}
#: What a candidate at the noise level on both parts spares of the rest of its round
#: (:func:`~hhra_phys.selection.round_settled`): its own kind, and after a library effect of
#: the dynamics all of discovery, terms and modes (on the selection part they could at best
#: tie with it, within the noise allowance: the named physics is kept before a stand-in,
#: and discovery's screening is not even run). Sensor effects are refitted whatever
#: settled the round (a sensor's drift and a biased valve leave the same trend: the tie
#: rule needs both); a discovered term or mode spares no mode (a mode at one entry reaches
#: the noise as a stand-in for a mode at another; the criterion tells them apart).
_SETTLES = {"effect": ("effect", "discovered", "mode"), "sensor": ("sensor",),
            "discovered": ("discovered",), "mode": ()}


def _kind(effect: str) -> str:
    """A library candidate's kind in a round: ``"sensor"`` for an effect that describes
    the measurement (:attr:`hhra_phys.parts.Effect.sensor`), else ``"effect"``."""
    cls = EFFECTS.get(effect)
    return "sensor" if cls is not None and getattr(cls, "sensor", False) else "effect"


def _shallow(v: Any) -> Any:
    """A list or dict copied one level deep (a loop path's own containers), else ``v``."""
    return list(v) if isinstance(v, list) else dict(v) if isinstance(v, dict) else v


def _lookahead(executor: Executor) -> int | None:
    """Library refits handed to ``executor`` ahead of the round: one per local worker.

    The round may settle early (a candidate at the noise level), after which the rest
    of the library is not refitted; jobs already running would still be waited for
    when the executor closes. Submitting one per worker keeps them busy, and since the
    next is submitted only when the round asks for the next result (after judging this
    one), a settled round wastes at most one fewer. ``None`` (all at once) for executors
    of unknown size (Dask).
    """
    n = getattr(executor, "_max_workers", None)
    return n if isinstance(n, int) and n > 0 else None


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


def summary_lines(res: LoopResult, out: Mapping[str, Any]) -> list[str]:
    """:meth:`LoopResult.summary`'s lines from the result and its JSON ``out``
    (:meth:`LoopResult.to_json`, passed in where it is already built)."""
    fm = format_metric
    lines = [f"chosen: {', '.join(res.chosen) or 'none'}"]
    for part in ("est", "val", "test"):
        b, f = out["base"].get(part, {}), out["final"].get(part, {})
        if f:
            lines.append(f"{part}: RMSE {fm(b.get('rmse'))} -> {fm(f.get('rmse'))}, "
                         f"VAF {fm(b.get('vaf'))} -> {fm(f.get('vaf'))} %")
    for rb, rf in zip(out["base"].get("records", []), out["final"].get("records", []),
                      strict=True):
        lines.append(f"record {rf['name']}: " + ", ".join(
            f"{part} RMSE {fm(rb[part]['rmse'])} -> {fm(rf[part]['rmse'])}"
            for part in ("est", "sel", "test") if rf[part].get("rmse") is not None))
    for name, est in res.final.derived.items():
        if est.free:
            ci = est.ci95 or (math.nan, math.nan)
            lines.append(f"derived {name} = {fm(est.value)} {est.unit}, 95 % CI "
                         f"[{fm(ci[0])}, {fm(ci[1])}]")
    return lines


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
             simulator: Simulator | Mapping[float, Simulator] | None = None) -> Problem:
    """A problem on the estimation part(s) (warm-started at ``start`` and ``x0``).

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
    return Problem(model, records, free=list(free), fixed=held, bounds=bnd,
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


def _run(cfg: _Settings, problem: Problem, optimizer: str, pop: int, iters: int,
         refine: str = "ipopt", warm: bool = True, ipopt_iter: int | None = None,
         stall: bool = True) -> FitResult:
    # A warm start seeds the first population with the problem's start values
    # (the previous fit); the base fit is not seeded. Each record is scored on its
    # own selection part. A refit that is judged (capped at ipopt_iter) stops where
    # IPOPT's iterate stalls (refine.STALL_ITER); a polish (stall=False) runs on.
    opts = FitOptions(optimizer=optimizer, refine=refine, pop_size=pop, max_iter=iters,
                      seed=cfg.seed, seed_population=warm, split=cfg.split,
                      refine_options={"max_iter": ipopt_iter or cfg.ipopt_iter,
                                      "stall_iter": STALL_ITER if stall else 0})
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


def selection_noise(problem: Problem, res: FitResult, sel: Any) -> dict[str, Any]:
    """Where a part's residual stands against the noise.

    Parameters
    ----------
    problem : Problem
        The fitted model's problem (on the estimation part of each record).
    res : FitResult
        Its fit.
    sel : Dataset or RecordSet or None
        The part to look at, one per record (a :class:`~hhra_phys.data.Dataset` for
        one record, a :class:`~hhra_phys.multi.RecordSet` for several): the selection
        parts (free run, initial state re-estimated on each), or ``None`` for the
        estimation parts themselves (the fit's residual, fitted initial states).

    Returns
    -------
    dict
        ``rmse`` (RMSE over all samples of the parts, output units), ``noise`` (their
        white-noise level, :func:`~hhra_phys.diagnose.noise_level`; the records' levels
        pooled by sample count), ``ratio`` (``rmse/noise``), ``ljung_box_p`` and
        ``white`` (``p > 0.05``) of the residual (with several records one Ljung-Box
        test of them together: statistics and degrees of freedom summed, records
        independent).
    """
    parts = [None] * len(problem.records) if sel is None else as_records(sel)
    ys = problem.simulate_parts(_free_values(problem, res), parts)
    datas = [pr.data if ds is None else ds
             for pr, ds in zip(problem.records, parts, strict=True)]
    rs = [d.y - yk for d, yk in zip(datas, ys, strict=True)]
    r = np.concatenate(rs)
    if not np.isfinite(r).all():
        return {"rmse": math.inf, "noise": math.nan, "ratio": math.inf, "ljung_box_p": 0.0,
                "white": False}
    sigmas = [noise_level(rk, (d.u, yk)) for rk, d, yk in zip(rs, datas, ys, strict=True)]
    tests = [whiteness(rk) for rk in rs]
    if len(rs) == 1:  # a pool of one is that record's own
        sigma, p, white = sigmas[0], float(tests[0]["ljung_box_p"]), bool(tests[0]["white"])
    else:
        sigma = float(np.sqrt(sum(rk.size * s ** 2 for rk, s in zip(rs, sigmas, strict=True))
                              / r.size))
        p = float(chi2.sf(sum(w["ljung_box_q"] for w in tests), sum(w["lags"] for w in tests)))
        white = p > 0.05
    rmse = float(np.sqrt(np.mean(r ** 2)))
    return {"rmse": rmse, "noise": sigma, "ratio": rmse / sigma if sigma > 0 else math.inf,
            "ljung_box_p": p, "white": white}


def _why_at_noise(level: Mapping[str, Any], noise_tol: float) -> str:
    """Which rule of :func:`at_noise_level` holds, in words (one need not imply the other:
    an RMSE within the allowance can still be a coloured residual)."""
    p = level["ljung_box_p"]
    if level["white"]:
        return f"white: Ljung-Box p {p:.2g} > 0.05"
    return (f"within the allowance 1 + noise_tol = {1 + noise_tol:.3g} x noise, though not "
            f"white: Ljung-Box p {p:.2g}")


def _why_not_at_noise(level: Mapping[str, Any], noise_tol: float) -> str:
    """Why the estimation part is not at the noise level, in words: above the allowance,
    or within it but clearly coloured (:data:`~hhra_phys.selection.COLOURED_P`)."""
    p = level["ljung_box_p"]
    if level["ratio"] <= 1 + noise_tol:
        return (f"RMSE {level['rmse']:.4g} = {level['ratio']:.3f} x noise, within the "
                f"allowance but clearly coloured: Ljung-Box p {p:.2g} < {COLOURED_P:g}")
    return f"RMSE {level['rmse']:.4g} = {level['ratio']:.3f} x noise, above the allowance"


def noise_stop(problem: Problem, res: FitResult, sel: Dataset, noise_tol: float,
               ) -> tuple[dict[str, Any], bool]:
    """The loop's noise-level stop: both non-test parts must be at the noise level.

    The selection part alone is a quarter of the record; a weak effect that it
    does not excite (a friction with few reversals in it) can leave it at the noise
    level while the estimation part, twice as long, still shows the effect. A
    round is therefore run when *either* part is above the noise level; the test
    part is never looked at. Whether a candidate is then accepted is still decided
    on selection by :func:`acceptance`, so a round that runs on the estimation
    part's evidence cannot add an effect the selection part does not confirm.

    Parameters
    ----------
    problem, res : Problem, FitResult
        The current model's problem and fit.
    sel : Dataset
        The selection part.
    noise_tol : float
        Structural-mismatch allowance (fraction of the noise level).

    Returns
    -------
    level : dict
        :func:`selection_noise` of the selection part, with the estimation part's
        under ``"estimation"``.
    stop : bool
        Both parts at the noise level (:func:`at_noise_level`).
    """
    level = selection_noise(problem, res, sel)
    level["estimation"] = selection_noise(problem, res, None)
    return level, stops_at_noise(level, noise_tol)


@dataclass(frozen=True)
class _Job:
    """One candidate refit: everything a worker needs (picklable)."""

    cfg: _Settings
    round: int
    effect: str
    effect_kw: dict[str, Any]
    model: Model
    free: tuple[str, ...]
    values: dict[str, float]
    x0: dict[str, float]
    evidence: dict[str, Any]
    cand_pop: int | None
    cand_iter: int | None
    crit_cur: float
    rmse_cur: float
    est_range: tuple[float, float]
    #: Parameters of the effects accepted in earlier rounds, searched again with the
    #: new ones (``augment(joint_search=True)``); empty (default): held at the previous fit.
    previous: tuple[str, ...] = ()
    #: Estimation MSE below which the candidate's boxes are widened (:func:`_widening_worth`;
    #: ``inf``: always, where the current model's error is not known).
    widen_below: float = math.inf
    #: Noise levels of the selection and estimation parts at the current model and the
    #: loop's noise tolerance (:func:`~hhra_phys.selection.round_settled`; NaN: unknown).
    noise: tuple[float, float, float] = (math.nan, math.nan, NOISE_TOL)
    #: Search a sharper switching width for the effect (``LoopOptions.fit_shapes``).
    fit_shapes: bool = False
    #: The loop's acceptance margin (``LoopOptions.margin``): a sharper shape passes the
    #: rule a candidate passes (:func:`_sharpen`).
    margin: float = 0.1


def _widening_worth(res: FitResult, noise_est: float) -> float:
    """The estimation MSE a candidate must reach to be widened: the current fit ``res``'s
    less :data:`~hhra_phys.fit.WIDEN_CLEAR_GAIN` of its part above the noise level
    ``noise_est`` (the share of the error a contender explains)."""
    mse = float(res.metrics["est"].get("mse", math.inf))
    if not (math.isfinite(mse) and math.isfinite(noise_est)):
        return math.inf
    return mse - WIDEN_CLEAR_GAIN * max(mse - noise_est ** 2, 0.0)


@dataclass
class _Outcome:
    """What a candidate refit returns to the loop (plain data, picklable)."""

    step: Step | None
    values: dict[str, float] = field(default_factory=dict)
    x0: dict[str, float] = field(default_factory=dict)
    free: list[str] = field(default_factory=list)
    error: str = ""
    #: Boxes of the candidate's parameters widened during its refit (kept on acceptance).
    boxes: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: Settings of the effect chosen during its refit beyond the job's (``fit_width``
    #: where :func:`_sharpen` kept a fitted width; kept on acceptance).
    effect_kw: dict[str, Any] = field(default_factory=dict)
    #: How the refit was integrated at its end (its ``settings["integration"]``): the
    #: accepted model's polish is simulated at least as finely (:func:`_as_refitted`).
    integration: dict[str, Any] = field(default_factory=dict)


def _search_size(n_new: int, pop: int | None, iters: int | None) -> tuple[int, int]:
    """Global search over a candidate's new parameters, sized to their number.

    The other parameters are held at the previous fit and IPOPT then frees all, so
    the search only has to place ``n_new`` values: a population of ``8 + 4*n_new``
    for ``10 + 5*n_new`` iterations (12 x 15 for one parameter) unless given.
    """
    return (pop if pop is not None else 8 + 4 * n_new,
            iters if iters is not None else 10 + 5 * n_new)


def _candidate_model(job: _Job) -> tuple[Model, list[str], Any]:
    """The current model with the job's effect; the effect's parameter names; the effect."""
    eff = make_effect(job.effect, data=job.cfg.data, values=job.values, model=job.model,
                      **job.effect_kw)
    return job.model.with_parts(eff), [p.name for p in eff.parameters], eff


def _widen_candidate(search: Callable[[Mapping[str, tuple[float, float]]],
                                      tuple[Problem, FitResult]],
                     boxes: dict[str, tuple[float, float]], all_free: Sequence[str],
                     notes: list[str], worth: float = math.inf) -> tuple[Problem, FitResult]:
    """A candidate's search (``search(boxes)``), widened where it ends at a box edge.

    A parameter (the effect's or the base's) that ends at the edge of its guessed box: the
    box, not the data, stopped it (a gravity load found at a third of its size on an
    actuator damped beyond the base box, which a stand-in then made up for). Its side is
    widened and the candidate searched again, as often as a fit widens
    (MAX_WIDEN_DECADES); kept when it fits estimation better, and, as a fit's widening, not
    widened further once a widening gains less than WIDEN_MIN_GAIN. ``boxes`` (the boxes
    opened so far) is updated with the kept widenings, ``notes`` with what was done.

    Only a candidate whose first search lowered the estimation MSE to at most ``worth``
    is widened: one that explains less than :data:`~hhra_phys.fit.WIDEN_CLEAR_GAIN` of
    the current model's error above the noise (:func:`_widening_worth`) is no contender,
    and a widening buys a few per cent (measured: a sensor drift and offset on a dead-zone
    record, selection 1.249 -> 1.225 and 1.26, each searched three more times with the
    base groups widened: 13.7 s and 12.2 s against 2.8 s for the dead zone that settled
    the round).
    """
    p2, r2 = search(boxes)
    if float(r2.metrics["est"]["mse"]) > worth:
        if _edge_boxes(p2, r2, all_free):
            notes.append("a parameter ended at its box edge; not widened: the candidate "
                         f"explains less than {100 * WIDEN_CLEAR_GAIN:.0f} % of the current "
                         "model's estimation error above the noise")
        return p2, r2
    for _ in range(MAX_WIDEN_DECADES):
        wide = _edge_boxes(p2, r2, all_free)
        if not wide:
            break
        p2w, r2w = search({**boxes, **wide})
        mse = float(r2.metrics["est"]["mse"])
        gain = mse - float(r2w.metrics["est"]["mse"])
        notes += [f"{n} ended at its box edge; box widened to [{lo:.4g}, {hi:.4g}] "
                  f"and the candidate searched again"
                  + ("" if gain > 0 else " (no better: kept as it was)")
                  for n, (lo, hi) in wide.items()]
        if not gain > 0:
            break
        boxes.update(wide)
        p2, r2 = p2w, r2w
        if gain < WIDEN_MIN_GAIN * mse:
            break  # kept, but a further decade would buy less still (fit.widen_boxes' stop)
    return p2, r2


def refit_candidate(job: _Job) -> _Outcome:
    """Add one effect to the current model, refit and score it on the selection part.

    Global search over the effect's new parameters (and those of the effects
    accepted earlier, ``job.previous``) with the rest of the previous fit held (and
    seeded), then IPOPT over all free parameters. Runs anywhere: the argument and
    the result are plain picklable data, so :func:`augment` may send it to any
    :class:`concurrent.futures.Executor` (processes, a Dask cluster); the result
    depends only on the job (its seed included), never on where it ran.
    """
    ts = time.perf_counter()
    cfg = job.cfg
    try:
        model_c, new, eff = _candidate_model(job)
        # With joint_search, the parameters of effects accepted earlier are searched
        # again with the new ones (seeded at their previous values): an effect accepted
        # earlier may have absorbed part of this one (a dead zone fitted alone grows to
        # mimic a sharp friction beside it) and IPOPT from the held value stays there.
        searched = new + [n for n in job.previous if n in job.free]
        fixed = {n: job.values[n] for n in job.free if n not in searched}
        all_free = list(job.free) + new
        pop, iters = _search_size(len(searched), job.cand_pop, job.cand_iter)
        # The first-order estimate of the residual analysis seeds the search (as discovery's
        # terms start at theirs), and a guessed box too small for it is opened to hold it.
        first, boxes = _first_order_start(job, model_c, new)
        if boxes:
            cfg = replace(cfg, default_bounds={**cfg.default_bounds, **boxes})
        widened_notes = [f"{n}'s first-order estimate {first[n]:.4g} lies beyond its box; "
                         f"box opened to [{lo:.4g}, {hi:.4g}]" for n, (lo, hi) in boxes.items()]

        def search(boxes_now: Mapping[str, tuple[float, float]]) -> tuple[Problem, FitResult]:
            cfg_b = replace(cfg, default_bounds={**cfg.default_bounds, **boxes_now})
            return _search_candidate(cfg_b, model_c, searched, fixed, all_free, job.values,
                                     job.x0, pop, iters, first)

        p2, r2 = _widen_candidate(search, boxes, all_free, widened_notes, job.widen_below)
        shaped = _sharpen(replace(cfg, default_bounds={**cfg.default_bounds, **boxes}),
                          job, eff, r2, all_free, widened_notes)
        chosen_kw: dict[str, Any] = {}
        if shaped is not None:
            p2, r2, model_c, eff, width, box = shaped
            chosen_kw = {"fit_width": True, **({"profile": eff.profile}
                                               if hasattr(eff, "profile") else {})}
            new, all_free = new + [width], all_free + [width]
            boxes[width] = box
    except Exception as exc:  # noqa: BLE001 - a failing candidate must not end the loop
        return _Outcome(None, error=f"its refit failed: {type(exc).__name__}: {exc}")
    crit = information_criterion(r2, cfg.criterion)
    vr = float(r2.metrics["val"].get("rmse", math.inf))
    if not math.isfinite(vr):
        vr = math.inf
    step = Step(job.round, job.effect, job.evidence, {n: r2.values[n] for n in new},
                {n: list(r2.ci95[n]) for n in new if n in r2.ci95},
                dict(r2.metrics["est"]), dict(r2.metrics["val"]), crit, job.crit_cur,
                job.rmse_cur)
    # Where it enters on this model: a role-bound entry ("rate:@velocity") by its state's name.
    entry_at = getattr(eff, "entry_at", None)
    step.entry = str((entry_at(job.model) if entry_at else getattr(eff, "entry", "")) or "")
    step.sensor = bool(getattr(eff, "sensor", False))
    step.regime = regime_coverage(eff, p2.per_record_values(_free_values(p2, r2)),
                                  {"est": [None] * len(p2.records), "sel": as_records(cfg.sel)})
    # A fitted switching width is the effect's shape, not its size: it is kept only where
    # it fits clearly better (_sharpen), and a sharp edge the record cannot resolve below
    # a sample (an interval reaching to zero) does not make the effect unidentified.
    bad = _unidentified(r2, [n for n in new if n != _width_param(eff)], model_c)
    if bad:
        step.identifiable = False
        step.notes.append(
            f"95 % CI of {', '.join(bad)} too wide: not identifiable from these data")
    if getattr(eff, "position_dependent", False):
        vrange = _output_range(p2, _free_values(p2, r2), cfg.sel)
        lo, hi = job.est_range
        if vrange[0] < lo - 1e-9 or vrange[1] > hi + 1e-9:
            step.notes.append(
                f"selection drives the output to [{vrange[0]:.3g}, {vrange[1]:.3g}] "
                f"{cfg.data.output_unit or ''}, outside the estimation range "
                f"[{lo:.3g}, {hi:.3g}]: this position-dependent effect is extrapolated there")
    step.notes.extend(widened_notes)
    step.seconds = time.perf_counter() - ts
    return _Outcome(step, _values(r2), dict(r2.x0), all_free, boxes=boxes,
                    effect_kw=chosen_kw, integration=dict(r2.settings.get("integration") or {}))


def _first_order_start(job: _Job, model: Model, new: Sequence[str]
                       ) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """The effect's first-order estimate (finite values inside the parameter's sign) as
    start values, and boxes opened to hold those beyond their box (at most a decade, or
    ten times as far from zero)."""
    est = job.evidence.get("estimate") or {}
    start: dict[str, float] = {}
    boxes: dict[str, tuple[float, float]] = {}
    for n in new:
        v = est.get(n)
        if v is None or not math.isfinite(float(v)):
            continue
        v = float(v)
        par = model.params[n]
        if n in job.cfg.bounds or (par.lower >= 0 and v <= 0):
            continue  # the user's box, or a positive parameter estimated at or below zero
        lo, hi = par.lower, par.upper
        if par.scale == "log":
            lo, hi = max(min(lo, v), lo / 10), min(max(hi, v), hi * 10)
        else:
            lo = max(min(lo, 1.2 * v), 10 * lo) if lo < 0 else lo
            hi = min(max(hi, 1.2 * v), 10 * hi) if hi > 0 else hi
        start[n] = min(max(v, lo), hi)
        if (lo, hi) != (par.lower, par.upper):
            boxes[n] = (lo, hi)
    return start, boxes


def _width_param(eff: Any) -> str | None:
    """The parameter an effect adds with ``fit_width=True`` (its fitted switching width:
    ``v_switch``, ``w_contact``), whether or not it has it now; ``None`` for effects
    without that option."""
    if "fit_width" not in getattr(eff, "__dataclass_fields__", {}):
        return None
    names = {p.name for p in replace(eff, fit_width=False).parameters}
    return next((p.name for p in replace(eff, fit_width=True).parameters
                 if p.name not in names), None)


def _sharpen(cfg: _Settings, job: _Job, eff: Any, res: FitResult, all_free: list[str],
             notes: list[str]
             ) -> tuple[Problem, FitResult, Model, Any, str, tuple[float, float]] | None:
    """The candidate with a sharper switching width fitted, where that fits clearly better
    (with ``LoopOptions.fit_shapes``; off by default, see there).

    A library effect with a smooth edge (Coulomb friction's smooth sign, a backlash's
    contact) is first refitted at its default width, which is physical but may be far
    wider than the machine's: on a 1 kHz drive whose friction switches within 1e-4 m/s,
    the true structure with library effects left 1.2e-4 m of estimation error and 2.7e-4 m
    on a separate test record at the default width (2.5e-4 m/s), 1.1e-5 m and 9.9e-6 m
    with the width fitted (8e-5 m/s); an outside check on the reference rig's exact Coulomb
    friction saw the library's, at its default width, lose to its discovered twin (a
    sharper ``sgn``; not reproduced here: on our exact-friction rig records the default
    width already reaches the noise).

    So the candidate is searched once more over its width alone (the rest held at its
    refit, then IPOPT over all), from the effect's lower bound up to the default width,
    once for each profile of its smooth sign (a Coulomb friction's algebraic and tanh,
    :data:`~hhra_phys.effects.SIGN_PROFILES`, unless the user chose one): at the drive's
    fitted width the algebraic sign's slow approach to its level left 4e-6 m of
    selection error where the tanh reached the 1e-6 m noise; the lower criterion wins.
    Sharper only: a switch wider than the default is no longer a Coulomb friction but a
    smooth damping, a stand-in for a velocity-dependent damping that discovery names
    (``omega*|omega|``); unbounded, the drive's first round took 0.017 m/s, 70 times the
    default. The default is replaced only where the sharper shape passes the rule a
    candidate effect passes against the model at the default width
    (:func:`~hhra_phys.selection.acceptance`: the selection error falls by the margin or
    to the noise, beyond the noise allowance, and the criterion falls; a width the data
    do not resolve costs a parameter and stays at the default). Why the whole rule: on the
    one-loop study's dead zone beside an exact friction (seed 2) a sharper width taken
    for a 1 % gain on selection left the friction absorbing the dead zone, whose refit
    then ended above the current model. Only a contender is sharpened, one whose
    refit took at least :data:`~hhra_phys.fit.WIDEN_CLEAR_GAIN` of the current model's
    estimation error above the noise (as for widening, :func:`_widening_worth`), and not
    one already at the noise level on both parts (:func:`~hhra_phys.selection.
    round_settled`: a sharper shape cannot beat it by more than the noise allowance).
    Measured: sharpening every friction refit cost 4-5 CPU s on each 20 s dead-zone record
    of ``benchmarks/bench_cost.py`` (+35-40 % of its diagnosis) and 2.4 s on the friction
    record, whose friction was at the noise at its default width. A ``fit_width`` or
    ``profile`` the user set is left as given.

    Returns
    -------
    tuple or None
        The refit's problem and fit, the model, the effect, the width's parameter name and
        its box; ``None``: the candidate as it was.
    """
    mse = float(res.metrics["est"].get("mse", math.inf))
    noise_sel, noise_est, tol = job.noise
    scores = SimpleNamespace(est=res.metrics["est"], val=res.metrics["val"])  # as a Step
    width = _width_param(eff) if job.fit_shapes else None
    if (width is None or eff.fit_width or "fit_width" in job.effect_kw
            or not mse <= job.widen_below
            or round_settled(scores, noise_sel, noise_est, tol, True)):
        return None
    free_s = all_free + [width]
    held = {n: res.values[n] for n in all_free if n in res.values}
    job_s = replace(job, values=_values(res), x0=dict(res.x0))
    pop, iters = _search_size(1, job.cand_pop, job.cand_iter)
    crit = information_criterion(res, cfg.criterion)
    sel = float(res.metrics["val"].get("rmse", math.inf))
    # The profile of the smooth sign too (a Coulomb friction's algebraic or tanh), unless
    # the user chose it: at one width the two differ in how fast they reach the level.
    profiles = [getattr(eff, "profile", None)]
    if profiles[0] is not None and "profile" not in job.effect_kw:
        profiles += [p for p in SIGN_PROFILES if p != profiles[0]]
    best: tuple[float, float, Any] | None = None
    tried: list[str] = []
    for profile in profiles:
        eff_s = replace(eff, fit_width=True, **({} if profile is None else {"profile": profile}))
        model_s = job.model.with_parts(eff_s)
        box = (float(model_s.params[width].lower), float(eff.width))
        # An explicit bound, as a user's: the fit's widening opens a guessed box a group
        # ends at, and a width widened past the default is a damping (the drive's first
        # round took 0.0104 m/s, 40 times the default, through that door).
        cfg_s = replace(cfg, bounds={**cfg.bounds, width: box})
        p_s, r_s = _search_candidate(cfg_s, model_s, [width], held, free_s, job_s.values,
                                     job_s.x0, pop, iters, {width: float(eff.width)})
        crit_s = information_criterion(r_s, cfg.criterion)
        sel_s = float(r_s.metrics["val"].get("rmse", math.inf))
        tried.append(f"{r_s.values[width]:.3g}" + (f" ({profile})" if len(profiles) > 1 else "")
                     + f": {cfg.criterion.upper()} {crit_s:.1f}, selection RMSE {sel_s:.4g}")
        ok, _ = acceptance(sel, sel_s, crit, crit_s, job.margin, cfg.criterion, noise_sel, tol)
        if ok and (best is None or crit_s < best[0]):
            best = (crit_s, sel_s, (p_s, r_s, model_s, eff_s, width, box))
    if best is None:
        notes.append(f"its switching width fitted ({'; '.join(tried)}) passes the acceptance "
                     f"rule against the default {eff.width:.3g} ({cfg.criterion.upper()} "
                     f"{crit:.1f}, selection RMSE {sel:.4g}) with neither: kept the default")
        return None
    crit_s, sel_s, out = best
    r_s, eff_s = out[1], out[3]
    shape = f" with the {eff_s.profile} sign" if len(profiles) > 1 else ""
    notes.append(f"its switching width fitted: {r_s.values[width]:.3g}{shape} instead of the "
                 f"default {eff.width:.3g} ({cfg.criterion.upper()} {crit:.1f} -> "
                 f"{crit_s:.1f}, selection RMSE {sel:.4g} -> {sel_s:.4g}; tried "
                 f"{'; '.join(tried)})")
    return out


def _search_candidate(cfg: _Settings, model: Model, searched: list[str],
                      fixed: dict[str, float], all_free: list[str],
                      values: Mapping[str, float], x0: Mapping[str, float], pop: int,
                      iters: int, first: Mapping[str, float] | None = None
                      ) -> tuple[Problem, FitResult]:
    """A candidate's two stages: global search over ``searched`` (the rest held at the
    previous fit's ``values`` and initial state ``x0``, the new parameters seeded at
    ``first``), then IPOPT over ``all_free``; the second stage's problem and fit."""
    p1 = _problem(cfg, model, searched, fixed, {**values, **(first or {})}, x0)
    p1 = _stiff_substeps(p1)
    r1 = _run(cfg, p1, "hgwo", pop, iters, refine="none")
    p2 = _problem(cfg, model, all_free, {}, _values(r1), r1.x0,
                  simulator=getattr(p1, "simulators", p1.sim))
    return p2, _run(cfg, p2, "none", 0, 0)


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


def _backward_step(cfg: _Settings, cur: FitResult, cur_prob: Problem, cur_free: list[str],
                   chosen: list[str], base_free: Sequence[str], rnd: int, margin: float,
                   noise_tol: float, cand_pop: int | None, cand_iter: int | None,
                   say: Callable[[str], None],
                   ) -> tuple[FitResult, Problem, list[str], list[Step], str | None]:
    """Try taking out each effect accepted before the newest one (stepwise selection).

    Each earlier effect is removed from the current model and the rest refitted
    like a candidate: a global search over the other effects' parameters (they may
    have absorbed what it did, warm-started from the current fit, the base
    parameters held), then IPOPT over all free parameters. The effect is removed
    when :func:`backward_decision` says the model without it is not worse by the
    acceptance rule; of several such effects the one whose removal leaves the lowest
    selection RMSE goes (one per call: the loop's next round may propose others).

    Returns
    -------
    cur, cur_prob, cur_free
        The model after the step (unchanged when nothing is removed).
    steps : list of Step
        One per effect checked (``action`` ``"keep"`` or ``"remove"``).
    removed : str or None
        The effect removed.
    """
    crit_with = information_criterion(cur, cfg.criterion)
    rmse_with = float(cur.metrics["val"]["rmse"])
    steps: list[Step] = []
    out: list[tuple[float, Step, Problem, FitResult, list[str]]] = []
    for effect in chosen[:-1]:
        ts = time.perf_counter()
        mine = _effect_params(cur_prob.model, effect)
        model_r = cur_prob.model.without(effect)
        free_r = [n for n in cur_free if n not in mine]
        searched = [n for n in free_r if n not in base_free and not n.startswith("x0_")]
        vals = {k: v for k, v in _values(cur).items() if k not in mine}
        try:
            pop, iters = _search_size(len(searched), cand_pop, cand_iter)
            p1 = _problem(cfg, model_r, searched, {n: vals[n] for n in free_r
                                                   if n not in searched}, vals, cur.x0)
            r1 = _run(cfg, p1, "hgwo", pop, iters, refine="none")
            p2 = _problem(cfg, model_r, free_r, {}, _values(r1), r1.x0,
                          simulator=getattr(p1, "simulators", p1.sim))
            r2 = _run(cfg, p2, "none", 0, 0)
        except Exception as exc:  # noqa: BLE001 - a failing refit keeps the effect
            say(f"  backward: refit without {effect} failed ({type(exc).__name__}: {exc}); "
                "kept")
            continue
        rmse_r = float(r2.metrics["val"].get("rmse", math.inf))
        rmse_r = rmse_r if math.isfinite(rmse_r) else math.inf
        crit_r = information_criterion(r2, cfg.criterion)
        noise = float(selection_noise(p2, r2, cfg.sel)["noise"])
        remove, why = backward_decision(rmse_r, rmse_with, crit_r, crit_with, noise, margin,
                                        noise_tol, cfg.criterion)
        step = Step(rnd, effect, {}, {n: cur.values[n] for n in mine if n in cur.values},
                    {n: list(cur.ci95[n]) for n in mine if n in cur.ci95},
                    dict(cur.metrics["est"]), dict(cur.metrics["val"]), crit_with, crit_r,
                    rmse_r, action="keep", reason=f"kept (proposed now it would be "
                    f"accepted): {why}" if not remove else why)
        step.seconds = time.perf_counter() - ts
        say(f"  backward: without {effect}: {why} -> {'remove' if remove else 'keep'} "
            f"[{step.seconds:.1f} s]")
        steps.append(step)
        if remove:
            out.append((rmse_r, step, p2, r2, free_r))
    if not out:
        return cur, cur_prob, cur_free, steps, None
    _, step, p2, r2, free_r = min(out, key=lambda t: t[0])
    step.action, step.removed = "remove", True
    step.reason = "removed (proposed now it would not be accepted): " + step.reason
    # Polished like an accepted candidate before the next round.
    prob = _problem(cfg, p2.model, free_r, {}, _values(r2), r2.x0)
    res = _run(cfg, prob, "none", 0, 0, ipopt_iter=POLISH_ITER, stall=False)
    say(f"round {rnd}: removed {step.effect}")
    return res, prob, free_r, steps, step.effect


class _DiscoveryFits:
    """What :class:`hhra_phys.discover.Discovery` needs of the loop's fits."""

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


@dataclass(frozen=True)
class LoopOptions:
    """Settings of the diagnosis loop (:func:`augment`), validated as a whole.

    Every field is also a keyword of :func:`augment`, which overrides the options it is
    given (``augment(ds, options=LoopOptions(seed=3), max_effects=2)``).

    Attributes
    ----------
    split : float
        Estimation fraction of the whole record (default 0.5).
    test : float
        Fraction held out at the end as the test part (default 0.25): it chooses
        nothing and only reports the base and final models' error
        (:attr:`LoopResult.test`). ``0`` restores the old two-way split, where the
        part after estimation both selects and reports (optimistic).
    candidates : sequence of str, optional
        Library effects that may be added (default: all registered; ``[]``: none, so
        that discovery alone proposes).
    max_effects : int
        Most additions (library effects, user effects, discovered terms and modes alike);
        0 adds nothing. Default 4: three library effects and one discovered term, what the
        loop could add when discovery ran once after the library (the public record needs
        all four: asymmetric valve, delay, saturation and a load mode, docs/diagnosis.md).
    top_k : int, optional
        Library candidates refitted per round, best ranked first. Default: all of them
        (until one settles the round, :func:`~hhra_phys.selection.round_settled`).
        The ranking orders and explains; refits decide (a first-order ranking put the
        effect that paid most far down on the public record, docs/diagnosis.md).
    pop_size, max_iter : int
        Global search of the base fit (default 100 x 200, as :func:`~hhra_phys.fit.fit`:
        a loop is only as good as its base: a smaller base search left every candidate
        judged against a weak base, docs/diagnosis.md).
    cand_pop, cand_iter : int, optional
        Global search over a candidate's new parameters (default: sized to their
        number, ``8 + 4*n_new`` points for ``10 + 5*n_new`` iterations).
    seed : int
        Seed of every global search.
    margin : float
        Required relative fall of the selection RMSE (0.1: at least 10 %), unless it
        falls to the selection residual's noise level
        (:func:`~hhra_phys.selection.acceptance`).
    noise_tol : float, optional
        Tolerance of the noise level: the loop stops when the selection RMSE is
        within ``(1 + noise_tol)`` of the selection residual's noise level (or that
        residual is white), and a candidate must remove more selection variance than
        ``((1 + noise_tol)^2 - 1) * noise^2``. Default: what the selection part's length
        justifies, :func:`~hhra_phys.selection.noise_tolerance` (0.068 for 400 samples);
        a number gives a flat allowance (:data:`NOISE_TOL` = 0.15 was the default until
        2026-11-25, ``docs/diagnosis.md``).
    criterion : {"bic", "aic"}
        Information criterion on the estimation part that must also fall.
    free : sequence of str, optional
        Free base parameters (default: the Problem's default).
    bounds : dict, optional
        Bounds overriding the model's (base and effect parameters); never widened.
    default_bounds : dict, optional
        Boxes replacing the model's defaults (e.g. scaled to a record in sample
        units, :func:`base_model_for`): like the model's own, widened by decades when
        a fitted group ends at an edge (:mod:`hhra_phys.fit`), unlike ``bounds``.
    effect_kw : dict, optional
        ``{effect: {field: value}}`` for :func:`~hhra_phys.effects.make_effect`.
    backend : {"auto", "native", "casadi"}
        Simulator backend: compiled native code by default (the compiled-code cache
        is keyed by the generated code, so a model structure compiles once per
        machine), CasADi's virtual machine without a compiler.
    ipopt_iter : int
        IPOPT iteration limit of a candidate's refinement. 20 iterations judged five
        HHRA candidates as well as 60 but left the two-tank example's side inflow
        unconverged (selection RMSE 0.0518 against 0.0510), so that a stand-in won;
        the default stays 60. The accepted candidate is polished again
        (:data:`POLISH_ITER`).
    initial_state : {"fit", "data", "zero"}
        Initial-state rule of every fit (:mod:`hhra_phys.problem`).
    background : bool
        Without an executor, compile the next candidates' simulators in a
        background thread while the current one is refitted (default True).
    discover : bool
        In every round, beside the library's effects, propose terms and modes outside the
        library (:class:`hhra_phys.discover.Discovery`): ranked with the effects by
        first-order score, refitted and judged by the same rule (default True). With
        several records they are screened on the record with the largest residual and
        fitted to all.
    discover_kw : dict, optional
        Options of :class:`~hhra_phys.discover.Discovery` (``method``, ``max_terms``,
        ``entries``).
    joint_search : bool
        A candidate's global search also covers the parameters of the effects
        accepted in earlier rounds, instead of holding them at the previous fit
        (default False: held). An effect fitted alone can absorb part of the next one
        (a dead zone grown to mimic a sharp friction) and hold the refit in that
        local minimum; on 10 pair records the joint search found one such pair more
        but accepted one stand-in more (spool lag for a delay), so it is off by
        default (docs/diagnosis.md, "Simulated study").
    backward : bool
        Backward step (stepwise selection): after a round accepts an effect and at
        least two are in, each effect accepted earlier is refitted out of the model
        and removed when it would not be accepted if proposed now
        (:func:`backward_decision`, the same rule read the other way). A removed
        effect is not proposed again; rounds go on until ``max_effects`` are in, so
        a loop may run more rounds than ``max_effects``. Each check is a
        :class:`Step` with ``action`` ``"keep"`` or ``"remove"``.
    revisit : bool
        Revisit the one greedy choice a searched shape won over a given mechanism: when a
        round accepted a discovered term or mode over an acceptable given (library or
        user) effect and the loop then ends above the noise level, the path from that
        effect is followed too (from the same round, by the same rounds and rule), and
        the final model of each path is compared by the rule of
        :func:`~hhra_phys.selection.choose` (selection RMSE; within the noise allowance,
        the information criterion). The first such round is revisited, once. On the public
        record a two-term input stand-in took round 1 from the asymmetric valve and the
        loop stopped at 7.4 x the noise (docs/diagnosis.md). ``settings["revisited"]``
        says what ran and which path was kept.
    intersample : bool
        After the base fit and in every round (one record), while the record's own
        behaviour holds, when the current fit's residual carries the signature of the
        wrong inter-sample behaviour (:func:`hhra_phys.intersample.hold_suspected`: a
        sub-sample shift, or the curvature a straight line leaves under a smooth input,
        which shows only once the model's own error is below it), refit the same model
        with each other one (:func:`~hhra_phys.intersample.refit_with_hold`) and judge
        each by the same rule (:mod:`hhra_phys.selection`) beside the round's other
        candidates; the one :func:`~hhra_phys.selection.choose` picks is kept (tied, it is
        preferred like a sensor effect: it describes the measurement), and every later fit
        and score uses it. Each is a :class:`Step` named ``"intersample:<kind>"`` marked
        ``sensor``, which changes no physics, adds no parameter and no effect; a path
        changes the behaviour once.
    budget : float, optional
        Wall-clock seconds the loop may take (default: no limit). Checked before every
        round and every candidate's refit: once spent, the round refits nothing more,
        chooses among what it refitted, and the loop ends at the best model so far (no
        backward step, no revisit); ``settings["stopped_by_budget"]`` and a warning say
        so, with what was not refitted. The base fit always runs whole; the estimate
        printed after it says how long a round may take.
    progress_bar : bool
        A progress bar per round on standard error, naming the candidate being refitted
        and how many remain (shown on a terminal only; the CLI turns it on).
    fit_shapes : {"chosen", "contenders", "off"} or bool
        Fit the switching width of a library effect with a smooth edge (Coulomb
        friction's ``v_switch``, a backlash's ``w_contact``) where a sharper one fits
        better, and a friction's sign profile (algebraic or tanh) with it
        (:func:`_sharpen`; CLI ``--shapes MODE``, ``--fit-shapes`` for ``"contenders"``).
        ``"chosen"`` (default): the round's chosen effect, once accepted and after the
        backward step, so the shape never decides which effect wins a round (and effects
        accepted earlier whose width is still the default, again after each later
        acceptance); ``"contenders"`` (``True``): every
        contender in its refit, before the round is decided (a library friction whose
        default width loses to its sharper discovered twin can then win); ``"off"``
        (``False``): the library's default widths. Why not contenders by default: on
        the one-loop study's record of an exact dead zone beside an exact friction (seed
        1) the sharpened friction took round 1 from the dead zone and absorbed it, where
        the default width leaves both to be named; on a 1 kHz drive whose friction
        switches within 1e-4 m/s the sharpened width is what names the friction
        (docs/diagnosis.md).
    rotate : bool
        Rotate the parts where one cannot decide alone (default True; CLI
        ``--no-rotate``): when the selection part and the information criterion on
        estimation disagree on a candidate and the part that says no holds the candidate's
        regime thinly (:func:`~hhra_phys.selection.needs_rotation`; the regime of
        :func:`~hhra_phys.regime.regime_coverage`, or for a candidate without a
        first-order column of :func:`~hhra_phys.regime.change_coverage`), the candidate
        and the current model are refitted on the selection part and scored on the
        estimation part, and the held-out error pooled over both folds decides
        (:func:`~hhra_phys.selection.rotated_verdict`; ``steps[].folds``). The model
        itself stays fitted on estimation.
    """

    split: float = 0.5
    test: float = 0.25
    candidates: tuple[str, ...] | None = None
    max_effects: int = 4
    top_k: int | None = None
    pop_size: int = 100
    max_iter: int = 200
    cand_pop: int | None = None
    cand_iter: int | None = None
    seed: int = 0
    margin: float = 0.1
    noise_tol: float | None = None
    criterion: str = "bic"
    free: tuple[str, ...] | None = None
    bounds: Mapping[str, tuple[float, float]] | None = None
    default_bounds: Mapping[str, tuple[float, float]] | None = None
    effect_kw: Mapping[str, Mapping[str, Any]] | None = None
    backend: str = "auto"
    ipopt_iter: int = 60
    initial_state: str = "fit"
    background: bool = True
    discover: bool = True
    discover_kw: Mapping[str, Any] | None = None
    joint_search: bool = False
    backward: bool = True
    revisit: bool = True
    intersample: bool = True
    budget: float | None = None
    progress_bar: bool = False
    fit_shapes: bool | str = "chosen"
    rotate: bool = True

    @property
    def shape_mode(self) -> str:
        """:attr:`fit_shapes` as one of :data:`SHAPE_MODES` (``True``: ``"contenders"``,
        ``False``: ``"off"``)."""
        if isinstance(self.fit_shapes, bool):
            return "contenders" if self.fit_shapes else "off"
        return str(self.fit_shapes)

    def validate(self) -> LoopOptions:
        """Check every setting; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        def need(ok: bool, text: str) -> None:
            if not ok:
                raise ParameterError(text)

        need(self.criterion in ("bic", "aic"),
             f"criterion must be 'bic' or 'aic', got {self.criterion!r}")
        need(0 <= self.margin < 1, f"margin must be in [0, 1), got {self.margin}")
        need(self.noise_tol is None or self.noise_tol >= 0,
             f"noise_tol must be >= 0, got {self.noise_tol}")
        need(self.budget is None or (isinstance(self.budget, (int, float))
                                     and not isinstance(self.budget, bool)
                                     and math.isfinite(self.budget) and self.budget > 0),
             f"budget must be a number of seconds > 0, got {self.budget!r}")
        need(isinstance(self.fit_shapes, bool) or self.fit_shapes in SHAPE_MODES,
             f"fit_shapes must be one of {', '.join(map(repr, SHAPE_MODES))} (or True for "
             f"'contenders', False for 'off'), got {self.fit_shapes!r}")
        need(isinstance(self.rotate, bool), f"rotate must be True or False, got {self.rotate!r}")
        need(isinstance(self.max_effects, int) and self.max_effects >= 0,
             f"max_effects must be an integer >= 0, got {self.max_effects!r}")
        need(self.top_k is None or (isinstance(self.top_k, int) and self.top_k >= 1),
             f"top_k must be an integer >= 1 or None, got {self.top_k!r}")
        for name in ("pop_size", "max_iter", "ipopt_iter"):
            v = getattr(self, name)
            need(isinstance(v, int) and v >= 1, f"{name} must be an integer >= 1, got {v!r}")
        for name in ("cand_pop", "cand_iter"):
            v = getattr(self, name)
            need(v is None or (isinstance(v, int) and v >= 1),
                 f"{name} must be an integer >= 1 or None, got {v!r}")
        need(self.backend in ("auto", "native", "casadi"),
             f"backend must be 'auto', 'native' or 'casadi', got {self.backend!r}")
        need(self.initial_state in ("fit", "data", "zero"),
             f"initial_state must be 'fit', 'data' or 'zero', got {self.initial_state!r}")
        bad_kw = sorted(set(self.discover_kw or {}) - {"method", "max_terms", "entries"})
        need(not bad_kw, f"discover_kw: unknown option(s) {', '.join(bad_kw)}; options: "
             "method, max_terms, entries")
        unknown = [n for n in (self.candidates or ()) if n not in EFFECTS]
        need(not unknown, f"unknown effect {unknown[0]!r}; library: {', '.join(EFFECTS)}"
             if unknown else "")
        return self

    @classmethod
    def of(cls, options: LoopOptions | None = None, **overrides: Any) -> LoopOptions:
        """``options`` (default: the defaults) with ``overrides`` applied, validated.

        Raises
        ------
        ParameterError
            An override that is not a setting (with the settings' names), or a bad value.
        """
        if "stop_on" in overrides:
            raise ParameterError(
                "stop_on was removed (its 'selection' rule stopped on the selection part "
                "alone): the loop stops when both the estimation and the selection parts "
                "are at the noise level (noise_stop); drop the setting")
        opts = with_overrides(options if options is not None else cls(), overrides, "loop",
                              ("candidates", "free"))
        if opts.candidates is not None:  # generic aliases (input_deadzone, ...) name the
            # same library parts: each is tried once
            opts = replace(opts, candidates=tuple(dict.fromkeys(
                effect_name(n) for n in opts.candidates)))
        return opts.validate()


def augment(
    data: Dataset | Sequence[Dataset],
    model: Model | None = None,
    *,
    options: LoopOptions | None = None,
    validation: Dataset | Sequence[Dataset] | None = None,
    base: FitResult | None = None,
    executor: Executor | None = None,
    progress: Callable[[str], None] | None = None,
    **settings: Any,
) -> LoopResult:
    """Fit, diagnose and augment a physical model with library effects and discovered terms.

    Parameters
    ----------
    data : Dataset or sequence of Dataset
        The whole record, N samples, split in time order into estimation (the
        first ``split*N``), selection (the next) and test (the last ``test*N``).
        Several records: each is split so; every fit (base and candidates) is
        one :class:`~hhra_phys.problem.Problem` of all of them, with shared parameters (an
        effect's new ones too) and per-record initial states; selection and test
        scores are pooled over the records (per record in ``records`` of
        ``base``/``final`` in :meth:`LoopResult.to_json`) and the evidence is
        summed over them (:func:`~hhra_phys.diagnose.analyse`).
    model : Model, optional
        Base model (default: :class:`~hhra_phys.models.hhra.HHRAModel`, pressure
        output if the record's output is pressure).
    options : LoopOptions, optional
        The loop's settings (default :class:`LoopOptions`'s).
    validation : Dataset or sequence of Dataset, optional
        Whole records as the test part (then ``test`` is ignored and every record of
        ``data`` splits into estimation and selection only); runs the several-record
        loop, even for one record of ``data``.
    base : FitResult, optional
        A fit of ``model`` on this record's estimation part to start from (e.g. the
        result of ``hhra-phys fit`` with the same split); its free set is the base
        free set. Default: fit it here.
    executor : concurrent.futures.Executor, optional
        Where the library candidates' refits of a round run (``ProcessPoolExecutor``, a
        Dask ``Client.get_executor()``, ...). Default: here, one after another. The
        results are the same either way for the same seed.
    progress : callable, optional
        Called with a line of text at every step.
    **settings
        Any field of :class:`LoopOptions` (``seed=3``, ``max_effects=2``, ...), overriding
        ``options``; validated with it (:meth:`LoopOptions.validate`).

    Returns
    -------
    LoopResult

    Notes
    -----
    A candidate is accepted when, on the selection part, its RMSE falls by at
    least ``margin`` (or to the noise level), the information criterion on estimation
    falls, and the
    selection variance it removes exceeds the noise allowance; of the acceptable
    candidates of a round (every kind) the one :func:`~hhra_phys.selection.choose` picks
    is added (:mod:`hhra_phys.selection`). The loop stops when a round accepts
    nothing, ``max_effects`` are in, or the estimation and selection residuals are
    both at the noise level (``rmse <= (1 + noise_tol) * noise`` or white by
    Ljung-Box, each with its own noise level).
    """
    opts = LoopOptions.of(options, **settings)
    res = _Loop(data, model, opts, validation, base, executor, progress).run()
    res.data = data  # for LoopResult.report's figures
    return res


class _Loop:
    """One run of :func:`augment`: its state, and one method per stage of the data path
    (base fit, inter-sample candidates, rounds of candidates, acceptance, result)."""

    #: The current round's estimate in units of the base fit (library, plus discovery
    #: once screened) and its start (:meth:`_estimate`, :meth:`_end_round`): the next
    #: round's estimate runs at this round's pace; none before the first round.
    round_units: float = 0.0
    round_discovery_units: float = 0.0
    round_t0: float = 0.0

    def __init__(self, data: Dataset | Sequence[Dataset], model: Model | None,
                 opts: LoopOptions, validation: Any, base: FitResult | None,
                 executor: Executor | None, progress: Callable[[str], None] | None) -> None:
        self.o, self.executor, self.base_given = opts, executor, base is not None
        self.say = _around_bars(progress) if opts.progress_bar else (progress or _silent)
        self.t0 = time.perf_counter()
        data, est, sel, held = _loop_parts(data, opts.split, opts.test, validation, base)
        # Default: the tolerance the selection part's length justifies (selection.py).
        self.tol = (noise_tolerance(sel.n) if opts.noise_tol is None
                    else float(opts.noise_tol))
        self.data, self.est, self.sel, self.held = data, est, sel, held
        self.hold_changed = False  # a path changes the records' hold at most once
        self.hold_tried: Any = None  # the fit the hold candidates were last tried on
        self.names = list(opts.candidates) if opts.candidates is not None else list(EFFECTS)
        if model is None:
            from hhra_phys.models.hhra import HHRAModel

            model = HHRAModel(output="pressure" if data.output_name == "pressure" else "angle")
        if base is not None and int(base.settings["data"]["n_est"]) != est.n:
            raise ParameterError(
                f"base was fitted on {base.settings['data']['n_est']} estimation samples, "
                f"the loop's estimation part has {est.n} (split={opts.split}): fit it with "
                "the same split")
        self.cfg = _Settings(est, sel, data, dict(opts.bounds or {}), opts.backend, opts.seed,
                             opts.ipopt_iter, opts.initial_state, None, opts.split,
                             opts.criterion, dict(opts.default_bounds or {}))
        self.discover = opts.discover
        self.steps: list[Step] = []
        self.chosen: list[str] = []
        self.diagnoses: list[Diagnosis] = []
        self.warnings: list[str] = []
        self.skipped: dict[str, str] = {}
        self.dropped: list[str] = []  # removed by the backward step, never proposed again
        self.levels: list[dict[str, Any]] = []
        self.settled: list[dict[str, Any]] = []  # rounds whose rest was skipped
        self.branch: dict[str, Any] | None = None  # the path not taken (LoopOptions.revisit)
        self.revisited: dict[str, Any] | None = None
        self.at_noise = False
        # The current fit and its refit on the selection part (_rotated_current).
        self._rot_cache: tuple[FitResult, FitResult] | None = None
        # The current fit and its simulated outputs on the parts (_current_outputs).
        self._out_cache: tuple[FitResult, dict[str, np.ndarray]] | None = None
        # Not path state (a revisit keeps them): whether the budget ended anything, and
        # the candidates of the round it ended.
        self.budget_spent = False
        self.budget_left: list[str] = []
        self._fit_base(model, base)

    # -- base fit and inter-sample candidates -----------------------------------------------
    def _fit_base(self, model: Model, base: FitResult | None) -> None:
        o, cfg, say = self.o, self.cfg, self.say
        if base is None:
            base_free = list(o.free) if o.free is not None else default_free(model)
            say(f"base fit: {', '.join(base_free)} (pop {o.pop_size}, {o.max_iter} iterations)")
            # The plain fit's simulator (default block): its compiled code is shared with
            # `hhra-phys fit` of the same model through the cache.
            prob = _problem(cfg, model, base_free, {}, {},
                            simulator=Simulator(model, fs=self.est.fs, backend=o.backend))
            cur = _base_fit(cfg, prob, o.pop_size, o.max_iter)
        else:
            base_free = [n for n in base.free if not n.startswith("x0_")]
            say(f"base fit given: {', '.join(base_free)}")
            prob = _problem(cfg, base.model, base_free, {}, base.values, base.x0,
                            simulator=Simulator(base.model, fs=self.est.fs, backend=o.backend))
            cur = _run(cfg, prob, "none", 0, 0, refine="none")
        # The fit's accuracy rule may have refined the substeps at the fitted values: the
        # base is scored there, so the loop's problems and candidates start from them (at
        # the problem's own coarser count a tank model's base, fitted at RK4 x 8, cost 30 %
        # more at its own values, and every candidate refit started from that worse point
        # and ended above the base).
        prob = _as_refitted(prob, cur.settings.get("integration"))
        self.cfg = replace(cfg, substeps=_substeps(prob))
        self.base_res, self.base_prob, self.base_free = cur, prob, base_free
        # The unit of the rounds' estimates (_estimate): the base fit's wall time.
        self.t_base = float(cur.settings.get("seconds", 0.0)) or 1.0
        self.unit_seconds: float | None = None
        self.cur, self.cur_prob, self.cur_free = cur, prob, list(base_free)
        say(f"  base: est RMSE {cur.metrics['est']['rmse']:.4g}, "
            f"selection RMSE {cur.metrics['val']['rmse']:.4g}")
        self.held_base = self.held  # the base is scored on the test part with its own hold
        self._hold()
        self.est_range = _output_range(self.cur_prob, _free_values(self.cur_prob, self.cur),
                                       None)

    def _hold(self) -> None:
        """The other inter-sample behaviours after the base fit, judged and chosen by the
        one rule."""
        won = self._round_holds(0)
        if not won:
            return
        noise = float(selection_noise(self.cur_prob, self.cur, self.sel)["noise"])
        best_step, cand = choose(won, noise, self.tol, self.o.criterion)
        self.say(f"  accepted {best_step.effect}")
        self._take_hold(cand)

    def _round_holds(self, rnd: int) -> list[tuple[Step, Any]]:
        """The acceptable other inter-sample behaviours of round ``rnd`` (0: after the
        base fit); none once this path changed the hold, for several records, or when the
        current fit's residual shows no sign of a wrong one. Every refit is a step."""
        if not self._holds_open():
            return []
        self.hold_tried = self.cur
        hold = _hold_candidates(self.cur, self.cur_prob, self.sel, self.o.margin, self.tol,
                                self.o.criterion, self.say, rnd)
        self.steps.extend(step for step, _ in hold)
        won = [(step, c) for step, c in hold if step.accepted]
        for step, _ in won:
            step.accepted = False  # acceptable; choose marks the one kept
        return won

    def _holds_open(self) -> bool:
        """Whether the other inter-sample behaviours are still candidates of this path: not
        once it changed the hold, not for several records, and not again on the fit they
        were last tried on (the same refits; round 1 starts from the base fit)."""
        return (self.o.intersample and not self.hold_changed
                and not isinstance(self.est, RecordSet) and self.cur is not self.hold_tried)

    def _take_hold(self, cand: Any) -> None:
        """Continue with ``cand``'s inter-sample behaviour: every record part and fit."""
        self.est, self.sel, self.held = cand.records(self.est, self.sel, self.held)
        self.data = self.data.with_intersample(cand.kind)
        self.cfg = replace(self.cfg, est=self.est, sel=self.sel, data=self.data)
        self.cur, self.cur_prob = cand.result, cand.problem
        self.hold_changed = True

    # -- rounds -----------------------------------------------------------------------------
    def run(self) -> LoopResult:
        """Rounds until one accepts nothing, ``max_effects`` are in, or the noise stop."""
        o = self.o
        self.stop = "max_effects"
        self.compiler = (ThreadPoolExecutor(1, thread_name_prefix="hhra-compile")
                         if self.executor is None and o.background and o.backend != "casadi"
                         else None)
        try:
            self._rounds(0)
            if self.branch is not None and not self.at_noise and not self._over_budget():
                self._revisit()
        finally:
            if self.compiler is not None:
                self.compiler.shutdown(wait=True, cancel_futures=True)
        return self._result()

    def _rounds(self, rnd: int) -> None:
        """Rounds after round ``rnd`` until one stops the loop (``self.stop`` says why)."""
        self.stop = "max_effects"
        # One round per accepted candidate while nothing is removed; each removal
        # takes a name out of the candidates for good, so the loop ends.
        while len(self.chosen) < self.o.max_effects:
            if self._over_budget():
                self.stop, self.budget_spent = "budget", True
                self.say(f"budget of {self.o.budget:g} s spent after "
                         f"{time.perf_counter() - self.t0:.0f} s: stop at the model so far")
                break
            rnd += 1
            stop = self._round(rnd)
            if stop:
                self.stop = stop
                break

    # What a path of rounds changes; a snapshot of these is a path's state.
    _PATH = ("steps", "chosen", "diagnoses", "warnings", "skipped", "dropped", "levels",
             "settled", "names", "cur", "cur_prob", "cur_free", "cfg", "discover", "stop",
             "at_noise", "data", "est", "sel", "held", "hold_changed", "hold_tried")

    def _snapshot(self) -> dict[str, Any]:
        return {k: _shallow(getattr(self, k)) for k in self._PATH}

    def _restore(self, state: Mapping[str, Any]) -> None:
        for k, v in state.items():
            setattr(self, k, _shallow(v))

    def _estimate(self, rnd: int, n_library: int) -> str:
        """What round ``rnd`` may cost (wall seconds), said before it runs.

        In units of the base fit's wall time (:data:`_ROUND_COST`), with the library's
        refits shared among the executor's workers; from round 2 on, scaled by the last
        round's measured cost per unit. The library's refits come first; discovery's
        (screen, term entries, modes) only when no library effect settles the round.
        """
        c = _ROUND_COST
        workers = _lookahead(self.executor) if self.executor is not None else 1
        library = c["library"] * n_library / (workers or 2)
        discovery = (c["screen"] + c["term"] * c["entries"] + c["mode"] * c["modes"]
                     if self.discover else 0.0)
        scale = self.t_base if self.unit_seconds is None else self.unit_seconds
        # The round's pace is measured on what it runs (discovery only if screened).
        self.round_units, self.round_t0 = library, time.perf_counter()
        self.round_discovery_units = discovery
        left = self.o.max_effects - len(self.chosen)
        text = (f"round {rnd}: {n_library} library candidate{'s' * (n_library != 1)}, about "
                f"{library * scale:.0f} s")
        if self.discover:
            text += (f"; then discovery, up to about {discovery * scale:.0f} s more, unless a "
                     "library effect reaches the noise level")
        text += f"; at most {left} round{'s' * (left != 1)} to go"
        if self.o.budget is not None:
            text += (f"; budget {self.o.budget:g} s, "
                     f"{time.perf_counter() - self.t0:.0f} s spent")
        return text

    def _over_budget(self) -> bool:
        """Whether the loop's wall-clock budget (:attr:`LoopOptions.budget`) is spent."""
        return self.o.budget is not None and time.perf_counter() - self.t0 > self.o.budget

    def _bar(self, rnd: int, n: int) -> Any:
        """Round ``rnd``'s progress bar over its ``n`` candidates (a silent one unless
        :attr:`LoopOptions.progress_bar`; on a terminal only)."""
        from tqdm import tqdm

        return tqdm(total=n, desc=f"round {rnd}", unit="candidate", leave=False,
                    disable=None if self.o.progress_bar else True,
                    bar_format="{desc}: {n}/{total} {bar} {elapsed}<{remaining} {postfix}")

    def _remember_branch(self, rnd: int, best: Step, tried: list[tuple[Step, Any]],
                         noise: float, judged: Mapping[int, str] | None = None) -> None:
        """Before ``best`` is accepted: keep the path of the best given effect it beat
        (``judged``: each step's reason before :func:`choose` added its verdict)."""
        if not self.o.revisit or self.branch is not None or not best.discovered:
            return
        given = [(s, p) for s, p in tried if not s.discovered]
        if not given:
            return
        k = tie_break([(float(s.val.get("rmse", math.inf)), s.criterion) for s, _ in given],
                      noise, self.tol)
        step = given[k][0]
        self.branch = {"round": rnd, "step": step, "payload": given[k][1],
                       "instead_of": best, "noise": noise, "state": self._snapshot(),
                       "judged": (judged or {}).get(id(step), step.reason)}

    def _revisit(self) -> None:
        """Follow the path of the given effect a discovered candidate won over; keep the
        better final model by the rule (:attr:`LoopOptions.revisit`)."""
        br, say = self.branch, self.say
        assert br is not None
        first = self._snapshot()
        first_sel = float(self.cur.metrics["val"]["rmse"])
        first_crit = information_criterion(self.cur, self.o.criterion)
        self._restore(br["state"])
        # The two steps of the branch round are copied: the first path keeps its own.
        alt, was = copy(br["step"]), copy(br["instead_of"])
        alt.notes, was.notes = list(alt.notes), list(was.notes)
        self.steps = [alt if s is br["step"] else was if s is br["instead_of"] else s
                      for s in self.steps]
        rnd = br["round"]
        say(f"revisit: the loop ended above the noise level after {was.effect} took round "
            f"{rnd} from {alt.effect}; following the path from {alt.effect}")
        alt.accepted, was.accepted = True, False
        # its reason said why it lost the round to `was`; what it was judged on stays
        alt.reason = f"accepted on revisiting round {rnd}: {br['judged']}"
        self._accept(rnd, alt, br["payload"])
        self._rounds(rnd)
        alt_sel = float(self.cur.metrics["val"]["rmse"])
        alt_crit = information_criterion(self.cur, self.o.criterion)
        keep_alt = tie_break([(first_sel, first_crit), (alt_sel, alt_crit)], br["noise"],
                             self.tol) == 1
        summary = (f"path from {was.effect}: selection RMSE {first_sel:.4g}, "
                   f"{self.o.criterion.upper()} {first_crit:.1f} ({', '.join(first['chosen'])})"
                   f"; path from {alt.effect}: {alt_sel:.4g}, {alt_crit:.1f} "
                   f"({', '.join(self.chosen)})")
        self.revisited = {"round": rnd, "instead_of": was.effect, "alternative": alt.effect,
                          "first": {"val_rmse": first_sel, "criterion": first_crit,
                                    "chosen": list(first["chosen"])},
                          "alternative_path": {"val_rmse": alt_sel, "criterion": alt_crit,
                                               "chosen": list(self.chosen)},
                          "kept": "alternative" if keep_alt else "first"}
        if keep_alt:
            was.reason = (f"accepted, then replaced on revisiting round {rnd} (the rule "
                          f"prefers the path from {alt.effect}: {summary}): {was.reason}")
            say(f"revisit: kept the path from {alt.effect} ({summary})")
        else:
            self._restore(first)
            br["instead_of"].notes.append(f"revisited round {rnd}, path kept: {summary}")
            say(f"revisit: kept the path from {was.effect} ({summary})")

    def _round(self, rnd: int) -> str | None:
        """One round; the reason the loop stops, or None to go on."""
        say, o = self.say, self.o
        remaining = [n for n in self.names if n not in self.chosen and n not in self.dropped]
        if not remaining and not self.discover and not self._holds_open():
            return "no candidates left"
        level, at_noise = noise_stop(self.cur_prob, self.cur, self.sel, self.tol)
        self.levels.append(level)
        self.at_noise = at_noise
        if at_noise:
            stop = _noise_stop_text(level, self.tol)
            say(f"round {rnd}: {stop}; stop")
            return stop
        if at_noise_level(level, self.tol) and at_noise_level(level["estimation"], self.tol):
            # The ratios alone would have stopped here (as before COLOURED_P): say why not.
            say(f"round {rnd}: the selection residual is at the noise level, the estimation "
                f"residual not ({_why_not_at_noise(level['estimation'], self.tol)}): "
                "the round runs")
        # The record's inter-sample behaviour is a candidate of every round, judged by
        # the same rule: a straight line's error under a smooth input shows only once
        # the model's own error is below it (docs/measuring.md).
        holds = self._round_holds(rnd)
        queue, jobs = self._queue(rnd, remaining)
        if not queue and not holds and not self.discover:
            return "no candidates left"
        say(self._estimate(rnd, len(queue)))
        tried = holds + (self._refit_all(rnd, queue, jobs, level)
                         if queue or self.discover else [])
        if not tried:
            say(f"round {rnd}: nothing accepted; stop")
            return "no candidate accepted"
        judged = {id(s): s.reason for s, _ in tried}  # choose prefixes each with its verdict
        best_step, payload = choose(tried, float(level["noise"]), self.tol, o.criterion)
        self._remember_branch(rnd, best_step, tried, float(level["noise"]), judged)
        self._accept(rnd, best_step, payload)
        return None

    def _queue(self, rnd: int, remaining: list[str]
               ) -> tuple[list[tuple[tuple[bool, int, float], str, Any]], list[_Job]]:
        """The round's library candidates (effects of the dynamics and sensor effects) in
        one ranking, and their refit jobs; discovery's come after them
        (:meth:`_discovered`)."""
        o, cur, cur_prob = self.o, self.cur, self.cur_prob
        crit_cur = information_criterion(cur, o.criterion)
        rmse_cur = float(cur.metrics["val"]["rmse"])
        queue: list[tuple[tuple[bool, int, float], str, Any]] = []
        jobs: list[_Job] = []
        if remaining:
            diag = analyse(cur_prob, _free_values(cur_prob, cur), candidates=remaining,
                           effect_kw=o.effect_kw)
            self.diagnoses.append(diag)
            for ev in diag.evidence:
                if ev.note.startswith("skipped"):
                    self.skipped[ev.name] = ev.note.removeprefix("skipped: ")
            self.names = [n for n in self.names if n not in self.skipped]
            ranked = diag.ranked()
            self.say(f"round {rnd}: ranking\n" + diag.summary())
            previous = (tuple(n for n in self.cur_free if n not in self.base_free)
                        if o.joint_search else ())
            widen_below = _widening_worth(cur, float(self.levels[-1]["estimation"]["noise"])
                                          if self.levels else math.nan)
            noise = self._noise_now()
            jobs = [_Job(self.cfg, rnd, ev.name, dict((o.effect_kw or {}).get(ev.name, {})),
                         cur_prob.model, tuple(self.cur_free), _values(cur), dict(cur.x0),
                         ev.to_json(), o.cand_pop, o.cand_iter, crit_cur, rmse_cur,
                         self.est_range, previous, widen_below, noise,
                         o.shape_mode == "contenders", o.margin)
                    for ev in (ranked if o.top_k is None else ranked[:o.top_k])]
            queue += [((not job.evidence["identifiable"], _KIND_ORDER["effect"],
                        -float(job.evidence["score"])), _kind(job.effect), job)
                      for job in jobs]
        queue.sort(key=lambda q: q[0])  # identifiable first, by score (stable: library order)
        if self.compiler is not None:
            for job in jobs:
                try:
                    m_c, new, _ = _candidate_model(job)
                except Exception:  # noqa: BLE001 - the refit reports it
                    continue
                self.compiler.submit(_warm_compile, self.cfg, m_c, 2 * _search_size(
                    len(new) + len(job.previous), o.cand_pop, o.cand_iter)[0])
        return queue, jobs

    def _discovered(self, rnd: int) -> tuple[Any, list[tuple[tuple[bool, int, float], str, Any]]]:
        """The round's discovery (screened now) and its candidates: discovered terms, then
        resonant modes, each by first-order score; ``(None, [])`` when the model cannot be
        screened (discovery then ends for the loop)."""
        o = self.o
        disc = _discovery(self.cfg, self.cur, self.cur_prob, self.cur_free, rnd, o.criterion,
                          o.discover_kw, self.say, self.skipped, self.tol)
        if disc is None:
            self.discover = False
            return None, []
        items = []
        for prop in disc.proposals():
            kind = "mode" if str(prop.entry).startswith("mode:") else "discovered"
            items.append(((False, _KIND_ORDER[kind], -prop.score), kind, prop))
        return disc, sorted(items, key=lambda q: q[0])

    def _refit_all(self, rnd: int, queue: list[tuple[tuple[bool, int, float], str, Any]],
                   jobs: list[_Job], level: Mapping[str, Any]) -> list[tuple[Step, Any]]:
        """Refit the round's candidates in order, judge each refit; the acceptable ones.

        The library's (``queue``) first, then, when discovery is on, the discovered terms
        and modes (:meth:`_discovered`, screened once the library's are judged). A
        candidate at the noise level on both parts settles the round for what
        :data:`_SETTLES` names: its own kind's later candidates, and after a library effect
        of the dynamics all of discovery (not even screened), are not refitted. Sensor
        effects go on until one of their own settles, so that a library effect and a
        sensor's explanation that each reach the noise meet in the tie rule
        (:func:`~hhra_phys.selection.choose`) instead of the first-ranked taking the round
        (a sensor's drift and a biased valve leave the same trend: ranked first, the valve
        took drift records before the drift was refitted). A discovered term or mode that
        settles the round does not spare the modes: a mode at one entry can reach the
        noise as a stand-in for the mode at another, which the information criterion
        tells apart.
        """
        o = self.o
        crit_cur = information_criterion(self.cur, o.criterion)
        rmse_cur = float(self.cur.metrics["val"]["rmse"])
        noise_sel = float(level["noise"])
        noise_est = float(level["estimation"]["noise"])
        # One stream of refits per library kind, each in queue order, so that a settled
        # kind's rest is cancelled without holding back the other kind's refits.
        library = {k: self._library_refits([item for _, kind, item in queue if kind == k])
                   for k in _LIBRARY_KINDS}
        tried: list[tuple[Step, Any]] = []
        settlers: dict[str, Step] = {}
        not_refitted: dict[str, list[str]] = {}
        queue = list(queue)
        disc, screened = None, not self.discover
        bar = self._bar(rnd, len(queue))
        k = 0
        while True:
            if k == len(queue) and not screened:
                screened = True
                disc = self._add_discovery(rnd, queue, settlers, not_refitted, bar)
            if k >= len(queue) or self._budget_ends(queue[k:]):
                break
            _, kind, item = queue[k]
            k += 1
            bar.set_postfix_str(_label(kind, item), refresh=False)
            bar.update(1)
            # Modes are not spared by a discovered candidate: a mode at one entry reaches the
            # noise as a stand-in for a mode at another (an output mode settled a load-mode
            # record's round before the load was refitted); the criterion tells them apart.
            by = next((s for s in settlers if kind in _SETTLES[s]), None)
            if by is not None and not _outscores(kind, item, settlers[by], self.say):
                not_refitted.setdefault(by, []).append(_label(kind, item))
                continue
            # Past a settler its kind's stream is behind (the spared refits were not read):
            # a library candidate refitted all the same is refitted on its own.
            got = self._refit_one(kind, item, library, disc, in_stream=by is None)
            if got is None:
                continue
            step, payload, veto = got
            ok = self._judge(step, veto, rmse_cur, crit_cur, noise_sel)
            if not veto:
                ok = self._rotate(step, payload, ok, rmse_cur, crit_cur, noise_sel, noise_est)
            if ok:
                tried.append((step, payload))
            if kind not in settlers and round_settled(step, noise_sel, noise_est, self.tol, ok):
                settlers[kind] = step
        self._end_round(rnd, bar, library, settlers, not_refitted)
        return tried

    def _end_round(self, rnd: int, bar: Any, library: Mapping[str, Any],
                   settlers: Mapping[str, Step], not_refitted: Mapping[str, list[str]]) -> None:
        """Close the round: its bar, its pace (the next estimate's unit), the library
        refits not started, and the notes of what settled it."""
        bar.close()
        if self.round_units:
            self.unit_seconds = (time.perf_counter() - self.round_t0) / self.round_units
        for stream in library.values():
            if hasattr(stream, "close"):
                stream.close()  # cancels library refits queued but not started
        self._report_settled(rnd, settlers, not_refitted)

    def _add_discovery(self, rnd: int, queue: list[Any], settlers: Mapping[str, Step],
                       not_refitted: dict[str, list[str]], bar: Any) -> Any:
        """After the library's refits: discovery's candidates appended to ``queue`` (its
        screen run now), or, when a settled candidate spares all of discovery, a note that
        it was not even screened; the round's :class:`Discovery` or None."""
        spares = [s for s in settlers if {"discovered", "mode"} <= set(_SETTLES[s])]
        if spares:
            not_refitted.setdefault(spares[0], []).append("discovery (not screened)")
            return None
        self.round_units += self.round_discovery_units
        disc, more = self._discovered(rnd)
        queue += more
        bar.total += len(more)
        return disc

    def _budget_ends(self, rest: Sequence[Any]) -> bool:
        """Whether the budget is spent before the round's ``rest``; says what is left."""
        if not self._over_budget():
            return False
        self.budget_spent = True
        self.budget_left = [_label(kind, item) for _, kind, item in rest]
        self.say(f"  budget of {self.o.budget:g} s spent: not refitted this round: "
                 f"{', '.join(self.budget_left)}")
        return True

    def _judge(self, step: Step, veto: str, rmse_cur: float, crit_cur: float,
               noise_sel: float) -> bool:
        """Judge a refitted candidate (:func:`~hhra_phys.selection.judge`, or its veto),
        say it and keep its step; whether it is acceptable."""
        o = self.o
        ok = judge(step, rmse_cur, crit_cur, noise_sel, o.margin, self.tol, o.criterion)
        if veto:
            ok, step.reason = False, f"dropped: {veto} ({step.reason})"
        self.say(f"  tried {step.effect}"
                 + (f": {step.expression}{_twins_text(step)}"
                    if isinstance(step, DiscoveredStep) else "")
                 + f"; {step.reason} [{step.seconds:.1f} s]")
        self.steps.append(step)
        return ok

    def _rotate(self, step: Step, payload: Any, ok: bool, rmse_cur: float, crit_cur: float,
                noise_sel: float, noise_est: float) -> bool:
        """The verdict on a judged candidate after the parts rotate, where they must.

        When the selection part and the criterion on estimation disagree and the part
        that says no holds the candidate's regime thinly
        (:func:`~hhra_phys.selection.needs_rotation`), the current model (IPOPT from its
        estimation fit) and then the candidate (from the current model's values there, its
        own parameters at their defaults) are refitted on the selection part and scored
        on the estimation part, and the held-out RMSE pooled over both folds decides
        (:func:`~hhra_phys.selection.rotated_verdict`); the step says so (``folds``, its
        reason). Otherwise (or with ``LoopOptions.rotate`` off) ``ok`` stands. A candidate
        without a first-order regime gets one here from what its fit changes
        (:meth:`_change_regime`: every candidate's step reports its regime). Inter-sample
        candidates do neither (they change no equation).
        """
        o = self.o
        if isinstance(payload, HoldCandidate):
            return ok
        fitted = None  # built only where needed: a library refit's model is assembled anew
        if step.regime is None:
            fitted = _fitted_candidate(payload)
            if fitted is None:
                return ok
            step.regime = self._change_regime(fitted, payload)
        if not o.rotate:
            return ok
        sel_vote, crit_vote = votes(rmse_cur, float(step.val.get("rmse", math.inf)), crit_cur,
                                    step.criterion, o.margin, noise_sel, self.tol)
        if sel_vote == crit_vote:
            return ok
        thin = thin_part(step.regime)
        if not needs_rotation(sel_vote, crit_vote, thin):
            return ok
        fitted = fitted or _fitted_candidate(payload)
        if fitted is None:
            return ok
        t0 = time.perf_counter()
        model, free, _, _, boxes = fitted
        try:
            rest_cur = self._rotated_current()
            # From the current model's fit on the selection part, the candidate's own
            # parameters at their defaults: started at its estimation fit, a parameter the
            # selection part cannot move (a saturation level where no input reaches it)
            # would carry the estimation part's answer into the fold that scores it there.
            rest = _rotated_fit(self.cfg, model, free, _values(rest_cur), boxes)
        except Exception as exc:  # noqa: BLE001 - the rotation is evidence, not the refit
            step.notes.append(f"parts not rotated: its refit on the selection part failed "
                              f"({type(exc).__name__}: {exc})")
            return ok
        if not math.isfinite(_val_rmse(rest_cur)):
            # Without the current model's other fold there is nothing to compare with:
            # every candidate would pass against an infinite error.
            step.notes.append("parts not rotated: the current model's refit on the selection "
                              "part could not be scored on estimation")
            return ok
        n_est, n_sel = (sum(ds.n for ds in as_records(p)) for p in (self.est, self.sel))
        before = pooled_rmse([(n_sel, rmse_cur), (n_est, _val_rmse(rest_cur))])
        after = pooled_rmse([(n_sel, float(step.val.get("rmse", math.inf))),
                             (n_est, _val_rmse(rest))])
        noise = pooled_rmse([(n_sel, noise_sel), (n_est, noise_est)])
        verdict, why = rotated_verdict(before, after, o.margin, noise, self.tol)
        part = {"sel": "selection", "est": "estimation"}[thin or "sel"]
        said = ("the criterion on estimation says yes, the selection part no"
                if crit_vote else "the selection part says yes, the criterion on estimation no")
        step.folds = {
            "k": 2, "why": f"{said}; the {part} part holds its regime thinly",
            "rmse_before": before, "rmse_after": after, "noise": noise, "accepted": verdict,
            "sel": {"rmse_before": rmse_cur, "rmse_after": float(step.val.get("rmse", math.nan))},
            "est": {"rmse_before": _val_rmse(rest_cur), "rmse_after": _val_rmse(rest)},
            "seconds": time.perf_counter() - t0}
        step.reason += (f"; {said}, and the {part} part holds its regime thinly: parts "
                        f"rotated (refitted on selection, scored on estimation): {why}")
        self.say(f"    parts rotated for {step.effect}: {why} -> "
                 f"{'acceptable' if verdict else 'refused'} "
                 f"[{step.folds['seconds']:.1f} s]")
        return verdict

    def _rotated_current(self) -> FitResult:
        """The current model refitted on the selection part and scored on estimation (once
        per current fit)."""
        cached = self._rot_cache
        if cached is not None and cached[0] is self.cur:
            return cached[1]
        res = _rotated_fit(self.cfg, self.cur_prob.model, self.cur_free, _values(self.cur), {})
        self._rot_cache = (self.cur, res)
        return res

    def _change_regime(self, fitted: tuple[Model, list[str], dict[str, float],
                                           dict[str, float], Any],
                       payload: Any = None) -> dict[str, Any] | None:
        """:func:`~hhra_phys.regime.change_coverage` of a fitted candidate against the
        current model on the estimation and selection parts (None if not simulated).
        A discovered candidate's own problem is used as it is (``payload.problem``); a
        library refit's (it ran elsewhere) is rebuilt from its values."""
        model, free, values, x0, _ = fitted
        try:
            if hasattr(payload, "problem") and hasattr(payload, "result"):
                prob, v = payload.problem, _free_values(payload.problem, payload.result)
            else:
                prob = _problem(self.cfg, model, free, {}, values, x0)
                v = prob.start_values()
            sel = as_records(self.sel)
            cur = self._current_outputs()
            change = {"est": np.concatenate(prob.simulate_parts(v)) - cur["est"],
                      "sel": np.concatenate(prob.simulate_parts(v, sel)) - cur["sel"]}
        except Exception:  # noqa: BLE001 - a measure only: never let it end a candidate
            return None
        return change_coverage(change)

    def _current_outputs(self) -> dict[str, np.ndarray]:
        """The current model's simulated outputs on the estimation and selection parts,
        once per current fit (every candidate of a round is compared with them)."""
        cached = self._out_cache
        if cached is not None and cached[0] is self.cur:
            return cached[1]
        vc = _free_values(self.cur_prob, self.cur)
        out = {"est": np.concatenate(self.cur_prob.simulate_parts(vc)),
               "sel": np.concatenate(self.cur_prob.simulate_parts(vc, as_records(self.sel)))}
        self._out_cache = (self.cur, out)
        return out

    def _report_settled(self, rnd: int, settlers: Mapping[str, Step],
                        not_refitted: Mapping[str, list[str]]) -> None:
        """Note on each settling step what it spared (and ``settings["settled"]``)."""
        for kind, rest in not_refitted.items():
            step = settlers[kind]
            what = {"effect": "library effect, discovered term or mode",
                    "sensor": "sensor effect"}.get(kind, "discovered candidate")
            note = (f"leaves both parts at the noise level, so no later {what} can beat it "
                    f"by more than the noise allowance: not refitted this round: "
                    f"{', '.join(rest)}")
            step.notes.append(note)
            self.settled.append({"round": rnd, "by": step.effect, "not_refitted": rest})
            self.say(f"  {step.effect} {note}")

    def _library_refits(self, jobs: list[_Job]) -> Any:
        """The refits of ``jobs`` in their order, on the loop's executor if it has one."""
        if self.executor is None:
            return map(refit_candidate, jobs)
        return iter(map_stopping(self.executor, refit_candidate, jobs,
                                 ahead=_lookahead(self.executor)))

    def _refit_one(self, kind: str, item: Any, library: Mapping[str, Any], disc: Any,
                   in_stream: bool = True) -> tuple[Step, Any, str] | None:
        """The refit of one queued candidate: (step, what to continue from, veto) or None.

        A library candidate's comes from its kind's stream of refits (queue order), or with
        ``in_stream=False`` from a refit of its own (on the loop's executor if it has one).
        """
        if kind in _LIBRARY_KINDS:
            if in_stream:
                out = next(library[kind])
            elif self.executor is not None:
                out = self.executor.submit(refit_candidate, item).result()
            else:
                out = refit_candidate(item)
            if out.step is None:
                self.skipped[item.effect] = out.error
                self.names = [n for n in self.names if n != item.effect]
                self.say(f"  skipped {item.effect}: {out.error}")
                return None
            return out.step, (item, out), ""
        got = disc.refit(item)
        if got is None:
            return None
        step, fitted, veto = got
        return step, fitted, veto

    def _accept(self, rnd: int, best_step: Step, payload: Any) -> None:
        """Add the chosen candidate, polish the model, then the backward step (another
        inter-sample behaviour: continue with its records and refit; no effect added)."""
        o, cfg = self.o, self.cfg
        if isinstance(payload, HoldCandidate):
            self._take_hold(payload)
            self.say(f"round {rnd}: accepted {best_step.effect}")
            return
        self.chosen.append(best_step.effect)
        if isinstance(payload, tuple):
            # Rebuild the accepted fit here from its values (wherever it ran), so the
            # serial and distributed loops continue from the same numbers.
            job, best = payload
            model_c, _, eff_c = _candidate_model(replace(
                job, effect_kw={**job.effect_kw, **best.effect_kw}))
            boxes = dict(best.boxes)
            # A fitted switching width keeps its box as a bound (sharper than the default
            # only, _sharpen); the other boxes it widened stay with it as guessed boxes.
            width = _width_param(eff_c) if best.effect_kw.get("fit_width") else None
            if width in boxes:
                cfg = self.cfg = replace(cfg, bounds={**cfg.bounds, width: boxes.pop(width)})
            if boxes:  # its widened boxes stay with it
                cfg = self.cfg = replace(cfg, default_bounds={**cfg.default_bounds, **boxes})
            free_c, vals_c, x0_c, integ = best.free, best.values, best.x0, best.integration
        else:
            model_c = payload.problem.model
            free_c = payload.free
            vals_c, x0_c = _values(payload.result), dict(payload.result.x0)
            integ = payload.result.settings.get("integration")
        # A candidate's IPOPT is capped (ipopt_iter) to judge it; the accepted one is
        # polished to convergence before the next round, with substeps by the accuracy
        # rule at its values as its refit had (the base fit's substeps, given, skip the
        # rule: a sharp friction refitted at ROS4 x 16 and polished at x 8 left the drive's
        # selection at 1.26e-6 m where its refit had reached the 1.0e-6 m noise).
        self._polish(model_c, free_c, vals_c, x0_c, integ)
        self.say(f"round {rnd}: accepted {best_step.effect}")
        if o.backward and len(self.chosen) >= 2 and not self._over_budget():
            self.cur, self.cur_prob, self.cur_free, back, gone = _backward_step(
                cfg, self.cur, self.cur_prob, self.cur_free, self.chosen, self.base_free, rnd,
                o.margin, self.tol, o.cand_pop, o.cand_iter, self.say)
            self.steps.extend(back)
            if gone is not None:
                self.chosen.remove(gone)
                self.dropped.append(gone)
        self._library_forms(rnd)
        if o.shape_mode == "chosen":
            # The newest effect first, then those accepted earlier whose shape stayed at
            # its default: the effect accepted now may be what let theirs show (on a 5 s
            # drive record the friction came first, beside a constant force still missing,
            # and its width fitted no better there; once the force came, the default width
            # left 6e-5 m where the noise is 1e-6 m, and stand-ins filled it). A library
            # form that replaced the newest (a discovered term) is among the earlier ones.
            newest = [best_step] if best_step.effect in self.chosen else []
            for step in [*newest, *self._earlier_shapes(best_step)]:
                if self._over_budget():
                    break
                self._sharpen_chosen(rnd, step)

    def _polish(self, model: Model, free: Sequence[str], values: Mapping[str, float],
                x0: Mapping[str, float], integration: Mapping[str, Any] | None) -> None:
        """Make ``model`` (its refit's ``values``, ``x0`` and ``integration`` record) the
        current model, polished to convergence: at least as finely as its refit ended
        (:func:`_as_refitted`), its substeps checked at its values
        (:func:`_accuracy_checked`), IPOPT up to :data:`POLISH_ITER` without the stall
        stop."""
        self.cur_prob = _accuracy_checked(_as_refitted(
            _problem(self.cfg, model, free, {}, values, x0), integration))
        self.cur = _run(self.cfg, self.cur_prob, "none", 0, 0, ipopt_iter=POLISH_ITER,
                        stall=False)
        self.cur_free = list(free)

    def _accepted_step(self, name: str) -> Step | None:
        """The step that last added ``name`` to the model (None: not added by a step)."""
        return next((s for s in reversed(self.steps) if s.effect == name and s.accepted
                     and s.action == "add"), None)

    def _library_forms(self, rnd: int) -> None:
        """Each chosen discovered term that holds the shape of a library effect the model
        lacks (``Step.same_as``: a constant at the input, ``-0.3*sgn(v)`` at a velocity's
        rate) is tried in that library form (:meth:`_try_library_form`).

        Why: a term discovered before the rest of the physics came in carries pieces that a
        later acceptance makes idle. On the drive (seeds 3 and 5) a term of round 1
        held the force offset beside a friction-like sign; once ``coulomb_friction`` came
        in round 2 the sign's coefficient went to 1e-4 of its level and the constant stayed,
        so the final model named the offset only as "the discovered form of
        ``input_offset``", with three idle coefficients. Only twins the loop may propose
        (among its candidates, not dropped) are tried, and only with the backward step on
        (``LoopOptions.backward``: it is one).
        """
        if not self.o.backward:
            return
        # Offered as given, not as this round's list: a twin is skipped as redundant while
        # its discovered form is in the model (the drive's constant force, seed 3).
        offered = (set(self.o.candidates) if self.o.candidates is not None else set(EFFECTS))
        for name in list(self.chosen):
            step = self._accepted_step(name)
            twins = [t for t in getattr(step, "same_as", ()) or ()
                     if t not in self.chosen and t in offered and t not in self.dropped]
            if twins and not self._over_budget():
                self._try_library_form(rnd, name, twins)

    def _try_library_form(self, rnd: int, name: str, twins: list[str]) -> None:
        """Replace the discovered term ``name`` by the library effects ``twins`` when the
        term would not be accepted over them now.

        The model without the term and with the twins is refitted like a candidate (a
        global search over the twins' parameters, the rest held at the current fit, then
        IPOPT over all) and compared with the current model by the backward step's rule
        (:func:`~hhra_phys.selection.backward_decision`): the discovered form stays only
        where it is still accepted against its library form. Replaced, the term's step
        gets ``action`` ``"remove"`` and each twin an accepted ``"add"`` step that says
        whose library form it is; the model is polished as an accepted one.
        """
        o, cfg, cur, cur_prob = self.o, self.cfg, self.cur, self.cur_prob
        ts = time.perf_counter()
        mine = _effect_params(cur_prob.model, name)
        model_r = cur_prob.model.without(name)
        vals = {k: v for k, v in _values(cur).items() if k not in mine}
        try:
            effs = [make_effect(t, data=cfg.data, values=vals, model=model_r,
                                **dict((o.effect_kw or {}).get(t, {}))) for t in twins]
            if any(e.applicable(model_r) is not None for e in effs):
                return
            model_t = model_r.with_parts(*effs)
            new = [p.name for e in effs for p in e.parameters]
            free_t = [n for n in self.cur_free if n not in mine] + new
            pop, iters = _search_size(len(new), o.cand_pop, o.cand_iter)
            p2, r2 = _search_candidate(cfg, model_t, new, {n: vals[n] for n in free_t
                                                           if n not in new},
                                       free_t, vals, cur.x0, pop, iters)
        except Exception as exc:  # noqa: BLE001 - a failing refit keeps the term as it is
            self.say(f"  library form of {name} ({', '.join(twins)}) failed "
                     f"({type(exc).__name__}: {exc}); kept")
            return
        crit_with = information_criterion(cur, cfg.criterion)
        rmse_with = float(cur.metrics["val"]["rmse"])
        rmse_t = float(r2.metrics["val"].get("rmse", math.inf))
        rmse_t = rmse_t if math.isfinite(rmse_t) else math.inf
        crit_t = information_criterion(r2, cfg.criterion)
        noise = float(selection_noise(p2, r2, cfg.sel)["noise"])
        swap, why = backward_decision(rmse_t, rmse_with, crit_t, crit_with, noise, o.margin,
                                      self.tol, cfg.criterion)
        forms = " and ".join(twins)
        term = Step(rnd, name, {}, {n: cur.values[n] for n in mine if n in cur.values},
                    {n: list(cur.ci95[n]) for n in mine if n in cur.ci95},
                    dict(cur.metrics["est"]), dict(cur.metrics["val"]), crit_with, crit_t,
                    rmse_t, action="keep",
                    reason=f"kept in its discovered form (against its library form {forms}: "
                           f"{why})")
        term.seconds = time.perf_counter() - ts
        self.say(f"  library form of {name}: {forms}: {why} -> "
                 f"{'replace' if swap else 'keep'} [{term.seconds:.1f} s]")
        self.steps.append(term)
        if not swap:
            return
        term.action, term.removed = "remove", True
        term.reason = (f"replaced by its library form {forms} (the discovered form would not "
                       f"be accepted over it now): {why}")
        self._polish(model_t, free_t, _values(r2), dict(r2.x0), r2.settings.get("integration"))
        at = self.chosen.index(name)
        self.chosen[at:at + 1] = twins
        self.dropped.append(name)
        for eff in effs:
            pn = [p.name for p in eff.parameters]
            self.steps.append(Step(
                rnd, eff.name, {}, {n: self.cur.values[n] for n in pn if n in self.cur.values},
                {n: list(self.cur.ci95[n]) for n in pn if n in self.cur.ci95},
                dict(self.cur.metrics["est"]), dict(self.cur.metrics["val"]),
                information_criterion(self.cur, cfg.criterion), crit_with, rmse_with,
                accepted=True, reason=f"accepted as the library form of {name}: {why}",
                entry=eff.entry_at(model_r), sensor=bool(getattr(eff, "sensor", False))))
        self.say(f"round {rnd}: replaced {name} by {forms}")

    def _earlier_shapes(self, newest: Step) -> list[Step]:
        """The accepted steps of the effects chosen before ``newest`` whose part has a
        switching width still held at its default, in the order they were accepted."""
        parts = {p.name: p for p in self.cur_prob.model.parts}
        out = []
        for name in self.chosen:
            part = parts.get(name)
            if (name == newest.effect or part is None or _width_param(part) is None
                    or getattr(part, "fit_width", True)):
                continue
            step = self._accepted_step(name)
            if step is not None:
                out.append(step)
        return out

    def _noise_now(self) -> tuple[float, float, float]:
        """Noise levels of the selection and estimation parts at the current model (the
        last round's start) and the loop's tolerance, as a :class:`_Job` carries them."""
        if not self.levels:
            return (math.nan, math.nan, float(self.tol))
        lv = self.levels[-1]
        return (float(lv["noise"]), float(lv["estimation"]["noise"]), float(self.tol))

    def _sharpen_chosen(self, rnd: int, step: Step) -> None:
        """The chosen effect's shape (``fit_shapes="chosen"``): its switching width, and its
        sign's profile, fitted in the current model where that fits clearly better
        (:func:`_sharpen`, the rules of a contender's), then the model polished.

        After the backward step, so the shape is fitted in the model the next round
        starts from: on a drive record a dead zone accepted first and removed once the
        friction came made the algebraic sign fit best beside it, the tanh without it.
        """
        cur, prob, o = self.cur, self.cur_prob, self.o
        eff = next((p for p in prob.model.parts if p.name == step.effect), None)
        width = _width_param(eff) if eff is not None else None
        if width is None or getattr(eff, "fit_width", True):
            return
        job = _Job(self.cfg, rnd, step.effect, dict((o.effect_kw or {}).get(step.effect, {})),
                   prob.model.without(step.effect), tuple(self.cur_free), _values(cur),
                   dict(cur.x0), {}, o.cand_pop, o.cand_iter, math.nan, math.nan,
                   self.est_range, noise=self._noise_now(), fit_shapes=True, margin=o.margin)
        notes: list[str] = []
        ts = time.perf_counter()
        try:
            shaped = _sharpen(self.cfg, job, eff, cur, list(self.cur_free), notes)
        except Exception as exc:  # noqa: BLE001 - the model as accepted stays
            notes.append(f"its shape could not be fitted ({type(exc).__name__}: {exc})")
            shaped = None
        when = "after acceptance" if step.round == rnd else f"in round {rnd}"
        step.notes += [f"{when}: {n}" for n in notes]
        label = f"  shape of {step.effect}{'' if step.round == rnd else ' again'}"
        if shaped is None:
            if notes:
                self.say(f"{label}: {notes[-1]} [{time.perf_counter() - ts:.1f} s]")
            return
        _, r_s, model_s, _, width, box = shaped
        self.cfg = replace(self.cfg, bounds={**self.cfg.bounds, width: box})
        free = [*self.cur_free, width]
        self._polish(model_s, free, _values(r_s), dict(r_s.x0), r_s.settings.get("integration"))
        step.params[width] = float(self.cur.values[width])
        self.say(f"{label}: {notes[-1]} [{time.perf_counter() - ts:.1f} s]")

    # -- result -----------------------------------------------------------------------------
    def _result(self) -> LoopResult:
        o, cur, cur_prob, data = self.o, self.cur, self.cur_prob, self.data
        final_level, _ = noise_stop(cur_prob, cur, self.sel, self.tol)
        final_diag = analyse(cur_prob, _free_values(cur_prob, cur), candidates=[
            n for n in self.names if n not in self.chosen]) if self.names else None
        lo, hi = self.est_range
        if any(getattr(part, "position_dependent", False) for part in cur_prob.model.parts):
            vr = _output_range(cur_prob, _free_values(cur_prob, cur), self.sel)
            if vr[0] < lo or vr[1] > hi:
                self.warnings.append(
                    f"selection output range [{vr[0]:.3g}, {vr[1]:.3g}] "
                    f"{data.output_unit or ''} (simulated) leaves the estimation range "
                    f"[{lo:.3g}, {hi:.3g}]: position-dependent effects are extrapolated there")
        if self.budget_spent:
            self.warnings.append(
                f"the loop stopped at its budget of {o.budget:g} s (after "
                f"{time.perf_counter() - self.t0:.0f} s): the model is the best so far, not "
                "the loop's end" + (f"; not refitted in the last round: "
                                    f"{', '.join(self.budget_left)}" if self.budget_left
                                    else ""))
        test_scores = {"base": _test_score(self.base_prob, self.base_res, self.held_base),
                       "final": _test_score(cur_prob, cur, self.held)}
        settings = {
            "split": o.split, "test": o.test, "candidates": self.names,
            "max_effects": o.max_effects, "top_k": o.top_k, "pop_size": o.pop_size,
            "max_iter": o.max_iter, "cand_pop": o.cand_pop, "cand_iter": o.cand_iter,
            "seed": o.seed, "margin": o.margin, "noise_tol": self.tol,
            "criterion": o.criterion, "backend": o.backend, "discover": o.discover,
            "joint_search": o.joint_search, "backward": o.backward,
            "intersample": o.intersample, "removed": list(self.dropped),
            "settled": self.settled, "revisit": o.revisit, "revisited": self.revisited,
            "rotate": o.rotate,
            "executor": type(self.executor).__name__ if self.executor is not None else None,
            "base_given": self.base_given, "stop": self.stop, "budget": o.budget,
            "stopped_by_budget": self.budget_spent,
            "not_refitted_by_budget": list(self.budget_left), "fit_shapes": o.shape_mode,
            "noise_levels": self.levels + [final_level],
            "seconds": time.perf_counter() - self.t0,
            "data": {"name": data.name, "n": data.n, "fs": data.fs, "n_est": self.est.n,
                     "n_sel": self.sel.n, "n_test": self.held.n if self.held is not None else 0},
        }
        return LoopResult(self.base_res, cur, self.steps, self.chosen, self.diagnoses,
                          final_diag, settings, self.warnings, self.skipped, test_scores)


def _outscores(kind: str, item: Any, settler: Step, say: Callable[[str], None]) -> bool:
    """Whether a library candidate is refitted though ``settler`` settled its round: its
    first-order score is above the settler's.

    A settled round's later candidates could at best tie with the settler, and a tie goes
    by the information criterion (:func:`~hhra_phys.selection.round_settled`): one that
    explains more of the residual to first order is a contender for that tie, whatever its
    rank (a friction ranked last as not identifiable, score 0.41, was spared by a backlash
    of score 0.31 that settled the round, and the backlash stood in for it: one_loop
    deadzone_friction seed 3).
    """
    if kind not in _LIBRARY_KINDS:
        return False
    mine = float(item.evidence.get("score", 0.0))
    theirs = float(settler.evidence.get("score", math.inf))
    if not mine > theirs:
        return False
    say(f"  {item.effect}: refitted though {settler.effect} settled the round: its "
        f"first-order score {mine:.3f} is above {settler.effect}'s {theirs:.3f}")
    return True


def _val_rmse(res: FitResult) -> float:
    """A fit's held-out RMSE (``inf`` where not finite)."""
    v = float(res.metrics["val"].get("rmse", math.inf))
    return v if math.isfinite(v) else math.inf


def _fitted_candidate(payload: Any) -> tuple[Model, list[str], dict[str, float],
                                             dict[str, float], dict[str, Any]] | None:
    """A judged candidate's model, free parameters, fitted values, fitted initial state
    and widened boxes (None for an inter-sample candidate, which changes no equation)."""
    if isinstance(payload, tuple):  # a library refit: (job, outcome)
        job, out = payload
        model, _, _ = _candidate_model(replace(job, effect_kw={**job.effect_kw,
                                                               **out.effect_kw}))
        return model, list(out.free), dict(out.values), dict(out.x0), dict(out.boxes)
    if isinstance(payload, HoldCandidate) or not hasattr(payload, "problem"):
        return None
    res = payload.result
    return payload.problem.model, list(payload.free), _values(res), dict(res.x0), {}


def _rotated_fit(cfg: _Settings, model: Model, free: Sequence[str],
                 start: Mapping[str, float], boxes: Mapping[str, tuple[float, float]]
                 ) -> FitResult:
    """``model`` refitted on the selection part(s) from ``start`` (the parameters it
    lacks at their defaults; IPOPT, capped as a candidate's refit) and scored on the
    estimation part(s): the other fold of the two. The initial state starts by the
    ``"data"`` rule on the selection part (the fitted one is the estimation part's)."""
    rot = replace(cfg, est=cfg.sel, sel=cfg.est,
                  default_bounds={**cfg.default_bounds, **boxes})
    return _run(rot, _problem(rot, model, free, {}, start, None), "none", 0, 0)


def _label(kind: str, item: Any) -> str:
    """A queued candidate's name in the loop's notes: the effect, or the discovery entry."""
    return item.effect if kind in _LIBRARY_KINDS else f"discovery at {item.entry}"


def _silent(text: str) -> None:
    """The loop's progress callback when none is given."""


def _around_bars(progress: Callable[[str], None] | None) -> Callable[[str], None]:
    """``progress`` writing its lines around the round's progress bar (not through it)."""
    from tqdm import tqdm

    user = progress or _silent

    def say(text: str) -> None:
        with tqdm.external_write_mode():
            user(text)
    return say


def _hold_candidates(cur: FitResult, prob: Problem, sel: Dataset, margin: float, tol: float,
                     criterion: str, say: Callable[[str], None], rnd: int = 0,
                     ) -> list[tuple[Step, Any]]:
    """The other inter-sample behaviours as candidates (:mod:`hhra_phys.intersample`) of
    round ``rnd``, each judged by :func:`acceptance`; none when the fit ``cur`` shows no
    sign of them. Each step is marked ``sensor``: it describes the measurement (what the
    input did between samples), not the dynamics, and :func:`choose` keeps it when tied."""
    sig = hold_signature(prob.data.y, prob.simulate_values(_free_values(prob, cur)))
    if not hold_suspected(sig):
        return []
    crit_cur = information_criterion(cur, criterion)
    rmse_cur = float(cur.metrics["val"]["rmse"])
    noise = float(selection_noise(prob, cur, sel)["noise"])
    out = []
    for kind in other_holds(prob.data.intersample):
        t0 = time.perf_counter()
        cand = refit_with_hold(cur, prob, sel, kind=kind, signature=sig)
        res = cand.result
        step = Step(rnd, cand.name, {"signature": cand.signature, "changes_physics": False},
                    dict(res.values), {k: list(v) for k, v in res.ci95.items()},
                    dict(res.metrics["est"]), dict(res.metrics["val"]),
                    information_criterion(res, criterion), crit_cur, rmse_cur,
                    seconds=time.perf_counter() - t0, sensor=True)
        # Passing the rule marks it acceptable; augment keeps the one choose picks.
        step.accepted = judge(step, rmse_cur, crit_cur, noise, margin, tol, criterion)
        step.reason = f"{cand.evidence}; {step.reason}"
        say(f"  tried {cand.name}: {step.reason} [{step.seconds:.1f} s]")
        out.append((step, cand))
    return out


def _loop_parts(data: Dataset | Sequence[Dataset], split: float, test: float,
                validation: Dataset | Sequence[Dataset] | None, base: FitResult | None,
                ) -> tuple[Any, Any, Any, Any]:
    """The records and their estimation, selection and test parts.

    One record (a list of one alike) without validation records: the record and
    :func:`split_record`'s parts; otherwise a :class:`~hhra_phys.multi.RecordSet` of the
    records and :func:`~hhra_phys.multi.split_records`'s.
    """
    records = as_records(data)
    whole = as_records(validation) if validation is not None and len(validation) else []
    if len(records) == 1 and not whole:
        return (records[0], *split_record(records[0], split, test))
    if base is not None:
        raise ParameterError("base: a given base fit is for one record; with several records "
                             "(or validation records) the loop fits its own base")
    return (RecordSet(records), *split_records(records, split, test, whole or None))


def _substeps(problem: Problem) -> tuple[tuple[float, int], ...]:
    """The base fit's substeps per sample rate, which candidates keep."""
    return tuple((float(fs), int(sim.substeps)) for fs, sim in problem.simulators.items())


def _noise_stop_text(level: Mapping[str, Any], noise_tol: float) -> str:
    """The stop reason of :func:`noise_stop` in words (which rule held on each part)."""
    e = level["estimation"]
    text = (f"selection residual at the noise level (RMSE {level['rmse']:.4g} = "
            f"{level['ratio']:.3f} x noise {level['noise']:.3g}, "
            f"{_why_at_noise(level, noise_tol)}), estimation residual too (RMSE "
            f"{e['rmse']:.4g} = {e['ratio']:.3f} x noise, {_why_at_noise(e, noise_tol)})")
    return text


def _discovery(cfg: _Settings, cur: FitResult, cur_prob: Any, cur_free: Sequence[str],
               rnd: int, criterion: str, discover_kw: Mapping[str, Any] | None,
               say: Callable[[str], None], skipped: dict[str, str],
               noise_tol: float = NOISE_TOL) -> Discovery | None:
    """This round's discovery candidates (screened), or None when the model cannot be
    screened (said and recorded in ``skipped["discovery"]``; a bad option is an error)."""
    try:
        return Discovery(_DiscoveryFits(cfg), cur, cur_prob, list(cur_free), round_no=rnd,
                         criterion=criterion, progress=say, noise_tol=noise_tol,
                         **dict(discover_kw or {}))
    except ParameterError as exc:
        if "cannot be simulated" not in str(exc):
            raise
        why = str(exc)
    except Exception as exc:  # noqa: BLE001 - a screening failure ends discovery, not the loop
        why = f"{type(exc).__name__}: {exc}"
    skipped["discovery"] = f"screening failed in round {rnd}: {why}"
    say(f"discovery skipped: {skipped['discovery']}")
    return None


def base_model_for(data: Dataset) -> tuple[Model, dict[str, tuple[float, float]]]:
    """The default base model for a record, and bounds that make sense for it.

    The fitting module's choice (:func:`hhra_phys.fit.default_model`): the HHRA
    with an angle or pressure output, rescaled to sample units with wide boxes for
    records without a sample time (such as the public actuator record).
    """
    from hhra_phys.fit import default_model

    return default_model(data)
