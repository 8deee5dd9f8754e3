"""The package's model against an independently written reference (hhra_phys.reference).

The package's own simulated rig generates data with the package's model and
integrator, so an error in the equations passes every test built on it
(a wrong sign argument in the orifice law once did: docs/model.md). These
tests compare the package with :mod:`hhra_phys.reference`, written a second time
from ``docs/model.md`` and the effects' documented formulas, in NumPy/SciPy only:

* right-hand sides and outputs point by point (all four sign quadrants of current
  and pressure, both valve laws, both outputs, every library effect);
* trajectories of the compiled RK4 simulator against ``solve_ivp`` with an exact
  zero-order hold, on nominal, perturbed, soft and stiff parameter sets;
* recovery: fits of records made by the reference.
"""

from __future__ import annotations

import ast
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from hhra_phys.effects import LIBRARY, make_effect
from hhra_phys.models.hhra import NOMINAL_GROUPS, HHRAModel
from hhra_phys.models.hhra.rig import default_input
from hhra_phys.reference import (
    EFFECT_NAMES,
    REFERENCE_GROUPS,
    reference_output,
    reference_record,
    reference_rhs,
    reference_state_names,
    simulate_reference,
)
from hhra_phys.simulate import Simulator

DT = 0.004
FS = 250.0
NOMINAL = {k: v for k, v in NOMINAL_GROUPS.items()}

# With smooth=True the reference evaluates the same documented smoothings as the
# package (same sign width, same signed root, same relu corners), so the two
# right-hand sides differ only by rounding: the tolerance is a few hundred ulps of
# the largest term (g_valve*I ~ 30, g_torque*p ~ 200).
RHS_RTOL = 1e-10
RHS_ATOL = 1e-9

# States: every sign of p and omega; |p| up to 0.95 (the orifice's stiff corner)
# and beyond the supply pressure (flow reversal). Currents of both signs and
# sizes far above the sign smoothing width (1e-3 mA) and one at it.
THETAS = (-0.6, 0.25)
OMEGAS = (-1.5, 0.0, 0.8)
PRESSURES = (-1.2, -0.95, -0.4, -0.02, 0.03, 0.45, 0.95, 1.1)
CURRENTS = (-1.0, -0.25, -1e-3, 0.0, 2e-4, 0.3, 1.0)


def _vector(model: HHRAModel, values: dict[str, float]) -> np.ndarray:
    """Parameter vector in the model's order; every name must be given."""
    missing = [n for n in model.params.names if n not in values]
    assert not missing, f"test forgot parameters {missing}"
    return np.array([values[n] for n in model.params.names], dtype=float)


def _package(model: HHRAModel, x: np.ndarray, u_lags: np.ndarray, p: np.ndarray,
             dt: float = DT) -> tuple[np.ndarray, float]:
    fns = model.functions(dt)
    return (np.array(fns["f"](x, u_lags, p)).ravel(), float(fns["h"](x, u_lags, p)))


def _assert_close(a: np.ndarray, b: np.ndarray, what: str, rtol: float = RHS_RTOL,
                  atol: float = RHS_ATOL) -> None:
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = max(1.0, float(np.max(np.abs(b))))
    err = float(np.max(np.abs(a - b)))
    assert err <= atol + rtol * scale * 100, f"{what}: package {a}, reference {b}, diff {err:.3g}"


# --- independence -------------------------------------------------------------------


def test_reference_imports_no_model_code() -> None:
    """The reference may use the data container and the excitation signals only."""
    root = Path(__file__).resolve().parents[2] / "hhra_phys" / "reference"
    files = sorted(root.glob("*.py"))
    # ... and each other (every module of the reference package is itself checked here).
    allowed = {"hhra_phys.data", "hhra_phys.excitation", "hhra_phys.reference",
               *(f"hhra_phys.reference.{p.stem}" for p in files if p.stem != "__init__")}
    assert files
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            mods: list[str] = []
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                assert node.level == 0, f"{path.name}: relative import"
                mods = [node.module or ""]
            for mod in mods:
                if mod.startswith("hhra_phys"):
                    assert mod in allowed, f"{path.name} imports {mod}"
                assert not mod.startswith("casadi"), f"{path.name} imports casadi"


