"""Oracles for the control export: closed-loop figures from their definitions on responses
with known closed forms, the operating point's units, and the ARX model's continuous image
against the continuous transfer function whose Tustin image it is."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hhra_phys import HHRAModel
from hhra_phys.arx import tustin_arx
from hhra_phys.control import ClosedLoopResponse, OperatingPoint, linearize
from hhra_phys.effects import CoulombFriction


def _response(t: np.ndarray, r: np.ndarray, y: np.ndarray) -> ClosedLoopResponse:
    return ClosedLoopResponse(t=t, r=r, y=y, u=np.zeros_like(t), u_demand=np.zeros_like(t),
                              x=np.zeros((t.size, 1)))


@pytest.mark.parametrize(("offset", "amp"), [(0.5, 1.0), (-0.2, 0.3), (0.0, 2.0)])
def test_tracking_rms_and_max_of_an_error_with_a_mean(offset: float, amp: float) -> None:
    t = np.arange(0, 2.0, 1e-3)
    e = offset + amp * np.sin(2 * np.pi * 5 * t)  # whole periods: mean(e^2) = off^2 + amp^2/2
    out = _response(t, np.zeros_like(t) + 3.0, 3.0 - e).tracking_error()
    assert out["rms"] == pytest.approx(math.sqrt(offset**2 + amp**2 / 2), rel=1e-3)
    assert out["max"] == pytest.approx(abs(offset) + amp, rel=1e-3)


@pytest.mark.parametrize(("tau", "dt", "target"), [(0.05, 1e-3, 2.0), (0.2, 4e-3, -10.0)])
def test_step_figures_of_a_first_order_lag(tau: float, dt: float, target: float) -> None:
    t = np.arange(0, 12 * tau, dt)
    y = target * (1 - np.exp(-t / tau))
    info = _response(t, np.full_like(t, target), y).step_info(settling=0.02)
    # settling: first sample from which |y/target - 1| <= 2 %, i.e. t >= tau ln 50
    first_in = np.ceil(tau * math.log(50) / dt - 1e-9) * dt
    assert info["settling_time"] == pytest.approx(first_in, abs=1e-9)
    assert info["rise_time"] == pytest.approx(tau * math.log(9), abs=2 * dt)
    assert info["overshoot"] == 0.0
    # r - y over the last 10 %: the lag is still short of the target by target*exp(-t/tau)
    k = int(round(0.1 * t.size))
    want = float(np.mean(target * np.exp(-t[-k:] / tau)))
    assert info["steady_state_error"] == pytest.approx(want, rel=1e-6)
    assert np.sign(info["steady_state_error"]) == np.sign(target)


@pytest.mark.parametrize("velocity", [30.0, -120.0])
def test_operating_velocity_is_in_degrees_per_second(velocity: float) -> None:
    """A friction model's linearisation at a moving point: the velocity given in deg/s is
    the same point as the state omega given in rad/s."""
    model = HHRAModel(effects=[CoulombFriction()])
    by_velocity = linearize(model, OperatingPoint(velocity=velocity))
    by_state = linearize(model, OperatingPoint(states={"omega": math.radians(velocity)}))
    np.testing.assert_allclose(by_velocity.A, by_state.A, rtol=1e-12, atol=1e-12)
    at_rest = linearize(model)
    assert not np.allclose(by_velocity.A, at_rest.A)  # the point matters for this model
    x = OperatingPoint(velocity=velocity, angle=10.0).state_vector(model)
    names = model.state_names
    assert x[names.index("omega")] == pytest.approx(velocity * math.pi / 180)
    assert x[names.index("theta")] == pytest.approx(10.0 * math.pi / 180)


@pytest.mark.parametrize(("b", "c", "kv", "dt"),
                         [(60.0, 9.0e3, 5.0e3, 1e-3), (8.0, 150.0, 30.0, 5e-3)])
def test_arx_continuous_image_is_the_continuous_tf(b, c, kv, dt) -> None:
    """linearize() of the exact Tustin image of G(s) = kv/(s^3 + b s^2 + c s) is G."""
    sys = linearize(tustin_arx(1.0, b, c, kv, dt), dt=dt)
    for w in (0.3, 3.0, math.sqrt(c), 0.2 / dt):
        s = 1j * w
        got = complex((sys.C @ np.linalg.solve(s * np.eye(sys.nstates) - sys.A, sys.B)
                       + sys.D)[0, 0])
        want = kv / (s**3 + b * s**2 + c * s)
        assert abs(got - want) <= 1e-6 * abs(want), w
