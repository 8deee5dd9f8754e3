"""Tests of the nine benchmark functions of the paper's Table 1 and their shifted variants."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys.errors import ParameterError
from hhra_phys.paper.benchmarks import (
    BENCHMARK_KEYS,
    ackley,
    get_benchmark,
    goldstein_price,
    griewank,
    kowalik,
    rastrigin,
    rosenbrock,
    six_hump_camel,
    sphere,
)

TABLE1 = {  # key: (dim, lower, upper, f_min) as in the paper (with the stated corrections)
    "f1": (30, -100, 100, 0.0),
    "f2": (30, -30, 30, 0.0),
    "f3": (30, -1.28, 1.28, 0.0),
    "f4": (30, -5.12, 5.12, 0.0),
    "f5": (30, -30, 30, 0.0),
    "f6": (30, -600, 600, 0.0),
    "f7": (2, -5, 5, -1.0316),
    "f8": (4, -5, 5, 0.0003),
    "f9": (2, -2, 2, 3.0),
}


def test_nine_functions_with_table1_settings():
    assert BENCHMARK_KEYS == tuple(f"f{i}" for i in range(1, 10))
    for key, (dim, lo, hi, fmin) in TABLE1.items():
        b = get_benchmark(key)
        assert (b.dim, b.lower, b.upper) == (dim, lo, hi)
        assert b.f_min == pytest.approx(fmin, abs=5e-5)
        assert b.bounds == [(lo, hi)] * dim


@pytest.mark.parametrize("key", BENCHMARK_KEYS)
def test_known_minimum_at_the_optimum(key):
    b = get_benchmark(key, seed=0).noise_free()
    assert b(b.x_min) == pytest.approx(b.f_min, rel=1e-12, abs=1e-14)
    assert np.all((b.x_min >= b.lower) & (b.x_min <= b.upper))


@pytest.mark.parametrize("key", BENCHMARK_KEYS)
def test_optimum_is_a_minimum_locally_and_against_random_points(key):
    b = get_benchmark(key).noise_free()
    rng = np.random.default_rng(1)
    near = b.x_min + rng.normal(scale=1e-3 * (b.upper - b.lower), size=(200, b.dim))
    assert np.all(b(near) >= b.f_min - 1e-12)
    far = rng.uniform(b.lower, b.upper, size=(2000, b.dim))
    assert np.nanmin(b(far)) > b.f_min


@pytest.mark.parametrize("key", BENCHMARK_KEYS)
def test_vectorised_matches_point_by_point(key):
    b = get_benchmark(key).noise_free()
    x = np.random.default_rng(2).uniform(b.lower, b.upper, size=(7, b.dim))
    out = b(x)
    assert out.shape == (7,)
    np.testing.assert_allclose(out, [b(row) for row in x], rtol=1e-14)
    assert isinstance(b(x[0]), float)


def test_values_away_from_the_optimum():
    z = np.zeros((1, 30))
    assert rosenbrock(z)[0] == 29.0  # (0 - 1)^2 in each of 29 terms
    assert sphere(np.full((1, 30), 2.0))[0] == 120.0
    assert rastrigin(np.full((1, 30), 1.0))[0] == pytest.approx(30.0)
    assert rastrigin(np.full((1, 30), 0.5))[0] == pytest.approx(30 * 20.25)
    assert ackley(z)[0] == pytest.approx(0.0, abs=1e-15)
    # Griewank with 1/4000 (the paper prints 1/40000): 30 * 100 / 4000 = 0.75 at x = 10 ...
    x = np.full((1, 30), 10.0)
    expected = 0.75 - np.prod(np.cos(10.0 / np.sqrt(np.arange(1, 31)))) + 1.0
    assert griewank(x)[0] == pytest.approx(expected)
    assert six_hump_camel(np.array([[0.0, 0.0]]))[0] == 0.0
    assert goldstein_price(np.array([[0.0, 0.0]]))[0] == 600.0
    # Kowalik with squared residuals: at x = 0 the model is 0, so f = sum a_i^2
    from hhra_phys.paper.benchmarks import KOWALIK_A

    assert kowalik(np.zeros((1, 4)))[0] == pytest.approx(np.sum(KOWALIK_A**2))


def test_kowalik_pole_gives_non_finite_cost_without_warning():
    # b_1 = 4: the first denominator 16 + 4*x3 + x4 vanishes at x3 = -4.25, x4 = 1
    x = np.array([[1.0, 0.0, -4.25, 1.0]])
    with np.errstate(all="raise"):
        assert not np.isfinite(kowalik(x)[0])


def test_quartic_noise_is_seeded_and_in_unit_interval():
    a = get_benchmark("f3", seed=5)
    b = get_benchmark("f3", seed=5)
    c = get_benchmark("f3", seed=6)
    x = np.zeros((50, 30))
    fa, fb, fc = a(x), b(x), c(x)
    np.testing.assert_array_equal(fa, fb)
    assert not np.array_equal(fa, fc)
    assert np.all((fa >= 0) & (fa < 1))
    assert len(np.unique(fa)) == 50  # fresh noise per point
    assert a.noise_free()(x[0]) == 0.0


@pytest.mark.parametrize("key", BENCHMARK_KEYS)
def test_shifted_variant_moves_the_optimum_and_keeps_the_minimum(key):
    base = get_benchmark(key).noise_free()
    s = base.shifted(3)
    assert s.is_shifted and not base.is_shifted
    assert s(s.x_min) == pytest.approx(base.f_min, rel=1e-9, abs=1e-12)
    width = base.upper - base.lower
    assert np.all(s.x_min >= base.lower + 0.1 * width - 1e-12)
    assert np.all(s.x_min <= base.upper - 0.1 * width + 1e-12)
    assert not np.allclose(s.x_min, base.x_min)
    # the old optimum is no longer optimal, and g(x) = f(x - shift)
    assert s(base.x_min) > base.f_min
    x = np.random.default_rng(0).uniform(base.lower, base.upper, size=(5, base.dim))
    np.testing.assert_allclose(s(x), base(x - s.shift))
    # the minimum over the box is still the known one
    far = np.random.default_rng(4).uniform(base.lower, base.upper, size=(2000, base.dim))
    assert np.nanmin(s(far)) > base.f_min
    # seeded
    np.testing.assert_array_equal(base.shifted(3).x_min, s.x_min)
    assert not np.array_equal(base.shifted(4).x_min, s.x_min)


def test_shift_seed_in_get_benchmark_and_noise_kept():
    s = get_benchmark("f3", seed=1, shift_seed=2)
    assert s.is_shifted and s.noise_rng is not None
    assert 0 <= s(s.x_min) < 1


def test_bad_input():
    with pytest.raises(ParameterError, match="key"):
        get_benchmark("f10")
    with pytest.raises(ParameterError, match="x"):
        get_benchmark("f7")(np.zeros((3, 3)))
