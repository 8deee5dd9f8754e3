"""Tests of hhra_phys.control: linearisation, discretisation, closed loop, uncertainty."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import control as ct
import numpy as np
import pytest

from hhra_phys import HHRAModel, Simulator
from hhra_phys import control as hc
from hhra_phys.arx import tustin_arx
from hhra_phys.errors import ParameterError
from hhra_phys.fit import fit
from hhra_phys.models.hhra.rig import simulate_rig
from hhra_phys.parameters import Parameter
from hhra_phys.parts import Context, Part, smooth_sign


@pytest.fixture(scope="module")
def small_fit():
    data = simulate_rig(seed=0, duration=4.0)
    return fit(data, pop_size=10, max_iter=5, seed=0)


def _coeffs(tf: ct.TransferFunction) -> tuple[np.ndarray, np.ndarray]:
    num = np.trim_zeros(np.asarray(tf.num[0][0], float), "f")
    den = np.asarray(tf.den[0][0], float)
    return num / den[0], den / den[0]


def test_linearize_at_rest_is_the_paper_tf():
    model = HHRAModel()
    sys = hc.linearize(model)
    assert sys.state_labels == ["theta", "omega", "p"]
    assert sys.input_labels == ["current"] and sys.output_labels == ["angle"]
    assert ct.isctime(sys, strict=True)
    tf = model.tf_coefficients()
    # Compare the characteristic polynomial and the high-frequency gain (C A^2 B).
    den = np.poly(sys.A)
    np.testing.assert_allclose(den, [1.0, tf["b"], tf["c"], 0.0], rtol=1e-10, atol=1e-9)
    kv_deg = (sys.C @ sys.A @ sys.A @ sys.B).item()
    assert kv_deg == pytest.approx(math.degrees(tf["kv"]), rel=1e-12)
    # Same frequency response as the paper's TF built from the groups.
    w = np.logspace(-1, 3, 40)
    np.testing.assert_allclose(sys(1j * w).ravel(), hc.paper_tf(model)(1j * w), rtol=1e-9)
    np.testing.assert_allclose(hc.to_tf(model)(1j * w), hc.paper_tf(model)(1j * w), rtol=1e-9)


def test_linearize_fit_result_uses_fitted_values(small_fit):
    sys = hc.linearize(small_fit)
    tf = small_fit.tf
    np.testing.assert_allclose(np.poly(sys.A), [1.0, tf["b"], tf["c"], 0.0], rtol=1e-9, atol=1e-9)
    w = np.logspace(0, 3, 20)
    np.testing.assert_allclose(sys(1j * w).ravel(), hc.paper_tf(small_fit)(1j * w), rtol=1e-9)
    # A parameter override changes the model.
    g = small_fit.values["g_valve"]
    sys2 = hc.linearize(small_fit, params={"g_valve": 2 * g})
    np.testing.assert_allclose(sys2(10j), 2 * sys(10j), rtol=1e-12)


def test_linearize_operating_point_is_exact_jacobian():
    model = HHRAModel(spool_lag=True)
    op = hc.OperatingPoint(current=0.4, angle=20.0, pressure=0.3, velocity=5.0)
    sys = hc.linearize(model, op)
    assert sys.state_labels == ["theta", "omega", "p", "xs"]
    x = op.state_vector(model)
    assert x[3] == pytest.approx(0.4)  # spool at the current
    f = model.functions(0.004)["f"]
    p = model.nominal()
    eps = 1e-6
    A_fd = np.column_stack([
        (np.array(f(x + eps * e, [op.current], p)) - np.array(f(x - eps * e, [op.current], p)))
        .ravel() / (2 * eps) for e in np.eye(4)
    ])
    np.testing.assert_allclose(sys.A, A_fd, rtol=1e-6, atol=1e-6)
    # Away from rest the orifice's flow-pressure gain is not zero.
    rest = hc.linearize(model)
    assert sys.A[2, 2] < rest.A[2, 2] - 1.0


@pytest.mark.parametrize(
    ("kwargs", "word"),
    [({"pressure": 1.2}, "pressure"), ({"angle": math.nan}, "angle"),
     ({"states": {"nope": 1.0}}, "nope")],
)
def test_operating_point_errors_name_the_field(kwargs, word):
    with pytest.raises(ParameterError, match=word):
        hc.linearize(HHRAModel(), hc.OperatingPoint(**kwargs))


def test_small_step_matches_nonlinear_simulation():
    model = HHRAModel()
    fs = 1000.0
    n = 600
    u = np.full(n, 0.01)  # 1 % of the rig's largest current
    y_nl = Simulator(model, fs=fs).simulate(u, model.nominal())
    lin = hc.discretize(hc.linearize(model), 1 / fs, "zoh")
    y_lin = ct.forced_response(lin, np.arange(n) / fs, u).outputs
    assert np.max(np.abs(y_lin - y_nl)) < 1e-3 * np.max(np.abs(y_nl))
    # A large step is visibly nonlinear (the orifice's pressure drop): the test can fail.
    u_big = np.full(n, 1.0)
    y_big = Simulator(model, fs=fs).simulate(u_big, model.nominal())
    y_lin_big = ct.forced_response(lin, np.arange(n) / fs, u_big).outputs
    assert np.max(np.abs(y_lin_big - y_big)) > 1e-3 * np.max(np.abs(y_big))


def test_discretize_methods_and_errors():
    sys = hc.linearize(HHRAModel())
    zoh = hc.discretize(sys, 0.004)
    tus = hc.discretize(sys, 0.004, "tustin")
    assert zoh.dt == pytest.approx(0.004) and tus.dt == pytest.approx(0.004)
    assert zoh.state_labels == sys.state_labels
    # Both keep the integrator at z = 1 and the resonance inside the unit circle.
    for d in (zoh, tus):
        assert np.min(np.abs(d.poles() - 1.0)) < 1e-9
        assert np.all(np.abs(d.poles()) <= 1.0 + 1e-12)
    assert not np.allclose(zoh.B, tus.B)
    with pytest.raises(ParameterError, match="method"):
        hc.discretize(sys, 0.004, "euler")
    with pytest.raises(ParameterError, match="dt"):
        hc.discretize(sys, -1.0)
    with pytest.raises(ParameterError, match="continuous"):
        hc.discretize(zoh, 0.004)


def test_arx_round_trip_through_tustin():
    tf = HHRAModel().tf_coefficients()
    dt = 0.004
    arx = tustin_arx(tf["a"], tf["b"], tf["c"], math.degrees(tf["kv"]), dt)
    sys = hc.linearize(arx, dt=dt)
    assert sys.input_labels == ["current"]
    np.testing.assert_allclose(np.poly(sys.A), [1.0, tf["b"], tf["c"], 0.0], rtol=1e-6,
                               atol=1e-6)
    w = np.logspace(0, 2.5, 15)
    np.testing.assert_allclose(sys(1j * w).ravel(), hc.paper_tf(HHRAModel())(1j * w), rtol=1e-6)
    back = hc.discretize(sys, dt, "tustin")
    z = np.exp(1j * w * dt)
    np.testing.assert_allclose(back(z).ravel(), arx.to_control(dt)(z), rtol=1e-6)
    with pytest.raises(ParameterError, match="dt"):
        hc.linearize(arx)


def _p_controller(k: float, dt: float) -> ct.StateSpace:
    return ct.ss([], [], [], [[k]], dt=dt)


def test_closed_loop_tracks_a_step_on_the_nominal_model():
    model = HHRAModel()
    dt = 0.002
    loop = hc.ClosedLoop(model, _p_controller(0.1, dt), dt=dt, current_limit=0.5)
    resp = loop.step(10.0, duration=3.0)
    info = resp.step_info()
    assert abs(info["steady_state_error"]) < 0.02
    assert info["overshoot"] < 5.0
    assert 0.1 < info["rise_time"] < 1.0
    assert np.max(np.abs(resp.u)) <= 0.5 + 1e-12
    assert np.max(np.abs(resp.u_demand)) == pytest.approx(1.0)  # 0.1 mA/deg * 10 deg
    assert resp.x.shape == (resp.t.size, 3)
    # The same controller as a callable gives the same run.
    same = hc.ClosedLoop(model, lambda t, r, y: 0.1 * (r - y), dt=dt, current_limit=0.5)
    np.testing.assert_allclose(same.step(10.0, 3.0).y, resp.y, rtol=0, atol=1e-12)
    # Without saturation a small step follows the linear design model closely.
    nl = hc.ClosedLoop(model, _p_controller(0.1, dt), dt=dt).step(0.5, 1.0)
    lin = hc.ClosedLoop(hc.linearize(model), _p_controller(0.1, dt), dt=dt).step(0.5, 1.0)
    assert np.max(np.abs(nl.y - lin.y)) < 2e-3 * 0.5


def test_closed_loop_rate_limit_and_two_input_controller():
    model = HHRAModel()
    dt = 0.002
    two = ct.ss([], [], [], [[0.1, -0.1]], dt=dt)  # u = 0.1 r - 0.1 y, inputs [r, y]
    resp = hc.ClosedLoop(model, two, dt=dt, rate_limit=10.0).step(5.0, 0.5)
    assert np.max(np.abs(np.diff(resp.u))) <= 10.0 * dt + 1e-12
    ref = hc.ClosedLoop(model, _p_controller(0.1, dt), dt=dt, rate_limit=10.0).step(5.0, 0.5)
    np.testing.assert_allclose(resp.y, ref.y, atol=1e-12)


@dataclass(frozen=True)
class _DryFriction(Part):
    """A test effect: smooth Coulomb friction on the shaft (extra parameter)."""

    stage: ClassVar[str] = "motion"
    name: ClassVar[str] = "test_friction"

    @property
    def parameters(self):
        return (Parameter("g_dry", "rad/s^2", 20.0, 0.0, 1e3, "linear", "dry friction"),)

    def apply(self, ctx: Context) -> None:
        ctx.add_rate("omega", -ctx.p["g_dry"] * smooth_sign(ctx.x["omega"], 1e-3))


def test_closed_loop_runs_models_with_effects():
    dt = 0.002
    plain = HHRAModel(spool_lag=True)
    model = plain.with_parts(_DryFriction())
    loop = hc.ClosedLoop(model, _p_controller(0.1, dt), dt=dt, current_limit=1.0)
    resp = loop.step(10.0, duration=1.0)
    assert resp.state_names == ["theta", "omega", "p", "xs"]
    base = hc.ClosedLoop(plain, _p_controller(0.1, dt), dt=dt, current_limit=1.0).step(10.0, 1.0)
    # Friction leaves a steady error that the P controller does not remove.
    assert resp.step_info()["steady_state_error"] > base.step_info()["steady_state_error"] + 0.01
    assert abs(resp.y[-1] - 10.0) < 1.0


def test_closed_loop_argument_errors():
    model = HHRAModel()
    with pytest.raises(ParameterError, match="continuous"):
        hc.ClosedLoop(model, ct.tf([1.0], [1.0, 1.0]), dt=0.002)
    with pytest.raises(ParameterError, match="sample time"):
        hc.ClosedLoop(model, _p_controller(0.1, 0.01), dt=0.002)
    with pytest.raises(ParameterError, match="current_limit"):
        hc.ClosedLoop(model, _p_controller(0.1, 0.002), dt=0.002, current_limit=-1.0)
    with pytest.raises(ParameterError, match="controller"):
        hc.ClosedLoop(model, "pid", dt=0.002)
    with pytest.raises(ParameterError, match="duration"):
        hc.ClosedLoop(model, _p_controller(0.1, 0.002), dt=0.002).run(np.sin)


def test_sampling_shapes_reproducibility_and_spread(small_fit):
    model = small_fit.model
    P1 = hc.sample_parameters(small_fit, 400, seed=3)
    P2 = hc.sample_parameters(small_fit, 400, seed=3)
    P3 = hc.sample_parameters(small_fit, 400, seed=4)
    assert P1.shape == (400, model.n_params)
    np.testing.assert_array_equal(P1, P2)
    assert not np.allclose(P1, P3)
    # Fixed parameters stay put, log groups positive, spread as the fit's std.
    for name in ("g_spring", "g_load"):
        assert np.all(P1[:, model.params.index(name)] == small_fit.values[name])
    i = model.params.index("g_valve")
    z = np.log10(P1[:, i])
    assert np.all(P1[:, i] > 0)
    assert np.std(z) == pytest.approx(small_fit.std["g_valve"], rel=0.15)
    assert np.mean(z) == pytest.approx(math.log10(small_fit.values["g_valve"]), abs=0.01)
    # Correlations are carried over.
    j = model.params.index("g_torque")
    k = small_fit.free.index("g_valve"), small_fit.free.index("g_torque")
    r = np.corrcoef(z, np.log10(P1[:, j]))[0, 1]
    assert r == pytest.approx(small_fit.correlation[k], abs=0.1)

    models = hc.sample_models(small_fit, 6, seed=1)
    assert len(models) == 6 and all(m.nstates == 3 for m in models)
    assert len({float(m.A[1, 2]) for m in models}) == 6
    margins = hc.loop_margins(models, _p_controller(0.05, 0.004))
    assert margins["pm"].shape == (6,) and margins["stable"].all()
    assert np.all(margins["gm"] > 6.0)


def test_sampling_refuses_unidentified_parameters(small_fit):
    import copy

    bad = copy.copy(small_fit)
    bad.std = dict(small_fit.std, g_leak=math.inf)
    with pytest.raises(ParameterError, match="g_leak"):
        hc.sample_parameters(bad, 5)
