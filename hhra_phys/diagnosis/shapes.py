"""The loop's stage after an acceptance: the polish of the accepted model, the shape of
smooth-edged library effects (Coulomb width, dead-zone edges), and a discovered term tried
in the form of the library effect it duplicates (physics before stand-ins).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

from hhra_phys.diagnosis.candidates import (
    _Job,
    _search_candidate,
    _search_size,
    _sharpen,
    _width_param,
)
from hhra_phys.diagnosis.fits import (
    _accuracy_checked,
    _as_refitted,
    _effect_params,
    _problem,
    _run,
    _values,
)
from hhra_phys.diagnosis.options import POLISH_ITER
from hhra_phys.diagnosis.selection import Step, backward_decision, information_criterion
from hhra_phys.diagnosis.stopping import selection_noise
from hhra_phys.effects import (
    EFFECTS,
    make_effect,
)
from hhra_phys.model import Model

__all__ = []


class _ShapeStage:
    """Polish, shapes and library forms of :class:`~hhra_phys.diagnosis.engine._Loop` (a mixin of
    its state)."""

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
        """The step that last added ``name`` to the model, alone or in a pair (None: not
        added by a step)."""
        return next((s for s in reversed(self.steps) if (s.effect == name or name in s.pair)
                     and s.accepted and s.action == "add"), None)

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
        (:func:`~hhra_phys.diagnosis.selection.backward_decision`): the discovered form stays only
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

    def _earlier_shapes(self, newest: Step) -> list[tuple[Step, str]]:
        """``(accepted step, effect)`` of the effects chosen before ``newest`` (both of a
        pair's are newest) whose part has a switching width still held at its default, in
        the order they were accepted."""
        parts = {p.name: p for p in self.cur_prob.model.parts}
        out = []
        for name in self.chosen:
            part = parts.get(name)
            if (name in (newest.pair or [newest.effect]) or part is None
                    or _width_param(part) is None or getattr(part, "fit_width", True)):
                continue
            step = self._accepted_step(name)
            if step is not None:
                out.append((step, name))
        return out

    def _noise_now(self) -> tuple[float, float, float]:
        """Noise levels of the selection and estimation parts at the current model (the
        last round's start) and the loop's tolerance, as a :class:`_Job` carries them."""
        if not self.levels:
            return (math.nan, math.nan, float(self.tol))
        lv = self.levels[-1]
        return (float(lv["noise"]), float(lv["estimation"]["noise"]), float(self.tol))

    def _sharpen_chosen(self, rnd: int, step: Step, name: str | None = None) -> None:
        """The chosen effect's shape (``fit_shapes="chosen"``): its switching width, and its
        sign's profile, fitted in the current model where that fits clearly better
        (:func:`_sharpen`, the rules of a contender's), then the model polished.

        After the backward step, so the shape is fitted in the model the next round
        starts from: on a drive record a dead zone accepted first and removed once the
        friction came made the algebraic sign fit best beside it, the tanh without it.
        """
        name = name or step.effect  # a pair's step holds two effects (pairs.py)
        cur, prob, o = self.cur, self.cur_prob, self.o
        eff = next((p for p in prob.model.parts if p.name == name), None)
        width = _width_param(eff) if eff is not None else None
        if width is None or getattr(eff, "fit_width", True):
            return
        job = _Job(self.cfg, rnd, name, dict((o.effect_kw or {}).get(name, {})),
                   prob.model.without(name), tuple(self.cur_free), _values(cur),
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
        label = f"  shape of {name}{'' if step.round == rnd else ' again'}"
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
