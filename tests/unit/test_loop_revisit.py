"""The loop's revisit (``LoopOptions.revisit``): when a discovered term took a round from an
acceptable given effect and the loop then ended above the noise, the path from that effect is
followed too, and the better final model by the rule is kept.

The bookkeeping is checked on a loop whose rounds are stand-ins (no fits): which path is
kept, what its steps and ``chosen`` say, and that the path not kept leaves nothing behind.
"""

from __future__ import annotations

import json

import pytest

from hhra_phys.diagnosis.discovery import DiscoveredStep
from hhra_phys.diagnosis.engine import _Loop
from hhra_phys.diagnosis.options import LoopOptions
from hhra_phys.diagnosis.selection import Step

NOISE = 0.08


class _Res:
    """The little of a FitResult the rule reads: selection RMSE, estimation MSE, free."""

    def __init__(self, sel: float, est: float, k: int) -> None:
        self.metrics = {"val": {"rmse": sel}, "est": {"mse": est ** 2}}
        self.settings = {"data": {"n_est": 512}}
        self.free = [f"p{i}" for i in range(k)]


def _loop(revisit: bool = True) -> _Loop:
    loop = object.__new__(_Loop)
    loop.o, loop.tol, loop.say = LoopOptions(revisit=revisit), 0.068, lambda s: None
    for name in ("steps", "chosen", "diagnoses", "warnings", "dropped", "levels", "settled",
                 "names"):
        setattr(loop, name, [])
    loop.skipped = {}
    loop.cur, loop.cur_prob, loop.cur_free, loop.cfg = _Res(0.93, 0.68, 6), None, [], None
    loop.discover, loop.stop, loop.at_noise = True, "", False
    loop.branch, loop.revisited = None, None
    loop.data = loop.est = loop.sel = loop.held = None  # the records (a path may change their hold)
    loop.hold_changed, loop.hold_tried = False, None
    return loop


def _round_one(loop: _Loop) -> tuple[DiscoveredStep, Step]:
    """Round 1: a discovered input term beats the asymmetric valve; both acceptable."""
    term = DiscoveredStep(1, "discovered_input_1", {}, {}, {}, {"rmse": 0.51}, {"rmse": 0.568},
                          -638.0, -354.0, 0.928, reason="accepted: selection ...",
                          entry="input", expression="u += 260*omega*p - 0.092*sgn(u)")
    term.accepted = True
    valve = Step(1, "asymmetric_valve", {}, {}, {}, {"rmse": 0.6}, {"rmse": 0.722}, -542.0,
                 -354.0, 0.928, entry="input",
                 reason="acceptable, not chosen (a higher selection error than "
                        "discovered_input_1): selection RMSE 0.928 -> 0.722")
    loop.steps += [term, valve]
    # the reasons as judged, before choose added its verdicts (what _round hands over)
    judged = {id(term): "selection ...", id(valve): "selection RMSE 0.928 -> 0.722"}
    loop._remember_branch(1, term, [(term, "T"), (valve, "V")], NOISE, judged)
    return term, valve


def _paths(loop: _Loop, first: tuple[float, float, int], alt: tuple[float, float, int],
           alt_effects: list[str]) -> None:
    """Accepting a candidate and later rounds, as stand-ins: each path ends at its model."""
    def accept(rnd, step, payload):
        loop.chosen.append(step.effect)
        loop.cur = _Res(0.72, 0.6, 7)

    def rounds(rnd):
        if loop.chosen == ["discovered_input_1"]:
            loop.cur, loop.stop = _Res(*first), "no candidate accepted"
        else:
            loop.chosen += alt_effects
            loop.steps.append(Step(rnd + 1, alt_effects[0], {}, {}, {}, {}, {}, 0.0, 0.0, 0.0,
                                   accepted=True, reason="accepted: ..."))
            loop.cur, loop.stop = _Res(*alt), "max_effects"
            loop.data, loop.hold_changed = "the records read as cubic", True  # a hold step
    loop._accept, loop._rounds = accept, rounds


