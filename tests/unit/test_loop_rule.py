"""The loop's acceptance rule and its noise-level stop, case by case.

A candidate (``hhra_phys.selection.judge``) is accepted only when all three hold: the
selection RMSE falls by the margin, the information criterion on estimation falls, and the
variance it removes exceeds what noise and structural mismatch allow,
``((1 + noise_tol)^2 - 1) * noise^2``. Each case below breaks exactly one of them. A
round runs unless the estimation and the selection residuals are both at the noise level
(``hhra_phys.selection.stops_at_noise``).
"""

from __future__ import annotations

import pytest

from hhra_phys.diagnosis.selection import COLOURED_P, Step, at_noise_level, stops_at_noise
from hhra_phys.diagnosis.selection import judge as _decide
from hhra_phys.errors import ParameterError

NOISE = 0.05


def _step(val_rmse: float, criterion: float) -> Step:
    return Step(1, "x", {}, {}, {}, {}, {"rmse": val_rmse}, criterion, 0.0, 0.0)


@pytest.mark.parametrize(
    ("rmse_cur", "val_rmse", "crit", "accepted", "why"),
    [
        (0.20, 0.10, -10.0, True, "all three hold"),
        (0.20, 0.19, -10.0, False, "a 5 % gain is below the 10 % margin"),
        (0.20, 0.21, -10.0, False, "worse on selection"),
        (0.20, 0.10, +10.0, False, "the criterion disagrees"),
        # an 11 % gain near the noise floor: less than the allowance (next test)
        (0.0600, 0.0535, -10.0, False, "removes less than the noise allowance"),
    ],
)
def test_each_condition_is_needed(rmse_cur, val_rmse, crit, accepted, why):
    step = _step(val_rmse, crit)
    assert _decide(step, rmse_cur, 0.0, NOISE, 0.1, 0.15, "bic") is accepted, why
    assert step.reason


def test_allowance_case_is_what_it_claims():
    # 0.0600^2 - 0.0535^2 = 0.000738 < ((1.15)^2 - 1) * 0.05^2 = 0.000806, with an 11 % gain
    assert 0.0535 <= 0.9 * 0.0600
    assert 0.0600 ** 2 - 0.0535 ** 2 < (1.15 ** 2 - 1) * NOISE ** 2
    # and the same gain far above the noise is accepted
    assert _decide(_step(0.0535 * 4, -1.0), 0.0600 * 4, 0.0, NOISE, 0.1, 0.15, "bic")


def _level(ratio: float, p: float) -> dict:
    return {"rmse": ratio * NOISE, "noise": NOISE, "ratio": ratio, "ljung_box_p": p,
            "white": p > 0.05}


@pytest.mark.parametrize(
    ("sel", "est", "both", "selection_only", "why"),
    [
        # the study's missed friction (seed 2, g_coulomb 8): selection 1.07 x noise,
        # estimation 1.30 x noise and coloured: the round must run
        ((1.07, 0.0), (1.30, 0.0), False, True, "estimation still shows structure"),
        ((1.01, 0.2), (0.98, 0.5), True, True, "both parts at the noise level"),
        ((1.40, 0.0), (1.00, 0.3), False, False, "selection shows structure"),
        ((1.10, 0.0), (1.30, 0.3), True, True, "a white estimation residual counts as noise"),
        ((1.30, 0.3), (1.30, 0.0), False, True, "a white selection residual alone is not enough"),
        # a cylinder lacking its seal friction (experiments/cylinder_friction.py seed 1):
        # both ratios within the allowance, the estimation residual clearly coloured
        ((0.991, 3.1e-5), (1.014, 1.4e-15), False, True,
         "a clearly coloured estimation residual is not noise, whatever its ratio"),
        ((1.01, 0.2), (1.04, 1e-4), True, True, "coloured, not clearly: the ratio decides"),
        # the one-loop gravity record (seed 5) with its true structure: the selection part,
        # scored from a re-estimated state, coloured; estimation white
        ((1.003, 1.3e-7), (0.996, 0.24), True, True,
         "the selection part keeps the ratio rule"),
    ],
)
def test_noise_stop_needs_both_non_test_parts(sel, est, both, selection_only, why):
    assert COLOURED_P == 1e-6
    level = {**_level(*sel), "estimation": _level(*est)}
    assert stops_at_noise(level, 0.15) is both, why
    # The selection part alone would have decided otherwise in some of these cases.
    assert at_noise_level(level, 0.15) is selection_only, why


@pytest.mark.parametrize("value", ["selection", "both"])
def test_the_removed_stop_on_setting_is_refused_by_name(value):
    from hhra_phys.diagnosis.options import LoopOptions

    with pytest.raises(ParameterError, match="stop_on was removed"):
        LoopOptions.of(stop_on=value)
