"""One candidate's refit: a picklable job (:class:`_Job`), its global search over the new
parameters, box widening, IPOPT over all free ones, the shape of a smooth-edged effect, and
the inter-sample and discovered candidates' refits.

Everything here runs in a worker process or here alike (:func:`refit_candidate`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import SimpleNamespace
from typing import Any

from hhra_phys.diagnosis.discovery import Discovery
from hhra_phys.diagnosis.fits import (
    _DiscoveryFits,
    _edge_boxes,
    _free_values,
    _output_range,
    _problem,
    _run,
    _Settings,
    _stiff_substeps,
    _unidentified,
    _values,
)
from hhra_phys.diagnosis.selection import (
    NOISE_TOL,
    Step,
    acceptance,
    information_criterion,
    round_settled,
)
from hhra_phys.effects import (
    SIGN_PROFILES,
    make_effect,
)
from hhra_phys.errors import ParameterError
from hhra_phys.fit import (
    MAX_WIDEN_DECADES,
    WIDEN_CLEAR_GAIN,
    WIDEN_MIN_GAIN,
)
from hhra_phys.model import Model
from hhra_phys.problem import Problem, as_records
from hhra_phys.regime import regime_coverage
from hhra_phys.result import FitResult

__all__ = ["refit_candidate"]


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
    #: new ones (``diagnose(joint_search=True)``); empty (default): held at the previous fit.
    previous: tuple[str, ...] = ()
    #: Estimation MSE below which the candidate's boxes are widened (:func:`_widening_worth`;
    #: ``inf``: always, where the current model's error is not known).
    widen_below: float = math.inf
    #: Noise levels of the selection and estimation parts at the current model and the
    #: loop's noise tolerance (:func:`~hhra_phys.diagnosis.selection.round_settled`; NaN: unknown).
    noise: tuple[float, float, float] = (math.nan, math.nan, NOISE_TOL)
    #: Search a sharper switching width for the effect (``LoopOptions.fit_shapes``).
    fit_shapes: bool = False
    #: The loop's acceptance margin (``LoopOptions.margin``): a sharper shape passes the
    #: rule a candidate passes (:func:`_sharpen`).
    margin: float = 0.1
    #: A pair's first effect (already in ``model``, its parameters in ``previous``, searched
    #: again with this one's, ``LoopOptions.pairs``); empty for a candidate of one effect.
    pair_with: str = ""


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
    the result are plain picklable data, so :func:`diagnose` may send it to any
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
    # A pair's step holds both effects' parameters (the first's were searched again).
    shown = new + (list(job.previous) if job.pair_with else [])
    step = Step(job.round, job.effect, job.evidence, {n: r2.values[n] for n in shown},
                {n: list(r2.ci95[n]) for n in shown if n in r2.ci95},
                dict(r2.metrics["est"]), dict(r2.metrics["val"]), crit, job.crit_cur,
                job.rmse_cur)
    # Where it enters on this model: a role-bound entry ("rate:@velocity") by its state's name.
    entry_at = getattr(eff, "entry_at", None)
    step.entry = str((entry_at(job.model) if entry_at else getattr(eff, "entry", "")) or "")
    step.sensor = bool(getattr(eff, "sensor", False))
    step.pair = [job.pair_with, job.effect] if job.pair_with else []
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
    (:func:`~hhra_phys.diagnosis.selection.acceptance`: the selection error falls by the margin or
    to the noise, beyond the noise allowance, and the criterion falls; a width the data
    do not resolve costs a parameter and stays at the default). Why the whole rule: on the
    one-loop study's dead zone beside an exact friction (seed 2) a sharper width taken
    for a 1 % gain on selection left the friction absorbing the dead zone, whose refit
    then ended above the current model. Only a contender is sharpened, one whose
    refit took at least :data:`~hhra_phys.fit.WIDEN_CLEAR_GAIN` of the current model's
    estimation error above the noise (as for widening, :func:`_widening_worth`), and not
    one already at the noise level on both parts (:func:`~hhra_phys.diagnosis.selection.
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