def test_the_path_from_the_given_effect_is_kept_when_it_ends_better():
    loop = _loop()
    term, valve = _round_one(loop)
    _paths(loop, first=(0.568, 0.51, 8), alt=(0.463, 0.38, 12),
           alt_effects=["input_delay", "valve_saturation"])
    loop._accept(1, term, "T")
    loop._rounds(1)
    loop._revisit()
    assert loop.chosen == ["asymmetric_valve", "input_delay", "valve_saturation"]
    assert loop.revisited["kept"] == "alternative" and loop.revisited["round"] == 1
    assert loop.hold_changed and loop.data == "the records read as cubic"  # kept with it
    kept = {s.effect: s for s in loop.steps}
    assert kept["asymmetric_valve"].accepted
    assert kept["asymmetric_valve"].reason == ("accepted on revisiting round 1: "
                                               "selection RMSE 0.928 -> 0.722")
    assert not kept["discovered_input_1"].accepted
    assert "replaced on revisiting round 1" in kept["discovered_input_1"].reason
    # the steps of the first path's round were copied, not changed
    assert term.accepted and not valve.accepted
    json.dumps(loop.revisited)  # the settings entry is plain data


def test_the_first_path_stays_when_the_alternative_is_not_better():
    loop = _loop()
    term, valve = _round_one(loop)
    _paths(loop, first=(0.463, 0.38, 9), alt=(0.55, 0.45, 12), alt_effects=["input_delay"])
    loop._accept(1, term, "T")
    loop._rounds(1)
    before = list(loop.steps)
    loop._revisit()
    assert loop.chosen == ["discovered_input_1"]
    assert len(loop.steps) == len(before)
    assert all(a is b for a, b in zip(loop.steps, before, strict=True))
    assert loop.revisited["kept"] == "first"
    assert loop.revisited["alternative_path"]["chosen"] == ["asymmetric_valve", "input_delay"]
    assert term.accepted and any("revisited round 1" in n for n in term.notes)
    # the path not kept changed the records' hold: the first path's records are back
    assert loop.data is None and loop.hold_changed is False


def test_a_tie_goes_to_the_criterion():
    # 0.4635 and 0.463 are within the noise allowance of each other (0.00046 against
    # 0.0009 deg^2): the lower BIC wins, here the first path's (the same estimation fit
    # with 4 parameters fewer)
    loop = _loop()
    term, _ = _round_one(loop)
    _paths(loop, first=(0.4635, 0.38, 8), alt=(0.463, 0.38, 12), alt_effects=["input_delay"])
    loop._accept(1, term, "T")
    loop._rounds(1)
    loop._revisit()
    assert loop.revisited["kept"] == "first"
    assert loop.revisited["first"]["criterion"] < loop.revisited["alternative_path"]["criterion"]


@pytest.mark.parametrize("case", ["off", "library winner", "no given effect"])
def test_no_branch_is_kept_when_there_is_nothing_to_revisit(case):
    loop = _loop(revisit=case != "off")
    term = DiscoveredStep(1, "d", {}, {}, {}, {}, {"rmse": 0.5}, -1.0, 0.0, 1.0, entry="input")
    valve = Step(1, "asymmetric_valve", {}, {}, {}, {}, {"rmse": 0.7}, -1.0, 0.0, 1.0)
    if case == "library winner":
        loop._remember_branch(1, valve, [(valve, 1), (term, 2)], NOISE)
    elif case == "no given effect":
        loop._remember_branch(1, term, [(term, 1)], NOISE)
    else:
        loop._remember_branch(1, term, [(term, 1), (valve, 2)], NOISE)
    assert loop.branch is None


def test_the_path_not_taken_is_followed_only_while_a_stand_in_stands():
    """Once the backward step removed the discovered term that took the branch round (or
    its library form replaced it) and the model holds given effects of the dynamics only,
    this path has undone the greedy choice itself; a stand-in left (a sensor's effect, a
    discovered term) still sends the loop down the other path."""
    loop = _loop()
    _round_one(loop)
    loop.revisit_skipped = None
    loop.chosen = ["discovered_input_1", "asymmetric_valve"]
    assert loop._branch_stands() and loop.revisit_skipped is None

    def add(effect, sensor=False):
        loop.steps.append(Step(2, effect, {}, {}, {}, {}, {}, 0.0, 0.0, 0.0, accepted=True,
                               sensor=sensor))

    add("coulomb_friction")
    add("input_offset")
    loop.chosen = ["coulomb_friction", "input_offset"]  # the term removed by the backward step
    assert not loop._branch_stands()
    assert "discovered_input_1" in loop.revisit_skipped
    assert "coulomb_friction, input_offset" in loop.revisit_skipped
    loop.revisit_skipped = None
    add("sensor_offset", sensor=True)
    loop.chosen = ["sensor_offset", "coulomb_friction", "input_offset"]
    assert loop._branch_stands() and loop.revisit_skipped is None
    loop.chosen = ["coulomb_friction", "unknown_effect"]  # added by no step: not trusted
    assert loop._branch_stands()
