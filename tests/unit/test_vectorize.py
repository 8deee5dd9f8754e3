"""SIMD vector code: lane-wise semantics, fallbacks, and the simulator's fused cost."""

from __future__ import annotations

import itertools

import casadi as ca
import numpy as np
import pytest

from hhra_phys import HHRAModel, Simulator
from hhra_phys.compile import compile_function
from hhra_phys.errors import ParameterError
from hhra_phys.models.hhra.rig import default_input, simulate_rig
from hhra_phys.problem import Problem
from hhra_phys.simulate import STATUS_OK
from hhra_phys.vectorize import SimdTarget, simd_target, supports

TARGET = simd_target()
needs_simd = pytest.mark.skipif(TARGET is None, reason="no C++ compiler for vector code")

SPECIAL = [-2.5, -1.0, -0.0, 0.0, 0.3, 1.0, 7.0, np.inf, -np.inf, np.nan]


def _ops_function() -> ca.Function:
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    outs = [
        x + y, x - y, x * y, x / y, -x, 2 * x, 1 / x, x * x, ca.sqrt(x), ca.exp(x),
        ca.log(x), x**y, x**3, ca.sin(x), ca.cos(x), ca.tan(x), ca.asin(x), ca.acos(x),
        ca.atan(x), ca.atan2(x, y), ca.sinh(x), ca.cosh(x), ca.tanh(x), ca.asinh(x),
        ca.acosh(x), ca.atanh(x), ca.fabs(x), ca.sign(x), ca.copysign(x, y), ca.fmod(x, y),
        ca.floor(x), ca.ceil(x), ca.erf(x), ca.log1p(x), ca.expm1(x), ca.hypot(x, y),
        x < y, x <= y, x == y, x != y, ca.logic_not(x), ca.logic_and(x, y),
        ca.logic_or(x, y), ca.if_else(x > y, x, y),
    ]
    return ca.Function("ops", [x, y], [ca.vertcat(*outs)], {"cse": True})


def _minmax_function() -> ca.Function:
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    return ca.Function("minmax", [x, y], [ca.vertcat(ca.fmin(x, y), ca.fmax(x, y))])


def _lanes_equal_scalar(fn: ca.Function, pairs: list[tuple[float, float]]) -> None:
    assert supports(fn)
    scalar = compile_function(fn, quiet=False)
    vector = compile_function(fn, quiet=False, simd=TARGET)
    assert scalar is not None and vector is not None and vector.width == TARGET.width
    w = TARGET.width
    pairs = pairs + pairs[: (-len(pairs)) % w]  # whole vectors
    for start in range(0, len(pairs), w):
        chunk = np.array(pairs[start:start + w])
        got = vector(chunk[:, 0][None, :], chunk[:, 1][None, :])[0]  # (n_out, width)
        for lane, (a, b) in enumerate(chunk):
            want = scalar(np.array([a]), np.array([b]))[0].ravel()
            np.testing.assert_array_equal(got[:, lane], want, err_msg=f"x={a}, y={b}")


@needs_simd
def test_every_supported_operation_is_lanewise_the_scalar_code():
    with np.errstate(all="ignore"):
        _lanes_equal_scalar(_ops_function(), list(itertools.product(SPECIAL, SPECIAL)))


@needs_simd
def test_fmin_fmax_follow_c99_nan_rules():
    # C99 lets fmin/fmax return either zero for (-0, +0); every other pair is exact.
    pairs = [(a, b) for a, b in itertools.product(SPECIAL, SPECIAL)
             if not (a == 0 and b == 0)]
    _lanes_equal_scalar(_minmax_function(), pairs)


@needs_simd
def test_operation_without_lanewise_version_is_refused_not_miscompiled():
    x = ca.SX.sym("x")
    fn = ca.Function("inv_erf", [x], [ca.erfinv(x)])
    assert not supports(fn)
    with pytest.warns(RuntimeWarning, match="using scalar code"):
        assert compile_function(fn, simd=TARGET) is None


def test_simd_setting_from_environment(monkeypatch):
    monkeypatch.setenv("HHRA_PHYS_SIMD", "off")
    assert simd_target() is None
    monkeypatch.setenv("HHRA_PHYS_SIMD", "3")
    with pytest.raises(ValueError, match="power of two"):
        simd_target()
    monkeypatch.setenv("HHRA_PHYS_SIMD", "wide")
    with pytest.raises(ValueError, match="HHRA_PHYS_SIMD"):
        simd_target()
    monkeypatch.setenv("HHRA_PHYS_SIMD", "4")
    forced = simd_target()
    assert forced is None or forced.width == 4  # None: no C++ compiler here