def test_documented_groups_match_the_physical_mapping() -> None:
    """docs/model.md's rig table (the reference's defaults) equals physical.py's groups.

    The table prints 4 significant figures, hence the 5e-4 relative tolerance.
    """
    for name, value in REFERENCE_GROUPS.items():
        assert NOMINAL_GROUPS[name] == pytest.approx(value, rel=5e-4, abs=1e-12), name


# --- right-hand sides and outputs ------------------------------------------------------


def _grid(extra: tuple[float, ...] = ()) -> list[np.ndarray]:
    return [np.array([th, w, p, *extra]) for th in THETAS for w in OMEGAS for p in PRESSURES]


@pytest.mark.parametrize("valve", ["orifice", "linear"])
@pytest.mark.parametrize("output", ["angle", "pressure"])
def test_rhs_and_output_match_reference(valve: str, output: str) -> None:
    model = HHRAModel(valve=valve, output=output)
    values = dict(NOMINAL)
    values.update({"g_spring": 3.0, "g_load": -2.5, "p_gain": 9.5, "p_offset": 0.4})
    p = _vector(model, values)
    quadrants = set()
    for x in _grid():
        for cur in CURRENTS:
            u = np.array([cur])
            f, h = _package(model, x, u, p)
            fr = reference_rhs(x, u, values, valve=valve, output=output, dt=DT)
            hr = reference_output(x, values, valve=valve, output=output)
            _assert_close(f, fr, f"{valve}/{output} f at x={x}, I={cur}")
            _assert_close(h, hr, f"{valve}/{output} h at x={x}")
            quadrants.add((np.sign(cur), np.sign(x[2])))
    assert {(1, 1), (1, -1), (-1, 1), (-1, -1)} <= quadrants


def test_orifice_quadrants_differ_from_a_pressure_signed_law() -> None:
    """The grid can tell sign(I) from sign(p): in the mixed quadrants they give other flows.

    Guards the test above against a grid on which the historical bug (the sign of
    the load pressure in the orifice law) would be invisible.
    """
    values = dict(NOMINAL)
    x = np.array([0.0, 0.0, -0.45])
    flow = reference_rhs(x, [1.0], values)[2] + values["g_leak"] * x[2]
    wrong = values["g_valve"] * 1.0 * math.sqrt(1 - np.sign(x[2]) * x[2])
    assert abs(flow - wrong) > 10.0


@pytest.mark.parametrize("valve", ["orifice", "linear"])
def test_rhs_with_spool_lag_matches_reference(valve: str) -> None:
    model = HHRAModel(valve=valve, spool_lag=True)
    values = dict(NOMINAL, tau_v=0.007)
    p = _vector(model, values)
    for x in _grid(extra=(0.35,)):
        for cur in (-0.8, 0.6):
            f, h = _package(model, x, np.array([cur]), p)
            fr = reference_rhs(x, [cur], values, valve=valve, spool_lag=True)
            _assert_close(f, fr, f"spool lag f at x={x}, I={cur}")
            _assert_close(h, reference_output(x, values, spool_lag=True), "spool lag h")


def test_smoothing_is_as_small_as_documented() -> None:
    """Package (smoothed) against the reference with exact sign and square root.

    docs/model.md: the smoothed root is within 0.1 % of sqrt for drops >= 0.25
    and the sign smoothing (eps = 1e-3 mA) is 1 - O((eps/I)^2), about 1e-5 off at
    |I| >= 0.25 mA. So the valve flow agrees to 0.1 % of itself there.
    """
    model = HHRAModel()
    p = _vector(model, NOMINAL)
    worst = 0.0
    for x in _grid():
        for cur in (-1.0, -0.25, 0.3, 1.0):
            if 1 - np.sign(cur) * x[2] < 0.25:
                continue
            f, _ = _package(model, x, np.array([cur]), p)
            fr = reference_rhs(x, [cur], NOMINAL, smooth=False)
            flow = abs(fr[2] + NOMINAL["g_compress"] * x[1] + NOMINAL["g_leak"] * x[2])
            worst = max(worst, abs(f[2] - fr[2]) / flow)
            assert abs(f[2] - fr[2]) <= 1e-3 * flow, (x, cur)
    assert worst > 0  # the exact reference is really exact, not the smoothed law again


