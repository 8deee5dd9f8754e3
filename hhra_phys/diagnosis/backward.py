"""The backward step: after an acceptance, each earlier addition stays only if the loop
would accept it now (:func:`~hhra_phys.diagnosis.selection.backward_decision`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

from hhra_phys.diagnosis.candidates import _search_size
from hhra_phys.diagnosis.fits import _effect_params, _problem, _run, _Settings, _values
from hhra_phys.diagnosis.options import POLISH_ITER
from hhra_phys.diagnosis.selection import Step, backward_decision, information_criterion
from hhra_phys.diagnosis.stopping import selection_noise
from hhra_phys.problem import Problem
from hhra_phys.result import FitResult

__all__ = []


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
