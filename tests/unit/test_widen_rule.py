"""The rule that lets a group out of its default box (``hhra_phys.widen``), without fits.

``tests/integration/test_widen.py`` fits records whose truth lies beyond a box; whether the
box was widened there depends on the search as much as on the rule, so a changed threshold
or a side read the wrong way could pass it. Here each piece of the rule is checked on its
own, on numbers chosen to sit at its thresholds (docs/fitting.md, "Widening"):

* :func:`widened_box`: a log-scaled side moves a decade, a signed one ten times as far from
  zero, a side at or across zero never;
* :func:`_may_widen`: at most ``MAX_WIDEN_DECADES`` beyond the default box, on either side;
* :func:`_release_gains`: the Gauss-Newton fall of the sum of squares when one edge group is
  let out and every free group follows, counted only when the step leaves the box;
* :func:`_sides_to_widen`: a default box's side is widened when that gain reaches ``need``;
* :func:`widen_boxes`: ``need`` is ``WIDEN_MIN_GAIN`` while the residual is mostly noise
  (excess at most ``WIDEN_MAX_EXCESS``) and ``WIDEN_CLEAR_GAIN`` otherwise; rounds stop once
  a refit gains less than ``WIDEN_MIN_GAIN``.
"""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys import widen as widenmod
from hhra_phys.fit import (
    MAX_WIDEN_DECADES,
    WIDEN_CLEAR_GAIN,
    WIDEN_MAX_EXCESS,
    WIDEN_MIN_GAIN,
    _may_widen,
    _release_gains,
    _sides_to_widen,
    widen_boxes,
    widened_box,
)
from hhra_phys.parameters import Parameter


def _log(name: str, lo: float, hi: float) -> Parameter:
    return Parameter(name, "-", lo, lo, hi, "log")


def _lin(name: str, lo: float, hi: float) -> Parameter:
    return Parameter(name, "-", min(max(0.0, lo), hi), lo, hi, "linear")


# --- widened_box and _may_widen -------------------------------------------------------------


@pytest.mark.parametrize(("par", "side", "want"), [
    (_log("g", 2.0, 20.0), "lower", (0.2, 20.0)),
    (_log("g", 2.0, 20.0), "upper", (2.0, 200.0)),
    (_lin("s", -5.0, 3.0), "lower", (-50.0, 3.0)),
    (_lin("s", -5.0, 3.0), "upper", (-5.0, 30.0)),
    (_lin("s", 0.0, 3.0), "lower", None),   # a side at zero is a sign
    (_lin("s", -5.0, 0.0), "upper", None),
    (_lin("s", 1.0, 3.0), "lower", None),   # a positive lower side: moving it out crosses 0
    (_lin("s", -5.0, -1.0), "upper", None),
])
def test_widened_box_moves_one_side_a_decade_or_ten_times_from_zero(par, side, want):
    got = widened_box(par, side)
    if want is None:
        assert got is None
    else:
        assert got == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize("side", ["lower", "upper"])
def test_a_log_side_may_widen_until_max_decades_beyond_the_default_box(side):
    first = (2.0, 20.0)
    allowed = []
    for k in range(MAX_WIDEN_DECADES + 2):
        f = 10.0 ** k
        par = _log("g", first[0] / f, first[1]) if side == "lower" else _log("g", first[0],
                                                                            first[1] * f)
        allowed.append(_may_widen(par, side, first))
    # 0, 1, ..., MAX-1 decades out: one more decade is allowed; MAX decades out: no more.
    assert allowed == [True] * MAX_WIDEN_DECADES + [False, False]


def test_a_signed_side_may_widen_until_max_decades_and_never_across_zero():
    first = (-5.0, 3.0)
    lows = [_may_widen(_lin("s", -5.0 * 10.0 ** k, 3.0), "lower", first)
            for k in range(MAX_WIDEN_DECADES + 1)]
    assert lows == [True] * MAX_WIDEN_DECADES + [False]
    assert not _may_widen(_lin("s", 0.0, 3.0), "lower", (0.0, 3.0))       # at zero
    assert not _may_widen(_lin("s", -5.0, 3.0), "lower", (0.0, 3.0))      # first side at zero
    assert not _may_widen(_lin("s", 1.0, 3.0), "lower", (-5.0, 3.0))      # across zero
    assert not _may_widen(_lin("s", -5.0, -2.0), "upper", (-5.0, 3.0))


# --- _release_gains ----------------------------------------------------------------------------


class _LinearLS:
    """``r(z) = J z - y``: the Gauss-Newton model is exact."""

    J: np.ndarray
    y: np.ndarray

    def __init__(self, problem):
        pass

    def __call__(self, z):
        return self.J @ z - self.y, self.J


