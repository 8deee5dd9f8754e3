"""Pairs (``hhra_phys.diagnosis.pairs``): when a round accepts nothing, the refused effects on
which the criterion and the selection part contradict each other are refitted two at a time.

Here: the rule that picks them (:func:`~hhra_phys.diagnosis.selection.contradicts`), which
pairs are refitted and in what order, what a pair's refit starts from (the first effect's
refit), the loop's stage with the refits stubbed, and an accepted pair adding both effects.
The refits themselves run on real records in the drive study
(``experiments/long_records.py --records drive``, docs/diagnosis.md).
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.diagnosis import pairs as pairs_mod
from hhra_phys.diagnosis.candidates import _Job, _Outcome
from hhra_phys.diagnosis.engine import _Loop
from hhra_phys.diagnosis.fits import _Settings
from hhra_phys.diagnosis.options import LoopOptions
from hhra_phys.diagnosis.selection import DECISIVE_CRITERION, Step, contradicts

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration" / "user_models"))
import drive  # noqa: E402

RMSE_CUR, CRIT_CUR = 0.01, -1000.0


def _step(effect="coulomb_friction", rmse=0.012, crit=CRIT_CUR - 500.0, **kw) -> Step:
    return Step(1, effect, {}, {}, {}, {"rmse": 0.005}, {"rmse": rmse}, crit, CRIT_CUR,
                RMSE_CUR, **kw)


def test_a_contradiction_is_the_criterion_decisively_for_and_the_selection_error_up():
    assert contradicts(_step(), RMSE_CUR, CRIT_CUR)
    # the selection error fell (only by less than the margin): no contradiction
    assert not contradicts(_step(rmse=0.0099), RMSE_CUR, CRIT_CUR)
    # the criterion lower, but not decisively
    assert not contradicts(_step(crit=CRIT_CUR - 0.5 * DECISIVE_CRITERION), RMSE_CUR, CRIT_CUR)
    assert contradicts(_step(crit=CRIT_CUR - 2 * DECISIVE_CRITERION), RMSE_CUR, CRIT_CUR)
    # a sensor's effect, an accepted one, a backward check, a failed refit: never
    assert not contradicts(_step(sensor=True), RMSE_CUR, CRIT_CUR)
    assert not contradicts(_step(accepted=True), RMSE_CUR, CRIT_CUR)
    assert not contradicts(_step(action="keep"), RMSE_CUR, CRIT_CUR)
    assert not contradicts(_step(rmse=float("inf")), RMSE_CUR, CRIT_CUR)
    assert not contradicts(_step(crit=float("nan")), RMSE_CUR, CRIT_CUR)


def test_a_discovered_term_is_never_a_contradiction():
    class _Disc(Step):
        discovered = True

    disc = _Disc(1, "discovered_rate_v_1", {}, {}, {}, {}, {"rmse": 0.02}, CRIT_CUR - 900,
                 CRIT_CUR, RMSE_CUR)
    assert not contradicts(disc, RMSE_CUR, CRIT_CUR)


def test_the_two_lowest_contradicted_start_pairs_with_every_other_refused_effect(monkeypatch):
    monkeypatch.setattr(pairs_mod, "_pair_job", lambda a, b: (a[0], b[0]))
    # the 20 s drive's round 1: four contradicted (selection up), three not (selection down,
    # the friction's own refit not even lower in criterion on a longer record)
    rows = {"valve_deadzone": (-104031.0, 0.011), "coulomb_friction": (-101872.0, 0.013),
            "input_offset": (-95556.0, 0.0128), "constant_force": (-95557.0, 0.0128),
            "valve_saturation": (-91417.0, 0.00996), "input_delay": (-91428.0, 0.00993),
            "valve_dynamics": (CRIT_CUR + 5.0, 0.0099)}
    crit_cur, rmse_cur = -91424.9, 0.009981
    refused = [(_step(n, rmse=r, crit=c), (n, None)) for n, (c, r) in rows.items()]
    got = pairs_mod.pair_jobs(refused, rmse_cur, crit_cur)
    firsts = {a for a, _ in got}
    assert firsts == {"valve_deadzone", "coulomb_friction"}  # the two lowest contradicted
    assert len(got) == 6 + 5  # each with every other, the pair of the two once
    assert len({frozenset(p) for p in got}) == len(got)
    # both contradicted first (deadzone+friction, then each with the offsets), then the rest
    both = [p for p in got if all(n in ("valve_deadzone", "coulomb_friction", "input_offset",
                                        "constant_force") for n in p)]
    assert got[:len(both)] == both and len(both) == 5
    assert ("coulomb_friction", "constant_force") in got
    assert pairs_mod.pair_jobs(refused[4:], rmse_cur, crit_cur) == []  # none contradicted


def _record(n: int = 400) -> Dataset:
    t = np.arange(n) / 100.0
    return Dataset(t=t, u=np.sin(t), y=np.cos(t), name="r")


def _job(effect: str, model, values, free, cfg) -> _Job:
    return _Job(cfg, 1, effect, {}, model, tuple(free), dict(values), {"x0_q": 0.0}, {},
                None, None, CRIT_CUR, RMSE_CUR, (0.0, 1.0))


def test_a_pair_starts_from_the_first_effects_refit_with_its_boxes_and_shape():
    model = drive.make_model()
    ds = _record()
    cfg = _Settings(ds, ds, ds, {"k_motor": (0.1, 30.0)}, "auto", 1, 60, "fit", None, 0.5,
                    "bic")
    base_free = ["k_motor", "c_visc"]
    vals = {"k_motor": 2.0, "c_visc": 1.0}
    friction = _job("coulomb_friction", model, vals, base_free, cfg)
    force = _job("constant_force", model, vals, base_free, cfg)
    width = "v_switch"  # the friction's switching width
    a_vals = {**vals, "g_coulomb": 0.5, width: 1e-4, "k_motor": 2.1}
    out_a = _Outcome(_step(), a_vals, {"x0_q": 0.01}, [*base_free, "g_coulomb", width],
                     boxes={width: (1e-6, 2.5e-4), "g_coulomb": (0.0, 5.0)},
                     effect_kw={"fit_width": True})
    job = pairs_mod._pair_job((friction, out_a), (force, _Outcome(_step())))
    assert job.effect == "constant_force" and job.pair_with == "coulomb_friction"
    assert "coulomb_friction" in [p.name for p in job.model.parts]
    assert job.values == a_vals and job.x0 == {"x0_q": 0.01}
    assert set(job.free) == set(out_a.free)
    assert {"g_coulomb", width} <= set(job.previous)  # searched again with the force
    # the fitted width keeps its box as a bound; the other widened box stays a guessed box
    assert job.cfg.bounds[width] == (1e-6, 2.5e-4) and job.cfg.bounds["k_motor"] == (0.1, 30.0)
    assert job.cfg.default_bounds["g_coulomb"] == (0.0, 5.0)
    friction_part = next(p for p in job.model.parts if p.name == "coulomb_friction")
    assert friction_part.fit_width  # its fitted shape, not the default width


def _loop(refused, refits, pairs=True):
    loop = object.__new__(_Loop)
    loop.o = LoopOptions(pairs=pairs)
    loop.refused, loop.tol = refused, 0.01  # as _round leaves it for _pairs
    loop.say = lambda text: None
    loop._over_budget = lambda: False
    loop.cur = SimpleNamespace(metrics={"val": {"rmse": RMSE_CUR}})
    loop._library_refits = lambda jobs: iter(refits(jobs))
    loop._judge = lambda step, veto, r, c, n: step.val["rmse"] < r
    loop._rotate = lambda step, payload, ok, *a: ok
    return loop


def test_the_stage_refits_every_pair_and_keeps_the_acceptable_ones(monkeypatch):
    monkeypatch.setattr(pairs_mod, "information_criterion", lambda res, kind="bic": CRIT_CUR)
    monkeypatch.setattr(pairs_mod, "_pair_job", lambda a, b: SimpleNamespace(
        pair_with=a[0], effect=b[0]))
    refused = [(_step(n, crit=c), (n, None)) for n, c in
               (("coulomb_friction", -2000.0), ("constant_force", -1500.0),
                ("valve_deadzone", -1800.0))]

    def refits(jobs):
        for job in jobs:  # only friction and force together reach the selection part
            both = {job.pair_with, job.effect} == {"coulomb_friction", "constant_force"}
            yield _Outcome(_step(job.effect, rmse=0.001 if both else 0.02,
                                 pair=[job.pair_with, job.effect]))

    level = {"noise": 1e-6, "estimation": {"noise": 1e-6}}
    won = _loop(refused, refits)._pairs(2, level)
    assert [s.pair for s, _ in won] == [["coulomb_friction", "constant_force"]]
    assert _loop(refused, refits, pairs=False)._pairs(2, level) == []
    assert _loop(refused[:1], refits)._pairs(2, level) == []


def test_a_pair_at_the_noise_level_settles_the_pairs(monkeypatch):
    monkeypatch.setattr(pairs_mod, "information_criterion", lambda res, kind="bic": CRIT_CUR)
    monkeypatch.setattr(pairs_mod, "_pair_job", lambda a, b: SimpleNamespace(
        pair_with=a[0], effect=b[0]))
    refused = [(_step(n, crit=c), (n, None)) for n, c in
               (("coulomb_friction", -2000.0), ("constant_force", -1500.0),
                ("valve_deadzone", -1800.0))]
    seen = []

    def refits(jobs):
        for job in jobs:
            seen.append((job.pair_with, job.effect))
            step = _step(job.effect, rmse=1e-6, pair=[job.pair_with, job.effect])
            step.est = {"rmse": 1e-6}
            yield _Outcome(step)

    level = {"noise": 1e-6, "estimation": {"noise": 1e-6}}
    won = _loop(refused, refits)._pairs(2, level)
    assert len(won) == 1 and len(seen) == 1  # the first pair reached the noise: no more


def test_an_accepted_pair_adds_both_effects_first_one_first():
    loop = object.__new__(_Loop)
    loop.o = LoopOptions(backward=False, fit_shapes="off")
    loop.chosen, loop.steps, loop.cfg = [], [], None
    loop.say = lambda text: None
    loop._accepted_fit = lambda step, payload: (None, [], {}, {}, None)
    loop._polish = lambda *a: None
    loop._library_forms = lambda rnd: None
    step = _step("constant_force", pair=["coulomb_friction", "constant_force"])
    loop._accept(1, step, object())
    assert loop.chosen == ["coulomb_friction", "constant_force"]
