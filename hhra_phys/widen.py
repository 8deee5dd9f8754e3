"""Box widening: a group that ends at the edge of its default box is let out, and refitted.

The rule of every fit path (:func:`fit_and_widen`, :func:`widen_boxes`; docs/fitting.md,
"Widening"): which parameters are at an edge (:func:`at_edges`), how far a side moves
(:func:`widened_box`), when letting a group out pays (a Gauss-Newton prediction,
:func:`_release_gains`, against the residual's excess over its noise), the refits of each
round, and the notes a result gets about them. Separate from :mod:`hhra_phys.fit` because
it is a rule of its own with its own thresholds (:data:`WIDEN_MIN_GAIN`,
:data:`WIDEN_MAX_EXCESS`, :data:`WIDEN_CLEAR_GAIN`), tested without fits
(``tests/unit/test_widen_rule.py``); every name here is also importable from
:mod:`hhra_phys.fit`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hhra_phys.parameters import split_record_name
from hhra_phys.problem import MAX_WIDEN_DECADES
from hhra_phys.refine import CompiledLeastSquares, Stage
from hhra_phys.result import FitResult

__all__ = [
    "at_edges",
    "widened_box",
    "fit_and_widen",
    "widen_boxes",
]


def fit_and_widen(
    problem: Any,
    search: Callable[..., tuple[np.ndarray, list[Stage], list[float]]],
    widen: bool = True,
) -> tuple[Any, np.ndarray, list[Stage], list[float], list[dict[str, Any]]]:
    """Search and refine ``problem``, then widen default boxes a group ends at and refit.

    The one place every fit (one record, a given problem, several records) runs its
    search and the box widening of :func:`widen_boxes`.

    Parameters
    ----------
    problem : Problem
    search : callable
        ``search(problem, z_start=None, label="") -> (z, stages, history)``
        (:func:`_search_and_refine` with the fit's settings).
    widen : bool
        Widen default boxes (``False``: one search, as given).

    Returns
    -------
    problem, z, stages, history, widened
        The (possibly widened) problem, the optimum in its coordinates, the stages and
        best-cost history of all searches, and the widened box sides (the problem's own
        widenings for start values first).
    """
    z, stages, history = search(problem)
    widened: list[dict[str, Any]] = list(getattr(problem, "widened", []))
    if widen:
        problem, z, more = widen_boxes(problem, z, search, stages, history)
        widened += more
    return problem, z, stages, history, widened


def _report_widening(result: FitResult, widened: list[dict[str, Any]], problem: Any) -> None:
    """Put the widened sides and the fixed-value notes into the result."""
    if widened:
        result.settings["widened"] = widened
        result.warnings.extend(_widening_notes(widened))
    result.warnings.extend(getattr(problem, "notes", []))


def _widening_notes(widened: list[dict[str, Any]]) -> list[str]:
    """One sentence per widened box side, from the rounds of :func:`widen_boxes`."""
    sides: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for w in widened:
        sides.setdefault((w["name"], w["side"], w.get("reason", "fit")), []).append(w)
    notes = []
    for (name, side, _), rounds in sides.items():
        first, last = rounds[0], rounds[-1]
        n = sum(int(w.get("decades", 1)) for w in rounds)
        if first.get("reason") == "start":
            notes.append(f"{name}'s start value lies beyond the {side} edge of its default box "
                         f"[{first['from'][0]:.4g}, {first['from'][1]:.4g}]; that side was "
                         f"widened by {n} decade{'s' if n > 1 else ''} to [{last['to'][0]:.4g}, "
                         f"{last['to'][1]:.4g}]")
            continue
        text = (f"{name} ended at the {side} edge of its default box [{first['from'][0]:.4g}, "
                f"{first['from'][1]:.4g}]; that side was widened by {n} decade"
                f"{'s' if n > 1 else ''} to [{last['to'][0]:.4g}, {last['to'][1]:.4g}] and the "
                "fit repeated")
        if last.get("searched", True) is False and last.get("gain", 1.0) >= WIDEN_MIN_GAIN:
            text += (f" locally (the refit gained {100 * last['gain']:.2g} %, less than "
                     "predicted: not worth a search of the wider box)")
        elif last.get("gain", 1.0) < WIDEN_MIN_GAIN:
            text += (f", which lowered the sum of squares by only {100 * last['gain']:.2g} %: "
                     f"the data do not determine {name} beyond the old edge (it is negligible "
                     "or unobservable there), so widening stopped")
        notes.append(text)
    return notes


#: Distance to a box edge (fraction of the box in fitting coordinates) that counts as "at it".
EDGE_TOL = 1e-4
#: Relative fall of the least-squares cost below which a widened box did not help: the
#: group sits at its edge because the data do not see it there (a leakage of zero), not
#: because the truth lies beyond, and further decades would only cost refits.
WIDEN_MIN_GAIN = 1e-3
#: Largest share of the sum of squares above the residual's noise level at which boxes
#: are widened (0.5: RMSE up to sqrt(2) times the noise). A model that lacks an effect
#: leaves a residual far above the noise and pushes groups to their edges to make up for
#: it; a wider box there buys a few per cent and distorts the groups the effect should
#: explain (the diagnosis loop then chose the wrong effect). Measured (docs/fitting.md):
#: 0.04-0.13 for the heavily damped rig whose group lies beyond its box, 0.86-0.93 for base
#: fits lacking a sharp friction, 0.53-0.99 for the loop's candidate fits there.
WIDEN_MAX_EXCESS = 0.5
#: Predicted relative fall of the sum of squares (Gauss-Newton, :func:`_release_gains`) from
#: letting one group out of its box above which the box is widened whatever the residual's
#: excess over the noise: a group its box holds that far from the optimum is held by the
#: guess, not pushed there by missing physics (a base fit lacking a sharp friction gained
#: 1-2 % from its widened groups, docs/fitting.md). The loop's candidates need it: a found
#: effect whose coefficient stops at a guessed bound (a gravity load at a third of its true
#: size) leaves a residual far above the noise, and without the widening a stand-in follows.
WIDEN_CLEAR_GAIN = 0.1


def at_edges(problem: Any, z: np.ndarray, tol: float = EDGE_TOL) -> list[tuple[int, str]]:
    """Free parameters (index, ``"lower"``/``"upper"``) whose coordinate ends at its box edge.

    Parameters
    ----------
    problem : Problem
    z : ndarray, shape (n_free,)
        Fitting coordinates.
    tol : float
        Distance to an edge, as a fraction of the box width, that counts as at it.
    """
    bz = problem.bounds_z()
    span = bz[:, 1] - bz[:, 0]
    out = []
    for i in range(problem.n_free):
        lo, hi = z[i] - bz[i, 0], bz[i, 1] - z[i]
        if min(lo, hi) <= tol * span[i]:
            out.append((i, "lower" if lo <= hi else "upper"))
    return out


def widened_box(par: Any, side: str) -> tuple[float, float] | None:
    """``par``'s box with one side widened once, or None when that side cannot move.

    A log-scaled (positive) parameter's side moves a decade; a signed (linear) one's
    moves ten times as far from zero; a side at zero, or on the other side of it, is a
    sign (physics), not a guessed size, and stays (None).
    """
    lo, hi = float(par.lower), float(par.upper)
    if par.scale == "log":
        return (lo / 10, hi) if side == "lower" else (lo, hi * 10)
    if side == "lower" and lo < 0:
        return 10 * lo, hi
    if side == "upper" and hi > 0:
        return lo, 10 * hi
    return None


def _cost(problem: Any, z: np.ndarray) -> float:
    """Least-squares cost ``0.5 sum r^2`` at ``z`` (``inf`` where the simulation fails)."""
    r = problem.simulate_values(problem.from_z(np.asarray(z, dtype=float))) - problem.y
    total = float(r @ r)
    return 0.5 * total if np.isfinite(total) else np.inf


def _cost_and_excess(problem: Any, z: np.ndarray) -> tuple[float, float]:
    """Least-squares cost ``0.5 sum r^2`` at ``z`` and the share of ``sum r^2`` above the noise.

    The noise is the residual's own (:func:`hhra_phys.noise.noise_level`: the part not
    coherent with the input and the simulated output); one simulation.
    """
    from hhra_phys.noise import noise_level

    yhat = problem.simulate_values(problem.from_z(np.asarray(z, dtype=float)))
    r = yhat - problem.y
    total = float(r @ r)
    if not np.isfinite(total):
        return np.inf, 1.0
    if total <= 0:
        return 0.0, 0.0
    u = getattr(getattr(problem, "data", None), "u", None)
    inputs = (u, yhat) if u is not None and np.shape(u) == r.shape else None
    return 0.5 * total, max(0.0, 1.0 - r.size * noise_level(r, inputs) ** 2 / total)


def _release_gains(problem: Any, z: np.ndarray, edges: list[tuple[int, str]]) -> list[float]:
    """Predicted relative fall of the sum of squares from letting each edge group out.

    One Gauss-Newton model of the least-squares cost at ``z`` (the exact residual
    Jacobian, as for the intervals): for each edge coordinate, the step over all free
    coordinates with that one released and the other edge ones held, against the step
    with all of them held. A group at an edge because the data do not see it there (a
    negligible effect's coefficient) gains nothing, nor does one the step would move
    back inside; widening its box would only cost a refit. Moving one coordinate alone
    is no test: a group correlated with others (damping with leakage) only pays off when
    they follow it.
    """
    r, J = CompiledLeastSquares(problem)(z)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
        return [0.0] * len(edges)
    total = float(r @ r)
    held = {i for i, _ in edges}

    def rest(cols: list[int]) -> tuple[float, np.ndarray]:
        dz, *_ = np.linalg.lstsq(J[:, cols], -r, rcond=1e-10)
        e = r + J[:, cols] @ dz
        return float(e @ e), dz

    base, _ = rest([j for j in range(problem.n_free) if j not in held])
    gains = []
    for i, side in edges:
        cols = [j for j in range(problem.n_free) if j not in held or j == i]
        ssr, dz = rest(cols)
        outward = dz[cols.index(i)] * (1.0 if side == "upper" else -1.0) > 0
        gains.append((base - ssr) / total if outward and total > 0 else 0.0)
    return gains


def widen_boxes(
    problem: Any,
    z: np.ndarray,
    search: Callable[..., tuple[np.ndarray, list[Stage], list[float]]],
    stages: list[Stage],
    history: list[float],
) -> tuple[Any, np.ndarray, list[dict[str, Any]]]:
    """Widen default boxes whose edge a free parameter ends at, and refit.

    The rule of every fit path (:func:`fit_and_widen`; the loop's base, candidate and
    backward refits are such fits): only default boxes (the model's, an effect's or
    ``default_bounds``, :attr:`Problem.default_boxes
    <hhra_phys.problem.Problem.default_boxes>`) of model parameters are widened, never the
    user's explicit bounds or initial states; a log-scaled (positive) parameter by one
    decade on that side per round, a signed (linear) one by moving that side ten times as
    far from zero (a side at zero is a sign and stays), at most :data:`MAX_WIDEN_DECADES`
    beyond the default box. A side is widened where moving the parameter out of its box
    lowers the sum of squares by at least :data:`WIDEN_MIN_GAIN` (predicted by a
    Gauss-Newton step, :func:`_release_gains`) while the residual is mostly noise (at most
    :data:`WIDEN_MAX_EXCESS` of the sum of squares above its noise level), and by at least
    :data:`WIDEN_CLEAR_GAIN` otherwise (with the model lacking something the edge is
    usually a symptom of it; a release that pays that much is the box's doing). Each
    round refines from the previous optimum first and searches the widened box globally
    only when that refit bears the prediction out (:func:`_widened_search`); rounds stop
    once a refit lowers the least-squares cost by less than :data:`WIDEN_MIN_GAIN`
    (relative), or a round's prediction was not borne out. A global refit starts with the
    previous optimum in its population, so it cannot end worse.

    Parameters
    ----------
    problem : Problem
    z : ndarray, shape (n_free,)
        The optimum of the first search, in fitting coordinates.
    search : callable
        As for :func:`fit_and_widen`.
    stages, history : list
        Extended in place with the refits' stages and histories.

    Returns
    -------
    problem, z, widened
        The widened problem (``problem`` itself if nothing was widened), its optimum and
        one dict per widened side and round: ``name``, ``side``, ``round``, ``from``,
        ``to`` (the box in physical units), ``gain`` (the refit's relative fall of the
        least-squares cost) and ``searched: False`` where only the refiners ran (the
        predicted gain was not borne out).
    """

    origin = getattr(problem, "default_boxes", {})
    widened: list[dict[str, Any]] = []
    edges = at_edges(problem, z)
    if not edges:
        return problem, z, widened  # the common case: no simulation, no Jacobian
    cost, excess = _cost_and_excess(problem, z)
    for round_ in range(1, MAX_WIDEN_DECADES + 1):
        if not np.isfinite(cost) or not edges:
            break  # a diverged fit is not at an edge for a reason a wider box would fix
        if excess is None:
            excess = _cost_and_excess(problem, z)[1]
        need = WIDEN_MIN_GAIN if excess <= WIDEN_MAX_EXCESS else WIDEN_CLEAR_GAIN
        box, changes = _sides_to_widen(problem, edges, _release_gains(problem, z, edges),
                                       origin, need, round_)
        if not changes:
            break
        values = problem.from_z(z)
        problem = problem.with_boxes({n: tuple(b) for n, b in box.items()})
        z, new_cost, confirmed = _widened_search(problem, problem.to_z(values), search,
                                                 f" (widened {round_})", cost, need,
                                                 stages, history)
        excess = None  # the next round's (a noise-level estimate: only if there is one)
        gain = (cost - new_cost) / cost if cost > 0 else 0.0
        for c in changes:
            c["gain"] = float(gain)
            if not confirmed:
                c["searched"] = False
        widened.extend(changes)
        cost = new_cost
        edges = at_edges(problem, z)
        if gain < WIDEN_MIN_GAIN or not confirmed:
            break
    return problem, z, widened


def _widened_search(problem: Any, z0: np.ndarray,
                    search: Callable[..., tuple[np.ndarray, list[Stage], list[float]]],
                    label: str, cost: float, need: float, stages: list[Stage],
                    history: list[float]) -> tuple[np.ndarray, float, bool]:
    """One widening round's refit of the widened ``problem`` from ``z0``: ``(z, cost, searched)``.

    The refiners alone first (``search(..., global_search=False)``), from the previous
    optimum: they reach whatever the release of the edge groups gains near it. The global
    search runs again only when that local gain is at least ``need``, the gain the
    Gauss-Newton prediction had to promise for the side to be widened: a prediction the
    local refit does not bear out (a model lacking an effect, whose residual is far from
    the Gauss-Newton model's linear reach) is not worth a search of the whole box
    (measured: a base fit lacking a dead zone, predicted >= 10 %, refitted 0.02 %, at
    the cost of a full H-GWO search). With no refiner the search runs as before. The
    better of the two optima is kept, so a confirmed round ends no worse than the
    search alone.
    """
    z_loc, more, _ = search(problem, z_start=z0, label=label, global_search=False)
    stages.extend(more)
    loc_cost = _cost(problem, z_loc) if more else np.inf
    if more and not (cost > 0 and (cost - loc_cost) / cost >= need):
        return z_loc, loc_cost, False
    z, more, hist = search(problem, z_start=z0, label=label)
    stages.extend(more)
    history.extend(hist)
    new_cost = _cost(problem, z)
    if loc_cost < new_cost:
        return z_loc, loc_cost, True
    return z, new_cost, True


def _sides_to_widen(problem: Any, edges: list[tuple[int, str]], gains: list[float],
                    origin: Mapping[str, tuple[float, float]], need: float, round_: int,
                    ) -> tuple[dict[str, list[float]], list[dict[str, Any]]]:
    """The boxes of one round of :func:`widen_boxes` and one record per widened side.

    A side is widened when its parameter's box is a default one (``origin``), the side
    is not a sign (at or across zero), it is less than :data:`MAX_WIDEN_DECADES` beyond
    the default box, and letting the parameter out pays at least ``need`` (the
    predicted relative fall of the sum of squares, ``gains``).
    """
    box: dict[str, list[float]] = {}
    changes: list[dict[str, Any]] = []
    for (i, side), predicted in zip(edges, gains, strict=True):
        par = problem.free_params[i]
        name = split_record_name(par.name)[0]
        if name not in origin or name in box or not _may_widen(par, side, origin[name]):
            continue
        # Model error, not a group beyond its box, unless the release clearly pays:
        # then the edge warning stays.
        new = widened_box(par, side) if predicted >= need else None
        if new is None:
            continue
        box[name] = list(new)
        changes.append({"name": name, "side": side, "round": round_,
                        "from": [par.lower, par.upper], "to": list(new)})
    return box, changes


def _may_widen(par: Any, side: str, first_box: tuple[float, float]) -> bool:
    """Whether ``side`` of ``par``'s box may move: not a sign, not yet at the widening limit."""
    k = 0 if side == "lower" else 1
    edge, first = [par.lower, par.upper][k], first_box[k]
    # A signed parameter's side at zero is a sign (physics), not a guessed size.
    if edge == 0 or first == 0 or edge * first < 0:
        return False
    return bool(abs(np.log10(edge / first)) < MAX_WIDEN_DECADES - 0.5)
