"""The one rule's tie rule (``choose``) and round settling (``round_settled``), case by case.

Every number below is worked out by hand from the rule's definitions: the noise allowance is
``((1 + noise_tol)^2 - 1) * noise^2``; candidates within it of the best selection RMSE are
told apart by the information criterion; a round is settled by an acceptable candidate at
``(1 + noise_tol)`` times the noise level on both parts.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hhra_phys.diagnosis.selection import (
    Step,
    choose,
    noise_allowance,
    noise_tolerance,
    round_settled,
    tie_break,
)
from hhra_phys.errors import ParameterError

NOISE = 0.05
TOL = 0.15


def _step(name: str, sel: float, crit: float, est: float | None = None,
          sensor: bool = False) -> Step:
    return Step(1, name, {}, {}, {}, {"rmse": est if est is not None else sel},
                {"rmse": sel}, crit, 0.0, 1.0, reason="r", sensor=sensor)


def test_lowest_selection_wins_when_the_others_are_clearly_worse():
    # 0.10^2 - 0.08^2 = 0.0036 > allowance 0.000806: no tie; the criterion is not asked
    a, b = _step("a", 0.08, 50.0), _step("b", 0.10, -50.0)
    assert noise_allowance(NOISE, TOL) == pytest.approx(0.000806, rel=1e-3)
    step, payload = choose([(b, "B"), (a, "A")], NOISE, TOL)
    assert step is a and payload == "A"
    assert a.accepted and a.reason.startswith("accepted: ")
    assert not b.accepted and "a higher selection error" in b.reason


def test_near_tie_goes_to_the_lower_criterion():
    # 0.060^2 - 0.055^2 = 0.000575 <= 0.000806: the selection part cannot tell them apart
    a, b = _step("a", 0.055, 10.0), _step("b", 0.060, 5.0)
    step, _ = choose([(a, 1), (b, 2)], NOISE, TOL)
    assert step is b
    assert "within the noise allowance" in a.reason and "higher BIC" in a.reason


def test_no_noise_level_means_no_tie_allowance():
    a, b = _step("a", 0.0550, 10.0), _step("b", 0.0551, 5.0)
    step, _ = choose([(a, 1), (b, 2)], math.nan, TOL)
    assert step is a  # without a noise level every difference counts


def test_a_non_finite_selection_error_never_wins_a_tie():
    a, b = _step("a", math.inf, -1e9), _step("b", 0.2, 0.0)
    assert choose([(a, 1), (b, 2)], NOISE, TOL)[0] is b


def test_choose_needs_a_candidate():
    with pytest.raises(ParameterError):
        choose([], NOISE, TOL)


@pytest.mark.parametrize(
    ("sel", "est", "accepted", "settled", "why"),
    [
        (0.055, 0.056, True, True, "both parts within 1.15 x noise"),
        (0.055, 0.060, True, False, "estimation above 1.15 x noise (0.0575)"),
        (0.060, 0.050, True, False, "selection above 1.15 x noise"),
        (0.050, 0.050, False, False, "an unacceptable candidate settles nothing"),
    ],
)
def test_round_settled(sel, est, accepted, settled, why):
    assert round_settled(_step("x", sel, 0.0, est), NOISE, NOISE, TOL, accepted) is settled, why


def test_round_settled_uses_each_parts_own_noise_level():
    step = _step("x", 0.055, 0.0, est=0.11)
    assert not round_settled(step, NOISE, NOISE, TOL, True)
    assert round_settled(step, NOISE, 0.10, TOL, True)  # estimation noise 0.10: 0.11 <= 0.115
    assert not round_settled(step, math.nan, 0.10, TOL, True)  # no noise level: no settling


def test_settling_cannot_hide_a_clear_winner():
    """The reason the skip is safe: a settled candidate's selection variance is within the
    allowance of any candidate's best possible, the noise variance itself."""
    best_possible = NOISE  # no model gets a part below its noise level
    settled = (1 + TOL) * NOISE
    assert settled ** 2 - best_possible ** 2 <= noise_allowance(NOISE, TOL) + 1e-15


