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

from hhra_phys.selection import Step, acceptance, backward_decision

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
