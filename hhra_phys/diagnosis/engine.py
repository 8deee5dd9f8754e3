"""The closed loop's engine: fit, diagnose, add an effect, refit, keep it only if it pays.

The record is split in time order into three parts (default 50/25/25 %):
**estimation** (every fit), **selection** (chooses among candidates) and **test**
(chooses nothing; reports the base and final models' error). :func:`diagnose` runs::

    fit the base model on estimation (as a plain fit: H-GWO 100 x 200 + IPOPT), or reuse one
    repeat:
        stop if the selection residual and the estimation residual are both at the
            noise level (RMSE <= (1 + noise_tol) * noise level, or white by Ljung-Box)
        rank, in one list by first-order score, the library effects not yet in the
            model (hhra_phys.diagnosis.residual.analyse) and the discovered terms and modes
            (hhra_phys.diagnosis.discovery.Discovery)
        refit them in that order (library effects anywhere, an Executor, or here:
            global search over the new parameters with the previous fit held, then
            IPOPT over all free parameters; discovered ones by IPOPT through the
            simulator), score each on selection, judge it by the one rule
            (hhra_phys.diagnosis.selection.acceptance), and skip the rest of a kind (library or
            discovered) once one of its candidates leaves both parts at the noise level
            (round_settled)
        add the winner among the acceptable ones (hhra_phys.diagnosis.selection.choose: lowest
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

The engine (:class:`_Loop`) holds one run's state; its stages live beside it, one
module each: inter-sample holds (:mod:`.holds`), rotated parts (:mod:`.rotation`), the
shape of accepted effects and library forms (:mod:`.shapes`), the path not taken
(:mod:`.revisit`); the refits themselves are :mod:`.candidates`, :mod:`.fits` and
:mod:`.backward`.

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
from dataclasses import replace
from typing import Any

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.diagnosis.backward import _backward_step
from hhra_phys.diagnosis.candidates import (
    _candidate_model,
    _discovery,
    _Job,
    _search_size,
    _widening_worth,
    _width_param,
    refit_candidate,
)
from hhra_phys.diagnosis.discovery_jobs import cancel_refits, submit_refits, take_refit
from hhra_phys.diagnosis.fits import (
    _as_refitted,
    _base_fit,
    _free_values,
    _output_range,
    _problem,
    _run,
    _Settings,
    _substeps,
    _test_score,
    _values,
    _warm_compile,
)
from hhra_phys.diagnosis.folds import fold_plan
from hhra_phys.diagnosis.holds import _HoldStage
from hhra_phys.diagnosis.options import LoopOptions
from hhra_phys.diagnosis.pairs import _PairStage
from hhra_phys.diagnosis.residual import Diagnosis, analyse
from hhra_phys.diagnosis.result import DiagnosisResult
from hhra_phys.diagnosis.revisit import _RevisitStage
from hhra_phys.diagnosis.rotation import _RotationStage
from hhra_phys.diagnosis.selection import (
    Step,
    at_noise_level,
    choose,
    information_criterion,
    noise_tolerance,
    round_settled,
    split_record,
)
from hhra_phys.diagnosis.shapes import _ShapeStage
from hhra_phys.diagnosis.stopping import _noise_stop_text, _why_not_at_noise, noise_stop
from hhra_phys.effects import (
    EFFECTS,
)
from hhra_phys.errors import ParameterError
from hhra_phys.interrupt import map_stopping
from hhra_phys.intersample import (
    HoldCandidate,
)
from hhra_phys.model import Model
from hhra_phys.multi import RecordSet, split_records
from hhra_phys.problem import as_records, default_free
from hhra_phys.result import FitResult
from hhra_phys.simulate import Simulator

__all__ = ["diagnose", "augment", "base_model_for"]

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
#: (:func:`~hhra_phys.diagnosis.selection.round_settled`): its own kind, and after a library
#: effect of the dynamics all of discovery, terms and modes (on the selection part they could
#: at best tie with it, within the noise allowance: the named physics is kept before a stand-in,
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


def diagnose(
    data: Dataset | Sequence[Dataset],
    model: Model | None = None,
    *,
    options: LoopOptions | None = None,
    validation: Dataset | Sequence[Dataset] | None = None,
    base: FitResult | None = None,
    executor: Executor | None = None,
    progress: Callable[[str], None] | None = None,
    **settings: Any,
) -> DiagnosisResult:
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
        ``base``/``final`` in :meth:`DiagnosisResult.to_json`) and the evidence is
        summed over them (:func:`~hhra_phys.diagnosis.residual.analyse`).
    model : Model, optional
        Base model (default: the registered default model of :mod:`hhra_phys.defaults`
        for the first record, as :func:`base_model_for` gives it: the HHRA, with a
        pressure output if the record's output is pressure, rescaled to sample units for a
        record without a sample time).
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
    DiagnosisResult

    Notes
    -----
    A candidate is accepted when, on the selection part, its RMSE falls by at
    least ``margin`` (or to the noise level), the information criterion on estimation
    falls, and the
    selection variance it removes exceeds the noise allowance; of the acceptable
    candidates of a round (every kind) the one :func:`~hhra_phys.diagnosis.selection.choose` picks
    is added (:mod:`hhra_phys.diagnosis.selection`). The loop stops when a round accepts
    nothing, ``max_effects`` are in, or the estimation and selection residuals are
    both at the noise level (``rmse <= (1 + noise_tol) * noise`` or white by
    Ljung-Box, each with its own noise level).
    """
    opts = LoopOptions.of(options, **settings)
    res = _Loop(data, model, opts, validation, base, executor, progress).run()
    res.data = data  # for DiagnosisResult.report's figures
    return res