# --- effects ---------------------------------------------------------------------------

#: Per effect: (make_effect settings, reference settings, parameter values to try).
EFFECT_CASES: dict[str, tuple[dict, dict, list[dict[str, float]]]] = {
    "coulomb_friction": ({}, {}, [{"g_coulomb": 0.05}, {"g_coulomb": 5.0},
                                  {"g_coulomb": 60.0}]),
    "coulomb_friction+stribeck": (
        {"stribeck": True}, {},
        [{"g_coulomb": 5.0, "g_stribeck": 2.0, "v_stribeck": 0.1},
         {"g_coulomb": 20.0, "g_stribeck": 15.0, "v_stribeck": 0.8}]),
    "valve_deadzone": ({}, {}, [{"i_dead": 0.01}, {"i_dead": 0.2}, {"i_dead": 0.7}]),
    "valve_deadzone@scale": ({"u_scale": 2.0}, {"u_scale": 2.0}, [{"i_dead": 0.3}]),
    "valve_deadzone@width": ({"width": 0.05}, {"width": 0.05}, [{"i_dead": 0.28}]),
    "valve_saturation@width": ({"width": 0.2}, {"width": 0.2}, [{"i_sat": 0.4}]),
    "valve_saturation": ({}, {}, [{"i_sat": 0.1}, {"i_sat": 0.4}, {"i_sat": 2.0}]),
    "valve_saturation@scale": ({"u_scale": 3.0, "width": 0.02},
                               {"u_scale": 3.0, "width": 0.02}, [{"i_sat": 0.5}]),
    "input_delay": ({}, {}, [{"delay": 0.0}, {"delay": 1.0}, {"delay": 2.4}, {"delay": 7.75}]),
    "valve_dynamics": ({}, {}, [{"tau_spool": 0.002}, {"tau_spool": 0.05}]),
    "gravity_load": ({}, {}, [{"g_grav_cos": 20.0, "g_grav_sin": -10.0},
                              {"g_grav_cos": -3.0, "g_grav_sin": 40.0}]),
    "backlash": ({}, {}, [{"play": 0.1}, {"play": 2.0}, {"play": 8.0}]),
    "backlash@width": ({"width": 0.003}, {"width": 0.003}, [{"play": 1.0}]),
    "backlash+fit_width": ({"fit_width": True}, {}, [{"play": 1.0, "w_contact": 0.05}]),
    "sensor_offset": ({}, {}, [{"y_offset": -1.5}, {"y_offset": 0.3}]),
    "sensor_drift": ({}, {}, [{"drift_rate": -0.4}, {"drift_rate": 0.02}]),
    "asymmetric_valve": ({}, {}, [{"asym": -0.3}, {"asym": 0.2}, {"asym": 0.7}]),
    "asymmetric_valve@scale": ({"u_scale": 0.5}, {"u_scale": 0.5}, [{"asym": 0.4}]),
    "input_offset": ({}, {}, [{"u_offset": 0.2}, {"u_offset": -0.05}]),
    "constant_force": ({}, {}, [{"g_const": 40.0}, {"g_const": -7.5}]),
}

#: A distinct input history, so that a delay reading the wrong lag shows.
U_HISTORY = np.array([0.7, -0.4, 0.15, 1.0, -0.9, 0.05, 0.5, -0.25, 0.8, -0.6,
                      0.3, -0.8, 0.9, -0.1, 0.45, -0.55, 0.2, 0.65])