def test_a_given_effect_keeps_a_tie_with_a_discovered_term_at_its_entry():
    from hhra_phys.diagnosis.discovery import DiscoveredStep

    lib = _step("valve_deadzone", 0.0512, -100.0)
    lib.entry = "input"
    term = DiscoveredStep(1, "discovered_input_1", {}, {}, {}, {"rmse": 0.0505},
                          {"rmse": 0.0505}, -120.0, 0.0, 1.0, reason="r", entry="input")
    # tied (0.0512^2 - 0.0505^2 << allowance) and the term has the lower BIC: the effect
    assert choose([(term, 1), (lib, 2)], NOISE, TOL)[0] is lib
    # at another entry the criterion decides as before
    other = DiscoveredStep(1, "discovered_rate_omega_1", {}, {}, {}, {"rmse": 0.0505},
                           {"rmse": 0.0505}, -120.0, 0.0, 1.0, reason="r", entry="rate:omega")
    lib2 = _step("valve_deadzone", 0.0512, -100.0)
    lib2.entry = "input"
    assert choose([(other, 1), (lib2, 2)], NOISE, TOL)[0] is other
    # beyond the allowance the clearly better term wins whatever its entry
    term3 = DiscoveredStep(1, "discovered_input_1", {}, {}, {}, {"rmse": 0.05},
                           {"rmse": 0.05}, -120.0, 0.0, 1.0, reason="r", entry="input")
    lib3 = _step("valve_deadzone", 0.09, -100.0)
    lib3.entry = "input"
    assert choose([(term3, 1), (lib3, 2)], NOISE, TOL)[0] is term3


def test_a_sensor_effect_keeps_a_tie_with_a_change_of_the_dynamics():
    # the drift record's round: the valve bias has the lower BIC, the drift the lower
    # selection error, the two within the allowance: the sensor's explanation is kept
    valve = _step("asymmetric_valve", 0.05273, -5957.1)
    drift = _step("sensor_drift", 0.05246, -5952.1, sensor=True)
    assert choose([(valve, 1), (drift, 2)], NOISE, TOL)[0] is drift
    assert "tied with a sensor effect" in valve.reason
    # a dynamics change clearly better on selection still wins
    valve2 = _step("asymmetric_valve", 0.050, -5957.1)
    drift2 = _step("sensor_drift", 0.080, -5952.1, sensor=True)
    assert choose([(drift2, 2), (valve2, 1)], NOISE, TOL)[0] is valve2
    # decisive evidence for the dynamics (criterion lower by more than 10) overrides it:
    # the two-tank side inflow against a level offset
    inflow = _step("side_inflow", 0.05102, -4783.5)
    offset = _step("sensor_offset", 0.05212, -4771.2, sensor=True)
    assert choose([(offset, 1), (inflow, 2)], NOISE, TOL)[0] is inflow
    assert "higher BIC" in offset.reason
    # among sensor effects the criterion decides as before
    off = _step("sensor_offset", 0.0525, -5960.0, sensor=True)
    drift3 = _step("sensor_drift", 0.0524, -5952.1, sensor=True)
    assert choose([(drift3, 1), (off, 2)], NOISE, TOL)[0] is off


def test_only_a_given_change_of_the_dynamics_is_decisive_against_a_sensor_effect():
    from hhra_phys.diagnosis.discovery import DiscoveredStep

    # a resonator read as foh: the other inter-sample behaviour (marked sensor) tied with a
    # discovered output feedthrough whose BIC is lower by 17.7; the search over shapes is
    # not charged, so the measurement's explanation is kept
    hold = _step("intersample:cubic", 0.04885, -6426.9, sensor=True)
    term = DiscoveredStep(2, "discovered_output_2", {}, {}, {}, {"rmse": 0.04859},
                          {"rmse": 0.04859}, -6444.6, 0.0, 1.0, reason="r", entry="output")
    assert choose([(term, 1), (hold, 2)], NOISE, TOL)[0] is hold
    assert "tied with a sensor effect" in term.reason
    # a given change with the same evidence is decisive (more than 10 lower), as before
    given = _step("output_feedthrough", 0.04859, -6444.6)
    hold2 = _step("intersample:cubic", 0.04885, -6426.9, sensor=True)
    assert choose([(hold2, 2), (given, 1)], NOISE, TOL)[0] is given
    # with a decisive given change among them, the criterion decides among all tied
    term2 = DiscoveredStep(2, "discovered_output_2", {}, {}, {}, {"rmse": 0.0486},
                           {"rmse": 0.0486}, -6450.0, 0.0, 1.0, reason="r", entry="output")
    given2 = _step("output_feedthrough", 0.04859, -6444.6)
    hold3 = _step("intersample:cubic", 0.04885, -6426.9, sensor=True)
    assert choose([(hold3, 2), (given2, 1), (term2, 3)], NOISE, TOL)[0] is term2


