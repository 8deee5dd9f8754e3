"""Held-out parts start right: through a leading window of the samples just before them.

A selection or test part cut from a record (the loop's parts, a fit's validation part)
starts from the state the model reaches at its first sample (issue 33, item 4): the model
runs into the part through a window of its input memory just before it, so a delay holds
the inputs before the part and a lag (the valve spool) its state there; under ``"fit"``
the state at the window's start is estimated on the part's outputs (``HELD_OUT_STATE``
``"part"``, the default) or on a longer window before the part that the part's score never
sees (``"window"``). Before, each part started at its own first sample with the input
before it taken equal to its first value: a part that starts just after an input step then
lacks the step for as many samples as the delay, and no initial state makes up for it.
A record not cut from another (no ``origin``) keeps that start: it has nothing before it.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import hhra_phys.record_problem as record_problem_module
from hhra_phys.data import Dataset
from hhra_phys.diagnosis.selection import split_record
from hhra_phys.effects import make_effect
from hhra_phys.fit import FitOptions, fit_problem
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.problem import LEAD_FRACTION, Problem, estimate_initial_state
from hhra_phys.reference.hhra import REFERENCE_GROUPS
from hhra_phys.simulate import Simulator

FS, N, NOISE = 250.0, 2000, 0.05
#: The estimation part ends at 1000, the selection part at 1500 (split 0.5, test 0.25).
SPLIT, TEST = 0.5, 0.25


def _square(lag: int) -> np.ndarray:
    """A +-0.5 mA square wave of half-period 125 samples whose edges fall ``lag`` samples
    before each part's first sample (1000 and 1500)."""
    n = np.arange(N)
    return np.where(((n - (1000 - lag)) // 125) % 2 == 0, 0.5, -0.5)


def _record(effect: str, value: float, seed: int = 0, lag: int = 3, **kw) -> tuple:
    """A record of the HHRA with one input effect, simulated by the package's own model
    (the truth is the model: only the start of the parts can make an error), its model,
    true values, true states and noise-free output."""
    model = HHRAModel(output="angle").with_parts(make_effect(effect, **kw))
    name = {"input_delay": "delay", "valve_dynamics": "tau_spool"}[effect]
    truth = {n: REFERENCE_GROUPS[n] for n in model.params.names if n in REFERENCE_GROUPS}
    truth[name] = value
    p = np.array([truth[n] for n in model.params.names])
    x0 = model.x0()
    u = _square(lag)
    y, X = Simulator(model, fs=FS).simulate(u, p[None, :], x0=x0[None, :], states=True)
    rng = np.random.default_rng(seed)
    ds = Dataset(t=np.arange(N) / FS, u=u, y=y[0] + NOISE * rng.standard_normal(N),
                 name="square")
    return ds, model, truth, X[0], y[0], name


def _problem(model, est, truth, name, rule: str) -> tuple[Problem, np.ndarray]:
    """The estimation part's problem at the true values (and the true initial state)."""
    start = {f"x0_{s}": float(v) for s, v in zip(model.state_names, model.x0(), strict=True)
             if s in model.fitted_states} if rule == "fit" else {}
    start[name] = truth[name]
    pr = Problem(model, [est], free=[name],
                 fixed={k: v for k, v in truth.items() if k != name},
                 initial_state=rule, start=start)
    return pr, pr.start_values()


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def _alone(part: Dataset) -> Dataset:
    """The part as a separate record (no place in the one it was cut from)."""
    return Dataset(t=part.t, u=part.u, y=part.y)


@pytest.fixture(params=["part", "window"])
def held_out_state(request, monkeypatch):
    monkeypatch.setattr(record_problem_module, "HELD_OUT_STATE", request.param)
    return request.param


@pytest.mark.parametrize(("delay", "seed", "lag", "alone_above"), [
    (10.0, 0, 3, 1.2), (7.0, 2, 0, 1.2), (9.0, 1, 1, 1.2),
    (5.0, 1, 2, None),  # alone, the state fitted on the part made up for 3 samples
])
def test_a_delay_part_just_after_a_step_is_at_the_noise(delay, seed, lag, alone_above,
                                                       held_out_state) -> None:
    ds, model, truth, X, y_true, name = _record("input_delay", delay, seed, lag, max_delay=12)
    est, sel, test = split_record(ds, SPLIT, TEST)
    pr, v = _problem(model, est, truth, name, "fit")
    for part in (sel, test):
        y = pr.simulate_values(v, data=part)
        # the true model with the true delay: the part's error is the noise's ...
        assert _rmse(part.y, y) < 1.1 * NOISE
        # ... where the same part on its own (the start before) lacks the step
        if alone_above:
            assert _rmse(part.y, pr.simulate_values(v, data=_alone(part))) > alone_above * NOISE
        a = part.origin[1]
        # the true state there (from the part's noisy angle alone, only the angle closely:
        # the part's error says how little the rest matters to it)
        x = pr.initial_states(v, data=part)[0]
        if held_out_state == "window":
            np.testing.assert_allclose(x, X[a], atol=2e-3)
        else:
            assert x[0] == pytest.approx(X[a, 0], abs=2e-3)
    # every scoring path: the loop's per-record parts and a fit's validation score
    assert _rmse(sel.y, pr.simulate_parts(v, [sel])[0]) < 1.1 * NOISE
    res = fit_problem(pr, [sel], options=FitOptions(optimizer="none", refine="none",
                                                     pop_size=0, max_iter=0))
    assert res.metrics["val"]["rmse"] == pytest.approx(
        _rmse(sel.y, pr.simulate_values(v, data=sel)), rel=1e-9)


def test_under_the_data_rule_the_window_carries_the_delay(held_out_state) -> None:
    ds, model, truth, _, _, name = _record("input_delay", 10.0, max_delay=12)
    est, sel, test = split_record(ds, SPLIT, TEST)
    pr, v = _problem(model, est, truth, name, "data")
    for part in (sel, test):
        now = _rmse(part.y, pr.simulate_values(v, data=part))
        before = _rmse(part.y, pr.simulate_values(v, data=_alone(part)))
        assert now < 0.2 * before and now < 2.5 * NOISE, (now, before)


def test_a_lag_part_starts_where_the_run_has_the_spool(held_out_state) -> None:
    ds, model, truth, X, _, name = _record("valve_dynamics", 10 / FS, dt=1 / FS)
    est, sel, test = split_record(ds, SPLIT, TEST)
    pr, v = _problem(model, est, truth, name, "fit")
    i = model.state_names.index("x_spool")
    for part in (sel, test):
        a = part.origin[1]
        assert abs(X[a, i]) > 0.2  # the spool is far from rest where the part starts
        x = pr.initial_states(v, data=part)[0]
        assert x[i] == pytest.approx(X[a, i], abs=0.02)
        assert _rmse(part.y, pr.simulate_values(v, data=part)) < 1.1 * NOISE


def test_the_window_is_before_the_part_and_short(monkeypatch) -> None:
    ds, model, truth, _, _, name = _record("input_delay", 10.0, max_delay=12)
    est, sel, test = split_record(ds, SPLIT, TEST)
    rec = _problem(model, est, truth, name, "fit")[0].records[0]
    a = test.origin[1]
    memory = model.n_lags + 2
    u_w, y_w, skip = rec.lead_window(test)  # "part": the memory, the state on the part
    assert u_w.size == skip == memory
    np.testing.assert_array_equal(y_w, ds.y[a - memory:a])  # before it, none of its own
    monkeypatch.setattr(record_problem_module, "HELD_OUT_STATE", "window")
    u_w, y_w, skip = rec.lead_window(test)
    assert skip == memory and u_w.size == memory + round(LEAD_FRACTION * test.n) < sel.n
    np.testing.assert_array_equal(y_w, ds.y[a - u_w.size:a])
    # a record not cut from another, a part at its record's start, the "zero" rule: none
    assert rec.lead_window(_alone(sel)) is None and rec.lead_window(est) is None
    assert _problem(model, est, truth, name, "zero")[0].records[0].lead_window(sel) is None
    # a window cut short by the record's start keeps at least one fitted sample
    early = ds.slice(5, 900)
    assert rec.lead_window(early)[0].size == 5 and rec.lead_window(early)[2] == 4


def test_the_skipped_samples_do_not_pull_the_state() -> None:
    """The window's first samples (whose delayed inputs lie before it) are left out of the
    state's fit: wild values there change nothing."""
    ds, model, truth, X, _, name = _record("input_delay", 10.0, max_delay=12)
    pr, v = _problem(model, ds.slice(0, 1000), truth, name, "fit")
    sim, p = pr.sim, pr.full(v)
    u, y = ds.u[800:1000], ds.y[800:1000].copy()
    x_a = estimate_initial_state(sim, u, y, p, X[800] + 0.01, skip=14)
    y[:14] += 5.0
    x_b = estimate_initial_state(sim, u, y, p, X[800] + 0.01, skip=14)
    np.testing.assert_allclose(x_a, x_b, rtol=0, atol=1e-12)
    assert not np.allclose(estimate_initial_state(sim, u, y, p, X[800] + 0.01), x_a)


def test_a_part_keeps_its_place_through_copies_that_keep_its_samples() -> None:
    rng = np.random.default_rng(1)
    ds = Dataset(t=np.arange(100) / FS, u=rng.standard_normal(100),
                 y=rng.standard_normal(100))
    est, rest = ds.split(0.5)
    sel, test = rest.split_at(20)
    assert est.origin[0] is ds and est.origin[1] == 0
    assert sel.origin[0] is ds and sel.origin[1] == 50
    assert test.origin[0] is ds and test.origin[1] == 70
    assert test.with_intersample("foh").origin == test.origin
    assert test.with_metadata(note=1).origin == test.origin
    # samples sent to a worker process: the record comes along
    root = pickle.loads(pickle.dumps(test)).origin[0]
    assert root is not ds and np.array_equal(root.u, ds.u)