def _ssr_with_free(J: np.ndarray, y: np.ndarray, z: np.ndarray, free: list[int]) -> float:
    """Least sum of squares over the coordinates ``free``, the others held at ``z``
    (normal equations, independently of the lstsq in the code)."""
    held = [j for j in range(z.size) if j not in free]
    rhs = y - J[:, held] @ z[held]
    A = J[:, free]
    dz = np.linalg.solve(A.T @ A, A.T @ rhs)
    e = A @ dz - rhs
    return float(e @ e)


@pytest.fixture
def linear_problem(monkeypatch):
    rng = np.random.default_rng(4)
    n = 60
    J = rng.standard_normal((n, 3))
    J[:, 2] = 0.9 * J[:, 0] + 0.3 * J[:, 2]  # group 2 follows group 0 (correlated)
    truth = np.array([1.5, 0.2, -0.4])        # group 0 wants out above 1, group 1 in
    y = J @ truth + 0.05 * rng.standard_normal(n)
    _LinearLS.J, _LinearLS.y = J, y
    monkeypatch.setattr(widenmod, "CompiledLeastSquares", _LinearLS)
    problem = type("P", (), {"n_free": 3})()
    z = np.array([1.0, 0.0, 0.0])  # group 0 at its upper edge (1), group 1 at its lower (0)
    return problem, z, J, y


def test_release_gain_is_the_fall_with_every_free_group_following(linear_problem):
    problem, z, J, y = linear_problem
    gains = _release_gains(problem, z, [(0, "upper"), (1, "lower")])
    r = J @ z - y
    total = float(r @ r)
    base = _ssr_with_free(J, y, z, [2])
    want0 = (base - _ssr_with_free(J, y, z, [0, 2])) / total
    assert want0 > 0.05  # the test's premise: letting group 0 out pays
    assert gains[0] == pytest.approx(want0, rel=1e-9)
    # Group 0 moved alone (group 2 held) would predict another gain: the step is joint.
    alone = (base - _ssr_with_free(J, y, z, [0])) / total
    assert abs(alone - want0) > 0.01 * want0
    # Group 1's optimum lies inside its box (above its lower edge): no gain.
    assert _ssr_with_free(J, y, z, [1, 2]) < base  # released, it would move (inward)
    assert gains[1] == 0.0


def test_release_gain_counts_only_a_step_out_of_the_box(linear_problem):
    problem, z, _, _ = linear_problem
    # The same coordinates read as sitting at the other edges: group 0's step (up) now goes
    # back inside its box, group 1's (up) out of it.
    gains = _release_gains(problem, z, [(0, "lower"), (1, "upper")])
    assert gains[0] == 0.0
    assert gains[1] > 0.0


# --- _sides_to_widen -----------------------------------------------------------------------------


class _Problem:
    """What the widening reads of a problem: free parameters, their boxes, coordinates."""

    def __init__(self, params, origin):
        self.free_params = list(params)
        self.default_boxes = dict(origin)

    def from_z(self, z):
        return np.asarray(z, dtype=float).copy()

    def to_z(self, values):
        return np.asarray(values, dtype=float).copy()

    def with_boxes(self, boxes):
        params = [p.with_(lower=boxes[p.name][0], upper=boxes[p.name][1],
                          nominal=min(max(p.nominal, boxes[p.name][0]), boxes[p.name][1]))
                  if p.name in boxes else p for p in self.free_params]
        return _Problem(params, self.default_boxes)


def _two_groups():
    params = [_log("g_a", 2.0, 20.0), _log("g_b", 2.0, 20.0)]
    return _Problem(params, {"g_a": (2.0, 20.0), "g_b": (2.0, 20.0)})


def test_a_side_is_widened_when_its_gain_reaches_need():
    problem = _two_groups()
    need = 0.01
    box, changes = _sides_to_widen(problem, [(0, "upper"), (1, "lower")],
                                   [need, need * (1 - 1e-9)], problem.default_boxes, need, 2)
    assert box == {"g_a": [2.0, 200.0]}
    assert changes == [{"name": "g_a", "side": "upper", "round": 2, "from": [2.0, 20.0],
                        "to": [2.0, 200.0]}]


def test_only_default_boxes_within_the_limit_are_widened():
    params = [_log("g_a", 2.0, 20.0), _log("g_b", 2.0, 20.0 * 10 ** MAX_WIDEN_DECADES)]
    problem = _Problem(params, {"g_b": (2.0, 20.0)})  # g_a's box is the user's
    box, changes = _sides_to_widen(problem, [(0, "upper"), (1, "upper")], [0.5, 0.5],
                                   problem.default_boxes, WIDEN_MIN_GAIN, 1)
    assert box == {} and changes == []


# --- widen_boxes: which ``need``, when to stop ---------------------------------------------------


