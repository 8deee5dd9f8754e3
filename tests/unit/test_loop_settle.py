"""A round's order and what a settled round spares (``loop._KIND_ORDER``, ``loop._SETTLES``).

The round is run by ``_Loop._refit_all`` on stand-in refits (no fits): each queued candidate
returns a step with given selection and estimation RMSEs, and the test reads which were
refitted and what the settling step's notes say.
"""

from __future__ import annotations

import pytest

from hhra_phys.loop import _KIND_ORDER, LoopOptions, _Loop
from hhra_phys.selection import Step

NOISE = 0.05
AT_NOISE = {"rmse": 0.0501}
ABOVE = {"rmse": 0.09}


class _Res:
    def __init__(self) -> None:
        self.metrics = {"val": {"rmse": 0.5}, "est": {"rmse": 0.5, "mse": 0.25}}
        self.settings = {"data": {"n_est": 512}}
        self.free = ["a", "b"]


class _Item:
    def __init__(self, name: str, entry: str = "") -> None:
        self.effect, self.entry = name, entry


def _loop(outcomes: dict[str, dict[str, float]]) -> tuple[_Loop, list[str]]:
    """A loop whose refits return a step at ``outcomes[name]`` (selection and estimation)."""
    loop = object.__new__(_Loop)
    loop.o, loop.tol, loop.say = LoopOptions(), 0.068, lambda s: None
    loop.steps, loop.settled, loop.names = [], [], []
    loop.skipped, loop.cur = {}, _Res()
    refitted: list[str] = []

    def refit_one(kind, item, library, disc):
        refitted.append(item.effect)
        out = outcomes[item.effect]
        step = Step(1, item.effect, {}, {}, {}, dict(out), dict(out), -1000.0, 0.0, 0.5)
        return step, item, ""

    loop._refit_one = refit_one
    loop._library_refits = lambda jobs: iter(())
    return loop, refitted


def _queue(*items: tuple[str, str]) -> list:
    q = [((False, _KIND_ORDER[kind], float(i)), kind,
          _Item(name, "rate:p" if kind == "discovered" else ""))
         for i, (kind, name) in enumerate(items)]
    return sorted(q, key=lambda x: x[0])


LEVEL = {"noise": NOISE, "estimation": {"noise": NOISE}}


def test_a_library_effect_at_the_noise_spares_the_discovered_terms_not_sensors_or_modes():
    loop, refitted = _loop({"valve_deadzone": AT_NOISE, "coulomb_friction": AT_NOISE,
                            "discovered_rate_p_1": AT_NOISE, "sensor_drift": ABOVE,
                            "discovered_mode_output_1": ABOVE})
    q = _queue(("discovered", "discovered_rate_p_1"), ("effect", "valve_deadzone"),
               ("mode", "discovered_mode_output_1"), ("sensor", "sensor_drift"),
               ("effect", "coulomb_friction"))
    tried = loop._refit_all(1, q, [], None, LEVEL)
    # library (effects and sensors by score) first, then discovered, then modes
    assert refitted == ["valve_deadzone", "sensor_drift", "discovered_mode_output_1"]
    assert [s.effect for s, _ in tried][0] == "valve_deadzone"
    assert loop.settled == [{"round": 1, "by": "valve_deadzone",
                             "not_refitted": ["coulomb_friction", "discovery at rate:p"]}]
    assert "library effect or discovered term" in loop.steps[0].notes[0]


def test_a_discovered_term_at_the_noise_spares_only_discovered_terms():
    loop, refitted = _loop({"valve_deadzone": ABOVE, "discovered_input_1": AT_NOISE,
                            "discovered_rate_p_1": AT_NOISE, "discovered_mode_input_1": ABOVE})
    q = _queue(("discovered", "discovered_input_1"), ("discovered", "discovered_rate_p_1"),
               ("effect", "valve_deadzone"), ("mode", "discovered_mode_input_1"))
    loop._refit_all(1, q, [], None, LEVEL)
    assert refitted == ["valve_deadzone", "discovered_input_1", "discovered_mode_input_1"]
    assert loop.settled[0]["by"] == "discovered_input_1"


@pytest.mark.parametrize("kind", ["sensor", "mode"])
def test_sensor_effects_and_modes_spare_no_physics(kind):
    first = "sensor_drift" if kind == "sensor" else "discovered_mode_output_1"
    loop, refitted = _loop({first: AT_NOISE, "valve_deadzone": AT_NOISE,
                            "discovered_rate_p_1": ABOVE})
    q = _queue((kind, first), ("effect", "valve_deadzone"),
               ("discovered", "discovered_rate_p_1"))
    loop._refit_all(1, q, [], None, LEVEL)
    # the dead zone (at the noise) then spares the discovered term
    assert first in refitted and "valve_deadzone" in refitted
    assert "discovered_rate_p_1" not in refitted


def test_a_spent_budget_ends_the_round_and_names_what_was_not_refitted():
    loop, refitted = _loop({"valve_deadzone": ABOVE, "coulomb_friction": ABOVE,
                            "discovered_rate_p_1": ABOVE})
    loop.budget_spent, loop.budget_left = False, []
    loop.o = LoopOptions(budget=5.0)
    checks = iter([False, True, True])  # spent after the first refit
    loop._over_budget = lambda: next(checks)
    q = _queue(("effect", "valve_deadzone"), ("effect", "coulomb_friction"),
               ("discovered", "discovered_rate_p_1"))
    tried = loop._refit_all(1, q, [], None, LEVEL)
    assert refitted == ["valve_deadzone"]
    assert [s.effect for s, _ in tried] == ["valve_deadzone"]  # still chosen among
    assert loop.budget_spent
    assert loop.budget_left == ["coulomb_friction", "discovery at rate:p"]