#: The loop's first name (``hhra_phys.diagnosis.engine.augment``): the same function.
augment = diagnose


class _Loop(_HoldStage, _RotationStage, _ShapeStage, _RevisitStage, _PairStage):
    """One run of :func:`diagnose`: its state, and one method per stage of the data path
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
        # The parts' folds, made before any fit: folds the estimation part is too short for
        # fail here (_RotationStage._fold_plan keeps them for the parts they were made of).
        self._fold_cache: tuple[tuple[Any, Any], list[Any]] | None = (
            ((est, sel), fold_plan(as_records(est), as_records(sel), opts.folds))
            if opts.rotate else None)
        self.hold_changed = False  # a path changes the records' hold at most once
        self.hold_tried: Any = None  # the fit the hold candidates were last tried on
        self.names = list(opts.candidates) if opts.candidates is not None else list(EFFECTS)
        if model is None:  # the registered default (the HHRA), as a fit without a model
            model = base_model_for(data if isinstance(data, Dataset) else data[0])[0]
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
        if opts.candidates is None:  # unasked: what each effect offers on this model
            self.skipped.update({n: why for n in self.names
                                 if (why := EFFECTS[n].unasked(model))})
            self.names = [n for n in self.names if n not in self.skipped]
        self.dropped: list[str] = []  # removed by the backward step, never proposed again
        self.levels: list[dict[str, Any]] = []
        self.settled: list[dict[str, Any]] = []  # rounds whose rest was skipped
        self.branch: dict[str, Any] | None = None  # the path not taken (LoopOptions.revisit)
        self.revisited: dict[str, Any] | None = None
        self.revisit_skipped: str | None = None  # why the path not taken was not followed
        # The round's refused library effects of the dynamics (pairs.py pairs them).
        self.refused: list[tuple[Step, Any]] = []
        # The round's discovery refits running on the executor (discovery_jobs.py).
        self.disc_refits: dict[int, Any] = {}
        self.at_noise = False
        # The current fit and its refits on the folds (_rotated_current).
        self._rot_cache: tuple[FitResult, list[FitResult]] | None = None
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

    # -- rounds -----------------------------------------------------------------------------
    def run(self) -> DiagnosisResult:
        """Rounds until one accepts nothing, ``max_effects`` are in, or the noise stop."""
        o = self.o
        self.stop = "max_effects"
        self.compiler = (ThreadPoolExecutor(1, thread_name_prefix="hhra-compile")
                         if self.executor is None and o.background and o.backend != "casadi"
                         else None)
        try:
            self._rounds(0)
            if (self.branch is not None and not self.at_noise and not self._over_budget()
                    and self._branch_stands()):
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

    def _estimate(self, rnd: int, n_library: int) -> str:
        """What round ``rnd`` may cost (wall seconds), said before it runs.

        In units of the base fit's wall time (:data:`_ROUND_COST`), with the library's
        refits and discovery's entries shared among the executor's workers (the screen runs
        here); from round 2 on, scaled by the last round's measured cost per unit. The
        library's refits come first; discovery's (screen, term entries, modes) only when no
        library effect settles the round.
        """
        c = _ROUND_COST
        workers = _lookahead(self.executor) if self.executor is not None else 1
        library = c["library"] * n_library / (workers or 2)
        discovery = (c["screen"] + (c["term"] * c["entries"] + c["mode"] * c["modes"])
                     / (workers or 2) if self.discover else 0.0)
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
        self.refused = []  # this round's (pairs.py): none left over from an earlier round
        queue, jobs = self._queue(rnd, remaining)
        if not queue and not holds and not self.discover:
            return "no candidates left"
        say(self._estimate(rnd, len(queue)))
        tried = holds + (self._refit_all(rnd, queue, jobs, level)
                         if queue or self.discover else [])
        if not tried:  # two effects that each show only beside the other (pairs.py)
            tried = self._pairs(rnd, level)
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
        (:func:`~hhra_phys.diagnosis.selection.choose`) instead of the first-ranked taking the round
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
            elif kind == "effect" and not step.sensor and math.isfinite(step.criterion):
                self.refused.append((step, payload))
            if kind not in settlers and round_settled(step, noise_sel, noise_est, self.tol, ok):
                settlers[kind] = step
        self._end_round(rnd, bar, library, settlers, not_refitted)
        return tried

    def _end_round(self, rnd: int, bar: Any, library: Mapping[str, Any],
                   settlers: Mapping[str, Step], not_refitted: Mapping[str, list[str]]) -> None:
        """Close the round: its bar, its pace (the next estimate's unit), the library
        refits not started, and the notes of what settled it."""
        bar.close()
        cancel_refits(self.disc_refits)  # a settled round's refits not taken
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
        if self.executor is not None and disc is not None and more:
            # Every entry's refit at once on the workers, taken below in queue order.
            self.disc_refits = submit_refits(self.executor, disc, [it for _, _, it in more])
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
        got = (take_refit(self.disc_refits, disc, item, self.say)
               if id(item) in self.disc_refits else disc.refit(item))
        if got is None:
            return None
        step, fitted, veto = got
        return step, fitted, veto

    def _accept(self, rnd: int, best_step: Step, payload: Any) -> None:
        """Add the chosen candidate, polish the model, then the backward step (another
        inter-sample behaviour: continue with its records and refit; no effect added)."""
        o = self.o
        if isinstance(payload, HoldCandidate):
            self._take_hold(payload)
            self.say(f"round {rnd}: accepted {best_step.effect}")
            return
        if best_step.pair:  # a pair (pairs.py): its first effect, then the second
            self.chosen.append(best_step.pair[0])
        self.chosen.append(best_step.effect)
        model_c, free_c, vals_c, x0_c, integ = self._accepted_fit(best_step, payload)
        cfg = self.cfg
        # A candidate's IPOPT is capped (ipopt_iter) to judge it; the accepted one is
        # polished to convergence before the next round, with substeps by the accuracy
        # rule at its values as its refit had (the base fit's substeps, given, skip the
        # rule: a sharp friction refitted at ROS4 x 16 and polished at x 8 left the drive's
        # selection at 1.26e-6 m where its refit had reached the 1.0e-6 m noise).
        self._polish(model_c, free_c, vals_c, x0_c, integ)
        self.say(f"round {rnd}: accepted {' + '.join(best_step.pair) or best_step.effect}")
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
            newest = [(best_step, name) for name in best_step.pair or [best_step.effect]
                      if name in self.chosen]
            for step, name in [*newest, *self._earlier_shapes(best_step)]:
                if self._over_budget():
                    break
                self._sharpen_chosen(rnd, step, name)

    def _accepted_fit(self, step: Step, payload: Any) -> tuple[Model, Sequence[str],
                                                                Mapping[str, float],
                                                                Mapping[str, float], Any]:
        """The accepted candidate's model, free parameters, values, initial state and
        integration; a library refit's boxes join the loop's settings."""
        if not isinstance(payload, tuple):
            res = payload.result
            return (payload.problem.model, payload.free, _values(res), dict(res.x0),
                    res.settings.get("integration"))
        # Rebuild the accepted fit here from its values (wherever it ran), so the serial
        # and distributed loops continue from the same numbers.
        job, best = payload
        cfg = self.cfg
        if step.pair:  # the first effect's fitted width bound and widened boxes
            cfg = replace(cfg, bounds={**job.cfg.bounds, **cfg.bounds},
                          default_bounds={**job.cfg.default_bounds, **cfg.default_bounds})
        model_c, _, eff_c = _candidate_model(replace(
            job, effect_kw={**job.effect_kw, **best.effect_kw}))
        boxes = dict(best.boxes)
        # A fitted switching width keeps its box as a bound (sharper than the default
        # only, _sharpen); the other boxes it widened stay with it as guessed boxes.
        width = _width_param(eff_c) if best.effect_kw.get("fit_width") else None
        if width in boxes:
            cfg = replace(cfg, bounds={**cfg.bounds, width: boxes.pop(width)})
        if boxes:  # its widened boxes stay with it
            cfg = replace(cfg, default_bounds={**cfg.default_bounds, **boxes})
        self.cfg = cfg
        return model_c, best.free, best.values, best.x0, best.integration

    # -- result -----------------------------------------------------------------------------
    def _result(self) -> DiagnosisResult:
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
            "revisit_skipped": self.revisit_skipped,
            "rotate": o.rotate, "folds": o.folds, "pairs": o.pairs,
            "executor": type(self.executor).__name__ if self.executor is not None else None,
            "base_given": self.base_given, "stop": self.stop, "budget": o.budget,
            "stopped_by_budget": self.budget_spent,
            "not_refitted_by_budget": list(self.budget_left), "fit_shapes": o.shape_mode,
            "noise_levels": self.levels + [final_level],
            "seconds": time.perf_counter() - self.t0,
            "data": {"name": data.name, "n": data.n, "fs": data.fs, "n_est": self.est.n,
                     "n_sel": self.sel.n, "n_test": self.held.n if self.held is not None else 0},
        }
        return DiagnosisResult(self.base_res, cur, self.steps, self.chosen, self.diagnoses,
                          final_diag, settings, self.warnings, self.skipped, test_scores)


def _outscores(kind: str, item: Any, settler: Step, say: Callable[[str], None]) -> bool:
    """Whether a library candidate is refitted though ``settler`` settled its round: its
    first-order score is above the settler's.

    A settled round's later candidates could at best tie with the settler, and a tie goes
    by the information criterion (:func:`~hhra_phys.diagnosis.selection.round_settled`): one that
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


def base_model_for(data: Dataset) -> tuple[Model, dict[str, tuple[float, float]]]:
    """The default base model for a record, and bounds that make sense for it.

    The fitting module's choice (:func:`hhra_phys.fit.default_model`, the registered
    default of :mod:`hhra_phys.defaults`): the HHRA with an angle or pressure output,
    rescaled to sample units with wide boxes for records without a sample time (such as
    the public actuator record).
    """
    from hhra_phys.fit import default_model

    return default_model(data)