def _run_widen(monkeypatch, excess: float, gain: float, refit_costs: list[float],
               local_costs: list[float] | None = None):
    """widen_boxes with g_a at its upper edge (cost 1 there), a release gain ``gain``
    predicted every round, the residual's excess over the noise ``excess`` and the global
    refits' costs ``refit_costs``; ``local_costs``: the costs the refiners alone reach in
    each round's check (None: no refiner ran, so the search runs unchecked). ``searches``
    lists the global searches' labels."""
    problem = _two_groups()
    costs, local = iter(refit_costs), iter(local_costs or [])
    reached = {}
    monkeypatch.setattr(widenmod, "at_edges", lambda prob, z: [(0, "upper")])
    monkeypatch.setattr(widenmod, "_cost_and_excess", lambda prob, z: (1.0, excess))
    monkeypatch.setattr(widenmod, "_cost", lambda prob, z: reached["cost"])
    monkeypatch.setattr(widenmod, "_release_gains", lambda prob, z, edges: [gain] * len(edges))
    searches = []

    def search(prob, z_start, label, global_search=True):
        if not global_search:
            if local_costs is None:
                return np.asarray(z_start, dtype=float), [], []
            reached["cost"] = next(local)
            return np.asarray(z_start, dtype=float), ["a refiner's stage"], []
        searches.append(label)
        reached["cost"] = next(costs)
        return np.asarray(z_start, dtype=float), [], []

    out, _, widened = widen_boxes(problem, np.array([20.0, 5.0]), search, [], [])
    return out, widened, searches


@pytest.mark.parametrize(("excess", "gain", "widens"), [
    (0.2, WIDEN_MIN_GAIN, True),                 # mostly noise: the small gain is enough
    (0.2, 0.5 * WIDEN_MIN_GAIN, False),
    (WIDEN_MAX_EXCESS, 2 * WIDEN_MIN_GAIN, True),  # at the excess limit: still "mostly noise"
    (0.8, 2 * WIDEN_MIN_GAIN, False),             # model error: a small gain is not the box's
    (0.8, 0.5 * WIDEN_CLEAR_GAIN, False),
    (0.8, WIDEN_CLEAR_GAIN, True),                # ... a clear one is
])
def test_the_gain_needed_depends_on_the_residuals_excess_over_noise(monkeypatch, excess, gain,
                                                                     widens):
    out, widened, searches = _run_widen(monkeypatch, excess, gain, [0.9999])
    assert bool(widened) is widens
    assert len(searches) == int(widens)
    if widens:
        assert widened[0]["name"] == "g_a" and widened[0]["side"] == "upper"
        assert out.free_params[0].upper == pytest.approx(200.0)


def test_rounds_stop_once_a_refit_gains_less_than_the_minimum(monkeypatch):
    # The first refit lowers the cost by 50 %, the second by less than WIDEN_MIN_GAIN.
    small = 0.5 * (1 - 0.5 * WIDEN_MIN_GAIN)
    out, widened, searches = _run_widen(monkeypatch, 0.2, 0.3, [0.5, small, small])
    assert [w["round"] for w in widened] == [1, 2]
    assert len(searches) == 2
    assert widened[0]["gain"] == pytest.approx(0.5)
    assert widened[1]["gain"] < WIDEN_MIN_GAIN
    assert out.free_params[0].upper == pytest.approx(2000.0)


def test_rounds_stop_at_the_decade_limit(monkeypatch):
    out, widened, searches = _run_widen(monkeypatch, 0.2, 0.3, [0.5, 0.25, 0.125, 0.06])
    assert len(widened) == MAX_WIDEN_DECADES
    assert out.free_params[0].upper == pytest.approx(20.0 * 10 ** MAX_WIDEN_DECADES)


def test_a_round_searches_globally_only_when_the_refiners_bear_the_prediction_out(monkeypatch):
    # Model error (need = WIDEN_CLEAR_GAIN): the local refit gains 0.2 %, less than the
    # 10 % the prediction promised: no global search, widening stops there.
    out, widened, searches = _run_widen(monkeypatch, 0.8, WIDEN_CLEAR_GAIN, [], [0.998])
    assert searches == [] and len(widened) == 1
    assert widened[0]["searched"] is False and widened[0]["gain"] == pytest.approx(0.002)
    assert out.free_params[0].upper == pytest.approx(200.0)
    # Borne out (a local gain just above the need): the global search runs, rounds go on
    # (the second round's check is not borne out).
    out, widened, searches = _run_widen(monkeypatch, 0.8, WIDEN_CLEAR_GAIN, [0.8],
                                        [0.99 - WIDEN_CLEAR_GAIN, 0.79])
    assert searches == [" (widened 1)"] and [w.get("searched", True) for w in widened] == [
        True, False]


def test_a_round_keeps_the_better_of_the_local_and_the_global_refit(monkeypatch):
    _, widened, searches = _run_widen(monkeypatch, 0.2, 0.3, [0.7, 0.7], [0.5, 0.5])
    assert searches == [" (widened 1)"]
    assert widened[0]["gain"] == pytest.approx(0.5)  # the local 0.5, not the search's 0.7
