"""The accuracy rule of the simulator: step doubling decides the substeps."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys.models.hhra import NOMINAL_GROUPS, HHRAModel
from hhra_phys.simulate import Simulator, accuracy_tolerance, step_doubling_error

FS = 250.0


@pytest.mark.parametrize("order", [1, 2, 4])
def test_step_doubling_recovers_the_error_of_a_known_order(order):
    """y_n = y* + C n^-q: the estimate is the exact error of y_n for orders 1 to 4."""
    rng = np.random.default_rng(order)
    truth = rng.normal(size=50)
    shape = rng.normal(size=50)
    n = 3
    y = {k: truth + shape * (k * n) ** -order for k in (1, 2, 4)}
    est = step_doubling_error(y[1], y[2], y[4])
    assert est == pytest.approx(np.max(np.abs(y[1] - truth)), rel=1e-9)


def test_step_doubling_is_conservative_beyond_fourth_order_and_flags_divergence():
    truth = np.linspace(0, 1, 20)
    y = {k: truth + 0.3 * (2.0 * k) ** -6 for k in (1, 2, 4)}
    assert step_doubling_error(y[1], y[2], y[4]) >= np.max(np.abs(y[1] - truth))
    assert step_doubling_error(truth, truth, truth) == 0.0
    bad = truth.copy()
    bad[5] = np.nan
    assert step_doubling_error(truth, bad, truth) == np.inf


@pytest.mark.parametrize("sigma", [0.02, 0.05, 0.2])
def test_tolerance_is_a_tenth_of_the_noise_of_the_record(sigma):
    rng = np.random.default_rng(7)
    t = np.arange(2000) / FS
    y = 20 * np.sin(2 * np.pi * 0.5 * t) + 3 * np.sin(2 * np.pi * 3 * t)
    tol = accuracy_tolerance(y + rng.normal(0, sigma, t.size))
    assert tol == pytest.approx(0.1 * sigma, rel=0.15)
    # No noise: a small share of the range instead of zero.
    assert 0 < accuracy_tolerance(y) < 1e-3


def _steps(seconds: float, seed: int, amplitude: float = 5.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n, hold = int(seconds * FS), int(0.2 * FS)
    u = np.repeat(rng.uniform(-amplitude, amplitude, -(-n // hold)), hold)[:n]
    return u - u.mean()


@pytest.mark.parametrize(("factor", "seed"), [(1.0, 1), (2.0, 2), (2.5, 3)])
def test_chosen_substeps_keep_the_error_below_the_tolerance(factor, seed):
    """Against CVODES: the stability rule alone misses the tolerance, the accuracy rule meets it.

    Resonance moved by ``factor`` (oil column stiffer by factor^2), 3 s of 5 mA steps
    (the nominal substeps err 1.7x the tolerance at 1x and go unstable beyond).
    """
    model = HHRAModel()
    n = dict(NOMINAL_GROUPS)
    k = factor ** 2
    values = dict(n, g_compress=n["g_compress"] * k, g_leak=n["g_leak"] * k,
                  g_valve=n["g_valve"] * k, g_damping=n["g_damping"] * factor)
    p = model.params.vector({a: b for a, b in values.items() if a in model.params.names})
    u = _steps(3.0, seed)
    base = Simulator(model, fs=FS)
    y_ref = base.reference(u, p, rtol=1e-9, atol=1e-9)
    tol = 0.002
    sim = base.accurate(u, p, tol)
    assert sim.accuracy["within"] and sim.accuracy["error_estimate"] <= tol
    assert sim.accuracy["tolerance"] == tol and sim.accuracy["substeps"] == sim.substeps
    y = sim.simulate(u, p[None, :])[0]
    assert np.max(np.abs(y - y_ref)) <= tol
    # The estimate is of the right size (not wildly pessimistic, never far below).
    err = np.max(np.abs(y - y_ref))
    assert 0.5 * err <= sim.accuracy["error_estimate"] <= 20 * max(err, 1e-6)
    # The nominal population substeps miss the tolerance here (or are unstable).
    y_nom = base.simulate(u, p[None, :])[0]
    assert not np.max(np.abs(y_nom - y_ref)) <= tol


def test_a_loose_tolerance_keeps_the_stability_rule_and_a_tight_one_refines():
    model = HHRAModel()
    p = model.nominal()
    u = _steps(2.0, 4)
    base = Simulator(model, fs=FS)
    loose = base.accurate(u, p, 1.0)
    # Stable at the nominal: the simulator's own substeps are kept when accurate enough.
    assert loose is base and loose.substeps == loose.accuracy["start_substeps"] == 2
    tight = base.accurate(u, p, 1e-4)
    assert tight.substeps > loose.substeps
    assert tight.accuracy["error_estimate"] < loose.accuracy["error_estimate"]
    # Built once and kept.
    assert base.accurate(u, p, 1e-4) is tight


@pytest.mark.parametrize("seed", [5, 6])
def test_coarsest_lets_the_estimate_choose_fewer_ros4_substeps_for_a_sharp_backlash(seed):
    """A stiff model: the rule's floor of 8 ROS4 substeps is not needed where the error
    estimate says fewer meet the tolerance, and what it chooses meets it against CVODES."""
    from hhra_phys.effects import make_effect
    from hhra_phys.simulate import ROS4_MIN_STIFF

    model = HHRAModel().with_parts(make_effect("backlash"))
    p = model.nominal()
    u = _steps(2.0, seed, amplitude=1.0)
    base = Simulator(model, fs=FS, block=2)
    assert base.method == "ros4" and base.substeps >= ROS4_MIN_STIFF
    y_ref = base.reference(u, p, rtol=1e-10, atol=1e-10)
    tol = 0.005  # a tenth of the rig's 0.05 deg noise
    sim = base.accurate(u, p, tol, coarsest=True)
    assert sim.method == "ros4" and sim.substeps < base.substeps
    assert sim.accuracy["within"] and sim.accuracy["start_substeps"] < ROS4_MIN_STIFF
    err = np.max(np.abs(sim.simulate(u, p[None, :])[0] - y_ref))
    assert err <= tol and sim.accuracy["error_estimate"] >= 0.5 * err
    # Without it the simulator's substeps are the start: never fewer.
    assert base.accurate(u, p, tol).substeps >= base.substeps
    # A tight tolerance asks for more than the coarsest choice.
    assert base.accurate(u, p, 1e-5, coarsest=True).substeps > sim.substeps


@pytest.mark.parametrize("intersample", ["foh", "cubic"])
def test_the_refined_simulator_keeps_the_inter_sample_behaviour(intersample):
    model = HHRAModel()
    p = model.nominal()
    u = _steps(1.0, 8)
    base = Simulator(model, fs=FS, intersample=intersample)
    tight = base.accurate(u, p, 1e-6)
    assert tight is not base and tight.substeps > base.substeps
    assert tight.intersample == intersample


@pytest.mark.parametrize("seed", [2, 5])
def test_the_accuracy_shift_is_the_part_of_the_integration_error_the_parameters_follow(seed):
    """``fit._accuracy_shift``: how far finer substeps move an optimum, in its own standard
    deviations: none for the same simulator, more for coarser substeps, and at most the
    whole change of the output over the residual variance (``|e|^2 / s^2``, computed here
    from two plain simulations), on a fit at the noise and on one lacking an effect."""
    import warnings

    from hhra_phys.fit import _accuracy_shift, fit
    from hhra_phys.problem import Problem
    from hhra_phys.reference import reference_record

    for eff in (None, {"valve_deadzone": {"i_dead": 0.15}}):
        est = reference_record(seed=seed, duration=8.0, effects=eff).split(0.5)[0]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            res = fit(est, HHRAModel(), pop_size=20, max_iter=20, split=1.0, seed=1)
        problems = {n: Problem(res.model, est, start=res.values,
                               simulator=Simulator(res.model, fs=est.fs, substeps=n))
                    for n in (1, 2, 8)}
        z = problems[1].to_z(problems[1].start_values())
        shift = {n: _accuracy_shift(problems[n], problems[8], z) for n in (1, 2)}
        assert _accuracy_shift(problems[8], problems[8], z) == 0.0
        assert 0 < shift[2] < shift[1]
        v = problems[8].from_z(z)
        e = problems[8].simulate_values(v) - problems[1].simulate_values(v)
        r = problems[8].simulate_values(v) - problems[8].y
        bound = float(e @ e) / (float(r @ r) / (r.size - problems[8].n_free))
        assert shift[1] <= bound * (1 + 1e-9)
