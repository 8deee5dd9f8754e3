"""Contiguous folds of the loop's rotation (``hhra_phys.diagnosis.folds``), the short-part
trigger (``selection.thin_parts``), and the loop's k-fold verdict (``_Loop._rotate``)."""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hhra_phys.data import Dataset
from hhra_phys.diagnosis import rotation as rotation_mod
from hhra_phys.diagnosis.engine import _Loop
from hhra_phys.diagnosis.fits import _Settings
from hhra_phys.diagnosis.folds import MAX_FOLDS, fold_plan
from hhra_phys.diagnosis.options import LoopOptions
from hhra_phys.diagnosis.selection import (
    REGIME_MIN_SAMPLES,
    Step,
    needs_rotation,
    pooled_rmse,
    split_record,
    thin_part,
    thin_parts,
)
from hhra_phys.errors import ParameterError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration" / "user_models"))
import drive  # noqa: E402


def _record(n: int = 1000, name: str = "r") -> Dataset:
    t = np.arange(n) / 100.0
    return Dataset(t=t, u=np.sin(t), y=np.arange(n, dtype=float), name=name)


def _span(ds: Dataset) -> tuple[int, int]:
    """A part's first and one-past-last sample in its record (y holds the index)."""
    return int(ds.y[0]), int(ds.y[-1]) + 1


def test_two_folds_swap_the_parts_themselves():
    est, sel, _ = split_record(_record(), 0.5, 0.25)
    (fold,) = fold_plan([est], [sel], 2)
    assert fold.name == "est" and fold.train == [sel] and fold.held == [est]
    assert fold.train[0] is sel and fold.held[0] is est  # the same parts, not copies
    assert fold.n_held == est.n


def test_three_folds_hold_each_estimation_block_out_and_train_on_the_rest():
    est, sel, _ = split_record(_record(1000), 0.5, 0.25)  # est 0:500, sel 500:750
    f1, f2 = fold_plan([est], [sel], 3)
    # block 1 out: the rest of the record is one piece (block 2 then selection)
    assert f1.name == "est 1/2" and [_span(p) for p in f1.train] == [(250, 750)]
    assert [_span(h) for h in f1.held] == [(0, 250)]
    # block 2 out: two pieces, the block before it and the selection part after it
    assert [_span(p) for p in f2.train] == [(0, 250), (500, 750)]
    assert _span(f2.held[0]) == (250, 500) and f2.held[1] is None
    assert f1.n_held + f2.n_held == est.n
    # every held block knows where it sits in the record (its leading window reads there)
    assert f2.held[0].origin[1] == 250 and f2.train[1].origin[1] == 500
    # no fold trains on the samples it holds out, and together they hold out estimation
    for f in (f1, f2):
        held = set(range(*_span(f.held[0])))
        assert not any(held & set(range(*_span(p))) for p in f.train)


def test_more_folds_and_several_records():
    parts = [split_record(_record(n, f"r{n}"), 0.5, 0.25) for n in (1200, 800)]
    est, sel = [p[0] for p in parts], [p[1] for p in parts]
    folds = fold_plan(est, sel, 4)
    assert [f.name for f in folds] == ["est 1/3", "est 2/3", "est 3/3"]
    mid = folds[1]  # each record: the block before, then the rest with its selection part
    assert [_span(p) for p in mid.train] == [(0, 200), (400, 900), (0, 133), (266, 600)]
    assert [None if h is None else _span(h) for h in mid.held] == [(200, 400), None,
                                                                   (133, 266), None]
    assert sum(f.n_held for f in folds) == sum(e.n for e in est)
    last = folds[-1]  # the last block takes the rest, its training pieces are the rest
    assert _span(last.held[0]) == (400, 600) and _span(last.train[0]) == (0, 400)


def test_parts_that_are_not_adjacent_stay_separate_pieces():
    a, b = _record(600, "a"), _record(600, "b")
    est, sel = a.slice(0, 300), b.slice(300, 450)  # selection from another record
    f1, _ = fold_plan([est], [sel], 3)
    assert [p.name for p in f1.train] == [est.slice(150, 300).name, sel.name]
    assert len(f1.held) == 2 and f1.held[1] is None


