"""The HHRA model: equations, parameter views, derivatives and transfer function."""

from __future__ import annotations

import math

import casadi as ca
import control
import numpy as np
import pytest

from hhra_phys import HHRAModel, Model
from hhra_phys.errors import ModelError, ParameterError
from hhra_phys.models.hhra import (
    AngleOutput,
    ChamberPressure,
    CurrentCommand,
    OrificeValve,
    RotaryMotion,
)
from hhra_phys.models.hhra.physical import PhysicalParameters


def test_default_parameters_are_the_rig_groups():
    model = HHRAModel()
    groups = PhysicalParameters().groups()
    for name in model.params.names:
        assert model.params[name].nominal == pytest.approx(groups[name])
    assert model.state_names == ["theta", "omega", "p"]


def test_equations_match_paper_form_at_a_point():
    """xdot from the composed parts equals the hand-written groups equations."""
    model = HHRAModel()
    f = model.functions(0.004)["f"]
    d = model.params.as_dict(model.nominal())
    x = np.array([0.3, -0.7, 0.4])
    u = 0.8
    got = np.array(f(x, [u], model.nominal())).ravel()
    root = math.sqrt(1 - x[2])  # sign(u) = +1; the smoothing changes it by < 0.05 % here
    expect = [
        x[1],
        d["g_torque"] * x[2] - d["g_damping"] * x[1],
        d["g_valve"] * u * root - d["g_compress"] * x[1] - d["g_leak"] * x[2],
    ]
    np.testing.assert_allclose(got, expect, rtol=5e-4)


def test_physical_groups_round_trip():
    phys = PhysicalParameters()
    groups = {k: v for k, v in phys.groups().items() if k != "g_kp"}
    scaled = {k: v * 1.3 for k, v in groups.items()}
    back = phys.from_groups(scaled)
    for k, v in back.groups().items():
        if k in scaled:
            assert v == pytest.approx(scaled[k], rel=1e-12)
    assert back.J != pytest.approx(phys.J)


def test_from_groups_rejects_impossible_group():
    with pytest.raises(ParameterError, match="J would be negative"):
        PhysicalParameters().from_groups({"g_torque": 1e9})


def test_derivatives_against_finite_differences():
    model = HHRAModel()
    x, u, p = model.symbols()
    xdot, y = model.assemble(x, u, p, 0.004)
    jac = ca.Function("jx", [x, u, p], [ca.jacobian(xdot, x), ca.jacobian(xdot, p),
                                        ca.jacobian(xdot, u)])
    f = ca.Function("ff", [x, u, p], [xdot])
    rng = np.random.default_rng(1)
    for _ in range(5):
        xv = rng.uniform([-1, -2, -0.8], [1, 2, 0.8])
        uv = rng.uniform(-1, 1, 1)
        pv = model.nominal() * rng.uniform(0.5, 2, model.n_params)
        Jx, Jp, Ju = (np.array(m) for m in jac(xv, uv, pv))
        for arg, J in ((0, Jx), (2, Jp), (1, Ju)):
            base = [xv, uv, pv]
            n = base[arg].size
            fd = np.zeros((3, n))
            for i in range(n):
                step = 1e-6 * max(1.0, abs(base[arg][i]))
                plus = [b.copy() for b in base]
                minus = [b.copy() for b in base]
                plus[arg][i] += step
                minus[arg][i] -= step
                fd[:, i] = (np.array(f(*plus)) - np.array(f(*minus))).ravel() / (2 * step)
            np.testing.assert_allclose(J, fd, rtol=1e-5, atol=1e-6)


def test_tf_coefficients_three_ways():
    """Groups TF == paper's physical TF (normalised) == CasADi linearisation == python-control."""
    phys = PhysicalParameters()
    model = HHRAModel()
    tf_groups = model.tf_coefficients()
    tf_phys = phys.tf_coefficients()
    for key in ("b", "c", "kv"):
        assert tf_groups[key] == pytest.approx(tf_phys[key] / tf_phys["a"], rel=1e-10)

    A, B, C, D = model.linearize()
    C_rad = C / (180 / math.pi)  # the model's output is in degrees
    sys_lin = control.ss(A, B, C_rad, D)
    num, den = control.tfdata(control.ss2tf(sys_lin))
    num = np.trim_zeros(np.ravel(num[0][0]), "f")
    den = np.ravel(den[0][0])
    den_n = den / den[0]
    np.testing.assert_allclose(den_n, [1, tf_groups["b"], tf_groups["c"], 0], rtol=1e-6,
                               atol=1e-8 * tf_groups["c"])
    assert num[-1] / den[0] == pytest.approx(tf_groups["kv"], rel=1e-6)

    G = control.tf([tf_phys["kv"]], [tf_phys["a"], tf_phys["b"], tf_phys["c"], 0])
    w = np.logspace(0, 3, 20)
    np.testing.assert_allclose(G(1j * w), sys_lin(1j * w).ravel(), rtol=1e-6)


