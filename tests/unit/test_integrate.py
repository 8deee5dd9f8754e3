"""The fixed-step methods of hhra_phys.integrate against SciPy, and their choice by the Simulator.

Orders are measured on a nonlinear pendulum against ``solve_ivp`` at tight
tolerances; stability on the scalar test equation; the simulator's choice and its
accuracy on the sharp-friction HHRA against CVODES.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from hhra_phys.effects import make_effect
from hhra_phys.integrate import METHODS, ORDER, advance, lu_solve
from hhra_phys.models.hhra import NOMINAL_GROUPS, HHRAModel
from hhra_phys.models.hhra.rig import default_input
from hhra_phys.sensitivity import TrajectorySensitivity
from hhra_phys.simulate import Simulator


def _f(x, u, p):
    return np.array([x[1], -p * np.sin(x[0]) - 3.0 * x[1] + u])


def _jac(x, u, p):
    return np.array([[0.0, 1.0], [-p * np.cos(x[0]), -3.0]])


@pytest.mark.parametrize("method", METHODS)
def test_order_on_a_nonlinear_pendulum(method: str) -> None:
    x0, T, p, u = np.array([1.0, 0.0]), 0.5, 100.0, 0.3
    ref = solve_ivp(lambda t, x: _f(x, u, p), (0, T), x0, rtol=1e-12, atol=1e-12).y[:, -1]
    errs = [np.max(np.abs(advance(method, _f, _jac, x0, u, p, T / n, n) - ref))
            for n in (20, 40, 80)]
    rates = [math.log2(errs[i] / errs[i + 1]) for i in range(2)]
    assert all(abs(r - ORDER[method]) < 0.5 for r in rates), (method, errs, rates)


def test_stability_on_the_stiff_test_equation() -> None:
    """RK4 explodes at |lambda| h = 1e6; ROS4 damps by R(-inf) = 1/3, ROS2 by about 0."""
    lam = -1e9
    f = lambda x, u, p: lam * x  # noqa: E731
    j = lambda x, u, p: np.array([[lam]])  # noqa: E731
    x = np.array([1.0])
    assert abs(advance("rk4", f, j, x, 0, 0, 1e-3, 1)[0]) > 1e6
    assert advance("ros4", f, j, x, 0, 0, 1e-3, 1)[0] == pytest.approx(1 / 3, rel=1e-4)
    assert abs(advance("ros2", f, j, x, 0, 0, 1e-3, 1)[0]) < 1e-3
    with pytest.raises(ValueError, match="unknown integration method"):
        advance("euler", f, j, x, 0, 0, 1e-3, 1)


def test_lu_solve_matches_numpy() -> None:
    rng = np.random.default_rng(2)
    a = np.eye(5) + 0.3 * rng.standard_normal((5, 5))
    b = rng.standard_normal(5)
    np.testing.assert_allclose(lu_solve(a, b), np.linalg.solve(a, b), rtol=1e-12)


FS = 250.0


def _friction(g_coulomb: float = 12.0) -> tuple[HHRAModel, np.ndarray]:
    model = HHRAModel(effects=[make_effect("coulomb_friction")])
    values = dict(NOMINAL_GROUPS, g_coulomb=g_coulomb)
    return model, np.array([values[n] for n in model.params.names])


def test_simulator_chooses_ros4_for_sharp_friction_only() -> None:
    base = Simulator(HHRAModel(), FS, backend="casadi")
    assert (base.method, base.substeps) == ("rk4", 2)
    assert base.method_reason.startswith("not stiff")
    model, _ = _friction()
    sim = Simulator(model, FS, backend="casadi")
    assert sim.method == "ros4" and sim.substeps >= 8
    assert sim.method_reason.startswith("stiff")
    # A soft switch (0.2 rad/s wide, as the earlier sample-tied smoothing) is not stiff.
    soft = HHRAModel(effects=[make_effect("coulomb_friction", width=0.2)])
    assert Simulator(soft, FS, backend="casadi").method == "rk4"
    with pytest.raises(Exception, match="method must be"):
        Simulator(model, FS, method="euler")


@pytest.mark.parametrize("g_coulomb", [12.0, 60.0])
def test_sharp_friction_is_accurate_against_cvodes(g_coulomb: float) -> None:
    """Automatic settings on friction switching within 0.005 rad/s: within 1/10 of the rig noise.

    Measured (2 s, seed 3, 8 ROS4 substeps): 1.4e-3 deg at 12 rad/s^2
    (docs/performance.md).
    """
    model, p = _friction(g_coulomb)
    u = default_input(2.0, FS, seed=3)
    sim = Simulator(model, FS, backend="casadi")
    y = sim.simulate(u, p)
    ref = sim.reference(u, p)
    assert np.ptp(ref) > 1.0
    assert np.max(np.abs(y - ref)) < 5e-3
    # RK4 at the rig's default 2 substeps cannot take it: flagged in a population.
    rk4 = Simulator(model, FS, substeps=2, method="rk4", backend="casadi")
    assert np.isnan(rk4.simulate(u, p[None, :])).all()


def test_ros4_sensitivities_match_finite_differences() -> None:
    model, p = _friction(12.0)
    sim = Simulator(model, FS, backend="casadi")
    u = default_input(0.6, FS, seed=4)
    x0 = np.array([0.05, 0.0, 0.0])
    sens = TrajectorySensitivity(sim)
    y, dy = sens(u, p, x0)
    np.testing.assert_allclose(y, sim.simulate(u, p[None, :], x0=x0)[0], atol=1e-9)
    # The refiners' residual-only path gives the same outputs, bit for bit (the line
    # search compares costs from it with those at points where the Jacobian was taken).
    assert np.array_equal(sens.outputs(u, p, x0), y)
    assert not np.array_equal(sens.outputs(u, p * 1.01, x0), y)
    i = model.params.index("g_coulomb")
    step = 1e-4 * p[i]
    P = np.tile(p, (2, 1))
    P[0, i] -= step
    P[1, i] += step
    Y = sim.simulate(u, P, x0=x0)
    fd = (Y[1] - Y[0]) / (2 * step)
    col = dy[:, model.nx + i]
    assert np.max(np.abs(col - fd)) <= 1e-4 * np.max(np.abs(fd)) + 1e-9