def _extra_states(name: str) -> list[tuple[float, ...]]:
    if name == "valve_dynamics":
        return [(-0.6,), (0.3,)]
    if name == "sensor_drift":  # the drift so far (deg)
        return [(0.0,), (-0.7,), (0.25,)]
    if name == "backlash":  # inside the play, within the contact width, beyond (rad)
        return [(0.0,), (0.012,), (-0.012,), (0.05,), (0.0174,), (-0.00872,)]
    return [()]


def test_every_library_effect_is_covered() -> None:
    assert set(EFFECT_NAMES) == set(LIBRARY)
    assert {case.split("+")[0].split("@")[0] for case in EFFECT_CASES} == set(LIBRARY)


@pytest.mark.parametrize("case", sorted(EFFECT_CASES))
def test_effect_rhs_and_output_match_reference(case: str) -> None:
    name = case.split("+")[0].split("@")[0]
    settings, ref_settings, sizes = EFFECT_CASES[case]
    effect = make_effect(name, **settings)
    model = HHRAModel(effects=[effect])
    assert reference_state_names(effects={name: {}}) == model.state_names
    u_lags = U_HISTORY[: model.n_lags + 1]
    for size in sizes:
        values = dict(NOMINAL, **size)
        p = _vector(model, values)
        eff = {name: {**ref_settings, **size}}
        for extra in _extra_states(name):
            for x in _grid(extra=extra):
                for cur in (-1.0, -0.05, 0.3, 1.0):
                    ul = np.concatenate([[cur], u_lags[1:]])
                    f, h = _package(model, x, ul, p, dt=settings.get("dt", DT))
                    fr = reference_rhs(x, ul, values, effects=eff, dt=settings.get("dt", DT))
                    hr = reference_output(x, values, effects=eff)
                    _assert_close(f, fr, f"{case} {size} f at x={x}, u={ul[:3]}")
                    _assert_close(h, hr, f"{case} {size} h at x={x}")


def test_all_effects_together_match_reference() -> None:
    """Interactions: the delay acts on the measured input before the other input effects."""
    order = ["input_delay", "valve_deadzone", "valve_saturation", "valve_dynamics",
             "asymmetric_valve", "coulomb_friction", "gravity_load", "backlash",
             "sensor_offset"]
    sizes = {"delay": 2.6, "i_dead": 0.1, "i_sat": 0.6, "tau_spool": 0.01, "asym": 0.15,
             "g_coulomb": 8.0, "g_grav_cos": 5.0, "g_grav_sin": -7.0, "play": 1.0,
             "y_offset": 0.2}
    model = HHRAModel(effects=[make_effect(n) for n in order])
    values = dict(NOMINAL, **sizes)
    p = _vector(model, values)
    eff = {n: {} for n in order}
    assert reference_state_names(effects=eff) == model.state_names
    for x in _grid(extra=(0.2, 0.004)):
        ul = U_HISTORY[: model.n_lags + 1]
        f, h = _package(model, x, ul, p)
        _assert_close(f, reference_rhs(x, ul, values, effects=eff), f"all effects f at {x}")
        _assert_close(h, reference_output(x, values, effects=eff), f"all effects h at {x}")


# --- trajectories ------------------------------------------------------------------------


def _stiff() -> dict[str, float]:
    """A stiffer actuator: 7.8x less hydraulic compliance (V_t/beta_e), more damping.

    g_compress, g_leak and g_valve all scale with 4*beta_e/V_t; the factor takes the
    hydraulic natural frequency sqrt(g_torque*g_compress)/(2 pi) from 15 to 42 Hz.
    """
    k = (42.0 * 2 * math.pi) ** 2 / (NOMINAL["g_torque"] * NOMINAL["g_compress"])
    return dict(NOMINAL, g_compress=NOMINAL["g_compress"] * k, g_leak=NOMINAL["g_leak"] * k,
                g_valve=NOMINAL["g_valve"] * k, g_damping=290.0)