def test_sensor_flag_round_trips_through_json():
    from hhra_phys.diagnosis.result import _step_from_json

    s = _step("sensor_drift", 0.05, -1.0, sensor=True)
    assert _step_from_json(s.to_json()).sensor is True
    assert _step_from_json(_step("gravity_load", 0.05, -1.0).to_json()).sensor is False


def test_tie_break_follows_choose_on_bare_fits():
    # the same numbers as the near-tie case: tied on selection, the lower criterion wins
    assert tie_break([(0.055, 10.0), (0.060, 5.0)], NOISE, TOL) == 1
    # clearly worse on selection (0.10^2 - 0.08^2 > allowance): the criterion is not asked
    assert tie_break([(0.10, -50.0), (0.08, 50.0)], NOISE, TOL) == 1
    # a fit that could not be simulated never wins over a finite one
    assert tie_break([(math.nan, -1e9), (0.2, 0.0)], NOISE, TOL) == 1
    with pytest.raises(ParameterError, match="at least one"):
        tie_break([], NOISE, TOL)


def test_tie_break_keeps_a_preferred_fit_only_in_a_tie():
    # the drag record: a pressure form (lower BIC) tied with a velocity form (preferred)
    fits = [(0.05192, -5979.4), (0.05145, -5976.1)]
    assert tie_break(fits, 0.0573, 0.068) == 0
    assert tie_break(fits, 0.0573, 0.068, prefer=[False, True]) == 1
    # no preferred fit among the tied: the criterion decides as before
    assert tie_break(fits, 0.0573, 0.068, prefer=[False, False]) == 0
    # a preferred fit clearly worse on selection is not tied: it does not win
    assert tie_break([(0.05, 0.0), (0.09, -100.0)], NOISE, TOL, prefer=[False, True]) == 0
    with pytest.raises(ParameterError, match="prefer has 1 entries for 2 fits"):
        tie_break(fits, NOISE, TOL, prefer=[True])


@pytest.mark.parametrize(("n", "tol"), [(400, 0.0684), (1200, 0.0400), (2, 0.7321)])
def test_noise_tolerance_from_the_sample_count(n, tol):
    # sqrt(1 + 2*sqrt(2/n)) - 1 by hand: 400 -> sqrt(1.14142) - 1
    assert noise_tolerance(n) == pytest.approx(tol, abs=1e-4)
    assert noise_tolerance(4 * n) < noise_tolerance(n)


def test_noise_tolerance_covers_white_noise_and_refuses_no_samples():
    # The ratio rmse^2 / noise_level^2 of white noise stays within the derived allowance
    # in at least 95 % of 200 draws (the level estimated from the same samples).
    from hhra_phys.noise import noise_level

    n = 400
    t = np.linspace(0, 8, n)
    u, y = np.sign(np.sin(2 * np.pi * 0.7 * t)), np.sin(2 * np.pi * 0.3 * t)
    lim = (1 + noise_tolerance(n)) ** 2
    inside = 0
    for k in range(200):
        r = np.random.default_rng(k).standard_normal(n)
        inside += np.mean(r ** 2) / noise_level(r, (u, y)) ** 2 <= lim
    assert inside >= 190
    with pytest.raises(ParameterError, match="n=0"):
        noise_tolerance(0)
