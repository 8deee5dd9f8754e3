"""Oracles for the ARX path: published Tustin mapping (SciPy's bilinear transform) and the
textbook FFRLS result written as a weighted least-squares problem solved in one batch."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import cont2discrete

from hhra_phys.arx import ARXModel, recursive_least_squares, tustin_arx, tustin_inverse

# (b, c, kv) of kv/(s^3 + b s^2 + c s): an HHRA-like lightly damped set, a well damped one, a
# slow one; dt 1 ms and 5 ms.
SETS = [(60.0, 9.0e3, 5.0e3, 1e-3), (400.0, 4.0e4, 2.0e4, 1e-3), (8.0, 150.0, 30.0, 5e-3)]


def _bilinear(b: float, c: float, kv: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    num, den, _ = cont2discrete(([kv], [1.0, b, c, 0.0]), dt, method="bilinear")
    return np.ravel(num), np.ravel(den)


@pytest.mark.parametrize(("b", "c", "kv", "dt"), SETS)
def test_continuous_poles_of_a_bilinear_image_are_the_continuous_poles(b, c, kv, dt) -> None:
    num, den = _bilinear(b, c, kv, dt)
    model = ARXModel(den[1:] / den[0], num / den[0], nk=0)
    got = np.sort_complex(model.continuous_poles(dt))
    want = np.sort_complex(np.roots([1.0, b, c, 0.0]))
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6 * abs(want).max())


@pytest.mark.parametrize(("b", "c", "kv", "dt"), SETS)
def test_tustin_image_and_inverse_match_scipy(b, c, kv, dt) -> None:
    num, den = _bilinear(b, c, kv, dt)
    model = tustin_arx(1.0, b, c, kv, dt)
    np.testing.assert_allclose(model.b, num / den[0], rtol=1e-7)  # SciPy rounds via state space
    np.testing.assert_allclose(np.concatenate([[1.0], model.a]), den / den[0], rtol=1e-7,
                               atol=1e-12)
    back = tustin_inverse(num, den, dt)
    assert back["b"] == pytest.approx(b, rel=1e-6)
    assert back["c"] == pytest.approx(c, rel=1e-6)
    assert back["kv"] == pytest.approx(kv, rel=1e-6)


def _factors(n: int, rate: float, start: float) -> np.ndarray:
    """The paper's recursion xi(k) = rate*xi(k-1) + (1 - rate), xi(0) = start."""
    xi = np.empty(n)
    xi[0] = start
    for k in range(1, n):
        xi[k] = rate * xi[k - 1] + (1.0 - rate)
    return xi


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(("rate", "start"), [(0.99, 0.95), (0.9, 0.8), (1.0, 0.97)])
def test_ffrls_equals_exponentially_weighted_least_squares(seed, rate, start) -> None:
    """After N updates with factors xi_k, FFRLS minimises
    sum_i (prod_{j>i} xi_j) e_i^2 + (prod_j xi_j) (theta - theta0)^T P0^-1 (theta - theta0)."""
    rng = np.random.default_rng(seed)
    n, p, p0 = 80, 4, 5.0
    phi = rng.standard_normal((n, p))
    theta_true = rng.standard_normal(p)
    # A parameter jump half way: forgetting matters for the answer.
    y = np.where(np.arange(n) < n // 2, phi @ theta_true, phi @ (1.5 * theta_true))
    y = y + 0.1 * rng.standard_normal(n)
    theta0 = 0.3 * np.ones(p)
    xi = _factors(n, rate, start)
    w = np.array([np.prod(xi[i + 1:]) for i in range(n)])
    w0 = np.prod(xi)
    lhs = (phi * w[:, None]).T @ phi + w0 * np.eye(p) / p0
    rhs = (phi * w[:, None]).T @ y + w0 * theta0 / p0
    want = np.linalg.solve(lhs, rhs)
    got, traj = recursive_least_squares(phi, y, p0=p0, theta0=theta0, forgetting=xi)
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(traj[-1], got)


def test_ffrls_default_factors_follow_the_papers_recursion() -> None:
    """fit_ffrls's default forgetting: update k (from 0) uses xi(k) of the recursion."""
    from hhra_phys.arx import FFRLS_XI0, FFRLS_XI_INIT, fit_ffrls, regression_matrix

    rng = np.random.default_rng(7)
    u = rng.standard_normal(300)
    y = np.zeros(300)
    for k in range(2, 300):
        y[k] = 1.2 * y[k - 1] - 0.5 * y[k - 2] + 0.3 * u[k - 1] + 0.01 * rng.standard_normal()
    fit = fit_ffrls(u, y, na=2, nb=1, nk=1)
    phi, target = regression_matrix(u, y, 2, 1, 1)
    xi = _factors(phi.shape[0], FFRLS_XI0, FFRLS_XI_INIT)
    want, _ = recursive_least_squares(phi, target, forgetting=xi)
    np.testing.assert_allclose(fit.model.theta, want, rtol=1e-10)