@pytest.mark.parametrize("k", [1, MAX_FOLDS + 1, 2.5, "3"])
def test_fold_counts_out_of_range_are_refused(k):
    est, sel, _ = split_record(_record(), 0.5, 0.25)
    with pytest.raises(ParameterError, match="folds"):
        fold_plan([est], [sel], k)
    with pytest.raises(ParameterError, match="folds"):
        LoopOptions(folds=k).validate()
    with pytest.raises(ParameterError, match="folds"):
        LoopOptions(folds=True).validate()


def test_folds_the_estimation_part_is_too_short_for_are_refused_before_any_fit():
    est, sel, _ = split_record(_record(160), 0.5, 0.25)  # 80 estimation samples
    assert len(fold_plan([est], [sel], 5)) == 4  # blocks of 20
    with pytest.raises(ParameterError, match="fewer than 20 samples"):
        fold_plan([est], [sel], 6)
    with pytest.raises(ParameterError, match="fewer than 20 samples"):
        _Loop(_record(160), drive.make_model(), LoopOptions(folds=6), None, None, None, None)


def _regime(est_in: float, sel_in: float, n_est: int = 2000, n_sel: int = 1000) -> dict:
    total = est_in * n_est + sel_in * n_sel
    return {p: {"samples": n, "in_regime": f, "share": f * n / total}
            for p, n, f in (("est", n_est, est_in), ("sel", n_sel, sel_in))}


def test_a_part_with_too_few_regime_samples_cannot_refuse_alone():
    # in proportion (neither thin by share), but the selection part holds 30 samples
    reg = _regime(0.03, 0.03)
    assert 1000 * 0.03 < REGIME_MIN_SAMPLES <= 2000 * 0.03
    assert thin_parts(reg) == ("sel",) and thin_part(reg) == "sel"
    assert needs_rotation(False, True, thin_parts(reg))  # the selection part refuses
    assert not needs_rotation(True, False, thin_parts(reg))  # estimation refuses: it can
    # a short record: both parts hold little; either may not refuse alone
    short = _regime(0.02, 0.02)
    assert thin_parts(short) == ("est", "sel")
    assert needs_rotation(True, False, thin_parts(short))
    # enough samples in both, in proportion: nothing is thin
    assert thin_parts(_regime(0.2, 0.2)) == ()
    assert not needs_rotation(False, True, ())


class _Res:
    def __init__(self, val: float) -> None:
        self.metrics = {"val": {"rmse": val}, "est": {"rmse": val, "mse": val * val}}
        self.values, self.x0, self.records = {}, {}, []


def test_the_loop_pools_every_fold_and_fits_each_model_once_per_fold(monkeypatch):
    est, sel, _ = split_record(_record(1000), 0.5, 0.25)
    loop = object.__new__(_Loop)
    loop.o, loop.tol, loop.say = LoopOptions(folds=3), 0.068, lambda s: None
    loop.cur, loop.cur_free = _Res(0.5), []
    loop.cur_prob = type("P", (), {"model": object()})()
    loop.est, loop.sel = est, sel
    loop.cfg, loop._rot_cache, loop._fold_cache = None, None, None
    calls = []
    scores = {("cur", "est 1/2"): 1.4, ("cur", "est 2/2"): 1.6,
              ("cand", "est 1/2"): 0.3, ("cand", "est 2/2"): 0.5}

    def fold_fit(cfg, fold, model, free, start, boxes):
        who = "cur" if model is loop.cur_prob.model else "cand"
        calls.append((who, fold.name))
        return _Res(scores[who, fold.name])

    monkeypatch.setattr(rotation_mod, "_fold_fit", fold_fit)
    monkeypatch.setattr(rotation_mod, "_fitted_candidate",
                        lambda payload: ("cand-model", ["a"], {}, {}, {}))
    monkeypatch.setattr(_Loop, "_change_regime",
                        lambda self, fitted, payload=None: _regime(0.2, 0.02, 500, 250))
    step = Step(1, "cand", {}, {}, {}, {"rmse": 0.49}, {"rmse": 0.49}, -100.0, 0.0, 0.5)
    ok = loop._rotate(step, object(), False, 0.5, 0.0, 0.05, 0.05)
    assert ok and step.folds["k"] == 3 and step.folds["accepted"]
    assert calls == [("cur", "est 1/2"), ("cur", "est 2/2"),
                     ("cand", "est 1/2"), ("cand", "est 2/2")]
    assert [b["held"] for b in step.folds["blocks"]] == ["sel", "est 1/2", "est 2/2"]
    assert step.folds["rmse_before"] == pytest.approx(
        pooled_rmse([(250, 0.5), (250, 1.4), (250, 1.6)]))
    assert step.folds["est"]["rmse_after"] == pytest.approx(pooled_rmse([(250, 0.3),
                                                                        (250, 0.5)]))
    assert "3 contiguous folds" in step.reason and "3 folds" in step.reason
    assert "holds only 5 samples of its regime" in step.folds["why"]
    # the current model's folds are fitted once per current fit
    loop._rotate(replace(step, folds=None, reason=""), object(), False, 0.5, 0.0, 0.05, 0.05)
    assert [c for c in calls if c[0] == "cur"] == [("cur", "est 1/2"), ("cur", "est 2/2")]