@pytest.fixture(scope="module")
def population():
    model = HHRAModel()
    rng = np.random.default_rng(5)
    P = model.nominal() * np.exp(0.4 * rng.standard_normal((19, model.n_params)))
    P[4, model.params.index("g_torque")] *= 1e5  # flagged unstable
    u = default_input(duration=3.0, seed=8)
    return model, P, u


@needs_simd
@pytest.mark.parametrize("width", ["auto", 4])
def test_vector_simulator_gives_the_scalar_numbers_bit_for_bit(population, width):
    model, P, u = population
    vec = Simulator(model, fs=250.0, simd=width)
    sca = Simulator(model, fs=250.0, simd=None)
    assert vec.simd is not None and sca.simd is None
    Yv, Xv = vec.simulate(u, P, states=True)
    Ys, Xs = sca.simulate(u, P, states=True)
    expected = TARGET.width if width == "auto" else width
    assert vec.vector_width(len(P)) == expected  # really the vector code
    np.testing.assert_array_equal(vec.last_status, sca.last_status)
    assert vec.last_status[4] != STATUS_OK
    np.testing.assert_array_equal(Yv, Ys)
    np.testing.assert_array_equal(Xv, Xs)
    np.testing.assert_array_equal(vec.simulate(u, P), Ys)


def test_population_states_equal_single_runs(population):
    model, P, u = population
    for simd in (None, "auto"):
        sim = Simulator(model, fs=250.0, simd=simd)
        Y, X = sim.simulate(u, P[:11], states=True)
        for i in (0, 5, 10):
            y, x = sim.simulate(u, P[i], states=True)
            np.testing.assert_allclose(Y[i], y, rtol=0, atol=1e-12)
            np.testing.assert_allclose(X[i], x, rtol=0, atol=1e-12)


@pytest.mark.parametrize("opts", [{"simd": None}, {"simd": "auto"}, {"backend": "casadi"}],
                         ids=["scalar", "vector", "casadi-vm"])
def test_fused_cost_equals_the_cost_of_the_simulated_outputs(population, opts):
    model, P, u = population
    sim = Simulator(model, fs=250.0, **opts)
    y = np.sin(np.arange(u.size) / 30.0)
    w = np.linspace(0.0, 2.0, u.size)
    Y = sim.simulate(u, P)
    for loss, weights in (("sq", None), ("abs", w)):
        cost = sim.simulate_cost(u, P, y, weights, loss)
        err = (y - Y) ** 2 if loss == "sq" else np.abs(y - Y)
        want = np.sum(err * (1.0 if weights is None else weights), axis=1)
        flagged = sim.last_status != STATUS_OK
        assert flagged[4] and np.isinf(cost[flagged]).all()
        np.testing.assert_allclose(cost[~flagged], want[~flagged], rtol=1e-12)
    single = sim.simulate_cost(u, P[0], y)
    assert isinstance(single, float)
    assert single == pytest.approx(np.sum((y - Y[0]) ** 2), rel=1e-12)


@pytest.mark.parametrize("simd", [None, "auto"])
def test_fused_cost_ignores_the_padding_after_the_record(simd):
    # 501 samples: the last chunk runs 499 samples past the record with the input
    # held, where this record's angle keeps growing beyond the divergence limit.
    model = HHRAModel()
    sim = Simulator(model, fs=250.0, diverge_limit=30.0, simd=simd)
    u = default_input(duration=5.0, seed=3)[:501]
    P = np.tile(model.nominal(), (16, 1))
    Y = sim.simulate(u, P)
    assert (sim.last_status == STATUS_OK).all() and np.abs(Y).max() < 30.0
    cost = sim.simulate_cost(u, P, np.zeros(u.size))
    assert (sim.last_status == STATUS_OK).all()
    np.testing.assert_allclose(cost, np.sum(Y**2, axis=1), rtol=1e-12)


def test_fused_cost_rejects_bad_measurements(population):
    model, P, u = population
    sim = Simulator(model, fs=250.0)
    with pytest.raises(ParameterError, match="shape"):
        sim.simulate_cost(u, P, np.zeros(u.size - 1))
    y = np.zeros(u.size)
    y[3] = np.nan
    with pytest.raises(ParameterError, match="non-finite"):
        sim.simulate_cost(u, P, y)
    with pytest.raises(ParameterError, match="loss"):
        sim.simulate_cost(u, P, np.zeros(u.size), loss="huber")


