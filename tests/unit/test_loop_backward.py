"""The loop's backward step: an effect accepted earlier is removed when, proposed now to
the model without it, the acceptance rule would refuse it (``hhra_phys.loop``).

One rule: ``backward_decision`` is ``acceptance`` read the other way, with the model
without the effect as "before" and the current model as "after". The cases below break one
condition each, as in ``test_loop_rule.py``, plus the stand-in case of the study (an
asymmetric valve that a true effect made redundant).
"""

from __future__ import annotations

import itertools

import pytest

from hhra_phys.diagnosis.selection import Step, acceptance, backward_decision

NOISE = 0.05


@pytest.mark.parametrize(
    ("without", "with_", "crit_without", "crit_with", "remove", "why"),
    [
        (0.20, 0.10, 0.0, -10.0, False, "the effect still pays: kept"),
        # the friction + angle-load pair: the load in, the stand-in explains little more
        (0.058, 0.055, 0.0, -2.0, True, "5 % gain, within the noise allowance: removed"),
        (0.20, 0.19, 0.0, -10.0, True, "gain below the 10 % margin: removed"),
        (0.20, 0.10, 0.0, +10.0, True, "the criterion prefers the model without it"),
        (0.20, 0.21, 0.0, -10.0, True, "the model without it is better on selection"),
    ],
)
def test_backward_decision_cases(without, with_, crit_without, crit_with, remove, why):
    out, reason = backward_decision(without, with_, crit_without, crit_with, NOISE, 0.1, 0.15)
    assert out is remove, why
    assert "selection RMSE" in reason


def test_backward_is_acceptance_read_the_other_way():
    # one rule, no second threshold: on a grid the two answers are always opposite
    grid = itertools.product((0.05, 0.06, 0.1, 0.3), (0.05, 0.055, 0.09, 0.2),
                             (-5.0, 5.0), (0.0, 0.1), (0.0, 0.15))
    for before, after, crit_after, margin, tol in grid:
        keep, _ = acceptance(before, after, 0.0, crit_after, margin, "bic", NOISE, tol)
        remove, _ = backward_decision(before, after, 0.0, crit_after, NOISE, margin, tol)
        assert remove is not keep


def test_step_json_says_the_action():
    step = Step(2, "asymmetric_valve", {}, {}, {}, {}, {"rmse": 0.055}, -2.0, 0.0, 0.058,
                action="remove", removed=True)
    js = step.to_json()
    assert js["action"] == "remove" and js["removed"] is True
    # forward candidates keep their old layout, with the action "add"
    add = Step(1, "x", {}, {}, {}, {}, {"rmse": 0.1}, 0.0, 0.0, 0.2).to_json()
    assert add["action"] == "add" and add["removed"] is False and "accepted" in add


# --- which accepted effect the backward step takes out ------------------------------------
#
# ``loop._backward_step`` with its fits replaced by a table: the selection RMSE of the model
# without each effect. The rule (its docstring): every effect accepted before the newest is
# checked, in the order accepted, the newest never; of those the rule would take out, the one
# whose removal leaves the lowest selection RMSE goes, one per call. The table puts that one
# in the middle of the removable ones, so taking the first or the last of them, the largest,
# or checking the newest instead of the oldest each remove another effect.

#: Selection RMSE of the current model without each effect (the current model: 0.050).
WITHOUT = {"a": 0.0540, "b": 0.0510, "d": 0.100, "c": 0.0530, "new": 0.0505}
#: ... and its estimation RMSE, which the criterion reads: lowest without c, so a rule that
#: picked the lowest criterion instead of the lowest selection RMSE would take c out.
EST_WITHOUT = {"a": 0.0540, "b": 0.0510, "d": 0.100, "c": 0.0502, "new": 0.0505}
RMSE_WITH = 0.050


class _FakeModel:
    def __init__(self, removed=frozenset()):
        self.removed = frozenset(removed)

    def without(self, effect):
        return _FakeModel(self.removed | {effect})


