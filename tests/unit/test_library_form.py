"""A discovered term that holds a library effect's shape is tried in its library form
(``_Loop._library_forms``): which terms and which twins, and when not.

The refit and the verdict themselves run on real records in the drive study
(``experiments/long_records.py --records drive``, docs/diagnosis.md); here the choice of
what is tried, with the refit stubbed.
"""

from __future__ import annotations

from hhra_phys.diagnosis.engine import _Loop
from hhra_phys.diagnosis.options import LoopOptions
from hhra_phys.diagnosis.selection import Step


class _Disc(Step):
    discovered = True


def _step(effect: str, same_as=(), accepted=True, action="add") -> Step:
    cls = _Disc if same_as else Step
    s = cls(1, effect, {}, {}, {}, {"rmse": 1.0}, {"rmse": 1.0}, 0.0, 0.0, 1.0,
            accepted=accepted, action=action)
    s.same_as = list(same_as)
    return s


def _loop(chosen, steps, names, dropped=(), backward=True):
    loop = object.__new__(_Loop)
    loop.o = LoopOptions(backward=backward, candidates=list(names))
    # this round's list: the twins skipped as redundant beside their discovered form
    loop.chosen, loop.steps, loop.names = list(chosen), list(steps), ["sensor_drift"]
    loop.dropped = list(dropped)
    loop.budget_end = None
    tried = []
    loop._over_budget = lambda: False
    loop._try_library_form = lambda rnd, name, twins: tried.append((name, twins))
    return loop, tried


NAMES = ["coulomb_friction", "constant_force", "input_offset", "sensor_drift"]


def test_a_term_is_tried_as_the_twins_the_model_lacks():
    # offered by the user, though not in this round's list (redundant beside the term)
    steps = [_step("discovered_rate_v_1", ["coulomb_friction", "constant_force"]),
             _step("coulomb_friction")]
    loop, tried = _loop(["discovered_rate_v_1", "coulomb_friction"], steps, NAMES)
    loop._library_forms(2)
    assert tried == [("discovered_rate_v_1", ["constant_force"])]


def test_nothing_is_tried_without_a_twin_to_add():
    # the twin already in the model, or not among the candidates offered, or dropped
    steps = [_step("discovered_input_1", ["input_offset"]), _step("input_offset")]
    for chosen, names, dropped in (
            (["discovered_input_1", "input_offset"], NAMES, ()),
            (["discovered_input_1"], ["coulomb_friction"], ()),
            (["discovered_input_1"], NAMES, ("input_offset",))):
        loop, tried = _loop(chosen, steps, names, dropped)
        loop._library_forms(2)
        assert tried == [], (chosen, names, dropped)


def test_only_accepted_added_terms_with_the_backward_step_on():
    steps = [_step("discovered_input_1", ["input_offset"], accepted=False)]
    loop, tried = _loop(["discovered_input_1"], steps, NAMES)
    loop._library_forms(1)
    assert tried == []  # its step was not the accepted one
    steps = [_step("discovered_input_1", ["input_offset"])]
    loop, tried = _loop(["discovered_input_1"], steps, NAMES, backward=False)
    loop._library_forms(1)
    assert tried == []
    loop, tried = _loop(["discovered_input_1"], steps, NAMES)
    loop._library_forms(1)
    assert tried == [("discovered_input_1", ["input_offset"])]
