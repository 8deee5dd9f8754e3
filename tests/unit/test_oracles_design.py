"""Oracles for experiment design: the predicted covariance against a plain NumPy Gauss-Newton
covariance from finite differences of simulated outputs (the initial position marginalised
by inverting the whole information matrix), the predicted widths and draws from it, the
E-criterion in closed form and the default input limit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hhra_phys.design import DesignOptions, InformationModel, criterion_value, design_input
from hhra_phys.errors import ParameterError
from hhra_phys.fit import fit
from hhra_phys.models.cylinder import LinearCylinderModel, cylinder_input, simulate_cylinder

FREE = ["c_force", "c_valve", "c_compress"]


@pytest.fixture(scope="module")
def fitted():
    rec = simulate_cylinder(seed=1, duration=6.0, noise=0.05)
    res = fit(rec, model=LinearCylinderModel(), optimizer="none", refine="ipopt", free=FREE,
              widen_bounds=False)
    return res, InformationModel(res)


def _numpy_covariance(res, info, u: np.ndarray) -> np.ndarray:
    """sigma^2 [(J^T J)^-1] of (log10 groups, initial position), its group block."""
    model = res.model
    sim = res.simulator(info.fs)
    names = model.params.names
    p0 = np.array([res.values[n] for n in names])
    x0 = model.x0()

    def y(z: np.ndarray) -> np.ndarray:
        p = p0.copy()
        for j, n in enumerate(FREE):
            p[names.index(n)] = 10.0 ** z[j]
        x = x0.copy()
        x[0] = z[-1]
        return sim.simulate(u, p, x0=x)

    z0 = np.array([math.log10(res.values[n]) for n in FREE] + [0.0])
    steps = np.array([1e-5] * len(FREE) + [1e-6])  # decades; metres of initial position
    J = np.column_stack([(y(z0 + h * e) - y(z0 - h * e)) / (2 * h)
                         for h, e in zip(steps, np.eye(z0.size), strict=True)])
    sigma = float(res.metrics["est"]["rmse"])
    return sigma**2 * np.linalg.inv(J.T @ J)[:len(FREE), :len(FREE)]


@pytest.mark.parametrize("seed", [4, 9])
def test_predicted_covariance_is_the_gauss_newton_covariance(fitted, seed: int) -> None:
    res, info = fitted
    u = cylinder_input(6.0, info.fs, seed=seed)
    cov, peak = info.covariance(u)
    want = _numpy_covariance(res, info, u)
    np.testing.assert_allclose(cov, want, rtol=2e-3, atol=2e-3 * np.abs(want).max())
    # relative 95 % width of a log10 coordinate with standard deviation s
    sd = np.sqrt(np.diag(want))
    widths = info.widths(u)
    for j, n in enumerate(FREE):
        assert widths[n] == pytest.approx(10 ** (1.96 * sd[j]) - 10 ** (-1.96 * sd[j]), rel=3e-3)


def test_draws_spread_like_the_fits_covariance(fitted) -> None:
    _, info = fitted
    draws = info.draws(600, seed=2)[1:]
    z = np.array([[math.log10(d[n]) for n in FREE] for d in draws])
    want = info.cov_z
    got = np.cov(z.T)
    np.testing.assert_allclose(np.sqrt(np.diag(got)), np.sqrt(np.diag(want)), rtol=0.12)


def test_e_criterion_is_the_largest_eigenvalue() -> None:
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    cov = q @ np.diag([0.5, 2.0, 7.0]) @ q.T
    assert criterion_value(cov, "e") == pytest.approx(7.0)
    assert criterion_value(cov, "a") == pytest.approx(9.5)
    assert criterion_value(cov, "d") == pytest.approx(math.log(7.0))


def test_default_input_limit_is_the_largest_magnitude(fitted) -> None:
    res, info = fitted
    ref = np.concatenate([np.full(100, 2.0), np.full(100, -6.0)])  # the peak is negative
    d = design_input(res, 3.0, reference_input=ref, candidates=2, local_steps=0, draws=0,
                     families=("aprbs",), seed=1, output_limit=200.0)
    assert d.limits["max_input"] == pytest.approx(6.0)
    assert np.max(np.abs(d.u)) <= 6.0 + 1e-12


@pytest.mark.parametrize("seed", [2, 5])
def test_design_options_object_and_keywords_give_one_design(fitted, seed: int) -> None:
    res, _ = fitted
    ref = cylinder_input(3.0, seed=seed)  # sets the default max_input only
    kw = {"candidates": 2, "local_steps": 3, "draws": 0, "families": ["aprbs", "free"],
          "seed": seed, "output_limit": 200.0, "split": 0.5}
    a = design_input(res, 3.0, reference_input=ref, **kw)
    b = design_input(res, 3.0, reference_input=ref, options=DesignOptions(**{
        **kw, "families": ("aprbs", "free"), "seed": seed + 1}), seed=seed)
    np.testing.assert_array_equal(a.u, b.u)
    assert a.value == b.value and a.evaluations == b.evaluations


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"criterion": "x"}, "criterion must be one of d, a, e"),
    ({"families": ("steps", "chirp")}, "families must be among"),
    ({"families": ()}, "families must be among"),
    ({"split": 1.5}, "split must be a fraction"),
    ({"output_limit": float("nan")}, "output_limit must be a finite number > 0"),
    ({"min_hold": None}, "min_hold must be a finite number > 0"),
    ({"fs": 0.0}, "fs must be a finite number > 0"),
    ({"candidates": -1}, "candidates must be an integer >= 0"),
    ({"draw": 2}, "unknown design setting.*draw"),
])
def test_design_settings_are_named_before_any_simulation(kwargs, match) -> None:
    with pytest.raises(ParameterError, match=match):
        DesignOptions.of(**kwargs)
