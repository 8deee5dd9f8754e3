"""Roles, not names: library effects bind to a model's velocity and position by role.

A model declares the physical role of its states (``State(..., role="velocity")``);
``coulomb_friction``, ``constant_force`` and ``gravity_load`` act on the rate of the
model's velocity whatever it is called, and an effect that cannot bind says which role
it needs and how to declare it. The HHRA's equations are the same as before roles
(``omega`` and ``theta`` bound by their roles).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from hhra_phys import Model, Parameter, Part, State
from hhra_phys.diagnosis.screening import entry_points, input_twin
from hhra_phys.effects import EFFECTS, library_twins, make_effect, motion_scales
from hhra_phys.errors import ModelError
from hhra_phys.models.cylinder import LinearCylinderModel
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.models.resonator import make_model as make_resonator
from hhra_phys.parts import ROLES, Motion

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration" / "user_models"))
import drive  # noqa: E402
import two_tank  # noqa: E402


def _rate(model: Model, state: str) -> ca.SX:
    x, u, p = model.symbols()
    xdot, _ = model.assemble(x, u, p, 0.001)
    return xdot[model.state_names.index(state)], x, u, p


def test_the_bundled_models_declare_roles():
    assert HHRAModel().motion == Motion("omega", "theta", True, "")
    assert LinearCylinderModel().motion == Motion("v", "x", False, "")
    assert make_resonator().motion == Motion("v", "x", False, "")
    assert drive.make_model().motion == Motion("v", "q", False, "")
    roles = {s.name: s.role for s in HHRAModel().states}
    assert roles == {"theta": "angle", "omega": "angular_velocity", "p": "effort"}
    assert set(ROLES) >= {"position", "velocity", "angle", "angular_velocity", "effort",
                          "level", "flow"}


def test_friction_and_constant_force_act_on_the_users_velocity():
    model = drive.make_model()
    fr = make_effect("coulomb_friction", model=model)
    cf = make_effect("constant_force", model=model)
    for eff in (fr, cf, make_effect("input_offset", model=model)):
        assert eff.applicable(model) is None, eff.name
    assert fr.entry_at(model) == cf.entry_at(model) == "rate:v"
    assert make_effect("input_offset").entry_at(model) == "input"
    both = model.with_parts(fr, cf)
    rate, x, u, p = _rate(both, "v")
    names = both.params.names
    f = ca.Function("f", [x, u, p], [rate])
    vals = dict(zip(names, both.nominal().tolist(), strict=True))
    vals.update(k_motor=2.0, c_visc=5.0, g_coulomb=0.3, g_const=0.1)
    pv = np.array([vals[n] for n in names])
    # dv/dt = k u - c v - g_coulomb sgn(v) + g_const, at v = 0.1 m/s (far beyond the width)
    got = float(f([0.0, 0.1], [0.5], pv))
    assert got == pytest.approx(2.0 * 0.5 - 5.0 * 0.1 - 0.3 * 0.1 / np.hypot(0.1, fr.width)
                                + 0.1, rel=1e-12)
    q_rate, *_ = _rate(both, "q")
    assert not ca.depends_on(q_rate, p)  # nothing added to the kinematic equation


def test_motion_effects_are_scaled_in_the_models_units():
    model = drive.make_model()
    fr = make_effect("coulomb_friction", model=model)
    # accel_scale: the command's full scale through k_motor (nominal 2 m/s^2/V, 1 V).
    assert fr.accel_scale == pytest.approx(2.0)
    assert fr.v_unit == "m/s" and fr.v_scale == 0.2
    assert fr.width == pytest.approx(0.005 * 0.2)
    g = {p.name: p for p in fr.parameters}["g_coulomb"]
    assert g.unit == "m/s^2" and g.upper == pytest.approx(0.6 * 2.0)
    st = make_effect("coulomb_friction", model=model, stribeck=True, fit_width=True)
    units = {p.name: p.unit for p in st.parameters}
    assert units == {"g_coulomb": "m/s^2", "g_stribeck": "m/s^2", "v_stribeck": "m/s",
                     "v_switch": "m/s"}
    assert {p.name: p for p in st.parameters}["v_switch"].upper == pytest.approx(0.1)
    # the cylinder: the force group at full load pressure, as g_torque on the HHRA
    cyl = LinearCylinderModel()
    c_force = cyl.params["c_force"].nominal
    assert motion_scales(cyl)["accel_scale"] == pytest.approx(c_force)
    # the HHRA keeps g_torque and the rig's units
    hh = make_effect("coulomb_friction", model=HHRAModel(), values={"g_torque": 150.0})
    assert (hh.accel_scale, hh.v_unit, hh.v_scale, hh.width) == (150.0, "rad/s", 1.0, 0.005)


def test_an_effect_that_cannot_bind_names_the_role_and_how_to_declare_it():
    tank = two_tank.make_model()
    why = make_effect("coulomb_friction").applicable(tank)
    assert "coulomb_friction needs a state with role 'velocity'" in why
    assert "State(..., role='velocity')" in why
    assert "constant_force needs a state with role 'velocity'" in \
        make_effect("constant_force").applicable(tank)
    why = make_effect("gravity_load").applicable(drive.make_model())
    assert "rotary position" in why and "role='angle'" in why and "constant_force" in why
    # the HHRA's backlash (an encoder in degrees) on a cylinder measured in mm: built anew
    why = make_effect("backlash").applicable(LinearCylinderModel())
    assert "1000" in why and "make_effect('backlash', model=...)" in why
    assert make_effect("backlash", model=LinearCylinderModel()).applicable(
        LinearCylinderModel()) is None
    assert "backlash needs a state with role 'velocity'" in make_effect("backlash").applicable(
        tank)


def test_a_backlash_binds_a_linear_drive_in_its_own_units():
    model = drive.make_model()
    rec = drive.simulate_record(seed=1, n=600)
    bl = make_effect("backlash", model=model, data=rec)
    assert bl.applicable(model) is None
    # 2 % of the position's scale (0.05 m) in the output's unit (mm): a play box in mm
    assert bl.slope == pytest.approx(1000.0) and bl.play_scale == pytest.approx(1.0)
    play = next(p for p in bl.parameters if p.name == "play")
    assert (play.unit, play.nominal, play.lower, play.upper) == ("mm", 0.5, 0.02, 10.0)
    assert bl.states[0].unit == "m" and bl.speed == pytest.approx(0.2)  # the velocity's scale
    # the HHRA keeps its own defaults: the same effect as the library's default
    from hhra_phys import HHRAModel
    assert make_effect("backlash", model=HHRAModel()) == make_effect("backlash")


def test_the_drives_backlash_lags_the_sensor_by_the_play_after_a_reversal():
    from hhra_phys import Simulator
    model = drive.make_model()
    bl = make_effect("backlash", model=model, width=0.001)
    with_play = model.with_parts(bl)
    fs, n = 1000.0, 2000
    u = np.where(np.arange(n) < n // 2, 0.5, -0.5)  # push one way, then the other
    p0 = model.nominal()
    base = dict(zip(model.params.names, p0, strict=True))
    p1 = np.array([base.get(k, 0.4) for k in with_play.params.names])  # play 0.4 mm
    y0 = Simulator(model, fs=fs).simulate(u, p0)
    y1 = Simulator(with_play, fs=fs).simulate(u, p1)
    # carried one way the sensor trails by half the play (mm), the other way it leads by it
    assert y1[n // 2 - 1] - y0[n // 2 - 1] == pytest.approx(-0.2, abs=0.01)
    assert y1[-1] - y0[-1] == pytest.approx(0.2, abs=0.01)


def test_only_the_friction_takes_the_motions_switching_width():
    from hhra_phys.effects import CORNER_WIDTH, FRICTION_WIDTH
    model = drive.make_model()
    rec = drive.simulate_record(seed=1, n=600)
    assert make_effect("coulomb_friction", model=model, data=rec).width == \
        pytest.approx(FRICTION_WIDTH * 0.2)
    for name in ("valve_deadzone", "valve_saturation"):  # a corner relative to u_scale
        assert make_effect(name, model=model, data=rec).width == CORNER_WIDTH


@dataclass(frozen=True)
class _TwoMasses(Part):
    name = "two_masses"
    stage = "motion"

    @property
    def parameters(self):
        return (Parameter("k", "1/s^2", 4.0, 0.4, 40.0, "log", "coupling"),)

    @property
    def states(self):
        return (State("q1", "m", role="position"), State("v1", "m/s", role="velocity"),
                State("q2", "m", role="position"), State("v2", "m/s", role="velocity"))

    def apply(self, ctx):
        d = ctx.x["q1"] - ctx.x["q2"]
        ctx.add_rate("q1", ctx.x["v1"])
        ctx.add_rate("q2", ctx.x["v2"])
        ctx.add_rate("v1", ctx.u - ctx.p["k"] * d)
        ctx.add_rate("v2", ctx.p["k"] * d)
        ctx.signals["y"] = ctx.x["q2"]


def test_several_velocities_need_the_model_to_name_one():
    model = Model([_TwoMasses()])
    why = make_effect("coulomb_friction").applicable(model)
    assert "several states have a velocity role (v1, v2)" in why
    assert "Model(..., velocity='v1')" in why
    named = Model([_TwoMasses()], velocity="v2", position="q2")
    assert named.motion == Motion("v2", "q2", False, "")
    fr = make_effect("coulomb_friction", model=named)
    assert fr.applicable(named) is None and fr.entry_at(named) == "rate:v2"
    # kept by derived models and by a saved model
    derived = named.with_parts(fr)
    assert derived.motion.velocity == "v2"
    spec = derived.to_json()
    assert spec["velocity"] == "v2" and spec["position"] == "q2"
    assert "velocity" not in HHRAModel().to_json()  # bound by roles: saved as before
    with pytest.raises(ModelError, match="declared velocity 'w' is not a state"):
        Model([_TwoMasses()], velocity="w")


def test_unknown_role_is_refused():
    with pytest.raises(ModelError, match="unknown role 'speed'"):
        State("v", "m/s", role="speed")


def test_every_effect_applies_or_says_why_on_the_users_drive():
    model = drive.make_model()
    for name in EFFECTS:
        eff = make_effect(name, model=model)
        why = eff.applicable(model)
        assert why is None or len(why) > 10, name
    assert make_effect("constant_force", model=model).applicable(model) is None


def test_constant_force_is_refused_where_the_model_has_a_free_constant_there():
    cyl = LinearCylinderModel()  # c_load is held: the effect is its free version
    assert make_effect("constant_force", model=cyl).applicable(cyl) is None
    free = Model(list(cyl.parts), stages=cyl.stages, held=())
    why = make_effect("constant_force", model=free).applicable(free)
    assert why is not None and "c_load" in why


def test_no_discovered_term_reads_a_sensors_state():
    model = drive.make_model().with_parts(make_effect("sensor_drift"))
    assert model.sensor_states() == ["y_drift"]
    entries = entry_points(model)
    assert "rate:y_drift" not in entries and "rate:v" in entries


@pytest.mark.parametrize(("model", "entry", "terms", "twins"), [
    (drive.make_model(), "rate:v", ("cube(v)", "sign(v)"), ["coulomb_friction"]),
    (drive.make_model(), "rate:v", ("one()",), ["constant_force"]),
    (drive.make_model(), "rate:v", ("sign(u)", "lin(q)"), []),  # the command's sign: none
    (drive.make_model(), "input", ("one()", "sat(u)"), ["valve_saturation", "input_offset"]),
    (drive.make_model(), "output", ("one()",), ["sensor_offset"]),
    (drive.make_model(), "output", ("sign(v)",), []),  # friction's shape, not its entry
    (HHRAModel(), "rate:omega", ("sign(omega)",), ["coulomb_friction"]),
    (HHRAModel(), "rate:omega", ("sin(theta)", "lin(p)"), ["gravity_load"]),
    (two_tank.make_model(), "rate:h1", ("one()",), []),  # no velocity: no force
])
def test_a_discovered_term_is_named_by_the_library_shape_it_holds(model, entry, terms, twins):
    """A discovered term holding a library effect's own shape at its entry is that physics
    in discovered form (issue 32, item 3), bound by role on any model."""
    assert sorted(library_twins(entry, terms, model)) == sorted(twins)


def test_the_input_entry_is_a_rate_where_the_input_acts_on_one_rate_linearly():
    """Discovery screens such an input entry once, at the rate (the same models)."""
    users = drive.make_model()
    assert input_twin(users) == "rate:v"  # dv/dt = k_motor*u - c_visc*v
    assert input_twin(two_tank.make_model()) == "rate:h1"  # the pump fills tank 1
    assert input_twin(make_resonator()) == "rate:v"
    # Still linear in u with an input offset or a friction beside it.
    for name in ("input_offset", "coulomb_friction", "sensor_offset"):
        assert input_twin(users.with_parts(make_effect(name, model=users))) == "rate:v", name
    # A valve law, a dead zone or a saturation at the input, or input lags: not the same.
    assert input_twin(HHRAModel()) is None
    assert input_twin(LinearCylinderModel()) is None
    for name in ("valve_deadzone", "valve_saturation", "input_delay"):
        assert input_twin(users.with_parts(make_effect(name, model=users))) is None, name


def test_the_score_floor_is_one_parameters_penalty_in_residual_share():
    """Below it a discovered entry cannot lower the criterion to first order: not refitted."""
    from hhra_phys.diagnosis.screening import score_floor

    n = 12_500
    floor = score_floor(n, "bic")
    assert floor == pytest.approx(np.log(n) / n, rel=1e-3)  # 7.5e-4 on the long drive
    assert -n * np.log1p(-floor) == pytest.approx(np.log(n))  # one BIC penalty exactly
    assert score_floor(1000, "aic") == pytest.approx(2 / 1000, rel=1e-3)
    assert score_floor(0) == 0.0


def test_the_loop_tries_a_linear_backlash_only_when_asked():
    from hhra_phys import HHRAModel
    from hhra_phys.diagnosis.engine import _Loop
    from hhra_phys.diagnosis.options import LoopOptions

    assert EFFECTS["backlash"].unasked(HHRAModel()) is None  # an angle: as always
    why = EFFECTS["backlash"].unasked(drive.make_model())
    assert "only when asked" in why and "--effects" in why
    rec = drive.simulate_record(seed=1, n=800)
    loop = _Loop(rec, drive.make_model(), LoopOptions(), None, None, None, None)
    assert "backlash" not in loop.names and "only when asked" in loop.skipped["backlash"]
    asked = _Loop(rec, drive.make_model(), LoopOptions(candidates=("backlash",)), None, None,
                  None, None)
    assert asked.names == ["backlash"] and "backlash" not in asked.skipped
