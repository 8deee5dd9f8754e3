"""The effect library: names, parameters, behaviour in the HHRA and in a user's own model."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys.effects import EFFECTS, Effect, Signals, make_effect
from hhra_phys.errors import ModelError
from hhra_phys.model import Model
from hhra_phys.models.hhra import (
    AngleOutput,
    ChamberPressure,
    CurrentCommand,
    HHRAModel,
    LinearValve,
    RotaryMotion,
)
from hhra_phys.simulate import Simulator

REQUIRED = ("coulomb_friction", "valve_deadzone", "valve_saturation", "input_delay",
            "valve_dynamics", "gravity_load", "backlash", "sensor_offset", "asymmetric_valve")

#: A clearly visible size of each effect (parameter values).
SIZES = {
    "coulomb_friction": {"g_coulomb": 30.0},
    "valve_deadzone": {"i_dead": 0.2},
    "valve_saturation": {"i_sat": 0.4},
    "input_delay": {"delay": 3.0},
    "valve_dynamics": {"tau_spool": 0.05},
    "gravity_load": {"g_grav_cos": 20.0, "g_grav_sin": 10.0},
    "backlash": {"play": 2.0},
    "sensor_offset": {"y_offset": 1.5},
    "asymmetric_valve": {"asym": 0.2},
}


def _input(n: int = 500) -> np.ndarray:
    u = np.zeros(n)
    u[20:150] = 0.6
    u[150:300] = -0.3
    u[300:420] = 0.9
    return u


def _sim(model: Model, u: np.ndarray, **values: float) -> np.ndarray:
    m = model.with_nominal(values) if values else model
    return Simulator(m, fs=250.0, backend="casadi").simulate(u, m.nominal())


def test_library_names_and_registry():
    for name in REQUIRED:
        assert name in EFFECTS
        eff = make_effect(name)
        assert isinstance(eff, Effect) and eff.name == name
        assert eff.signature and eff.entry in ("input", "output") or eff.entry.startswith("rate:")
        for p in eff.parameters:
            assert p.unit and p.lower < p.upper and p.description


def test_make_effect_errors_name_the_problem():
    with pytest.raises(ModelError, match="unknown effect 'stiction'"):
        make_effect("stiction")
    with pytest.raises(ModelError, match="no field"):
        make_effect("backlash", u_scale=2.0)


def test_make_effect_scales_to_the_record():
    class D:
        u = np.array([-5.0, 5.0])
        y = np.array([0.0, 2.0])
        dt = 1.0

    eff = make_effect("valve_deadzone", data=D())
    assert eff.parameters[0].upper == pytest.approx(0.9 * 5.0)
    fr = make_effect("coulomb_friction", values={"g_torque": 2.0})
    assert fr.parameters[0].upper == pytest.approx(0.6 * 2.0)


@pytest.mark.parametrize("name", REQUIRED)
def test_each_effect_changes_the_output(name):
    u = _input()
    base = _sim(HHRAModel(), u)
    model = HHRAModel(effects=[make_effect(name)])
    y = _sim(model, u, **SIZES[name])
    assert np.isfinite(y).all()
    assert np.max(np.abs(y - base)) > 0.05, name


def test_absent_sizes_leave_the_output_alone():
    u = _input()
    base = _sim(HHRAModel(), u)
    for name, vals in {"valve_deadzone": {"i_dead": 1e-3}, "input_delay": {"delay": 0.0},
                       "gravity_load": {"g_grav_cos": 0.0, "g_grav_sin": 0.0},
                       "asymmetric_valve": {"asym": 0.0}}.items():
        y = _sim(HHRAModel(effects=[make_effect(name)]), u, **vals)
        assert np.max(np.abs(y - base)) < 0.01 * np.max(np.abs(base)), name


def test_integer_delay_equals_a_shifted_input():
    u = _input()
    shifted = np.concatenate([np.full(3, u[0]), u[:-3]])
    y_ref = _sim(HHRAModel(), shifted)
    y = _sim(HHRAModel(effects=[make_effect("input_delay")]), u, delay=3.0)
    assert np.allclose(y, y_ref, atol=1e-9)


def test_delay_acts_before_a_dead_zone_added_earlier():
    """The delay substitutes the delayed input into what earlier input parts built."""
    u = _input()
    shifted = np.concatenate([np.full(2, u[0]), u[:-2]])
    dz = make_effect("valve_deadzone")
    y_ref = _sim(HHRAModel(effects=[dz]), shifted, i_dead=0.2)
    y = _sim(HHRAModel(effects=[dz, make_effect("input_delay")]), u, i_dead=0.2, delay=2.0)
    assert np.allclose(y, y_ref, atol=1e-9)


def test_fractional_delay_interpolates_linearly():
    u = _input()
    y2 = _sim(HHRAModel(effects=[make_effect("input_delay")]), u, delay=2.0)
    y3 = _sim(HHRAModel(effects=[make_effect("input_delay")]), u, delay=3.0)
    y25 = _sim(HHRAModel(effects=[make_effect("input_delay")]), u, delay=2.5)
    # The model is nearly linear in the held input here, so the half-sample delay
    # lies between the neighbouring integer delays.
    mid = 0.5 * (y2 + y3)
    assert np.max(np.abs(y25 - mid)) < 0.05 * np.max(np.abs(y3 - y2)) + 1e-6


def test_effects_on_a_users_own_model():
    """A hand-composed model (linearised valve) takes friction and a delay as parts."""
    user = Model([CurrentCommand(), LinearValve(), ChamberPressure(), RotaryMotion(),
                  AngleOutput()], name="mine")
    aug = user.with_parts(make_effect("coulomb_friction"), make_effect("input_delay"))
    assert {"g_coulomb", "delay"} <= set(aug.params.names)
    u = _input()
    y0 = _sim(user, u)
    y = _sim(aug, u, g_coulomb=30.0, delay=2.0)
    assert np.isfinite(y).all() and np.max(np.abs(y - y0)) > 0.1
    # Friction only slows the motion down: the travelled range shrinks.
    assert np.ptp(y) < np.ptp(y0)
    again = Model.from_json(aug.to_json())
    assert again.params.names == aug.params.names
    assert np.allclose(_sim(again, u, g_coulomb=30.0, delay=2.0), y)


def test_applicability_is_checked():
    pm = HHRAModel(output="pressure")
    assert "not affine in its position" in make_effect("backlash").applicable(pm)
    assert "p_offset" in make_effect("sensor_offset").applicable(pm)
    dz = make_effect("valve_deadzone")
    assert "already" in dz.applicable(HHRAModel(effects=[dz]))
    assert make_effect("gravity_load").applicable(HHRAModel()) is None


@pytest.mark.parametrize("name", REQUIRED)
def test_first_order_signatures_have_the_record_length(name):
    u = _input()
    sig = Signals(u=u, dt=0.004, theta=np.linspace(0, 1, u.size),
                  omega=np.sin(np.linspace(0, 9, u.size)))
    cols = make_effect(name).first_order(sig)
    assert cols.shape[0] == u.size and np.isfinite(cols).all()


def test_bad_smoothing_settings_are_refused_by_name():
    from hhra_phys.errors import ParameterError

    for name, bad in (("backlash", {"width": 0.0}), ("backlash", {"speed": -1.0}),
                      ("valve_deadzone", {"width": -0.01}), ("valve_saturation", {"width": 0.0}),
                      ("coulomb_friction", {"width": -1.0})):
        with pytest.raises(ParameterError, match=name):
            make_effect(name, **bad)


def test_friction_profile_is_the_shape_of_its_sign():
    """``profile="tanh"``: the same level and slope at rest as the algebraic sign, the
    level reached sooner (at three widths 0.995 against 0.949), a different motion, and
    saved with the model."""
    from hhra_phys.errors import ParameterError

    u = _input()
    tanh = make_effect("coulomb_friction", profile="tanh", fit_width=True)
    alg = make_effect("coulomb_friction", fit_width=True)
    y_t = _sim(HHRAModel(effects=[tanh]), u, g_coulomb=30.0, v_switch=0.05)
    y_a = _sim(HHRAModel(effects=[alg]), u, g_coulomb=30.0, v_switch=0.05)
    assert np.isfinite(y_t).all() and 1e-3 < np.max(np.abs(y_t - y_a)) < 0.5
    v = np.array([-3.0, 0.0, 1e-3, 3.0])
    sig = Signals(u=np.zeros(4), dt=0.004, velocity=v * tanh.width)
    g = tanh.probe()["g_coulomb"]
    col_t, col_a = tanh.first_order(sig)[:, 0], alg.first_order(sig)[:, 0]
    np.testing.assert_allclose(col_t, -g * np.tanh(v), rtol=1e-12)
    np.testing.assert_allclose(col_a, -g * v / np.sqrt(v * v + 1), rtol=1e-12)
    assert col_t[-1] < col_a[-1] < 0  # nearer the level (-g) at three widths
    again = Model.from_json(HHRAModel(effects=[tanh]).to_json())
    assert np.allclose(_sim(again, u, g_coulomb=30.0, v_switch=0.05), y_t)
    with pytest.raises(ParameterError, match="profile"):
        make_effect("coulomb_friction", profile="exact")


def test_backlash_width_can_be_fitted():
    eff = make_effect("backlash", fit_width=True, width=0.02)
    p = {q.name: q for q in eff.parameters}
    assert p["w_contact"].nominal == 0.02 and p["w_contact"].unit == "deg"
    u = _input()
    model = HHRAModel(effects=[eff])
    narrow = _sim(model, u, play=2.0, w_contact=0.005)
    wide = _sim(model, u, play=2.0, w_contact=0.2)
    assert 0.01 < np.max(np.abs(narrow - wide)) < 0.2


@pytest.mark.parametrize(("name", "setting"), [("coulomb_friction", "eps"),
                                               ("valve_deadzone", "eps"),
                                               ("valve_saturation", "eps"),
                                               ("backlash", "eps_omega")])
def test_the_removed_smoothing_settings_are_refused_by_name(name, setting):
    from hhra_phys.effects import make_effect
    from hhra_phys.errors import ModelError

    with pytest.raises(ModelError, match=f"{setting} was removed"):
        make_effect(name, **{setting: 0.01})


def test_a_saved_model_with_a_removed_setting_is_refused_by_name():
    from hhra_phys.effects import make_effect
    from hhra_phys.errors import ModelError
    from hhra_phys.model import Model
    from hhra_phys.models.hhra import HHRAModel

    spec = HHRAModel(effects=[make_effect("backlash")]).to_json()
    part = next(p for p in spec["parts"] if "backlash" in p["type"].lower())
    part["args"]["eps_omega"] = None
    with pytest.raises(ModelError, match="eps_omega"):
        Model.from_json(spec)


@pytest.mark.parametrize("kind", ["hhra", "resonator"])
def test_sensor_drift_adds_a_ramp_and_nothing_else(kind) -> None:
    """The sensor's zero drifts linearly from the record's start; the physics is untouched."""
    from hhra_phys.models.resonator import ResonatorDrive, ResonatorMotion, ResonatorSensor

    model = (HHRAModel() if kind == "hhra"
             else Model([ResonatorDrive(), ResonatorMotion(w_n=30.0), ResonatorSensor()]))
    u = _input()
    drift = make_effect("sensor_drift", y_scale=5.0, dt=0.004)
    assert drift.applicable(model) is None
    assert drift.stage == "output" and drift.entry == "output"
    base = _sim(model, u)
    for rate in (0.3, -0.05):
        got = _sim(model.with_parts(drift), u, drift_rate=rate)
        np.testing.assert_allclose(got - base, rate * np.arange(u.size) / 250.0, atol=1e-9)
    # The first-order signature is the probe's ramp; the bound scales with y_scale / dt.
    sig = Signals(u=u, dt=0.004)
    np.testing.assert_allclose(drift.first_order(sig)[:, 0],
                               drift.probe()["drift_rate"] * 0.004 * np.arange(u.size))
    (par,) = drift.parameters
    assert par.upper == pytest.approx(5.0 / (100 * 0.004)) and par.lower == -par.upper
