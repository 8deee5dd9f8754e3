"""A group outside its default box: every fit path widens that side and refits.

The rig of ``experiments/widen_box.py`` has ``g_damping`` 28 times nominal. Measured there
(5 seeds, 8 s records, pop 30, 40 it., docs/fitting.md): without widening b/c is 13-20 % off
in 5/5 seeds on every path, with it below 5 % in 5/5 for a single-record fit (median
1.1 %), the diagnosis loop's base fit (a given ``Problem``; the same 5/5, median 1.1 %) and
a fit of two records at once (5/5, median 0.9 %). The tests ask for 2 of 3 seeds.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from hhra_phys.diagnosis.engine import augment
from hhra_phys.fit import fit
from hhra_phys.models.hhra.model import HHRAModel
from hhra_phys.models.hhra.rig import simulate_rig

_SPEC = importlib.util.spec_from_file_location(
    "widen_box", Path(__file__).resolve().parents[2] / "experiments" / "widen_box.py")
widen_box = importlib.util.module_from_spec(_SPEC)  # type: ignore[arg-type]
_SPEC.loader.exec_module(widen_box)  # type: ignore[union-attr]


def _bc_error(res, truth) -> float:
    tf = HHRAModel().tf_coefficients_of(truth)
    return abs((res.tf["b"] / res.tf["c"]) / (tf["b"] / tf["c"]) - 1)


@pytest.mark.parametrize(("seeds", "need"), [
    pytest.param((0,), 1, id="seed0"),
    pytest.param((0, 1, 2), 2, id="seeds0-2", marks=pytest.mark.slow),
])
def test_a_group_beyond_its_default_box_is_recovered_by_widening(seeds, need) -> None:
    """Seed 0 in the default run; the rate over seeds 0-2 (and the loop's and the
    several-record paths' rates below) are slow."""
    good = 0
    for seed in seeds:
        data = simulate_rig(seed=seed, duration=8.0, physical=widen_box.heavy_damping())
        res = fit(data, pop_size=30, max_iter=40, seed=seed)
        sides = {(w["name"], w["side"]) for w in res.settings["widened"]}
        assert ("g_damping", "upper") in sides
        assert any("that side was widened by" in w for w in res.warnings)
        assert not any("ended at its" in w for w in res.warnings)
        truth = data.metadata["true_params"]["g_damping"]
        assert res.settings["bounds"]["g_damping"][1] > truth  # the box now holds the truth
        good += _bc_error(res, data.metadata["true_params"]) < 0.05
    assert good >= need


@pytest.mark.parametrize("seed", [2, 3])
def test_a_signed_effect_parameter_beyond_its_box_is_widened_and_recovered(seed) -> None:
    """A gravity load of 300 rad/s^2 (the effect's box is +-105) on the independent
    reference rig: the coefficient's side is moved ten times as far from zero and the fit
    recovers it (measured on seeds 1 and 2 before the test was written: 305 and 308; the
    test runs seeds 2 and 3 and asks for 10 %),
    while the side of its box at zero-crossing stays where it was."""
    from hhra_phys.effects import make_effect
    from hhra_phys.problem import default_free
    from hhra_phys.reference import reference_record

    data = reference_record(seed, duration=8.0, noise_deg=0.05, effects={
        "gravity_load": {"g_grav_sin": 300.0, "g_grav_cos": -60.0}})
    model = HHRAModel().with_parts(make_effect("gravity_load", data=data))
    res = fit(data, model, free=default_free(model), pop_size=30, max_iter=40, seed=seed)
    grav = [w for w in res.settings.get("widened", []) if w["name"] == "g_grav_sin"]
    assert grav and grav[0]["side"] == "upper"
    assert grav[0]["to"][0] == grav[0]["from"][0]  # the other side is untouched
    assert grav[0]["to"][1] == pytest.approx(10 * grav[0]["from"][1])
    assert res.values["g_grav_sin"] == pytest.approx(300.0, rel=0.1)
    assert res.metrics["val"]["rmse"] < 1.5 * 0.05


def test_explicit_bounds_are_never_widened() -> None:
    data = simulate_rig(seed=0, duration=6.0, physical=widen_box.heavy_damping())
    nominal = HHRAModel().params["g_damping"]
    box = (nominal.lower, nominal.upper)
    res = fit(data, pop_size=20, max_iter=20, seed=0, bounds={"g_damping": box})
    assert res.settings["bounds"]["g_damping"] == list(box)
    assert all(w["name"] != "g_damping" for w in res.settings.get("widened", []))
    assert any(w.startswith("g_damping ended at its upper bound") for w in res.warnings)


@pytest.mark.slow
def test_the_loop_base_fit_widens_and_recovers() -> None:
    good = 0
    for seed in range(3):
        data = simulate_rig(seed=seed, duration=8.0, physical=widen_box.heavy_damping())
        res = augment(data, HHRAModel(), candidates=[], pop_size=30, max_iter=40, seed=seed,
                      test=0.0, discover=False)
        widened = res.to_json()["base"]["widened"]  # the loop's JSON says it
        assert ("g_damping", "upper") in {(w["name"], w["side"]) for w in widened}
        assert any("that side was widened by" in w for w in res.base.warnings)
        good += _bc_error(res.base, data.metadata["true_params"]) < 0.05
    assert good >= 2


@pytest.mark.slow
def test_a_two_record_fit_widens_and_recovers() -> None:
    good = 0
    for seed in range(3):
        records = [simulate_rig(seed=s, duration=8.0, physical=widen_box.heavy_damping())
                   for s in (seed, seed + 100)]
        res = fit(records, model=HHRAModel(), pop_size=30, max_iter=40, seed=seed)
        sides = {(w["name"], w["side"]) for w in res.settings["widened"]}
        assert ("g_damping", "upper") in sides
        assert not any("ended at its" in w for w in res.warnings)
        good += _bc_error(res, records[0].metadata["true_params"]) < 0.05
    assert good >= 2


def test_explicit_bounds_of_a_two_record_fit_are_never_widened() -> None:
    records = [simulate_rig(seed=s, duration=3.0, physical=widen_box.heavy_damping())
               for s in (0, 1)]
    nominal = HHRAModel().params["g_damping"]
    box = (nominal.lower, nominal.upper)
    res = fit(records, model=HHRAModel(), pop_size=10, max_iter=10, seed=0,
              bounds={"g_damping": box})
    assert res.settings["bounds"]["g_damping"] == list(box)
    assert all(w["name"] != "g_damping" for w in res.settings.get("widened", []))
    assert any(w.startswith("g_damping ended at its upper bound") for w in res.warnings)


def test_a_start_beyond_a_default_box_widens_it_by_whole_decades() -> None:
    """A candidate warm-started at a widened base fit keeps its start inside its box."""
    from hhra_phys.problem import MAX_WIDEN_DECADES, Problem

    data = simulate_rig(seed=0, duration=2.0)
    par = HHRAModel().params["g_damping"]
    p = Problem(HHRAModel(), data, start={"g_damping": 28 * par.upper})
    box = next(q for q in p.free_params if q.name == "g_damping")
    assert (box.lower, box.upper) == pytest.approx((par.lower, 100 * par.upper))
    assert p.widened[0]["reason"] == "start" and p.widened[0]["decades"] == 2
    far = Problem(HHRAModel(), data, start={"g_damping": 1e9 * par.upper})
    box = next(q for q in far.free_params if q.name == "g_damping")
    assert box.upper == pytest.approx(par.upper * 10**MAX_WIDEN_DECADES)
    given = Problem(HHRAModel(), data, bounds={"g_damping": (par.lower, par.upper)},
                    start={"g_damping": 28 * par.upper})
    assert not given.widened
    assert next(q for q in given.free_params if q.name == "g_damping").upper == par.upper


def test_the_loops_default_bounds_widen_and_its_bounds_do_not() -> None:
    """``augment(default_bounds=...)`` (the CLI's boxes for a record) widen; ``bounds`` never."""
    data = simulate_rig(seed=0, duration=6.0, physical=widen_box.heavy_damping())
    nominal = HHRAModel().params["g_damping"]
    box = {"g_damping": (nominal.lower, nominal.upper)}
    kw = {"candidates": [], "pop_size": 20, "max_iter": 20, "seed": 0, "test": 0.0,
          "discover": False}
    given = augment(data, HHRAModel(), default_bounds=box, **kw)
    assert ("g_damping", "upper") in {(w["name"], w["side"])
                                      for w in given.to_json()["base"].get("widened", [])}
    fixed = augment(data, HHRAModel(), bounds=box, **kw)
    assert all(w["name"] != "g_damping" for w in fixed.to_json()["base"].get("widened", []))



def _candidate_step(data, effect: str):
    res = augment(data, HHRAModel(), candidates=[effect], discover=False, max_effects=1,
                  backward=False, intersample=False, pop_size=30, max_iter=40, seed=0,
                  background=False)
    return next(s for s in res.steps if s.effect == effect)


@pytest.mark.parametrize(("effect", "name", "hidden", "seed"), [
    pytest.param("valve_deadzone", "i_dead",
                 {"gravity_load": {"g_grav_cos": 10.0, "g_grav_sin": -15.0}}, 2,
                 id="dead_band-gravity"),
    pytest.param("backlash", "play", {"valve_deadzone": {"i_dead": 0.1}}, 1,
                 id="play-dead_zone", marks=pytest.mark.slow),  # a stiff candidate
])
def test_a_candidate_parameter_the_record_does_not_see_at_its_edge_is_not_widened(
        effect, name, hidden, seed) -> None:
    """A dead band or a play on a record without one (another effect hidden) shrinks to the
    lower edge of its box (the default one, or the one opened to the first-order estimate),
    where the record does not see it (flat profile): that side is not widened, while base
    groups the record sees at their edges still are."""
    from hhra_phys.effects import make_effect
    from hhra_phys.reference import reference_record

    data = reference_record(seed, duration=8.0, effects=hidden)
    step = _candidate_step(data, effect)
    par = HHRAModel().with_parts(make_effect(effect)).params[name]
    first = step.evidence["estimate"][name]
    lower = max(min(par.lower, first), par.lower / 10) if first > 0 else par.lower
    assert step.params[name] == pytest.approx(lower, rel=1e-3)  # at its edge
    assert not any(n.startswith(f"{name} ended at its box edge") for n in step.notes)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2])
def test_a_candidate_parameter_the_data_pull_out_of_its_box_is_widened(seed) -> None:
    """The gravity family of experiments/one_loop.py (300 rad/s^2 against the effect's box of
    +-105, damping beyond the base box): the coefficient stops at its box edge, where the
    record sees it; that side is widened and the candidate searched again."""
    from hhra_phys.reference import reference_record

    data = reference_record(seed, duration=8.0, noise_deg=0.05, params={"g_damping": 60.0},
                            effects={"gravity_load": {"g_grav_sin": 300.0,
                                                      "g_grav_cos": -60.0}})
    step = _candidate_step(data, "gravity_load")
    assert any(n.startswith("g_grav_sin ended at its box edge; box widened") for n in step.notes)
    assert step.params["g_grav_sin"] > 105