class _FakeResult:
    def __init__(self, model):
        self.model = model
        gone = sorted(model.removed)
        val = RMSE_WITH if not gone else WITHOUT[gone[0]]
        est = RMSE_WITH if not gone else EST_WITHOUT[gone[0]]
        self.metrics = {"val": {"rmse": val}, "est": {"rmse": est}}
        self.values = {f"k_{e}": 1.0 for e in WITHOUT if e not in model.removed}
        self.ci95 = {n: [0.5, 1.5] for n in self.values}
        self.x0, self.records, self.free = {}, None, list(self.values)


def _fake_loop(monkeypatch):
    import math as _math
    import types

    from hhra_phys.diagnosis import backward as loop

    runs = []

    def problem(cfg, model, free, fixed, vals, x0, simulator=None):
        return types.SimpleNamespace(model=model, sim=None, free=list(free))

    def run(cfg, prob, optimizer, pop, iters, **kw):
        runs.append((sorted(prob.model.removed), optimizer))
        return _FakeResult(prob.model)

    monkeypatch.setattr(loop, "_problem", problem)
    monkeypatch.setattr(loop, "_run", run)
    monkeypatch.setattr(loop, "_effect_params", lambda model, effect: [f"k_{effect}"])
    monkeypatch.setattr(loop, "_values", lambda res: dict(res.values))
    # BIC-like: 1000 points, one parameter per effect.
    monkeypatch.setattr(loop, "information_criterion", lambda res, kind="bic": (
        1000 * _math.log(res.metrics["est"]["rmse"] ** 2) + len(res.values) * _math.log(1000)))
    monkeypatch.setattr(loop, "selection_noise", lambda prob, res, sel: {"noise": NOISE})
    return loop, runs


def test_backward_step_removes_the_effect_whose_removal_leaves_the_lowest_rmse(monkeypatch):
    loop, runs = _fake_loop(monkeypatch)
    chosen = ["a", "b", "d", "c", "new"]
    cur = _FakeResult(_FakeModel())
    cfg = type("Cfg", (), {"criterion": "bic", "sel": None})()
    said = []
    res, prob, free, steps, removed = loop._backward_step(
        cfg, cur, type("P", (), {"model": _FakeModel()})(), [f"k_{e}" for e in chosen],
        chosen, [], 3, 0.1, 0.15, None, None, said.append)
    # Every effect accepted before the newest is checked, in the order accepted.
    assert [s.effect for s in steps] == ["a", "b", "d", "c"]
    # a, b and c would not be accepted now (d would), and b's removal leaves the lowest RMSE.
    assert [s.val_rmse_before for s in steps] == [WITHOUT[e] for e in ("a", "b", "d", "c")]
    assert removed == "b"
    assert [(s.effect, s.action, s.removed) for s in steps] == [
        ("a", "keep", False), ("b", "remove", True), ("d", "keep", False), ("c", "keep", False)]
    assert sorted(res.model.removed) == ["b"] and "k_b" not in free
    assert prob.model.removed == {"b"}
    assert runs[-1] == (["b"], "none")  # the model without b polished before the next round
    assert said[-1] == "round 3: removed b"


def test_backward_step_removes_nothing_when_every_effect_still_pays(monkeypatch):
    loop, _ = _fake_loop(monkeypatch)
    monkeypatch.setitem(WITHOUT, "b", 0.100)
    monkeypatch.setitem(WITHOUT, "a", 0.100)
    chosen = ["a", "b", "new"]
    cur = _FakeResult(_FakeModel())
    cfg = type("Cfg", (), {"criterion": "bic", "sel": None})()
    res, _, free, steps, removed = loop._backward_step(
        cfg, cur, type("P", (), {"model": _FakeModel()})(), ["k_a", "k_b", "k_new"], chosen,
        [], 2, 0.1, 0.15, None, None, lambda s: None)
    assert removed is None and res is cur and free == ["k_a", "k_b", "k_new"]
    assert [(s.effect, s.action) for s in steps] == [("a", "keep"), ("b", "keep")]
