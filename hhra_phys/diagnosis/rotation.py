"""The loop's rotated parts: where the selection part and the criterion disagree and the
part that refuses holds the candidate's regime thinly (or only a few samples of it), the
candidate and the current model are refitted on each other fold (the selection part, or the
rest of the record around each estimation block: :mod:`hhra_phys.diagnosis.folds`) and
scored on what it held out, and the error pooled over all folds is the one verdict.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from hhra_phys.diagnosis.candidates import _candidate_model
from hhra_phys.diagnosis.discovery import DiscoveredStep
from hhra_phys.diagnosis.fits import (
    _free_values,
    _judged_options,
    _problem,
    _Settings,
    _values,
)
from hhra_phys.diagnosis.folds import Fold, LaterStartProblem, fold_plan
from hhra_phys.diagnosis.result import _twins_text
from hhra_phys.diagnosis.selection import (
    REGIME_MIN_SAMPLES,
    Step,
    judge,
    needs_rotation,
    pooled_rmse,
    regime_samples,
    rotated_verdict,
    thin_parts,
    votes,
)
from hhra_phys.fit import fit_problem
from hhra_phys.intersample import (
    HoldCandidate,
)
from hhra_phys.model import Model
from hhra_phys.parameters import record_name
from hhra_phys.problem import Problem, as_records
from hhra_phys.regime import change_coverage
from hhra_phys.result import FitResult

__all__ = []


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


def _fold_fit(cfg: _Settings, fold: Fold, model: Model, free: Sequence[str],
              start: Mapping[str, float], boxes: Mapping[str, tuple[float, float]]
              ) -> FitResult:
    """``model`` refitted on a fold's pieces from ``start`` (the parameters it lacks at
    their defaults; IPOPT, capped as a candidate's refit) and scored on its held-out
    block(s) (:mod:`hhra_phys.diagnosis.folds`). A piece that starts in the middle of its
    record has every state's initial value fitted, started at the state the model
    reaches there at ``start`` through the samples before it (as a scored part starts)."""
    rot = replace(cfg, est=fold.train, sel=[ds for ds in fold.held if ds is not None],
                  default_bounds={**cfg.default_bounds, **boxes})
    problem = _problem(rot, model, free, {}, start, None, kind=LaterStartProblem)
    later = _later_starts(problem)
    if later:
        problem = _problem(rot, model, free, {}, {**start, **later}, None,
                           kind=LaterStartProblem)
    return fit_problem(problem, fold.held, options=_judged_options(rot, "none", 0, 0))


def _later_starts(problem: Problem) -> dict[str, float]:
    """``{x0_<state>_rec<k>: value}``: for each record of ``problem`` that starts in the
    middle of its own record, the state at its first sample through the samples before it
    (:meth:`~hhra_phys.problem.RecordProblem.initial_states` with its leading window), at
    the problem's start values."""
    out: dict[str, float] = {}
    for k, (pr, vk) in enumerate(problem.per_record_values(problem.start_values()), start=1):
        if not pr.x0_states or pr.lead_window(pr.data) is None:
            continue
        x = pr.initial_states(vk, data=pr.data)[0]
        for state in pr.x0_states:
            value = float(x[pr.model.state_names.index(state)])
            if math.isfinite(value):
                out[record_name(f"x0_{state}", k)] = value
    return out


def _thin_text(part: str, regime: Mapping[str, Any] | None) -> str:
    """Why ``part`` (``"est"`` or ``"sel"``) cannot refuse alone, in words."""
    name = {"sel": "selection", "est": "estimation"}[part]
    n = regime_samples(regime, part) if regime and part in regime else math.inf
    if n < REGIME_MIN_SAMPLES:
        return f"the {name} part holds only {round(n)} samples of its regime"
    return f"the {name} part holds its regime thinly"