def test_a_fold_fit_on_two_pieces_scores_its_held_block_at_the_noise():
    """The current model refitted on each fold of a drive record (the multi-piece path:
    one initial state a piece) predicts the block it did not see, from its own start."""
    noise = 0.002
    data = drive.simulate_record(seed=3, n=1600, noise=noise)
    est, sel, _ = split_record(data, 0.5, 0.25)
    model = drive.make_model()
    cfg = _Settings(est, sel, data, {}, "auto", 1, 60, "fit", None, 0.5, "bic")
    start = {"k_motor": 2.0, "c_visc": 5.0}
    for fold in fold_plan([est], [sel], 3):
        res = rotation_mod._fold_fit(cfg, fold, model, ["k_motor", "c_visc"], start, {})
        assert res.values["k_motor"] == pytest.approx(drive.TRUTH["k_motor"], rel=0.02)
        assert res.values["c_visc"] == pytest.approx(drive.TRUTH["c_visc"], rel=0.05)
        val = res.metrics["val"]["rmse"]
        assert math.isfinite(val) and val < 1.5 * noise, (fold.name, val)


def test_a_later_piece_fits_every_states_start_an_early_one_the_models():
    from hhra_phys.diagnosis.folds import LaterStartProblem
    from hhra_phys.problem import Problem

    data = drive.simulate_record(seed=1, n=800)
    early, later = data.slice(0, 400), data.slice(400, 800)
    model = drive.make_model()
    assert model.fitted_states == ["q"]  # the user's drive starts at rest
    plain = Problem(model, [early, later], free=["k_motor"], initial_state="fit")
    assert plain.free_names == ["k_motor", "x0_q_rec1", "x0_q_rec2"]
    fold = LaterStartProblem(model, [early, later], free=["k_motor"], initial_state="fit")
    assert fold.free_names == ["k_motor", "x0_q_rec1", "x0_q_rec2", "x0_v_rec2"]
    widened = fold.with_boxes({"k_motor": (0.1, 40.0)})
    assert type(widened) is LaterStartProblem and widened.free_names == fold.free_names


def test_a_fold_starts_its_later_piece_where_the_model_is_there():
    data = drive.simulate_record(seed=2, n=1600)
    est, sel, _ = split_record(data, 0.5, 0.25)
    cfg = _Settings(est, sel, data, {}, "auto", 1, 60, "fit", None, 0.5, "bic")
    (fold,) = fold_plan([est], [sel], 2)
    prob = rotation_mod._problem(replace(cfg, est=fold.train), drive.make_model(),
                                 ["k_motor", "c_visc"], {}, dict(drive.TRUTH), None,
                                 kind=rotation_mod.LaterStartProblem)
    start = rotation_mod._later_starts(prob)
    # the true velocity at the selection part's first sample (the record's own derivative)
    a = sel.origin[1]
    v_true = (data.y[a + 5] - data.y[a - 5]) / (10 * data.dt) / drive.MM_PER_M
    assert abs(v_true) > 0.01  # moving there: a start at rest would be wrong
    assert start["x0_v_rec1"] == pytest.approx(v_true, abs=0.1 * abs(v_true) + 2e-3)
    assert start["x0_q_rec1"] == pytest.approx(data.y[a] / drive.MM_PER_M, abs=1e-4)
