"""Held-out parts start right: from the state the model reaches at their first sample.

A selection or test part cut from the record the estimation part was cut from is
simulated as the continuation of the estimation record's run (issue 33, item 4): an input
delay sees the inputs before the part's first sample, a lag (the valve spool) its state
there. Before, each part started from its first measured output with the input before it
taken equal to its first value, and under the ``"fit"`` rule with a state re-estimated on
the part itself: a part that starts just after an input step then lacks the step for as
many samples as the delay, and no initial state makes up for it.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from hhra_phys.data import Dataset
from hhra_phys.effects import make_effect
from hhra_phys.fit import FitOptions, fit_problem
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.problem import Problem
from hhra_phys.reference.hhra import REFERENCE_GROUPS
from hhra_phys.selection import split_record
from hhra_phys.simulate import Simulator

FS, N, NOISE = 250.0, 2000, 0.05
#: The estimation part ends at 1000, the selection part at 1500 (split 0.5, test 0.25).
SPLIT, TEST = 0.5, 0.25


def _square(lag: int) -> np.ndarray:
    """A +-0.5 mA square wave of half-period 125 samples whose edges fall ``lag`` samples
    before each part's first sample (1000 and 1500)."""
    n = np.arange(N)
    return np.where(((n - (1000 - lag)) // 125) % 2 == 0, 0.5, -0.5)


def _record(effect: str, value: float, seed: int = 0, **kw) -> tuple:
    """A record of the HHRA with one input effect, simulated by the package's own model
    (the truth is the model: only the start of the parts can make an error), its model,
    true values, true states and noise-free output."""
    model = HHRAModel(output="angle").with_parts(make_effect(effect, **kw))
    name = {"input_delay": "delay", "valve_dynamics": "tau_spool"}[effect]
    truth = {n: REFERENCE_GROUPS[n] for n in model.params.names if n in REFERENCE_GROUPS}
    truth[name] = value
    p = np.array([truth[n] for n in model.params.names])
    x0 = model.x0()
    u = _square(3)
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


@pytest.fixture(scope="module")
def delay_record():
    return _record("input_delay", 10.0, max_delay=12)


@pytest.mark.parametrize("rule", ["fit", "data"])
def test_a_delay_part_just_after_a_step_is_at_the_noise(delay_record, rule) -> None:
    ds, model, truth, _, y_true, name = delay_record
    est, sel, test = split_record(ds, SPLIT, TEST)
    pr, v = _problem(model, est, truth, name, rule)
    a = est.n
    for part in (sel, test):
        y = pr.simulate_values(v, data=part)
        # the true model with the true delay: the part's error is the noise's
        assert _rmse(part.y, y) < 1.1 * NOISE
        if rule == "fit":  # from the true initial state: the true run, exactly
            np.testing.assert_allclose(y, y_true[a:a + part.n], atol=1e-6)
        a += part.n
    # every scoring path: the loop's per-record parts and a whole held-out record
    for ys, part in zip(pr.simulate_parts(v, [sel]), [sel], strict=True):
        assert _rmse(part.y, ys) < 1.1 * NOISE
    assert _rmse(test.y, pr.records[0].simulate_values(v, data=test)) < 1.1 * NOISE
    if rule == "fit":  # a fit's validation score (the loop's refits are scored so)
        res = fit_problem(pr, [sel], options=FitOptions(optimizer="none", refine="none",
                                                         pop_size=0, max_iter=0))
        assert res.metrics["val"]["rmse"] == pytest.approx(
            _rmse(sel.y, pr.simulate_values(v, data=sel)), rel=1e-9)
        assert res.metrics["val"]["rmse"] < 1.1 * NOISE


def test_a_lag_part_starts_from_the_state_the_run_reaches(delay_record) -> None:
    ds, model, truth, X, y_true, name = _record("valve_dynamics", 10 / FS, dt=1 / FS)
    est, sel, test = split_record(ds, SPLIT, TEST)
    for rule in ("fit", "data"):
        pr, v = _problem(model, est, truth, name, rule)
        if rule == "data":  # the rule's start on the estimation record is the noisy y[0]
            v_est_x0 = pr.initial_states(v)[0]
        else:
            v_est_x0 = X[0]
            np.testing.assert_allclose(pr.initial_states(v)[0], X[0], atol=1e-12)
        for part, k in ((sel, est.n), (test, est.n + sel.n)):
            x = pr.initial_states(v, data=part)[0]
            if rule == "fit":  # the spool (and every state) where the true run has it
                np.testing.assert_allclose(x, X[k], rtol=1e-6, atol=1e-6)
            # a run from the estimation record's start reaches the same state
            _, Xr = pr.sim.simulate(ds.u[:k + 1], pr.full(v)[None, :], x0=v_est_x0[None, :],
                                    states=True)
            np.testing.assert_allclose(x, Xr[0, k], rtol=1e-9, atol=1e-9)
            assert _rmse(part.y, pr.simulate_values(v, data=part)) < 1.1 * NOISE
    i = model.state_names.index("x_spool")
    assert abs(X[est.n, i]) > 0.2  # the spool is far from rest where the part starts


def test_a_separate_record_keeps_its_own_start(delay_record) -> None:
    ds, model, truth, _, _, name = delay_record
    est, sel, _ = split_record(ds, SPLIT, TEST)
    pr, _ = _problem(model, est, truth, name, "fit")
    rec = pr.records[0]
    assert rec.lead_in(sel) is not None and rec.lead_in(sel).size == est.n
    # a record not cut from the estimation record's: no run-in, its own initial state
    alone = Dataset(t=sel.t, u=sel.u, y=sel.y)
    assert alone.origin is None and rec.lead_in(alone) is None
    # a part that starts before the estimation record: none either
    late, early = ds.split(0.5)[1], ds.slice(0, 400)
    assert Problem(model, [late], free=[name],
                   fixed={k: v for k, v in truth.items() if k != name},
                   start={name: truth[name]}).records[0].lead_in(early) is None


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
    # samples sent to a worker process: an equal record, recognised as the same
    root = pickle.loads(pickle.dumps(test)).origin[0]
    assert root is not ds and np.array_equal(root.u, ds.u)
