"""Every effect's first-order signature against its closed form and against its own ``apply``.

The signature (:meth:`Effect.first_order`) is what the diagnosis projects the residual on;
it must be the change the effect makes at its entry point. Closed forms are written here
from the documented formulas (dead zone ``-clip(u, -d, d)``, saturation ``clip(u, -s, s) - u``,
one-sample delay ``u[k-1] - u[k]``, the zero-order-hold first-order lag from SciPy's
``cont2discrete``, gravity ``-a [cos theta, sin theta]``, offset a constant); the
consistency checks evaluate the effect's own ``apply`` on the same signals.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy import signal as sps

from hhra_phys.effects import LIBRARY, make_effect
from hhra_phys.parts import Context, Signals

DT = 0.004
N = 400


def _signals(seed: int = 0) -> Signals:
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1.5, 1.5, N // 20), 20)
    t = np.arange(N) * DT
    return Signals(u=u, dt=DT, states={"theta": 0.8 * np.sin(2.1 * t),
                                       "omega": 1.68 * np.cos(2.1 * t)})


def _apply(effect, sig: Signals, values: dict[str, float], what: str) -> np.ndarray:
    """The effect's change to ``what`` ("u", "y" or "rate:<state>") on the signals, (N,)."""
    nl = effect.n_lags
    u = ca.SX.sym("u", nl + 1)
    names = ["theta", "omega", "p"] + [s.name for s in effect.states]
    xs = ca.SX.sym("x", len(names))
    x = {n: xs[i] for i, n in enumerate(names)}
    p = {k: ca.SX(v) for k, v in values.items()}
    ctx = Context(x, p, u, DT)
    ctx.signals["command"] = ctx.u
    ctx.signals["flow"] = 2.0 * ctx.u
    ctx.signals["y"] = 180.0 / math.pi * x["theta"]
    before = {"u": ctx.u, "y": ctx.signals["y"], "flow": ctx.signals["flow"]}
    effect.apply(ctx)
    if what == "u":
        change = ctx.u - before["u"]
    elif what == "y":
        change = ctx.signals["y"] - before["y"]
    elif what == "flow":
        change = ctx.signals["flow"] - before["flow"]
    else:
        change = ctx.rates[what[5:]]
    fn = ca.Function("change", [xs, u], [change])
    out = np.empty(N)
    for k in range(N):
        lags = [sig.u[max(k - j, 0)] for j in range(nl + 1)]
        state = [sig.states["theta"][k], sig.states["omega"][k], 0.0] + [0.0] * len(effect.states)
        out[k] = float(fn(state, lags))
    return out


def test_every_library_effect_has_a_signature_of_the_record_length():
    sig = _signals()
    for name in LIBRARY:
        cols = make_effect(name).first_order(sig)
        assert cols is not None and cols.shape[0] == N and np.isfinite(cols).all(), name


@pytest.mark.parametrize("seed", [0, 1])
def test_deadzone_and_saturation_closed_forms_and_apply(seed):
    sig = _signals(seed)
    dz = make_effect("valve_deadzone")
    d = dz.probe()["i_dead"]
    np.testing.assert_allclose(dz.first_order(sig)[:, 0], -np.clip(sig.u, -d, d), atol=1e-12)
    # apply: corners of half width width*u_scale (0.01 mA): within that of the closed
    # form, and exact beyond the corners
    got = _apply(dz, sig, {"i_dead": d}, "u")
    np.testing.assert_allclose(got, -np.clip(sig.u, -d, d), atol=0.01)
    away = np.abs(np.abs(sig.u) - d) >= 0.01
    assert away.sum() > N // 2
    np.testing.assert_allclose(got[away], -np.clip(sig.u, -d, d)[away], atol=1e-12)
    sat = make_effect("valve_saturation")
    s = 0.8 * float(np.max(np.abs(sig.u)))
    closed = np.clip(sig.u, -s, s) - sig.u
    np.testing.assert_allclose(sat.first_order(sig)[:, 0], closed, atol=1e-12)
    got = _apply(sat, sig, {"i_sat": s}, "u")
    np.testing.assert_allclose(got, closed, atol=0.01)
    away = np.abs(np.abs(sig.u) - s) >= 0.01
    np.testing.assert_allclose(got[away], closed[away], atol=1e-12)


