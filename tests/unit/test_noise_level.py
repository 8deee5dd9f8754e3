"""The noise level of a residual under white, coloured and quantised noise, and with
model error at low and high frequency (hhra_phys.noise)."""

import numpy as np
import pytest
from scipy import signal as sps

from hhra_phys.excitation import irregular_steps
from hhra_phys.noise import difference_level, noise_level, noise_spectrum


def _ar1(rng, n, a, sd):
    w = sd * rng.standard_normal(n)
    w[1:] *= np.sqrt(1 - a * a)
    return sps.lfilter([1.0], [1.0, -a], w)


def _input(n, seed):
    u = irregular_steps(n, levels=4, amplitude=1.0, seed=seed)
    return u, np.cumsum(u) / 250 * 30  # an integrating plant's simulated output


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("kind", ["white", "ar09", "ar05", "quantised"])
def test_noise_alone_is_read_at_its_size(kind, seed):
    rng = np.random.default_rng(seed)
    n = 1000
    u, y = _input(n, seed)
    if kind == "white":
        e = 0.05 * rng.standard_normal(n)
    elif kind == "quantised":  # a slow output read by a coarse encoder, little noise
        slow = 3 * np.sin(np.arange(n) / 37.0) + 0.01 * rng.standard_normal(n)
        e = np.round(slow / 0.088) * 0.088 - slow
    else:
        e = _ar1(rng, n, 0.9 if kind == "ar09" else 0.5, 0.05)
    sd = float(np.std(e))
    assert noise_level(e, (u, y)) == pytest.approx(sd, rel=0.2)


@pytest.mark.parametrize("seed", [0, 1])
def test_difference_estimate_misses_coloured_noise(seed):
    """The earlier estimate reads AR(1) 0.9 noise at about sqrt(1 - 0.9) of its size."""
    rng = np.random.default_rng(seed)
    e = _ar1(rng, 2000, 0.9, 0.05)
    u, y = _input(2000, seed)
    assert difference_level(e) < 0.45 * np.std(e)
    assert noise_level(e, (u, y)) > 0.85 * np.std(e)
    assert noise_level(e) == difference_level(e)  # without inputs: the earlier estimate


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_model_error_is_not_noise(seed):
    """Fast error coherent with the input, and a slow integrated nonlinear error, both
    on top of white noise 0.05: the level stays near 0.05."""
    rng = np.random.default_rng(seed)
    n = 1000
    u, y = _input(n, seed)
    e = 0.05 * rng.standard_normal(n)
    b, a = sps.butter(2, [0.3, 0.45], btype="band")
    fast = sps.lfilter(b, a, np.diff(u, prepend=0.0)) * 5
    slow = np.cumsum(np.abs(u) - 0.5) / 250 * 3
    assert np.std(fast) > 0.1 and np.std(slow) > 0.1
    assert difference_level(e + fast) > 1.5 * 0.05
    assert noise_level(e + fast, (u, y)) < 1.25 * 0.05
    assert noise_level(e + slow, (u, y)) < 1.25 * 0.05


def test_spectrum_parts_add_up():
    rng = np.random.default_rng(3)
    u, y = _input(1500, 3)
    r = 0.05 * rng.standard_normal(1500) + 0.02 * (y - y.mean())
    spec = noise_spectrum(r, (u, y), fs=250.0)
    assert spec["variance"] == pytest.approx(np.var(r), rel=0.15)
    assert spec["noise_variance"] < 0.5 * spec["variance"]
    assert np.all((spec["coherence"] >= 0) & (spec["coherence"] <= 1))
    assert spec["f"][-1] == pytest.approx(125.0)


@pytest.mark.parametrize("seed", [0, 1])
def test_interval_factor_of_coloured_noise(seed):
    """AR(1) 0.9: intervals about sqrt(19) = 4.4x too narrow; white: about 1."""
    from hhra_phys.noise import interval_factor

    rng = np.random.default_rng(seed)
    assert interval_factor(_ar1(rng, 2000, 0.9, 0.05))["factor"] == pytest.approx(4.36, rel=0.3)
    assert interval_factor(0.05 * rng.standard_normal(2000))["factor"] < 1.3


def test_coloured_covariance_matches_the_spread_of_the_estimates():
    """Least squares under AR(1) noise: the sandwich sd is the estimates' spread over seeds.

    The white-noise sd understates the spread of a slowly varying regressor's
    coefficient by about sqrt((1 + a)/(1 - a)) (4.4 at 0.9); the sandwich does not.
    """
    from hhra_phys.noise import coloured_covariance, interval_factor

    a, n = 0.9, 2000
    t = np.arange(n)
    X = np.column_stack([np.sin(2 * np.pi * t / 400), np.sign(np.sin(2 * np.pi * t / 150))])
    info_inv = np.linalg.inv(X.T @ X)
    est, sds, sds_white = [], [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        y = X @ np.array([1.0, -0.5]) + _ar1(rng, n, a, 0.05)
        b = info_inv @ X.T @ y
        r = y - X @ b
        cov = float(r @ r) / (n - 2) * info_inv
        model = interval_factor(r)
        est.append(b)
        sds_white.append(np.sqrt(np.diag(cov)))
        sds.append(np.sqrt(np.diag(coloured_covariance(-X, r, cov, model))))
    spread = np.std(est, axis=0, ddof=1)
    ratio = spread / np.mean(sds, axis=0)
    assert np.all((ratio > 0.75) & (ratio < 1.3)), ratio
    assert np.all(spread / np.mean(sds_white, axis=0) > 2.5)
    # White noise: the sandwich is the usual covariance.
    r = 0.05 * np.random.default_rng(1).standard_normal(n)
    cov = float(r @ r) / (n - 2) * info_inv
    assert np.allclose(coloured_covariance(X, r, cov, {"a": 0.0, "c": 0.0}), cov, rtol=0.1)
