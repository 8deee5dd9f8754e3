"""Discovery's first stage: the entries and term library a model offers, and the
first-order screening of terms and modes that ranks them (no simulation).

The method as a whole is described in :mod:`hhra_phys.diagnosis.discovery`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import casadi as ca
import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.diagnosis.first_order import linear_response, nuisance_basis
from hhra_phys.errors import ParameterError
from hhra_phys.model import Model
from hhra_phys.problem import Problem
from hhra_phys.terms import (
    _NP,
    FAMILIES,
    MODE_DAMPINGS,
    MODE_N_PERIODS,
    MODE_PERIOD_RANGE,
    MODE_STARTS,
    _basis,
    _parse,
    velocity_pairs,
    velocity_states,
)

__all__ = [
    "Candidate",
    "EntryScreen",
    "entry_points",
    "input_followers",
    "input_twin",
    "score_floor",
    "term_library",
    "screen",
    "variable_forms",
    "variable_series",
    "lasso_path",
    "ModeScreen",
    "load_column",
    "mode_column",
    "screen_mode",
]

#: Quantile of |q| where a hinge knot starts.
KNOT_QUANTILE = 0.6


#: Other variables whose best first-order term also leads a fitted form of an entry's
#: term (:class:`Discovery`): in steady motion terms in different variables can be
#: first-order equivalent (a drag torque in the velocity equals a pressure term), so the
#: first pick alone does not decide the variable.
ALT_VARIABLES = 2


#: Least fraction of the first pick's first-order share another variable's best term
#: must explain to lead a form of its own.
ALT_FRACTION = 0.5


def entry_points(model: Model) -> list[str]:
    """Candidate entry points of ``model``: ``input``, ``output``, ``rate:<state>``.

    The rate of a position whose rate is a velocity state (``d theta/dt = omega``,
    :func:`velocity_pairs`) is no entry: that equation is the definition of the velocity,
    not a balance a missing force or flow enters. Terms there stood in for what belonged
    at the velocity's rate (a drag written as ``d theta/dt += -0.41*omega*|omega|``; a
    term that took the place of a hidden resonance; docs/diagnosis.md). Nor is the rate of a
    sensor effect's state (:meth:`~hhra_phys.model.Model.sensor_states`, a drift's
    ``y_drift``): the measurement's, not the dynamics'.
    """
    kinematic = set(velocity_pairs(model).values()) | set(model.sensor_states())
    return ["input", "output", *[f"rate:{s}" for s in model.state_names if s not in kinematic]]


def score_floor(n: int, criterion: str = "bic") -> float:
    """Least first-order score with which a discovered candidate can lower the criterion.

    A candidate whose picks explain the share ``s`` of the estimation residual's variance
    lowers ``N ln(RSS/N)`` by ``-N ln(1 - s)`` to first order and adds at least one
    parameter's penalty (``ln N`` for BIC, 2 for AIC): below ``1 - exp(-penalty/N)`` its
    criterion cannot fall, and :func:`~hhra_phys.diagnosis.selection.acceptance` asks it to. An
    entry below that floor is screened and not refitted (issue 31: the long drive
    record's fourth round refitted three resonant modes of scores 4e-4 to 6e-4, 30 s, where
    the floor of 12,500 samples is 7.5e-4).

    Parameters
    ----------
    n : int
        Samples of the estimation part(s).
    criterion : {"bic", "aic"}
        The loop's information criterion.

    Returns
    -------
    float
        The floor, a fraction of the residual's variance (0 for ``n < 1``).
    """
    if n < 1:
        return 0.0
    penalty = math.log(n) if criterion == "bic" else 2.0
    return -math.expm1(-penalty / n)


def input_twin(model: Model) -> str | None:
    """The rate entry that is the same entry as ``input`` on ``model``, or None.

    Where the input acts on one state's rate alone, linearly, with a gain that depends on
    neither the states nor the input (``d v/dt = f0(x, p) + b(p)*u``, a drive's motor or a
    resonator's force), and not on the output, a term ``u += g`` is the term
    ``d v/dt += b*g``: the two entries hold the same models, and discovery screening and
    refitting both (a long drive record's round spent 14 s refitting each, to the same
    criterion and selection error) doubles the cost for nothing. The rate is kept: it is the
    balance a missing force or flow enters. A valve (the HHRA's flow law), an input part
    that is not linear (a dead zone), input lags or an input read by the output: None.

    Parameters
    ----------
    model : Model
        The current model (with the effects accepted so far: one that makes the input act
        nonlinearly ends the twin).

    Returns
    -------
    str or None
        ``"rate:<state>"`` (an entry of :func:`entry_points`), or None.
    """
    if model.n_lags:
        return None
    x, u, p = model.symbols()
    xdot, y = model.assemble(x, u, p, 1.0)
    if ca.depends_on(y, u):
        return None
    gain = ca.jacobian(xdot, u)
    if ca.depends_on(gain, ca.vertcat(x, u)):
        return None
    rows = [i for i in range(model.nx) if not gain[i, 0].is_zero()]
    if len(rows) != 1:
        return None
    entry = f"rate:{model.state_names[rows[0]]}"
    return entry if entry in entry_points(model) else None


def input_followers(model: Model) -> list[str]:
    """The input ``u`` and the model's signals that depend on it directly (not only through
    the states): the HHRA's ``command`` and ``flow``, a resonator's ``drive``.

    At the output entry no discovered term uses them unless the model declares direct
    feedthrough (:class:`~hhra_phys.model.Model`, ``feedthrough=True``): an output term of
    the input stood in for missing dynamics (a resonator's cubic spring found at the input
    ended with ``y += -0.00924*u + ...`` beside it, issue 32).
    """
    names = [n for n in model.signal_names() if n != "y"]
    if not names:
        return ["u"]
    x, u, p = model.symbols()
    ctx = model._context(x, u, p, 1.0)
    return ["u", *[n for n in names if ca.depends_on(ctx.signals[n], u)]]


def _signal_function(model: Model, dt: float) -> tuple[list[str], ca.Function | None]:
    """Names of the model's own signals (not ``y``) and ``(x, u_lags, p) -> signals``."""
    names = [n for n in model.signal_names() if n != "y"]
    if not names:
        return [], None
    x, u, p = model.symbols()
    ctx = model._context(x, u, p, dt)
    fn = ca.Function("signals", [x, u, p], [ca.vertcat(*[ctx.signals[n] for n in names])])
    return names, fn


def _lag_matrix(u: np.ndarray, n_lags: int) -> np.ndarray:
    """(n_lags + 1, N): the current and past inputs of every sample (first value before)."""
    padded = np.concatenate([np.full(n_lags, u[0]), u])
    return np.stack([padded[n_lags - j: n_lags - j + u.size] for j in range(n_lags + 1)])


def variable_series(problem: Problem, values: np.ndarray,
                    data: Dataset | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Simulated states, the input ``u`` and the model's signals on a record, and the output.

    Parameters
    ----------
    problem : Problem
        The fitted problem.
    values : array, shape (n_free,)
        Free values (physical units).
    data : Dataset, optional
        Another record (validation); its initial state by the problem's rule.

    Returns
    -------
    series : dict of str to ndarray, each shape (N,)
    yhat : ndarray, shape (N,)
    """
    d = problem.data if data is None else data
    P = problem.full(values)
    X0 = problem.initial_states(values, data=data)[0]
    sim = problem.simulator_for(d)
    yhat, X = sim.simulate(d.u, P, x0=X0, states=True)
    model = problem.model
    out = {n: X[:, i] for i, n in enumerate(model.state_names)}
    out["u"] = np.asarray(d.u, dtype=float)
    names, fn = _signal_function(model, 1.0 / d.fs)
    if fn is not None:
        lags = _lag_matrix(out["u"], model.n_lags)
        S = np.array(fn.map(d.n)(X.T, lags, np.tile(P[:, None], (1, d.n))), dtype=float)
        for i, n in enumerate(names):
            if n not in out:
                out[n] = S[i]
    return out, yhat


@dataclass(frozen=True)
class Candidate:
    """One candidate term at an entry point (first-order screening).

    Attributes
    ----------
    spec : str
        Term specification (``"odd2(omega)"``).
    column : ndarray, shape (N,)
        The term with coefficient 1 on the estimation record (entry unit).
    knot : float
        Starting knot of a hinge term (variable unit), else 0.
    """

    spec: str
    column: np.ndarray = field(repr=False)
    knot: float = 0.0


def term_library(series: Mapping[str, np.ndarray], entry: str,
                 units: Mapping[str, str] | None = None,
                 exclude: Sequence[str] = ()) -> tuple[list[Candidate], dict[str, float]]:
    """Candidate terms at ``entry`` from the simulated variables, and the variables' scales.

    Parameters
    ----------
    series : dict of str to ndarray
        Simulated states, ``u`` and signals (:func:`variable_series`).
    entry : str
        Entry point; ``input`` sees states and ``u`` only.
    units : dict, optional
        Units of the variables: states with unit ``rad`` also get ``sin``/``cos``.
    exclude : sequence of str
        Variables no term may use (:func:`screen`: at the output the input and the
        signals that follow it directly, unless the model declares feedthrough).

    Returns
    -------
    candidates : list of Candidate
    scales : dict of str to float
        ``max|v|`` of every variable used (its unit).
    """
    units = dict(units or {})
    names = [n for n in series if (entry != "input" or n == "u" or n in units)
             and n not in exclude]
    kept, scales = _term_variables(series, names)
    cands: list[Candidate] = []
    N = len(next(iter(series.values())))
    cands.append(Candidate("one()", np.ones(N)))
    for n in kept:
        cands.extend(_variable_terms(n, series[n], scales[n], units.get(n) == "rad"))
    for i, a in enumerate(kept):
        for b in kept[i + 1:]:
            cands.append(Candidate(f"prod({a},{b})",
                                   series[a] / scales[a] * series[b] / scales[b]))
    return cands, scales


def _term_variables(series: Mapping[str, np.ndarray],
                    names: list[str]) -> tuple[list[str], dict[str, float]]:
    """The variables of ``names`` worth terms, and their scales ``max|v|``.

    A constant (or zero) variable, or one equal to an earlier one up to sign and scale,
    is left out: its terms would only repeat others.
    """
    scales: dict[str, float] = {}
    kept: list[str] = []
    for n in names:
        v = np.asarray(series[n], dtype=float)
        s = float(np.max(np.abs(v))) if v.size else 0.0
        if not (np.isfinite(s) and s > 0) or np.std(v) <= 1e-9 * s:
            continue  # constant or zero: nothing a term of it could add beyond "one"
        # A signal equal to an earlier variable (the HHRA's command is its input) adds
        # only duplicate columns.
        if any(abs(np.corrcoef(v, series[k])[0, 1]) > 0.9999 for k in kept):
            continue
        kept.append(n)
        scales[n] = s
    return kept, scales


def _variable_terms(n: str, v: np.ndarray, scale: float, rad: bool) -> list[Candidate]:
    """The terms of one variable ``n`` (values ``v``, scale ``scale``): every family of
    :data:`FAMILIES` of ``v / scale``, and ``sin``/``cos`` of an angle in rad."""
    q = v / scale
    cands: list[Candidate] = []
    for fam in FAMILIES:
        knot = 0.0
        if fam.startswith("hinge"):
            side = q if fam == "hinge+" else -q
            pos = side[side > 0]
            if pos.size < 10:
                continue  # too few samples on that side to place a knot
            knot = float(np.quantile(pos, KNOT_QUANTILE))
        cands.append(Candidate(f"{fam}({n})", np.asarray(_basis(fam, [q], knot, _NP)),
                               knot * scale))
    if rad:
        for fam in ("sin", "cos"):
            cands.append(Candidate(f"{fam}({n})", np.asarray(_basis(fam, [v], 0.0, _NP))))
    return cands


@dataclass
class EntryScreen:
    """First-order screening of one entry point.

    Attributes
    ----------
    entry : str
    picked : list of int
        Indices into :attr:`candidates` chosen by matching pursuit, best first.
    explained : list of float
        Fraction of the projected residual explained after each pick.
    beta : ndarray
        First-order coefficients of the picks (entry unit).
    candidates : list of Candidate
    scales : dict of str to float
    S : ndarray, shape (N, n_candidates)
        Projected output responses of every candidate (kept for the L1 path).
    r : ndarray, shape (N,)
        Projected residual.
    """

    entry: str
    picked: list[int]
    explained: list[float]
    beta: np.ndarray
    candidates: list[Candidate]
    scales: dict[str, float]
    S: np.ndarray = field(repr=False)
    r: np.ndarray = field(repr=False)

    @property
    def score(self) -> float:
        """Residual fraction the picks explain to first order (0..1)."""
        return self.explained[-1] if self.explained else 0.0

    def to_json(self) -> dict[str, Any]:
        """JSON-able summary."""
        return {"entry": self.entry, "score": self.score,
                "terms": [self.candidates[i].spec for i in self.picked],
                "explained": list(self.explained),
                "beta": [float(b) for b in self.beta]}


def _pursuit(S: np.ndarray, r: np.ndarray, k: int, first: int | None = None
             ) -> tuple[list[int], list[float], np.ndarray]:
    """Orthogonal matching pursuit: up to ``k`` columns of ``S`` explaining ``r`` (the
    first one ``first`` when given)."""
    norms = np.linalg.norm(S, axis=0)
    ok = norms > 1e-9 * max(float(norms.max(initial=0.0)), 1e-300)
    Sn = np.where(ok, S / np.where(ok, norms, 1.0), 0.0)
    rr = float(r @ r) or 1e-300
    picked: list[int] = []
    explained: list[float] = []
    res = r.copy()
    beta = np.zeros(0)
    for _ in range(k):
        c = np.abs(Sn.T @ res)
        c[picked] = -1.0
        if picked:  # skip columns almost in the span of the picks (duplicates)
            Qp, _ = np.linalg.qr(Sn[:, picked])
            leftover = np.linalg.norm(Sn - Qp @ (Qp.T @ Sn), axis=0)
            c[leftover < 0.05] = -1.0
        j = int(np.argmax(c)) if first is None or picked else first
        if c[j] <= 0:
            break
        picked.append(j)
        beta, *_ = np.linalg.lstsq(S[:, picked], r, rcond=None)
        res = r - S[:, picked] @ beta
        explained.append(float(np.clip(1 - (res @ res) / rr, 0.0, 1.0)))
    return picked, explained, beta


def variable_forms(scr: EntryScreen, k: int, n: int = ALT_VARIABLES,
                   fraction: float = ALT_FRACTION) -> list[EntryScreen]:
    """The entry's screening led by other variables than its first pick's.

    For each variable the first pick does not use, its single-variable term that explains
    most of the projected residual; of those explaining at least ``fraction`` of the first
    pick's share, the ``n`` best each lead a pursuit of up to ``k`` terms (the first pick
    forced, the rest as usual).

    Returns
    -------
    list of EntryScreen
        Best leading term first; empty when the screen picked nothing.
    """
    if not scr.picked:
        return []
    lead = set(_parse(scr.candidates[scr.picked[0]].spec)[1])
    norms = np.linalg.norm(scr.S, axis=0)
    share = np.where(norms > 0, (scr.S.T @ scr.r) / np.where(norms > 0, norms, 1.0), 0.0) ** 2
    share /= float(scr.r @ scr.r) or 1e-300
    best: dict[str, int] = {}
    for j, c in enumerate(scr.candidates):
        vs = _parse(c.spec)[1]
        if len(vs) != 1 or vs[0] in lead:
            continue
        if vs[0] not in best or share[j] > share[best[vs[0]]]:
            best[vs[0]] = j
    lead_share = scr.explained[0]
    top = sorted((j for j in best.values() if share[j] >= fraction * lead_share),
                 key=lambda j: -share[j])[:n]
    out = []
    for j in top:
        picked, explained, beta = _pursuit(scr.S, scr.r, k, first=j)
        out.append(replace(scr, picked=picked, explained=explained, beta=beta))
    return out


def screen(problem: Any, values: np.ndarray, entries: Sequence[str] | None = None,
           max_terms: int = 4) -> list[EntryScreen]:
    """First-order screening of every entry point, best first (module docstring).

    Parameters
    ----------
    problem : Problem
        The fitted problem (model and estimation record, or records). With several records
        the candidate terms are built on all of them (one scale per variable, over every
        record), each record's columns are propagated through the model linearised at its
        own fit, and the pursuit runs on the records' rows stacked: one screening of the
        record set.
    values : array, shape (n_free,)
        Fitted free values.
    entries : sequence of str, optional
        Entry points to screen (default: :func:`entry_points`).
    max_terms : int
        Most terms picked per entry.

    Returns
    -------
    list of EntryScreen
        Sorted by :attr:`EntryScreen.score`, highest first.
    """
    model = problem.model
    allowed = entry_points(model)
    entries = list(entries) if entries is not None else allowed
    for e in entries:
        if e not in allowed:
            raise ParameterError(f"unknown entry point {e!r}; entry points of this model: "
                                 f"{', '.join(allowed)}")
    values = np.asarray(values, dtype=float)
    blocks = problem.per_record_values(values)
    per: list[dict[str, Any]] = []
    for pr, v in blocks:
        series, yhat = variable_series(pr, v)
        if not np.isfinite(yhat).all():
            raise ParameterError("the fitted model cannot be simulated on its record")
        Q = nuisance_basis(pr, v, yhat)
        r = pr.data.y - yhat
        per.append({"pr": pr, "P": pr.full(v), "Q": Q, "series": series, "n": yhat.size,
                    "r_p": r - Q @ (Q.T @ r),
                    "umax": float(np.max(np.abs(pr.data.u))) or 1.0})
    # A sensor's own state (a drift's y_drift) is the measurement's, not a variable of the
    # dynamics: no term reads it (it could not be removed with its sensor effect).
    sensor = set(model.sensor_states())
    pooled = {n: np.concatenate([b["series"][n] for b in per]) for n in per[0]["series"]
              if n not in sensor}
    units = {s.name: s.unit for s in model.states}
    r_p = np.concatenate([b["r_p"] for b in per])
    edges = np.cumsum([0] + [b["n"] for b in per])
    out = []
    direct = [] if model.feedthrough else input_followers(model)
    for e in entries:
        cands, scales = term_library(pooled, e, units, direct if e == "output" else ())
        cols = np.column_stack([c.column for c in cands])
        parts = []
        for k, b in enumerate(per):
            S = linear_response(b["pr"], b["P"], e, cols[edges[k]:edges[k + 1]], b["umax"])
            parts.append(S - b["Q"] @ (b["Q"].T @ S))
        S = np.vstack(parts)
        S[~np.isfinite(S)] = 0.0
        picked, explained, beta = _pursuit(S, r_p, max_terms)
        out.append(EntryScreen(e, picked, explained, beta, cands, scales, S, r_p))
    out.sort(key=lambda s: -s.score)
    return out


def lasso_path(S: np.ndarray, r: np.ndarray, max_terms: int,
               n_lambda: int = 40) -> list[list[int]]:
    """Supports of sizes 1..``max_terms`` along an L1 path (coordinate descent).

    Columns are normalised; the penalty falls geometrically from the one at which
    the first column enters to 1e-3 of it. The first support of each size met on
    the way is returned (nested in practice).
    """
    norms = np.linalg.norm(S, axis=0)
    ok = norms > 0
    A = np.where(ok, S / np.where(ok, norms, 1.0), 0.0)
    lam_max = float(np.max(np.abs(A.T @ r)))
    beta = np.zeros(A.shape[1])
    supports: dict[int, list[int]] = {}
    for lam in lam_max * np.geomspace(1.0, 1e-3, n_lambda):
        for _ in range(200):
            change = 0.0
            for j in np.flatnonzero(ok):
                rho = float(A[:, j] @ (r - A @ beta + A[:, j] * beta[j]))
                new = math.copysign(max(abs(rho) - lam, 0.0), rho)
                change = max(change, abs(new - beta[j]))
                beta[j] = new
            if change < 1e-10 * lam_max:
                break
        active = [int(j) for j in np.flatnonzero(beta)]
        active.sort(key=lambda j: -abs(beta[j]))
        if active and len(active) <= max_terms and len(active) not in supports:
            supports[len(active)] = active
        if len(active) > max_terms:
            break
    return [supports[k] for k in sorted(supports)]


def mode_column(y: np.ndarray, dt: float, w: float, zeta: float) -> np.ndarray:
    """``(H - 1) y`` of a sampled output (bilinear discretisation), starting at rest.

    Parameters
    ----------
    y : ndarray, shape (N,)
        Output (any unit).
    dt : float
        Sample period [time unit].
    w, zeta : float
        Natural frequency [rad per time unit] and damping ratio of ``H``.

    Returns
    -------
    ndarray, shape (N,)
        The mode's contribution at mix 1 (the output's unit).
    """
    from scipy import signal as sps

    # scipy.signal.bilinear: the same coefficients as cont2discrete's "bilinear" (to
    # rounding) at half its cost; the screen filters a whole grid of modes.
    b, a = sps.bilinear([-1.0, -2 * zeta * w, 0.0], [1.0, 2 * zeta * w, w * w], fs=1.0 / dt)
    return sps.lfilter(b, a, np.asarray(y, dtype=float) - float(y[0]))


def load_column(v: np.ndarray, dt: float, w: float, zeta: float) -> np.ndarray:
    """Change of ``dv/dt`` made by a light load mode (ratio 1, to first order).

    The load follows ``v`` through ``G(s) = (2 z w s + w^2)/(s^2 + 2 z w s + w^2)``
    and reacts with minus its acceleration: ``-s G(s) v`` (bilinear discretisation),
    starting from steady motion at ``v[0]``.

    Parameters
    ----------
    v : ndarray, shape (N,)
        Simulated velocity state (its unit).
    dt : float
        Sample period [time unit].
    w, zeta : float
        Natural frequency [rad per time unit] and damping ratio of the load.

    Returns
    -------
    ndarray, shape (N,)
        In the velocity's unit per time unit.
    """
    from scipy import signal as sps

    b, a = sps.bilinear([-2 * zeta * w, -w * w, 0.0], [1.0, 2 * zeta * w, w * w], fs=1.0 / dt)
    return sps.lfilter(b, a, np.asarray(v, dtype=float) - float(v[0]))


@dataclass
class ModeScreen:
    """First-order screening of a mode at the output over a grid of periods and dampings.

    Attributes
    ----------
    entry : str
        ``"mode:output"``, ``"mode:input"`` or ``"mode:rate:<v>"``.
    periods : ndarray, shape (n_periods,)
        Screened periods [time unit].
    explained : ndarray, shape (n_periods, n_dampings)
        Fraction of the projected residual the mode explains at its best mix.
    mix : ndarray, shape (n_periods, n_dampings)
        That mix.
    starts : list of tuple
        ``(w, zeta, mix, explained)`` of the best grid points with distinct periods.
    """

    entry: str
    periods: np.ndarray
    explained: np.ndarray
    mix: np.ndarray
    starts: list[tuple[float, float, float, float]]

    @property
    def score(self) -> float:
        """Residual fraction the best grid point explains to first order (0..1)."""
        return float(self.explained.max(initial=0.0))

    def to_json(self) -> dict[str, Any]:
        """JSON-able summary (the starts and the best explained fraction per period)."""
        return {"entry": self.entry, "score": self.score,
                "periods": [float(p) for p in self.periods],
                "explained_by_period": [float(e) for e in self.explained.max(axis=1)],
                "starts": [{"w": w, "zeta": z, "mix": k, "explained": e}
                           for w, z, k, e in self.starts]}


def screen_mode(problem: Problem, values: np.ndarray, target: str = "output",
                n_starts: int = MODE_STARTS) -> ModeScreen:
    """Screen a resonant mode (:class:`DiscoveredMode`) to first order.

    The mode's change at its entry at mix 1 (:func:`mode_column` of the simulated
    output, or of the measured input propagated through the model linearised at
    the fit, :func:`~hhra_phys.diagnosis.first_order.linear_response`) is projected off what
    the model's free parameters absorb (:func:`~hhra_phys.diagnosis.first_order.nuisance_basis`)
    and compared with the projected residual, for every period of a log grid (4
    to 300 samples, at most an eighth of the record) and damping of
    :data:`MODE_DAMPINGS`.

    Parameters
    ----------
    problem : Problem
        The fitted problem.
    values : ndarray, shape (n_free,)
        Fitted free values.
    target : str
        Entry of the mode: ``"output"``, ``"input"`` or ``"rate:<v>"`` (``v`` one of
        :func:`velocity_states`; the change is :func:`load_column` of the simulated
        ``v`` at that state's rate).
    n_starts : int
        Number of starts returned (best points with periods at least 20 % apart).

    Returns
    -------
    ModeScreen
    """
    velocity = target[5:] if target.startswith("rate:") else ""
    if target not in ("output", "input") and velocity not in velocity_states(problem.model):
        raise ParameterError(f"a mode enters at the output, the input or the rate of a "
                             f"velocity state ('rate:<v>', v one of "
                             f"{velocity_states(problem.model)}), got {target!r}")
    values = np.asarray(values, dtype=float)
    d = problem.data
    yhat = problem.simulate_values(values)
    if not np.isfinite(yhat).all():
        raise ParameterError("the fitted model cannot be simulated on its record")
    Q = nuisance_basis(problem, values, yhat)
    r = d.y - yhat
    r = r - Q @ (Q.T @ r)
    rr = float(r @ r) or 1e-300
    dt = 1.0 / d.fs
    hi = min(MODE_PERIOD_RANGE[1], d.n / 8)
    periods = np.geomspace(MODE_PERIOD_RANGE[0], max(hi, 2 * MODE_PERIOD_RANGE[0]),
                           MODE_N_PERIODS) * dt
    grid = [(i, j) for i in range(periods.size) for j in range(len(MODE_DAMPINGS))]
    if velocity:
        src = variable_series(problem, values)[0][velocity]
        cols = np.column_stack([load_column(src, dt, 2 * math.pi / periods[i],
                                            MODE_DAMPINGS[j]) for i, j in grid])
    else:
        src = yhat if target == "output" else np.asarray(d.u, dtype=float)
        cols = np.column_stack([mode_column(src, dt, 2 * math.pi / periods[i],
                                            MODE_DAMPINGS[j]) for i, j in grid])
    umax = float(np.max(np.abs(d.u))) or 1.0
    S = linear_response(problem, problem.full(values), target, cols, umax)
    S = S - Q @ (Q.T @ S)
    S[~np.isfinite(S)] = 0.0
    expl = np.zeros((periods.size, len(MODE_DAMPINGS)))
    mix = np.zeros_like(expl)
    for col, (i, j) in zip(S.T, grid, strict=True):
        cc = float(col @ col)
        if cc > 0:
            mix[i, j] = float(col @ r) / cc
            expl[i, j] = float(col @ r) ** 2 / (cc * rr)
    if velocity:  # a load has a positive inertia: the other sign explains nothing
        expl[mix <= 0] = 0.0
    starts: list[tuple[float, float, float, float]] = []
    for flat in np.argsort(-expl, axis=None):
        i, j = np.unravel_index(flat, expl.shape)
        T = float(periods[i])
        if any(abs(T / (2 * math.pi / s[0]) - 1) < 0.2 for s in starts):
            continue
        starts.append((2 * math.pi / T, MODE_DAMPINGS[j], float(mix[i, j]), float(expl[i, j])))
        if len(starts) >= n_starts:
            break
    return ModeScreen(f"mode:{target}", periods, expl, mix, starts)
