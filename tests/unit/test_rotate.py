"""Parts that rotate where one cannot decide alone (``selection.needs_rotation`` and
``rotated_verdict``; ``regime.change_coverage``; the loop's ``_Loop._rotate``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hhra_phys.diagnosis import result as result_mod
from hhra_phys.diagnosis import rotation as rotation_mod
from hhra_phys.diagnosis.engine import _Loop
from hhra_phys.diagnosis.options import LoopOptions
from hhra_phys.diagnosis.selection import (
    REGIME_THIN,
    Step,
    acceptance,
    needs_rotation,
    pooled_rmse,
    rotated_verdict,
    thin_part,
    votes,
)
from hhra_phys.regime import REGIME_LEVEL, change_coverage


def _regime(est_share: float, n_est: int = 512, n_sel: int = 512) -> dict:
    return {"est": {"samples": n_est, "share": est_share},
            "sel": {"samples": n_sel, "share": 1.0 - est_share}}


@pytest.mark.parametrize("before,after,cb,ca", [
    (1.0, 0.5, 0.0, -10.0), (1.0, 0.95, 0.0, -10.0), (1.0, 0.5, 0.0, 5.0),
    (1.0, 0.99, 0.0, 5.0), (0.06, 0.0505, 0.0, -1.0), (1.0, math.inf, 0.0, -1.0)])
def test_votes_are_the_two_halves_of_acceptance(before, after, cb, ca):
    sel, crit = votes(before, after, cb, ca, 0.1, 0.05, 0.068)
    ok, _ = acceptance(before, after, cb, ca, 0.1, "bic", 0.05, 0.068)
    assert ok == (sel and crit)
    assert crit == (ca < cb)


def test_thin_part_compares_a_parts_share_of_the_regime_with_its_share_of_samples():
    assert thin_part(_regime(0.9)) == "sel"  # half the samples, a tenth of the regime
    assert thin_part(_regime(0.1)) == "est"
    assert thin_part(_regime(0.5)) is None
    # the threshold: a share below REGIME_THIN x the part's share of samples
    edge = 1.0 - 0.5 * REGIME_THIN
    assert thin_part(_regime(edge - 0.01)) is None
    assert thin_part(_regime(edge + 0.01)) == "sel"
    # unequal parts: 3/4 of the samples in estimation holding 3/4 of the regime: even
    assert thin_part(_regime(0.75, 768, 256)) is None
    assert thin_part(_regime(0.95, 768, 256)) == "sel"
    assert thin_part(None) is None
    assert thin_part({"est": {"samples": 5, "share": 0.0},
                      "sel": {"samples": 5, "share": 0.0}}) is None


def test_only_the_part_that_says_no_and_holds_the_regime_thinly_rotates():
    # criterion yes, selection no: rotate when the selection part is the thin one
    assert needs_rotation(False, True, "sel")
    assert not needs_rotation(False, True, "est")
    # selection yes, criterion no: rotate when estimation is the thin one
    assert needs_rotation(True, False, "est")
    assert not needs_rotation(True, False, "sel")
    # agreement, or no thin part: no rotation
    assert not needs_rotation(True, True, "sel")
    assert not needs_rotation(False, False, "sel")
    assert not needs_rotation(False, True, None)


def test_pooled_rmse_weighs_each_part_by_its_samples():
    assert pooled_rmse([(100, 1.0), (300, 1.0)]) == pytest.approx(1.0)
    assert pooled_rmse([(100, 2.0), (300, 0.0)]) == pytest.approx(1.0)
    assert math.isnan(pooled_rmse([]))


def test_rotated_verdict_asks_the_gain_and_the_allowance_of_the_pooled_error():
    ok, why = rotated_verdict(1.0, 0.5, 0.1, 0.05, 0.068)
    assert ok and "decides" in why and "clear gain" in why
    assert not rotated_verdict(1.0, 0.95, 0.1, 0.05, 0.068)[0]  # below the margin
    assert rotated_verdict(0.0520, 0.0499, 0.1, 0.05, 0.068)[0] is False  # within allowance
    assert rotated_verdict(0.2, 0.049, 0.1, 0.05, 0.068)[0]  # to the noise level
    assert not rotated_verdict(1.0, math.inf, 0.1, 0.05, 0.068)[0]


def test_change_coverage_finds_where_the_fitted_candidate_changes_the_output():
    est = np.zeros(400)
    est[100:200] = 1.0
    sel = np.zeros(400)
    sel[10:14] = 1.0
    cov = change_coverage({"est": est, "sel": sel})
    assert cov["est"]["in_regime"] == pytest.approx(0.25)
    assert cov["sel"]["share"] == pytest.approx(4 / 104)
    assert thin_part(cov) == "sel"
    # the level is REGIME_LEVEL of the 99th percentile, so one spike does not set it
    spiky = np.full(400, 0.5)
    spiky[0] = 1e6
    cov = change_coverage({"est": spiky, "sel": np.full(400, 0.5)})
    assert cov["level"] == pytest.approx(REGIME_LEVEL * 0.5)
    assert thin_part(cov) is None
    assert change_coverage({"est": np.zeros(5), "sel": np.zeros(5)}) is None
    assert change_coverage({"est": np.full(5, np.nan), "sel": np.zeros(5)}) is None


class _Res:
    def __init__(self, val: float) -> None:
        self.metrics = {"val": {"rmse": val}, "est": {"rmse": val, "mse": val * val}}
        self.values, self.x0, self.records = {}, {}, []


def _loop(monkeypatch, rotated: dict[str, float], regime: dict | None):
    """A loop whose current model and candidate refit on the selection part score
    ``rotated["cur"]`` and ``rotated["cand"]`` on the estimation part."""
    loop = object.__new__(_Loop)
    loop.o, loop.tol, loop.say = LoopOptions(), 0.068, lambda s: None
    loop.cur, loop.cur_free = _Res(0.5), []
    loop.cur_prob = type("P", (), {"model": object()})()
    loop.est = loop.sel = type("D", (), {"n": 500})()
    loop.cfg, loop._rot_cache, loop._fold_cache = None, None, None
    calls = []

    def fold_fit(cfg, fold, model, free, start, boxes):
        calls.append(model)
        return _Res(rotated["cur" if model is loop.cur_prob.model else "cand"])

    monkeypatch.setattr(rotation_mod, "_fold_fit", fold_fit)
    monkeypatch.setattr(rotation_mod, "_fitted_candidate",
                        lambda payload: ("cand-model", ["a"], {}, {}, {}))
    monkeypatch.setattr(rotation_mod, "as_records", lambda d: [d])
    monkeypatch.setattr(_Loop, "_change_regime", lambda self, fitted, payload=None: regime)
    return loop, calls


def _step(val: float, crit: float) -> Step:
    return Step(1, "cand", {}, {}, {}, {"rmse": val}, {"rmse": val}, crit, 0.0, 0.5)


def test_loop_rotates_a_criterion_yes_selection_no_candidate_thin_in_selection(monkeypatch):
    loop, calls = _loop(monkeypatch, {"cur": 1.5, "cand": 0.3}, _regime(0.95))
    step = _step(0.49, -100.0)  # selection: no (2 %); criterion: yes
    ok = loop._rotate(step, object(), False, 0.5, 0.0, 0.05, 0.05)
    assert ok and step.folds["accepted"] and step.folds["k"] == 2
    assert step.folds["rmse_before"] == pytest.approx(pooled_rmse([(500, 0.5), (500, 1.5)]))
    assert step.folds["est"] == {"rmse_before": 1.5, "rmse_after": 0.3}
    assert "parts rotated" in step.reason and step.regime["sel"]["share"] == pytest.approx(0.05)
    assert calls == [loop.cur_prob.model, "cand-model"]
    # the current model's fold is fitted once per current fit
    loop._rotate(_step(0.49, -100.0), object(), False, 0.5, 0.0, 0.05, 0.05)
    assert calls == [loop.cur_prob.model, "cand-model", "cand-model"]


def test_loop_keeps_the_verdict_where_no_part_is_thin_or_both_agree(monkeypatch):
    loop, calls = _loop(monkeypatch, {"cur": 1.5, "cand": 0.3}, _regime(0.5))
    step = _step(0.49, -100.0)
    assert loop._rotate(step, object(), False, 0.5, 0.0, 0.05, 0.05) is False
    assert step.folds is None and calls == []
    loop, calls = _loop(monkeypatch, {"cur": 1.5, "cand": 0.3}, _regime(0.95))
    step = _step(0.3, -100.0)  # both say yes
    assert loop._rotate(step, object(), True, 0.5, 0.0, 0.05, 0.05) is True
    assert step.folds is None and calls == []


def test_loop_rotation_can_refuse(monkeypatch):
    loop, _ = _loop(monkeypatch, {"cur": 1.5, "cand": 1.49}, _regime(0.95))
    step = _step(0.49, -100.0)
    assert loop._rotate(step, object(), False, 0.5, 0.0, 0.05, 0.05) is False
    assert step.folds["accepted"] is False


def test_an_inter_sample_candidate_never_rotates(monkeypatch):
    loop, calls = _loop(monkeypatch, {"cur": 1.5, "cand": 0.3}, _regime(0.95))
    monkeypatch.setattr(rotation_mod, "_fitted_candidate", lambda payload: None)
    step = _step(0.49, -100.0)
    assert loop._rotate(step, object(), False, 0.5, 0.0, 0.05, 0.05) is False
    assert calls == []


def test_folds_survive_the_json_round_trip():
    step = _step(0.49, -100.0)
    step.folds = {"k": 2, "accepted": True, "rmse_before": 1.0, "rmse_after": 0.5}
    again = result_mod._step_from_json(step.to_json())
    assert again.folds == step.folds


def test_rotate_option_is_validated():
    with pytest.raises(Exception, match="rotate"):
        LoopOptions(rotate="yes").validate()


def test_every_candidate_without_a_first_order_regime_reports_one(monkeypatch):
    # votes agree: no rotation, but the regime is measured from what the fit changes
    loop, calls = _loop(monkeypatch, {"cur": 1.5, "cand": 0.3}, _regime(0.7))
    step = _step(0.3, -100.0)
    assert loop._rotate(step, object(), True, 0.5, 0.0, 0.05, 0.05) is True
    assert step.regime == _regime(0.7) and step.folds is None and calls == []
    # a first-order regime is kept as it is
    step = _step(0.3, -100.0)
    step.regime = _regime(0.4)
    loop._rotate(step, object(), True, 0.5, 0.0, 0.05, 0.05)
    assert step.regime == _regime(0.4)


def test_rotate_off_measures_but_never_rotates(monkeypatch):
    loop, calls = _loop(monkeypatch, {"cur": 1.5, "cand": 0.3}, _regime(0.95))
    loop.o = LoopOptions(rotate=False)
    step = _step(0.49, -100.0)  # would rotate (test above) and be accepted
    assert loop._rotate(step, object(), False, 0.5, 0.0, 0.05, 0.05) is False
    assert step.folds is None and calls == [] and step.regime == _regime(0.95)


def test_no_rotation_against_a_current_fold_that_failed(monkeypatch):
    # an infinite error of the current model's other fold would let any candidate pass
    loop, _ = _loop(monkeypatch, {"cur": math.inf, "cand": 0.3}, _regime(0.95))
    step = _step(0.49, -100.0)
    assert loop._rotate(step, object(), False, 0.5, 0.0, 0.05, 0.05) is False
    assert step.folds is None and any("not rotated" in n for n in step.notes)


def test_a_hold_candidate_is_neither_measured_nor_rotated(monkeypatch):
    from hhra_phys.intersample import HoldCandidate

    loop, calls = _loop(monkeypatch, {"cur": 1.5, "cand": 0.3}, _regime(0.95))
    hold = object.__new__(HoldCandidate)
    step = _step(0.49, -100.0)
    assert loop._rotate(step, hold, False, 0.5, 0.0, 0.05, 0.05) is False
    assert step.regime is None and calls == []