class _RotationStage:
    """The rotated parts of :class:`~hhra_phys.diagnosis.engine._Loop` (a mixin of its state)."""

    def _judge(self, step: Step, veto: str, rmse_cur: float, crit_cur: float,
               noise_sel: float) -> bool:
        """Judge a refitted candidate (:func:`~hhra_phys.diagnosis.selection.judge`, or its veto),
        say it and keep its step; whether it is acceptable."""
        o = self.o
        ok = judge(step, rmse_cur, crit_cur, noise_sel, o.margin, self.tol, o.criterion)
        if veto:
            ok, step.reason = False, f"dropped: {veto} ({step.reason})"
        self.say(f"  tried {' + '.join(step.pair) if step.pair else step.effect}"
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
        (:func:`~hhra_phys.diagnosis.selection.needs_rotation`), the current model (IPOPT from its
        estimation fit) and then the candidate (from the current model's values there, its
        own parameters at their defaults) are refitted on the selection part and scored
        on the estimation part, and the held-out RMSE pooled over both folds decides
        (:func:`~hhra_phys.diagnosis.selection.rotated_verdict`); the step says so (``folds``, its
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
        thin = thin_parts(step.regime)
        if not needs_rotation(sel_vote, crit_vote, thin):
            return ok
        fitted = fitted or _fitted_candidate(payload)
        if fitted is None:
            return ok
        t0 = time.perf_counter()
        model, free, _, _, boxes = fitted
        try:
            folds = self._fold_plan()
            rest_cur = self._rotated_current()
            # From the current model's fit on each fold, the candidate's own parameters at
            # their defaults: started at its estimation fit, a parameter the fold cannot
            # move (a saturation level where no input reaches it) would carry the
            # estimation part's answer into the block that scores it.
            rest = [_fold_fit(self.cfg, f, model, free, _values(c), boxes)
                    for f, c in zip(folds, rest_cur, strict=True)]
        except Exception as exc:  # noqa: BLE001 - the rotation is evidence, not the refit
            step.notes.append(f"parts not rotated: its refit on a fold failed "
                              f"({type(exc).__name__}: {exc})")
            return ok
        if not all(math.isfinite(_val_rmse(c)) for c in rest_cur):
            # Without the current model's other folds there is nothing to compare with:
            # every candidate would pass against an infinite error.
            step.notes.append("parts not rotated: the current model's refit on a fold could "
                              "not be scored on the block it held out")
            return ok
        n_sel = sum(ds.n for ds in as_records(self.sel))
        cand_sel = float(step.val.get("rmse", math.inf))
        blocks = [{"held": "sel", "samples": n_sel, "rmse_before": rmse_cur,
                   "rmse_after": cand_sel}]
        blocks += [{"held": f.name, "samples": f.n_held, "rmse_before": _val_rmse(c),
                    "rmse_after": _val_rmse(r)}
                   for f, c, r in zip(folds, rest_cur, rest, strict=True)]
        before = pooled_rmse([(b["samples"], b["rmse_before"]) for b in blocks])
        after = pooled_rmse([(b["samples"], b["rmse_after"]) for b in blocks])
        noise = pooled_rmse([(n_sel, noise_sel)] + [(f.n_held, noise_est) for f in folds])
        verdict, why = rotated_verdict(before, after, o.margin, noise, self.tol, len(blocks))
        refusing = "sel" if crit_vote else "est"
        said = ("the criterion on estimation says yes, the selection part no"
                if crit_vote else "the selection part says yes, the criterion on estimation no")
        held_by = _thin_text(refusing, step.regime)
        how = ("refitted on selection, scored on estimation" if len(blocks) == 2 else
               f"{len(blocks)} contiguous folds, each block held out in turn")
        step.folds = {
            "k": len(blocks), "why": f"{said}; {held_by}",
            "rmse_before": before, "rmse_after": after, "noise": noise, "accepted": verdict,
            "sel": {"rmse_before": rmse_cur, "rmse_after": float(step.val.get("rmse", math.nan))},
            "est": {key: (blocks[1][key] if len(blocks) == 2 else
                          pooled_rmse([(b["samples"], b[key]) for b in blocks[1:]]))
                    for key in ("rmse_before", "rmse_after")},
            "blocks": blocks, "seconds": time.perf_counter() - t0}
        step.reason += f"; {said}, and {held_by}: parts rotated ({how}): {why}"
        self.say(f"    parts rotated for {step.effect}: {why} -> "
                 f"{'acceptable' if verdict else 'refused'} "
                 f"[{step.folds['seconds']:.1f} s]")
        return verdict

    def _fold_plan(self) -> list[Fold]:
        """The folds beyond the loop's own (:func:`~hhra_phys.diagnosis.folds.fold_plan`),
        once per estimation and selection parts (an inter-sample change replaces them)."""
        cached = self._fold_cache
        if cached is not None and cached[0][0] is self.est and cached[0][1] is self.sel:
            return cached[1]
        plan = fold_plan(as_records(self.est), as_records(self.sel), self.o.folds)
        self._fold_cache = ((self.est, self.sel), plan)
        return plan

    def _rotated_current(self) -> list[FitResult]:
        """The current model refitted on each fold and scored on its held-out block (once
        per current fit)."""
        cached = self._rot_cache
        if cached is not None and cached[0] is self.cur:
            return cached[1]
        res = [_fold_fit(self.cfg, f, self.cur_prob.model, self.cur_free, _values(self.cur), {})
               for f in self._fold_plan()]
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
