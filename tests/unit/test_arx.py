"""Tests of hhra_phys.arx: Tustin map, ARX simulation, LS/RLS/FFRLS and metaheuristic fits."""

from __future__ import annotations

import warnings

import control
import numpy as np
import pytest
import scipy.signal

from hhra_phys import arx
from hhra_phys.errors import DataError, ParameterError
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.models.hhra.physical import PhysicalParameters

# A stable ARX(3, 3, 1): poles 0.9 and 0.7 +- 0.2j.
POLES = np.array([0.9, 0.7 + 0.2j, 0.7 - 0.2j])
A3 = np.real(np.poly(POLES))[1:]
B3 = np.array([0.5, -0.2, 0.1])


def _data(model: arx.ARXModel, n: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    u = np.random.default_rng(seed).normal(size=n)
    return u, model.simulate(u)


# --------------------------------------------------------------------------- Tustin


TF_CASES = [
    (1.0, 3.0, 5.0, 2.0, 0.01),
    (*HHRAModel().tf_coefficients().values(), 0.004),
    (*PhysicalParameters().tf_coefficients().values(), 0.004),
    (2.0, 0.5, 40.0, -3.0, 0.05),
]


@pytest.mark.parametrize(("a", "b", "c", "kv", "dt"), TF_CASES)
def test_tustin_matches_control_and_scipy(a: float, b: float, c: float, kv: float, dt: float):
    num, den = arx.tustin_coefficients(a, b, c, kv, dt)
    sys_d = control.sample_system(control.tf([kv], [a, b, c, 0.0]), dt, method="tustin")
    c_num = np.ravel(sys_d.num[0][0])
    c_den = np.ravel(sys_d.den[0][0])
    np.testing.assert_allclose(den, c_den / c_den[0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(num, c_num / c_den[0], rtol=1e-7)
    s_num, s_den, _ = scipy.signal.cont2discrete(([kv], [a, b, c, 0.0]), dt, method="bilinear")
    np.testing.assert_allclose(den, s_den, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(num, np.ravel(s_num), rtol=1e-7)
    # The integrator survives as a root at z = 1; the numerator is kv (1 + z^-1)^3 scaled.
    assert abs(den.sum()) < 1e-9
    np.testing.assert_allclose(num / num[0], [1.0, 3.0, 3.0, 1.0])


@pytest.mark.parametrize(("a", "b", "c", "kv", "dt"), TF_CASES)
def test_tustin_inverse_roundtrip(a: float, b: float, c: float, kv: float, dt: float):
    num, den = arx.tustin_coefficients(a, b, c, kv, dt)
    back = arx.tustin_inverse(num, den, dt)
    expected = {"a": 1.0, "b": b / a, "c": c / a, "kv": kv / a}
    for key, value in expected.items():
        assert back[key] == pytest.approx(value, rel=1e-6), key


def test_tustin_inverse_refuses_non_images():
    num, den = arx.tustin_coefficients(1.0, 3.0, 5.0, 2.0, 0.01)
    leaky = den.copy()
    leaky[-1] += 1e-3  # moves the pole off z = 1
    with pytest.raises(ParameterError, match="denominator"):
        arx.tustin_inverse(num, leaky, 0.01)
    eq13 = np.concatenate([[0.0], num[1:]])  # b0 = 0 as in the paper's eq. 13
    with pytest.raises(ParameterError, match="numerator"):
        arx.tustin_inverse(eq13, den, 0.01)
    nearest = arx.tustin_inverse(eq13, den, 0.01, rtol=np.inf)
    assert nearest["b"] == pytest.approx(3.0, rel=1e-6)  # the denominator was exact
    with pytest.raises(ParameterError, match="4 finite"):
        arx.tustin_inverse(num[:3], den, 0.01)
    with pytest.raises(ParameterError, match="dt"):
        arx.tustin_coefficients(1.0, 3.0, 5.0, 2.0, 0.0)


def test_ls_on_tustin_data_recovers_continuous_model():
    tf = HHRAModel().tf_coefficients()
    dt = 0.004
    truth = arx.tustin_arx(tf["a"], tf["b"], tf["c"], tf["kv"], dt)
    assert (truth.na, truth.nb, truth.nk) == (3, 4, 0)
    u = np.repeat(np.random.default_rng(1).normal(size=60), 10)
    y = truth.simulate(u)
    fit = arx.fit_ls(u, y, 3, 4, 0, on_ill_conditioned="ignore")
    b_full, a_full = fit.model.filter_coefficients()
    back = arx.tustin_inverse(b_full, a_full, dt, rtol=1e-5)
    for key in ("b", "c", "kv"):
        assert back[key] == pytest.approx(tf[key], rel=1e-4), key


# --------------------------------------------------------------------------- simulation


def test_free_run_equals_control_forced_response():
    model = arx.ARXModel(A3, B3, nk=1)
    dt = 0.01
    u = np.random.default_rng(2).normal(size=300)
    t = dt * np.arange(u.size)
    resp = control.forced_response(model.to_control(dt), T=t, U=u)
    np.testing.assert_allclose(model.simulate(u), np.ravel(resp.outputs), atol=1e-12)
    delayed = arx.ARXModel(A3[:2], B3, nk=3)  # more zeros in front than poles
    resp = control.forced_response(delayed.to_control(dt), T=t, U=u)
    np.testing.assert_allclose(delayed.simulate(u), np.ravel(resp.outputs), atol=1e-12)


@pytest.mark.parametrize(("na", "nb", "nk"), [(3, 3, 1), (2, 3, 0), (3, 2, 2), (0, 2, 1)])
def test_population_with_initial_conditions_matches_lfiltic(na: int, nb: int, nk: int):
    rng = np.random.default_rng(3)
    theta = 0.2 * rng.normal(size=(4, na + nb))
    u = rng.normal(size=150)
    y_hist, u_hist = rng.normal(size=5), rng.normal(size=5)
    sims = arx.simulate_population(theta, u, na, nb, nk, y_hist, u_hist, max_pole_radius=None)
    for row, sim in zip(theta, sims, strict=True):
        b = np.concatenate([np.zeros(nk), row[na:]])
        a = np.concatenate([[1.0], row[:na]])
        zi = scipy.signal.lfiltic(b, a, y_hist[::-1], u_hist[::-1])
        np.testing.assert_allclose(sim, scipy.signal.lfilter(b, a, u, zi=zi)[0], atol=1e-12)
        model = arx.ARXModel.from_theta(row, na, nb, nk)
        np.testing.assert_allclose(model.simulate(u, y_hist, u_hist), sim, atol=1e-12)


def test_predict_is_one_step_and_simulate_is_free_run():
    model = arx.ARXModel(A3, B3, nk=1)
    u, y = _data(model)
    noisy = y + 0.05 * np.random.default_rng(4).normal(size=y.size)
    pred = model.predict(u, noisy)
    k = 10  # by hand: -a . y(k-1..k-3) + b . u(k-1..k-3)
    hand = -A3 @ noisy[k - 1 : k - 4 : -1] + B3 @ u[k - 1 : k - 4 : -1]
    assert pred[k] == pytest.approx(hand)
    np.testing.assert_allclose(model.predict(u, y), y, atol=1e-12)
    np.testing.assert_allclose(model.simulate(u), y, atol=1e-12)  # ignores the measured y


def test_unstable_candidates_cost_inf_without_error():
    u, y = _data(arx.ARXModel(A3, B3))
    unstable = np.concatenate([[-2.5], A3[1:], B3])  # a pole far outside the unit circle
    good = np.concatenate([A3, B3])
    theta = np.vstack([good, unstable, np.full(6, np.nan), [-1.0, 0, 0, 0.1, 0, 0]])
    cost = arx.itae_cost(u, y)(theta)
    assert cost[0] == pytest.approx(0.0, abs=1e-6)
    assert np.isinf(cost[1]) and np.isinf(cost[2])
    assert np.isfinite(cost[3])  # an integrator (pole on the unit circle) is allowed
    assert arx.pole_radius(theta[[0, 3], :3]) == pytest.approx([0.9, 1.0])
    with np.errstate(all="raise"):  # unchecked: overflow is not an exception either
        sims = arx.simulate_population(
            np.vstack([unstable] * 2), np.ones(2000), max_pole_radius=None
        )
    assert not np.isfinite(sims).all()


def test_model_and_input_validation():
    with pytest.raises(ParameterError, match="na"):
        arx.regression_matrix(np.ones(10), np.ones(10), na=-1)
    with pytest.raises(ParameterError, match="theta"):
        arx.ARXModel.from_theta([1.0, 2.0], 3, 3, 1)
    with pytest.raises(ParameterError, match="nb >= 1"):
        arx.ARXModel([0.5], [])
    with pytest.raises(DataError, match="same length"):
        arx.fit_ls(np.ones(10), np.ones(11))
    with pytest.raises(ParameterError, match="y_init"):
        arx.ARXModel(A3, B3).simulate(np.ones(10), y_init=[1.0])
    with pytest.raises(ParameterError, match="both"):
        arx.regression_matrix(np.ones(10), np.ones(10), y_init=0.0)


# --------------------------------------------------------------------------- estimators


@pytest.mark.parametrize(("na", "nb", "nk"), [(3, 3, 1), (2, 3, 0), (1, 2, 2)])
def test_ls_recovers_exact_arx(na: int, nb: int, nk: int):
    rng = np.random.default_rng(5)
    a = np.real(np.poly(POLES[:na]))[1:] if na else np.empty(0)
    truth = arx.ARXModel(a, rng.normal(size=nb), nk)
    u, y = _data(truth, seed=6)
    fit = arx.fit_ls(u, y, na, nb, nk)
    np.testing.assert_allclose(fit.model.theta, truth.theta, atol=1e-10)
    assert fit.info["rank"] == na + nb
    assert fit.info["rows"] == u.size - max(na, nk + nb - 1)


def test_ls_conditioning_checks():
    with pytest.raises(DataError, match=r"rank deficient|identically zero"):
        arx.fit_ls(np.ones(200), np.random.default_rng(0).normal(size=200), 2, 2, 1)
    u, y = _data(arx.ARXModel(A3, B3))
    with pytest.warns(arx.ConditioningWarning, match="condition number"):
        arx.fit_ls(u, y, cond_limit=1.0)
    with pytest.raises(DataError, match="ill-conditioned"):
        arx.fit_ls(u, y, cond_limit=1.0, on_ill_conditioned="raise")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fit = arx.fit_ls(u, y)  # well conditioned: no warning at the default limit
    assert 1.0 < fit.info["cond"] < 1e3


def test_rls_converges_to_ls():
    u, y = _data(arx.ARXModel(A3, B3), n=1500, seed=7)
    y = y + 0.1 * np.random.default_rng(8).normal(size=y.size)
    ls = arx.fit_ls(u, y).model.theta
    rls = arx.fit_rls(u, y)
    # RLS from P(0) = p0 I, theta(0) = theta0 is exactly LS regularised by I/p0:
    phi, target = arx.regression_matrix(u, y)
    reg = np.linalg.solve(
        phi.T @ phi + np.eye(6) / arx.RLS_P0, phi.T @ target + arx.RLS_THETA0 / arx.RLS_P0
    )
    np.testing.assert_allclose(rls.model.theta, reg, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(rls.model.theta, ls, rtol=1e-4, atol=1e-6)
    # ... and it gets there: far from LS after a few updates, close long before the end.
    assert np.abs(rls.trajectory[5] - ls).max() > 1e-2
    assert np.abs(rls.trajectory[750] - ls).max() < 0.05


def test_forgetting_factor_follows_the_recursion():
    xi = arx.forgetting_factor(500)
    assert xi[0] == pytest.approx(arx.FFRLS_XI_INIT)
    np.testing.assert_allclose(xi[1:], 0.99 * xi[:-1] + 0.01, rtol=1e-14)
    assert 0.999 < xi[-1] < 1.0
    np.testing.assert_allclose(arx.forgetting_factor(5, xi0=1.0, xi_init=0.9), 0.9)
    with pytest.raises(ParameterError, match="xi_init"):
        arx.forgetting_factor(5, xi_init=0.0)


def test_ffrls_tracks_a_parameter_step():
    n, step = 1000, 100
    u = np.random.default_rng(9).normal(size=n)
    before, after = arx.ARXModel([-0.5], [1.0]), arx.ARXModel([-0.5], [2.0])
    y = np.concatenate([before.simulate(u[:step]), np.zeros(n - step)])
    y[step:] = after.simulate(u[step:], y_init=y[:step], u_init=u[:step])
    ff, rls = arx.fit_ffrls(u, y, 1, 1, 1), arx.fit_rls(u, y, 1, 1, 1)
    row = step + 100 - 1  # regression row of sample k is k - 1 here
    err_ff = abs(ff.trajectory[row, 1] - 2.0)
    err_rls = abs(rls.trajectory[row, 1] - 2.0)
    assert err_ff < 0.5 * err_rls
    assert abs(ff.model.b[0] - 2.0) < 0.02 < abs(rls.model.b[0] - 2.0)
    # A constant forgetting factor (xi0 = 1) follows a late step exactly on noise-free data.
    y2 = np.concatenate([before.simulate(u[:500]), np.zeros(n - 500)])
    y2[500:] = after.simulate(u[500:], y_init=y2[:500], u_init=u[:500])
    const = arx.fit_ffrls(u, y2, 1, 1, 1, xi0=1.0, xi_init=0.95)
    np.testing.assert_allclose(const.model.theta, [-0.5, 2.0], atol=1e-6)


# --------------------------------------------------------------------------- metaheuristics


def test_hybrid_box_contains_the_ffrls_estimate():
    u, y = _data(arx.ARXModel(A3, B3), n=600, seed=10)
    y = y + 0.05 * np.random.default_rng(11).normal(size=y.size)
    theta_hat = arx.fit_ffrls(u, y).model.theta
    assert (theta_hat < 0).any() and (theta_hat > 0).any()
    box = arx.hybrid_box(theta_hat, 0.3)
    assert np.all(box[:, 0] < theta_hat) and np.all(theta_hat < box[:, 1])
    np.testing.assert_allclose(box[:, 1] - box[:, 0], 0.6 * np.abs(theta_hat))
    zero = arx.hybrid_box([0.0, -2.0], 0.5)
    assert zero[0, 0] < 0.0 < zero[0, 1] and zero[0, 1] < 1e-9
    np.testing.assert_allclose(zero[1], [-3.0, -1.0])
    for bad in (0.0, 1.5, np.nan):
        with pytest.raises(ParameterError, match="zeta_s"):
            arx.hybrid_box(theta_hat, bad)
    fit = arx.fit_ffrls_hgwo(u, y, zeta_s=0.3, pop_size=12, max_iter=8, seed=1)
    np.testing.assert_allclose(fit.info["ffrls_theta"], theta_hat)
    np.testing.assert_allclose(fit.info["bounds"], box)
    assert np.all(box[:, 0] <= fit.model.theta) and np.all(fit.model.theta <= box[:, 1])
    assert fit.method == "ffrls_hgwo" and fit.nfev == 12 * 2 + 8 * 24


@pytest.mark.parametrize("method", ["pso", "gwo", "hgwo"])
def test_metaheuristic_fit_is_reproducible_and_converges(method: str):
    truth = arx.ARXModel([-0.8], [0.5], nk=1)
    u = np.repeat(np.random.default_rng(12).choice([-1.0, 1.0], size=30), 10)
    y = truth.simulate(u)
    t = 0.01 * np.arange(u.size)
    kw = {"method": method, "na": 1, "nb": 1, "nk": 1, "pop_size": 30, "max_iter": 60}
    fit = arx.fit_metaheuristic(u, y, t, seed=3, **kw)
    again = arx.fit_metaheuristic(u, y, t, seed=3, **kw)
    np.testing.assert_array_equal(fit.model.theta, again.model.theta)
    assert np.all(np.diff(fit.convergence) <= 0)
    assert fit.convergence[-1] == pytest.approx(fit.info["best_itae"])
    assert 0 <= fit.noi <= 60 and fit.nfev == fit.convergence_nfev[-1]
    np.testing.assert_allclose(fit.model.theta, truth.theta, atol=0.05)


@pytest.mark.parametrize("seed", [1, 4])
def test_metaheuristic_options_object_and_keywords_give_one_fit(seed: int):
    truth = arx.ARXModel([-0.7], [0.4], nk=1)
    u = np.repeat(np.random.default_rng(seed).choice([-1.0, 1.0], size=20), 8)
    y = truth.simulate(u)
    opts = arx.MetaheuristicOptions(method="pso", na=1, nb=1, pop_size=10, max_iter=6,
                                    seed=seed, optimizer_options={"w": 0.5})
    a = arx.fit_metaheuristic(u, y, options=opts)
    b = arx.fit_metaheuristic(u, y, method="pso", na=1, nb=1, pop_size=10, max_iter=6,
                              seed=seed, options={"w": 0.5})  # a dict: the optimiser's own
    c = arx.fit_metaheuristic(u, y, options=opts, seed=seed + 1)  # a keyword overrides
    np.testing.assert_array_equal(a.model.theta, b.model.theta)
    assert a.info["options"]["w"] == 0.5 and a.method == "pso" and c.info["seed"] == seed + 1
    h = arx.HybridOptions(na=1, nb=1, pop_size=6, max_iter=3, seed=seed, zeta_s=0.4)
    np.testing.assert_array_equal(arx.fit_ffrls_hgwo(u, y, options=h).model.theta,
                                  arx.fit_ffrls_hgwo(u, y, na=1, nb=1, pop_size=6, max_iter=3,
                                                     seed=seed, zeta_s=0.4).model.theta)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"method": "cmaes"}, "method: expected one of hgwo, gwo, pso, de"),
    ({"pop_size": 0}, "pop_size must be an integer >= 1"),
    ({"bounds": (1.0, -1.0)}, "bounds must be"),
    ({"max_pole_radius": -1.0}, "max_pole_radius"),
    ({"popsize": 5}, "unknown fit_metaheuristic setting.*popsize"),
])
def test_metaheuristic_bad_settings_are_named_before_any_work(kwargs, match):
    u = np.ones(20)
    with pytest.raises(ParameterError, match=match):
        arx.fit_metaheuristic(u, u, **kwargs)


def test_hybrid_bad_settings_are_named():
    u = np.ones(20)
    with pytest.raises(ParameterError, match="zeta_s"):
        arx.fit_ffrls_hgwo(u, u, zeta_s=0.0)
    with pytest.raises(ParameterError, match="unknown fit_ffrls_hgwo setting.*bounds"):
        arx.fit_ffrls_hgwo(u, u, bounds=(-1, 1))  # the hybrid's box is eq. 29's