def test_delay_closed_form_and_apply():
    sig = _signals()
    delay = make_effect("input_delay")
    closed = np.concatenate([sig.u[:1], sig.u[:-1]]) - sig.u
    np.testing.assert_array_equal(delay.first_order(sig)[:, 0], closed)
    np.testing.assert_allclose(_apply(delay, sig, {"delay": 1.0}, "u"), closed, atol=1e-15)


def test_spool_lag_signature_is_the_zero_order_hold_lag():
    sig = _signals()
    lag = make_effect("valve_dynamics", dt=DT)
    tau = lag.probe()["tau_spool"]
    ad, bd, cd, dd, _ = sps.cont2discrete((np.array([[-1 / tau]]), np.array([[1 / tau]]),
                                           np.eye(1), np.zeros((1, 1))), DT,
                                          method="zoh")
    # Started at rest on u[0] (the spool has followed the input so far).
    lagged = sps.dlsim((ad, bd, cd, dd, DT), sig.u, x0=[sig.u[0]])[1][:, 0]
    np.testing.assert_allclose(lag.first_order(sig)[:, 0], lagged - sig.u, atol=1e-9)


def test_gravity_columns_are_the_two_torques():
    sig = _signals()
    grav = make_effect("gravity_load")
    cols = grav.first_order(sig)
    a = grav.probe()["g_grav_cos"]
    th = sig.states["theta"]
    np.testing.assert_allclose(cols, -a * np.column_stack([np.cos(th), np.sin(th)]), rtol=1e-12)
    rate = _apply(grav, sig, grav.probe(), "rate:omega")
    np.testing.assert_allclose(rate, cols.sum(axis=1), rtol=1e-12, atol=1e-12)


def test_friction_signature_is_its_own_rate_change():
    sig = _signals()
    for kw in ({}, {"stribeck": True}):
        fr = make_effect("coulomb_friction", **kw)
        cols = fr.first_order(sig)
        rate = _apply(fr, sig, fr.probe(), "rate:omega")
        if not kw:
            np.testing.assert_allclose(cols[:, 0], rate, rtol=1e-9, atol=1e-12)
        # opposes the motion wherever the shaft moves
        moving = np.abs(sig.states["omega"]) > 0.5
        assert np.all(np.sign(rate[moving]) == -np.sign(sig.states["omega"][moving]))


def test_offset_and_asymmetry_are_what_they_add():
    sig = _signals()
    off = make_effect("sensor_offset", y_scale=2.0)
    np.testing.assert_allclose(off.first_order(sig)[:, 0], 0.2)
    np.testing.assert_allclose(_apply(off, sig, off.probe(), "y"), 0.2)
    asym = make_effect("asymmetric_valve")
    flow = _apply(asym, sig, asym.probe(), "flow")
    # flow 2u scaled by 1 + asym*sgn(u): a change 2*asym*|u| (smooth sign within 0.01 mA)
    big = np.abs(sig.u) > 0.2  # beyond the smooth sign's corner: within 0.13 %
    np.testing.assert_allclose(flow[big], 2 * 0.05 * np.abs(sig.u[big]), rtol=2e-3)
    np.testing.assert_allclose(asym.first_order(sig)[:, 0], 0.05 * np.abs(sig.u))


def test_backlash_signature_is_half_the_probe_play_against_the_motion():
    sig = _signals()
    bl = make_effect("backlash")
    cols = bl.first_order(sig)[:, 0]
    w = sig.states["omega"]
    moving = np.abs(w) > 0.1
    # at contact the encoder lags the shaft by half the play (0.5 deg probe): -0.25 deg
    np.testing.assert_allclose(cols[moving], -0.25 * np.sign(w[moving]), atol=2e-3)