PARAMETER_SETS: dict[str, dict[str, float]] = {
    "nominal": dict(NOMINAL),
    # Every group moved by a factor 1.3-2.5 (away from nominal and the box centre).
    "perturbed": dict(NOMINAL, g_torque=NOMINAL["g_torque"] * 0.55,
                      g_damping=NOMINAL["g_damping"] * 2.2, g_compress=NOMINAL["g_compress"] * 1.4,
                      g_leak=NOMINAL["g_leak"] * 0.45, g_valve=NOMINAL["g_valve"] * 1.8),
    # Heavy load, soft oil column: about 5 Hz, little damping, nearly no leakage.
    "soft": dict(NOMINAL, g_torque=40.0, g_compress=25.0, g_damping=1.0, g_leak=1.0,
                 g_valve=20.0),
    "stiff": _stiff(),
}

#: Substeps for the comparison: RK4's error (h^4) far below the tolerance.
SUBSTEPS = {"nominal": 8, "perturbed": 8, "soft": 8, "stiff": 16}

#: Trajectory tolerance [deg]: 1/500 of the rig's 0.05 deg noise. Measured (3 s
#: records, rtol 1e-10): 1e-7 to 1e-6 deg with these substeps.
TRAJ_TOL_DEG = 1e-4


def _u(seconds: float = 3.0, seed: int = 1) -> np.ndarray:
    return default_input(seconds, FS, seed=seed)


@pytest.fixture(scope="module")
def references() -> dict[str, np.ndarray]:
    u = _u()
    return {name: simulate_reference(u, FS, vals, x0=[0.1, 0.0, 0.0])
            for name, vals in PARAMETER_SETS.items()}


@pytest.mark.parametrize("name", sorted(PARAMETER_SETS))
def test_trajectory_matches_reference(name: str, references: dict[str, np.ndarray]) -> None:
    model = HHRAModel()
    sim = Simulator(model, FS, substeps=SUBSTEPS[name], backend="casadi")
    y = sim.simulate(_u(), _vector(model, PARAMETER_SETS[name]), x0=np.array([0.1, 0.0, 0.0]))
    yr = references[name]
    assert np.ptp(yr) > 5.0  # the record moves the shaft (a still shaft proves nothing)
    err = float(np.max(np.abs(y - yr)))
    assert err < TRAJ_TOL_DEG, f"{name}: max |package - reference| = {err:.3g} deg"


# The default substeps are chosen from the *nominal* model (2 RK4 substeps at 250
# Hz). On the stiff set the stability check fails for them (spectral radius x
# substep 2.42 > rho_max 2.0 at 99 % supply pressure): a single parameter vector
# is then simulated with substeps chosen for its own parameters, with a warning
# (docs/model.md, "Single parameter vectors follow their parameters"; it used to return all
# NaN without a word).
@pytest.mark.parametrize("name", ["nominal", "perturbed", "soft", "stiff"])
def test_trajectory_with_default_substeps(name: str, references: dict[str, np.ndarray]) -> None:
    model = HHRAModel()
    sim = Simulator(model, FS, backend="casadi")
    assert (sim.method, sim.substeps) == ("rk4", 2)
    p = _vector(model, PARAMETER_SETS[name])
    u = _u()
    unstable = sim.stability_index(p, float(np.max(np.abs(u))))[0] > sim.rho_max
    assert unstable == (name == "stiff")  # the premise: only the stiff set needs more
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        y = sim.simulate(u, p, x0=np.array([0.1, 0.0, 0.0]))
    said = [w for w in caught if "unstable for RK4" in str(w.message)]
    assert bool(said) == unstable  # refined with a warning exactly when it had to be
    assert (sim.last_substeps > sim.substeps) == unstable
    assert sim.last_status.tolist() == [0]
    err = float(np.max(np.abs(y - references[name])))
    # 2 RK4 substeps: about 3e-5 deg on the rig (docs/model.md); 1e-3 deg is 1/50 of the noise.
    assert np.isfinite(y).all() and err < 1e-3, f"{name}: {err:.3g} deg"