@pytest.mark.parametrize("cost", ["itae", "mse", "rmse", "ssr"])
def test_problem_cost_is_the_metric_of_its_simulation(cost):
    data = simulate_rig(seed=1, duration=3.0)
    problem = Problem(HHRAModel(), data, cost=cost)
    box = problem.bounds_z()
    rng = np.random.default_rng(2)
    Z = box[:, 0] + (box[:, 1] - box[:, 0]) * rng.random((24, problem.n_free))
    fused = problem(Z)
    direct = problem.cost_of(problem.simulate_values(problem.from_z(Z)))
    finite = np.isfinite(direct)
    assert finite.sum() >= 12
    np.testing.assert_array_equal(np.isfinite(fused), finite)
    np.testing.assert_allclose(fused[finite], direct[finite], rtol=1e-10)


def test_forced_width_uses_detected_flags():
    target = simd_target()
    if target is None:
        pytest.skip("no C++ compiler for vector code")
    sim = Simulator(HHRAModel(), fs=250.0, simd=2)
    assert sim.simd == SimdTarget(2, target.compiler, target.flags)
    with pytest.raises(ParameterError, match="power of two"):
        Simulator(HHRAModel(), fs=250.0, simd=6)


@pytest.mark.parametrize("opts", [{"simd": None}, {"simd": None, "lanes": 1}, {"simd": "auto"},
                                  {"backend": "casadi"}],
                         ids=["scalar-lanes", "scalar-one-lane", "vector", "casadi-vm"])
def test_members_starting_from_different_states_keep_their_own(population, opts):
    """A population whose members start from different states (the loop's and the
    multi-record fits' per-member initial states): member i runs from x0[i] in every layout
    (interleaved scalar lanes, SIMD lanes, the VM) and in every entry (outputs, states,
    fused cost), over more than one chunk (the final state carried to the next chunk)."""
    model, P, u = population
    P = np.delete(P, 4, axis=0)[:11]  # the stable members (row 4 is flagged)
    n = len(P)
    rng = np.random.default_rng(11)
    X0 = np.column_stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-2.0, 2.0, n),
                          rng.uniform(-0.5, 0.5, n)])
    # Fixed substeps: a single vector would otherwise get substeps chosen for itself.
    sim = Simulator(model, fs=250.0, substeps=2, **opts)
    assert u.size > sim.chunk  # the state crosses a chunk boundary
    Y = sim.simulate(u, P, x0=X0)
    Yx, X = sim.simulate(u, P, x0=X0, states=True)
    assert (sim.last_status == STATUS_OK).all()
    y = np.sin(np.arange(u.size) / 30.0)
    cost = sim.simulate_cost(u, P, y, x0=X0)
    for i in range(n):
        yi, xi = sim.simulate(u, P[i], x0=X0[i], states=True)
        assert sim.last_substeps == 2
        np.testing.assert_allclose(Y[i], yi, rtol=0, atol=1e-12, err_msg=f"member {i}")
        np.testing.assert_allclose(Yx[i], yi, rtol=0, atol=1e-12, err_msg=f"member {i}")
        np.testing.assert_allclose(X[i], xi, rtol=0, atol=1e-12, err_msg=f"member {i}")
        np.testing.assert_array_equal(X[i][0], X0[i])
        assert cost[i] == pytest.approx(np.sum((y - yi) ** 2), rel=1e-12), f"member {i}"
    # The starts matter: the members' first outputs are their own initial angles.
    np.testing.assert_allclose(Y[:, 0], np.degrees(X0[:, 0]), rtol=1e-12)


def test_a_simulator_whose_code_has_exploded_is_refused_at_once(monkeypatch):
    """Generated code beyond ``MAX_SOURCE_BYTES`` is refused before the compiler starts
    (a loop candidate's 82 MB once compiled for over 30 CPU minutes): a clear error naming
    the function and its size, which a loop turns into a failed candidate."""
    import hhra_phys.compile as comp
    from hhra_phys.errors import ModelError

    x = ca.SX.sym("x", 3)
    fn = ca.Function("exploded", [x], [ca.sin(x) * ca.cos(x) + x ** 3])
    monkeypatch.setattr(comp, "MAX_SOURCE_BYTES", 200)
    called = []
    monkeypatch.setattr(comp, "_build", lambda *a, **k: called.append(a) or False)
    with pytest.raises(ModelError, match=r"generated code of exploded is .* MB"):
        compile_function(fn)
    assert not called  # the compiler never ran
    sim = Simulator(HHRAModel(), fs=250.0)
    with pytest.raises(ModelError, match="generated code"):
        sim.simulate(default_input(seed=0, duration=0.4), HHRAModel().params.vector())
