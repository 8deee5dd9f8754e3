"""The compiled population simulator against CVODES, flags and shapes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from hhra_phys import HHRAModel, Model, Parameter, Part, Simulator, State, register_part
from hhra_phys.errors import ParameterError
from hhra_phys.models.hhra.rig import default_input
from hhra_phys.simulate import (
    MAX_AUTO_SUBSTEPS,
    STATUS_DIVERGED,
    STATUS_OK,
    STATUS_UNSTABLE,
    CodeOptions,
)


@pytest.fixture(scope="module")
def setup():
    model = HHRAModel()
    sim = Simulator(model, fs=250.0)
    u = default_input(duration=4.0, seed=3)
    return model, sim, u


def test_contract_shapes(setup):
    model, sim, u = setup
    y = sim.simulate(u, model.nominal())
    assert y.shape == u.shape
    P = np.tile(model.nominal(), (4, 1))
    Y = sim.simulate(u, P)
    assert Y.shape == (4, u.size)
    np.testing.assert_array_equal(Y[2], y)


def test_against_cvodes_reference(setup):
    model, sim, u = setup
    y = sim.simulate(u, model.nominal())
    y_ref = sim.reference(u, model.nominal())
    # A tenth of the rig's default noise (0.05 deg) is the target; RK4 does far better.
    assert np.max(np.abs(y - y_ref)) < 5e-3
    assert np.max(np.abs(y_ref)) > 5  # the record moves the shaft


def test_population_rows_equal_single_runs(setup):
    model, sim, u = setup
    rng = np.random.default_rng(0)
    P = model.nominal() * rng.uniform(0.6, 1.4, (7, model.n_params))
    Y = sim.simulate(u, P)
    for i in (0, 3, 6):
        np.testing.assert_allclose(Y[i], sim.simulate(u, P[i]), rtol=0, atol=1e-12)


def test_unstable_and_nan_rows_are_flagged_not_raised(setup):
    model, sim, u = setup
    P = np.tile(model.nominal(), (4, 1))
    P[1, model.params.index("g_torque")] *= 1e5  # hydraulic resonance far beyond RK4's reach
    P[2, model.params.index("g_leak")] = np.nan
    Y = sim.simulate(u, P)
    assert np.isfinite(Y[0]).all() and np.isfinite(Y[3]).all()
    assert np.isnan(Y[1]).all() and np.isnan(Y[2]).all()
    assert sim.last_status[0] == STATUS_OK
    assert sim.last_status[1] == STATUS_UNSTABLE
    assert sim.last_status[2] in (STATUS_UNSTABLE, STATUS_DIVERGED)


def test_parameters_asking_for_hundreds_of_substeps_are_flagged_not_built(setup):
    """One member far off the model's range: no simulator beyond MAX_AUTO_SUBSTEPS is
    generated for it (a loop candidate's asked for 587,127 and grew to gigabytes)."""
    model, sim, u = setup
    p = model.nominal().copy()
    p[model.params.index("g_torque")] *= 1e5
    assert sim.plan(p, float(np.max(np.abs(u))))[1] > MAX_AUTO_SUBSTEPS
    with pytest.warns(RuntimeWarning, match=f"more than {MAX_AUTO_SUBSTEPS}"):
        y = sim.simulate(u, p)
    assert np.isnan(y).all() and sim.last_status[0] == STATUS_UNSTABLE
    assert sim.last_substeps <= MAX_AUTO_SUBSTEPS
    ros = Simulator(model, fs=250.0, method="ros4")
    assert ros.plan(p, float(np.max(np.abs(u))), method="ros4")[1] > MAX_AUTO_SUBSTEPS
    ros.simulate(u, p)
    assert ros.last_substeps <= MAX_AUTO_SUBSTEPS


@register_part
@dataclass(frozen=True)
class _FastModes(Part):
    """A relaxation ``a`` and a resonance ``b`` far faster than a 250 Hz sample rate."""

    name = "fast_modes"
    stage = "fast_modes"

    @property
    def parameters(self):
        return (Parameter("k_relax", "1/s", 1e9, 1.0, 1e12, "log", "relaxation rate"),
                Parameter("w_res", "rad/s", 1e5, 1.0, 1e9, "log", "resonance"))

    @property
    def states(self):
        return (State("a", "", 0.0, "relaxing state"), State("b", "", 0.0, "position"),
                State("c", "", 0.0, "velocity"))

    def apply(self, ctx):
        ctx.add_rate("a", -ctx.p["k_relax"] * ctx.x["a"] + ctx.u)
        ctx.add_rate("b", ctx.x["c"])
        ctx.add_rate("c", -ctx.p["w_res"] ** 2 * ctx.x["b"] + ctx.x["a"])
        ctx.signals["y"] = ctx.x["b"]


def test_a_given_count_is_a_floor_under_the_stiff_rule_up_to_its_cap():
    """Stiff at its nominal values: ROS4 and the rule's substeps over a given count, but
    never more than MAX_AUTO_SUBSTEPS (a loop candidate's start asked for 459,462)."""
    model = Model([_FastModes()], name="fast")
    sim = Simulator(model, fs=250.0, substeps=2, backend="casadi")
    method, n_rule, _ = sim.plan(model.nominal())
    assert method == "ros4" and n_rule > MAX_AUTO_SUBSTEPS
    assert sim.method == "ros4" and sim.substeps == MAX_AUTO_SUBSTEPS
    assert f"{n_rule} substeps capped at {MAX_AUTO_SUBSTEPS}" in sim.method_reason
    slower = model.with_nominal(w_res=1e3)  # the rule's 16, over the given 2
    assert Simulator(slower, fs=250.0, substeps=2, backend="casadi").substeps == \
        Simulator(slower, fs=250.0).plan(slower.nominal())[1] == 16


def test_marginal_candidate_is_not_silently_wrong(setup):
    """A candidate RK4 cannot integrate at this step is flagged, not returned as numbers."""
    model, sim, u = setup
    p = model.nominal().copy()
    p[model.params.index("g_torque")] *= 400
    p[model.params.index("g_compress")] *= 40
    y = sim.simulate(u, p)
    if np.isfinite(y).all():  # accepted: then it must be accurate
        assert np.max(np.abs(y - sim.reference(u, p))) < 0.05
    else:
        assert sim.last_status[0] != STATUS_OK


def test_initial_state_and_states_output(setup):
    model, sim, u = setup
    x0 = np.array([0.5, 0.0, 0.0])
    y, X = sim.simulate(u, model.nominal(), x0=x0, states=True)
    assert y[0] == pytest.approx(np.degrees(0.5))
    assert X.shape == (u.size, 3)
    np.testing.assert_allclose(np.degrees(X[:, 0]), y, atol=1e-12)
    with pytest.raises(ParameterError, match="x0 has shape"):
        sim.simulate(u, model.nominal(), x0=np.zeros(5))


def test_bad_inputs_raise_clear_errors(setup):
    model, sim, u = setup
    with pytest.raises(ParameterError, match="n_pop, 7"):
        sim.simulate(u, np.ones((3, 2)))
    bad = u.copy()
    bad[10] = np.nan
    with pytest.raises(ParameterError, match="non-finite samples"):
        sim.simulate(bad, model.nominal())
    with pytest.raises(ParameterError, match="fs must be"):
        Simulator(model, fs=-1)


def test_casadi_backend_gives_the_same_numbers(setup):
    model, sim, u = setup
    vm = Simulator(model, fs=250.0, backend="casadi")
    P = np.tile(model.nominal(), (3, 1)) * np.array([[1.0], [1.1], [0.9]])
    np.testing.assert_allclose(vm.simulate(u[:500], P), sim.simulate(u[:500], P), atol=1e-9)


def test_block_padding_does_not_change_results(setup):
    model, sim, u = setup
    odd = u[:997]
    other = Simulator(model, fs=250.0, block=7)
    np.testing.assert_allclose(other.simulate(odd, model.nominal()),
                               sim.simulate(odd, model.nominal()), atol=1e-12)


def test_spool_lag_model_simulates(setup):
    _, _, u = setup
    model = HHRAModel(spool_lag=True)
    sim = Simulator(model, fs=250.0)
    y = sim.simulate(u, model.nominal())
    assert np.max(np.abs(y - sim.reference(u, model.nominal()))) < 5e-3


@pytest.mark.parametrize("layout", [{"block": 7, "chunk": 90}, {"lanes": 2, "threads": 1}])
def test_code_options_object_and_keywords_build_one_simulator(setup, layout):
    """The code layout as a CodeOptions or as keywords (which override it) is the same
    simulator; neither changes the numbers."""
    model, sim, u = setup
    a = Simulator(model, fs=250.0, code=CodeOptions(**layout), backend="casadi")
    b = Simulator(model, fs=250.0, backend="casadi", **layout)
    c = Simulator(model, fs=250.0, code=CodeOptions(block=3, lanes=1), backend="casadi",
                  **{"block": 10, "lanes": 4, **layout})
    for other in (b, c):
        assert (other.block, other.lanes, other.chunk, other.threads) == (
            a.block, a.lanes, a.chunk, a.threads)
    assert a.code == CodeOptions(**layout)
    np.testing.assert_allclose(a.simulate(u[:400], model.nominal()),
                               sim.simulate(u[:400], model.nominal()), rtol=0, atol=1e-10)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"threads": 0}, "threads must be a positive integer"),
    ({"chunk": 2.5}, "chunk must be a positive integer"),
    ({"simd": 6}, "simd must be a power of two"),
    ({"simd": "wide"}, "simd must be 'auto'"),
    ({"blocks": 3}, "unknown simulator code setting.*blocks"),
    ({"method": "euler"}, "method must be 'auto' or one of"),
])
def test_simulator_settings_are_named_before_any_work(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        Simulator(HHRAModel(), fs=250.0, **kwargs)
