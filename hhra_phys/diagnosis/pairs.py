"""The loop's pairs: two effects that each show only beside the other.

A round accepts an effect when its refit lowers the selection part's free-run error and
the information criterion on estimation. Two missing effects that need each other defeat
that: on a drive with Coulomb friction and a constant force offset, each alone lowers the
criterion by thousands of units and *raises* the selection error (the simulated position
drifts where the other is missing), so no round accepts anything, whatever the record's
length (docs/diagnosis.md). When a round accepts nothing, the effects on which the evidence
contradicts itself that way (:func:`~hhra_phys.diagnosis.selection.contradicts`) are
refitted two at a time: the second is added to the first one's refit and both are searched
(the first seeded at its own refit), and each pair is one candidate, judged, rotated and
chosen by the same rule as any other (``steps[].pair``). An accepted pair adds both effects;
the backward step may later remove either.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from itertools import combinations
from typing import Any

from hhra_phys.diagnosis.candidates import _candidate_model, _Job, _width_param
from hhra_phys.diagnosis.selection import PAIR_CANDIDATES, Step, information_criterion

__all__: list[str] = []


def _pair_job(first: tuple[_Job, Any], second: tuple[_Job, Any]) -> _Job:
    """The refit job of ``second``'s effect added to ``first``'s refit: the first effect in
    the model at its fitted values (with its fitted shape), its parameters searched again
    with the second's, its widened boxes kept (a fitted width as a bound)."""
    job_a, out_a = first
    job_b, _ = second
    model_a, new_a, eff_a = _candidate_model(
        replace(job_a, effect_kw={**job_a.effect_kw, **out_a.effect_kw}))
    boxes = dict(out_a.boxes)
    width = _width_param(eff_a) if out_a.effect_kw.get("fit_width") else None
    bounds = {width: boxes.pop(width)} if width in boxes else {}
    cfg = replace(job_b.cfg, bounds={**job_b.cfg.bounds, **bounds},
                  default_bounds={**job_b.cfg.default_bounds, **boxes})
    previous = tuple(new_a) + ((width,) if width and width not in new_a else ())
    return replace(job_b, cfg=cfg, model=model_a, free=tuple(out_a.free),
                   values=dict(out_a.values), x0=dict(out_a.x0), previous=previous,
                   pair_with=job_a.effect)


def pair_jobs(split: Sequence[tuple[Step, Any]]) -> list[_Job]:
    """The pairs of the round's contradicted candidates (``(step, (job, outcome))``): the
    :data:`~hhra_phys.diagnosis.selection.PAIR_CANDIDATES` with the lowest criterion, each
    pair once, the one with the lower criterion first (its refit is the start), pairs in
    order of their two criteria's sum (the most promising first)."""
    best = sorted(split, key=lambda sp: sp[0].criterion)[:PAIR_CANDIDATES]
    pairs = sorted(combinations(best, 2), key=lambda ab: ab[0][0].criterion + ab[1][0].criterion)
    return [_pair_job(a[1], b[1]) for a, b in pairs]


class _PairStage:
    """The pairs of :class:`~hhra_phys.diagnosis.engine._Loop` (a mixin of its state: the
    round's contradicted candidates in ``self.split``, its options, judge and rotation)."""

    def _pairs(self, rnd: int, level: Mapping[str, Any]) -> list[tuple[Step, Any]]:
        """The acceptable pairs of round ``rnd``'s contradicted candidates (none unless at
        least two; every pair's refit is a step)."""
        split = list(getattr(self, "split", []))
        if not self.o.pairs or len(split) < 2 or self._over_budget():
            return []
        jobs = pair_jobs(split)
        names = sorted({name for job in jobs for name in (job.pair_with, job.effect)})
        self.say(f"round {rnd}: nothing accepted; {len(jobs)} pairs of {', '.join(names)} "
                 "(the criterion for each, the selection error up: each may need another)")
        crit_cur = information_criterion(self.cur, self.o.criterion)
        rmse_cur = float(self.cur.metrics["val"]["rmse"])
        noise_sel = float(level["noise"])
        noise_est = float(level["estimation"]["noise"])
        won: list[tuple[Step, Any]] = []
        for job, out in zip(jobs, self._library_refits(jobs), strict=True):
            if out.step is None:
                self.say(f"  pair {job.pair_with} + {job.effect}: {out.error}")
                continue
            step, payload = out.step, (job, out)
            ok = self._judge(step, "", rmse_cur, crit_cur, noise_sel)
            ok = self._rotate(step, payload, ok, rmse_cur, crit_cur, noise_sel, noise_est)
            if ok:
                won.append((step, payload))
            if self._over_budget():
                break
        return won