@pytest.mark.parametrize("name", ["soft", "stiff"])
def test_population_rows_stay_unrefined(name: str) -> None:
    """Optimiser populations keep NaN rows for candidates unstable at the simulator's substeps."""
    model = HHRAModel()
    sim = Simulator(model, FS, backend="casadi")
    P = np.vstack([_vector(model, PARAMETER_SETS["nominal"]), _vector(model, PARAMETER_SETS[name])])
    Y = sim.simulate(_u(1.0), P, x0=np.array([0.1, 0.0, 0.0]))
    stiff = name == "stiff"
    assert np.isfinite(Y[0]).all() and np.isnan(Y[1]).all() == stiff
    assert sim.last_status.tolist() == [0, 1 if stiff else 0]
    assert (sim.last_method, sim.last_substeps) == ("rk4", 2)


#: Effects on trajectories (sizes that clearly change the response).
TRAJ_EFFECTS: dict[str, dict[str, float]] = {
    "coulomb_friction": {"g_coulomb": 12.0},
    "valve_deadzone": {"i_dead": 0.15},
    "valve_saturation": {"i_sat": 0.5},
    "input_delay": {"delay": 2.5},
    "valve_dynamics": {"tau_spool": 0.02},
    "gravity_load": {"g_grav_cos": 10.0, "g_grav_sin": 8.0},
    "backlash": {"play": 1.5},
    "sensor_offset": {"y_offset": 0.7},
    "asymmetric_valve": {"asym": 0.2},
}


#: Substeps of the comparison where 8 are not enough for 1e-4 deg: the sharp
#: friction's reversals are resolved to first order only (about 3e-4 deg with 8
#: ROS4 substeps, 5e-5 with 16; docs/performance.md); the backlash's contacts
#: within its 0.01 deg width likewise (4e-4 deg with 8, 6e-5 with 16, 9e-6 with 32).
TRAJ_SUBSTEPS = {"coulomb_friction": 24, "backlash": 32}


@pytest.mark.parametrize("name", sorted(TRAJ_EFFECTS))
def test_effect_trajectory_matches_reference(name: str) -> None:
    u = _u(2.0, seed=3)
    model = HHRAModel(effects=[make_effect(name)])
    values = dict(NOMINAL, **TRAJ_EFFECTS[name])
    sim = Simulator(model, FS, substeps=TRAJ_SUBSTEPS.get(name, 8), backend="casadi")
    y = sim.simulate(u, _vector(model, values))
    # Friction switching within 0.005 rad/s and a backlash contact 0.01 deg wide make
    # the model stiff: integrated with ROS4.
    assert sim.method == ("ros4" if name in ("coulomb_friction", "backlash") else "rk4")
    eff = {name: TRAJ_EFFECTS[name]}
    yr = simulate_reference(u, FS, values, effects=eff)
    err = float(np.max(np.abs(y - yr)))
    # Without the effect the output moves by far more than the tolerance: the
    # comparison sees the effect, not only the HHRA underneath.
    y0 = simulate_reference(u, FS, NOMINAL)
    assert float(np.max(np.abs(yr - y0))) > 50 * TRAJ_TOL_DEG
    assert err < TRAJ_TOL_DEG, f"{name}: max |package - reference| = {err:.3g} deg"


def test_exact_switching_is_close_to_smoothed_away_from_switches() -> None:
    """smooth=False (exact sign/sqrt) agrees with smooth=True to the smoothing's size.

    On the orifice HHRA without friction the smoothing only matters within a
    micro-ampere of zero current and near the supply pressure, which the record
    does not reach: the outputs must agree to 1e-3 deg. Exact Coulomb friction
    (sticking) must differ visibly from the package's sample-period-wide friction.
    """
    u = _u(2.0, seed=2)
    a = simulate_reference(u, FS, NOMINAL)
    b = simulate_reference(u, FS, NOMINAL, smooth=False)
    assert float(np.max(np.abs(a - b))) < 1e-3
    eff = {"coulomb_friction": {"g_coulomb": 30.0}}
    ys, Xs = simulate_reference(u, FS, NOMINAL, effects=eff, states=True)
    ye, Xe = simulate_reference(u, FS, NOMINAL, effects=eff, smooth=False, states=True)
    stuck = Xe[:, 1] == 0.0
    assert stuck.sum() > 10  # the exact friction holds the shaft for a while
    assert not (Xs[1:, 1] == 0.0).any()  # the smoothed one only creeps (x0 is at rest)
    # While stuck the pressure torque stays within the static friction level.
    push = NOMINAL["g_torque"] * Xe[stuck, 2]
    assert np.all(np.abs(push) <= 30.0 * (1 + 1e-6))
    assert float(np.max(np.abs(ys - ye))) > 1e-2


