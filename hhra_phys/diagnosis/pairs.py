"""The loop's pairs: two effects that each show only beside the other.

A round accepts an effect when its refit lowers the selection part's free-run error and
the information criterion on estimation. Two missing effects that need each other defeat
that: on a drive with Coulomb friction and a constant force offset, each alone lowers the
criterion by thousands of units and *raises* the selection error (the simulated position
drifts where the other is missing), so no round accepts anything, whatever the record's
length (docs/diagnosis.md). When a round accepts nothing, the effects on which the evidence
contradicts itself that way (:func:`~hhra_phys.diagnosis.selection.contradicts`) are
paired with every other refused effect of the dynamics (:func:`pair_jobs`): the second is
added to the first one's refit and both are searched (the first seeded at its own refit),
and each pair is one candidate, judged, rotated and chosen by the same rule as any other
(``steps[].pair``). An accepted pair adds both effects; the backward step may later remove
either.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

from hhra_phys.diagnosis.candidates import _candidate_model, _Job, _width_param
from hhra_phys.diagnosis.selection import (
    PAIR_CANDIDATES,
    Step,
    contradicts,
    information_criterion,
    round_settled,
)

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


def pair_jobs(refused: Sequence[tuple[Step, Any]], rmse_cur: float, crit_cur: float
              ) -> list[_Job]:
    """The pairs of a round that accepted nothing, from its refused effects of the dynamics
    (``(step, (job, outcome))``).

    Each of the :data:`~hhra_phys.diagnosis.selection.PAIR_CANDIDATES` contradicted ones
    (:func:`~hhra_phys.diagnosis.selection.contradicts`) with the lowest criterion is paired
    with every other refused effect: the partner need not show anything alone (on a 50 s
    drive record the Coulomb friction's own refit stayed at the base's criterion, with a
    first-order score of 0, and only the pair with the constant force reached the noise).
    The contradicted one's refit is the start (the second added to it); each pair once;
    pairs of two contradicted effects first, then by the partner's criterion.
    """
    firsts = sorted((sp for sp in refused if contradicts(sp[0], rmse_cur, crit_cur)),
                    key=lambda sp: sp[0].criterion)[:PAIR_CANDIDATES]
    seen: set[frozenset[str]] = set()
    pairs = []
    for first in firsts:
        for second in refused:
            key = frozenset((first[0].effect, second[0].effect))
            if len(key) < 2 or key in seen:
                continue
            seen.add(key)
            both = contradicts(second[0], rmse_cur, crit_cur)
            pairs.append(((not both, second[0].criterion), first, second))
    pairs.sort(key=lambda item: item[0])
    return [_pair_job(first[1], second[1]) for _, first, second in pairs]


class _PairStage:
    """The pairs of :class:`~hhra_phys.diagnosis.engine._Loop` (a mixin of its state: the
    round's contradicted candidates in ``self.split``, its options, judge and rotation)."""

    def _pairs(self, rnd: int, level: Mapping[str, Any]) -> list[tuple[Step, Any]]:
        """The acceptable pairs of round ``rnd`` (:func:`pair_jobs`; none without a
        contradicted effect, or once a pair leaves both parts at the noise level); every
        pair's refit is a step."""
        crit_cur = information_criterion(self.cur, self.o.criterion)
        rmse_cur = float(self.cur.metrics["val"]["rmse"])
        jobs = pair_jobs(list(self.refused), rmse_cur, crit_cur)
        if not self.o.pairs or not jobs or self._over_budget():
            return []
        firsts = ", ".join(dict.fromkeys(job.pair_with for job in jobs))
        self.say(f"round {rnd}: nothing accepted; {len(jobs)} pairs with {firsts} (the "
                 "criterion for it, the selection error up: it may need another effect)")
        noise_sel = float(level["noise"])
        noise_est = float(level["estimation"]["noise"])
        won: list[tuple[Step, Any]] = []
        refits = self._library_refits(jobs)
        for job, out in zip(jobs, refits, strict=False):
            if out.step is None:
                self.say(f"  pair {job.pair_with} + {job.effect}: {out.error}")
                continue
            step, payload = out.step, (job, out)
            ok = self._judge(step, "", rmse_cur, crit_cur, noise_sel)
            ok = self._rotate(step, payload, ok, rmse_cur, crit_cur, noise_sel, noise_est)
            if ok:
                won.append((step, payload))
            # A pair at the noise level on both parts: no later pair can beat it by more
            # than the allowance (the round's rule, selection.round_settled).
            if round_settled(step, noise_sel, noise_est, self.tol, ok) or self._over_budget():
                break
        if hasattr(refits, "close"):  # the pairs not started are not refitted
            refits.close()
        return won
