"""The loop's inter-sample stage: other holds of the input between samples, judged by the
one rule after the base fit and in every round until the path changes the hold once.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from hhra_phys.data import Dataset
from hhra_phys.diagnosis.fits import _free_values
from hhra_phys.diagnosis.selection import Step, choose, information_criterion, judge
from hhra_phys.diagnosis.stopping import selection_noise
from hhra_phys.intersample import (
    hold_signature,
    hold_suspected,
    other_holds,
    refit_with_hold,
)
from hhra_phys.multi import RecordSet
from hhra_phys.problem import Problem
from hhra_phys.result import FitResult

__all__ = []


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


class _HoldStage:
    """The inter-sample stage of :class:`~hhra_phys.diagnosis.engine._Loop` (a mixin: it reads
    and sets the loop's records, fits and steps)."""

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