# --- records and recovery ------------------------------------------------------------------


def test_reference_record_is_like_the_rig() -> None:
    ds = reference_record(seed=4, duration=4.0, noise_deg=0.0)
    assert ds.metadata["generator"] == "reference"
    assert ds.fs == FS and len(ds) == 1000
    assert ds.output_unit == "deg" and ds.input_unit == "mA"
    truth = ds.metadata["truth"]
    y = simulate_reference(ds.u, FS, truth["params"], x0=truth["x0"])
    assert np.array_equal(y, ds.y)
    for key in ("seed", "noise_deg", "true_params", "valve", "effects", "x0"):
        assert key in ds.metadata
    # Same input family as the package's rig for the same seed.
    np.testing.assert_allclose(ds.u, default_input(4.0, FS, seed=np.random.default_rng(4)),
                               rtol=1e-3)


#: A truth away from the nominal values and from the box centre (docs/benchmarks.md, point 6).
RECOVERY_TRUTH = dict({k: v for k, v in REFERENCE_GROUPS.items() if k != "g_kp"},
                      g_torque=120.0, g_damping=7.5, g_compress=68.0, g_leak=3.8, g_valve=42.0)
RECOVERY_NOISE = 0.05


@pytest.mark.parametrize(("seeds", "need"), [
    pytest.param((0,), (1, 1, 1), id="seed0"),
    pytest.param(tuple(range(5)), (4, 4, 3), id="seeds0-4", marks=pytest.mark.slow),
])
def test_fit_recovers_reference_records(seeds, need) -> None:
    """Fits of reference records (5 seeds, 8 s, pop 30 x 40 + IPOPT) recover the truth.

    Measured on this branch: validation RMSE 0.049-0.052 deg for noise 0.05 (<= 1.04x)
    on 5 of 5; the well-determined combinations ``g_torque*g_compress`` (hydraulic
    frequency squared) and ``g_torque*g_valve`` (the transfer function's kv) within
    1 % on 5 of 5; every free group inside its linearised 95 % interval on 3 of 5
    only: on seeds 3 and 4 the truth lies just outside the intervals of g_valve,
    g_compress, g_torque (and g_damping) along the weak pressure-scale direction
    (correlation 0.9995+), and a refit started at the truth ends at the same
    optimum, so it is the intervals, not the search (reported, left alone). The
    thresholds keep a margin above noise: 4 of 5 at 1.2x noise, 4 of 5 within 3 %,
    3 of 5 inside the intervals. The default run fits seed 0 (all three hold there); the
    rate over seeds 0-4 is slow.
    """
    from hhra_phys.fit import fit

    t = RECOVERY_TRUTH
    rmse_ok, combos_ok, inside = [], [], []
    for seed in seeds:
        ds = reference_record(seed=seed, duration=8.0, noise_deg=RECOVERY_NOISE, params=t)
        res = fit(ds, pop_size=30, max_iter=40, seed=seed)
        v = res.values
        rmse_ok.append(res.metrics["val"]["rmse"] <= 1.2 * RECOVERY_NOISE)
        combos_ok.append(
            abs(v["g_torque"] * v["g_compress"] / (t["g_torque"] * t["g_compress"]) - 1) < 0.03
            and abs(v["g_torque"] * v["g_valve"] / (t["g_torque"] * t["g_valve"]) - 1) < 0.03)
        inside.append(all(lo <= t[n] <= hi for n, (lo, hi) in res.ci95.items()
                          if n.startswith("g_")))
    assert sum(rmse_ok) >= need[0], rmse_ok
    assert sum(combos_ok) >= need[1], combos_ok
    assert sum(inside) >= need[2], inside