def test_linear_valve_tf_includes_pressure_gain():
    model = HHRAModel(valve="linear")
    tf = model.tf_coefficients()
    d = model.params.as_dict(model.nominal())
    assert tf["b"] == pytest.approx(d["g_damping"] + d["g_leak"] + d["g_kp"])
    kp = d["g_kp"] * PhysicalParameters().compliance
    phys_tf = PhysicalParameters().tf_coefficients(k_pa=kp)
    assert tf["c"] == pytest.approx(phys_tf["c"] / phys_tf["a"], rel=1e-10)


def test_model_composition_and_errors():
    base = Model([CurrentCommand(), OrificeValve(), ChamberPressure(), RotaryMotion(),
                  AngleOutput()])
    assert base.nx == 3
    with pytest.raises(ModelError, match="no output part"):
        Model([CurrentCommand(), OrificeValve(), ChamberPressure(), RotaryMotion()]).functions(0.01)
    with pytest.raises(ModelError, match="needs signal 'command'"):
        Model([OrificeValve(), ChamberPressure(), RotaryMotion(), AngleOutput()]).functions(0.01)
    with pytest.raises(ParameterError, match="duplicate parameter"):
        Model([CurrentCommand(), OrificeValve(), OrificeValve(), ChamberPressure(),
               RotaryMotion(), AngleOutput()])
    lagged = HHRAModel(spool_lag=True)
    assert lagged.state_names == ["theta", "omega", "p", "xs"]
    assert "tau_v" in lagged.params
    assert not HHRAModel().without("angle_output").has_part("angle_output")
    with pytest.raises(ParameterError, match="unknown parameter 'nope'"):
        HHRAModel().params.index("nope")


def test_with_nominal_widens_bounds_and_json_round_trip():
    model = HHRAModel(nominal={"g_leak": 1000.0})
    par = model.params["g_leak"]
    assert par.nominal == 1000.0 and par.lower <= 1000.0 <= par.upper
    again = Model.from_json(model.to_json())
    assert isinstance(again, HHRAModel)
    assert again.params.names == model.params.names
    np.testing.assert_array_equal(again.nominal(), model.nominal())
    pressure = HHRAModel(output="pressure")
    assert Model.from_json(pressure.to_json()).part_names() == pressure.part_names()


def test_parameter_vector_helpers():
    model = HHRAModel()
    v = model.params.vector(g_leak=2.0)
    assert v[model.params.index("g_leak")] == 2.0
    with pytest.raises(ParameterError, match="expected \\(7,\\)"):
        model.params.as_dict(np.ones(3))
    with pytest.raises(ParameterError, match="n_pop, 7"):
        model.params.check_population(np.ones((2, 3)))


def test_a_user_part_named_like_a_library_class_does_not_replace_it():
    """A user's ``GravityLoad`` part beside the library's ``GravityLoad`` effect: both load."""
    from dataclasses import dataclass
    from typing import ClassVar

    from hhra_phys.effects import GravityLoad as LibraryGravity
    from hhra_phys.parameters import Parameter
    from hhra_phys.parts import PART_TYPES, Part, part_type_name, register_part

    @register_part
    @dataclass(frozen=True)
    class GravityLoad(Part):
        stage: ClassVar[str] = "motion"

        @property
        def parameters(self):
            return (Parameter("g_gravity", "rad/s^2", 1.0, 0.01, 100.0, "log", "gravity"),)

        def apply(self, ctx):
            ctx.add_rate("omega", -ctx.p["g_gravity"] * ca.sin(ctx.x["theta"]))

    try:
        assert PART_TYPES["GravityLoad"] is LibraryGravity
        assert part_type_name(LibraryGravity) == "GravityLoad"
        assert part_type_name(GravityLoad).endswith(".GravityLoad")
        base = HHRAModel()
        user = Model([*base.parts, GravityLoad()], name="user")
        lib = Model([*base.parts, LibraryGravity()], name="lib")
        for model, cls in ((user, GravityLoad), (lib, LibraryGravity)):
            again = Model.from_json(model.to_json())
            assert type(again.parts[-1]) is cls
            assert again.params.names == model.params.names
    finally:
        PART_TYPES.pop(part_type_name(GravityLoad), None)
    with pytest.raises(ModelError, match="import the module"):
        Model.from_json({"parts": [{"type": "nowhere.Missing", "args": {}}]})
