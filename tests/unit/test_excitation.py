"""Tests of hhra_phys.excitation: periods, recurrences, zero mean, levels, seeds."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys import excitation as E
from hhra_phys.errors import ParameterError


def smallest_period(x: np.ndarray) -> int:
    """Smallest p with x[k + p] == x[k] for all k (x must hold at least two periods)."""
    for p in range(1, x.size // 2 + 1):
        if np.array_equal(x[p:], x[:-p]):
            return p
    raise AssertionError("no period found")


def test_m_sequence_recurrence_and_period() -> None:
    x = E.m_sequence(60)
    assert all(x[i] == x[i - 3] ^ x[i - 4] for i in range(4, x.size))
    assert smallest_period(x) == 15
    one = E.m_sequence()
    assert one.size == 15 and one.sum() == 8  # 8 ones, 7 zeros
    np.testing.assert_array_equal(one[:4], [1, 1, 1, 1])
    other = E.m_sequence(30, state=(1, 0, 0, 1))
    np.testing.assert_array_equal(other[:4], [1, 0, 0, 1])
    assert all(other[i] == other[i - 3] ^ other[i - 4] for i in range(4, 30))
    assert E.m_sequence(samples_per_bit=3).size == 45


def test_inverse_m_sequence_zero_mean_period_30() -> None:
    r = E.inverse_m_sequence(n_periods=3)
    assert set(np.unique(r)) == {-1.0, 1.0}
    assert smallest_period(r) == 30
    period = r[:30]
    assert period.sum() == 0.0  # exactly zero mean
    np.testing.assert_array_equal(period[15:], -period[:15])  # second half inverts the first
    # every other bit of the M-sequence inverted
    s = 2.0 * E.m_sequence(30) - 1.0
    np.testing.assert_array_equal(period, s * (-1.0) ** np.arange(30))
    held = E.inverse_m_sequence(samples_per_bit=4)
    assert held.size == 120 and held.sum() == 0.0


def test_inverse_repeat_checks_input() -> None:
    with pytest.raises(ParameterError, match="odd"):
        E.inverse_repeat([1, 0, 1, 1])
    with pytest.raises(ParameterError, match="bits"):
        E.inverse_repeat([0.5, 1, 0])
    np.testing.assert_array_equal(E.inverse_repeat([1, 0, 0]), [1, 1, -1, -1, -1, 1])


@pytest.mark.parametrize("order", [2, 3, 5, 7, 10, 12])
def test_prbs_period(order: int) -> None:
    period = 2**order - 1
    x = E.prbs(order, 2 * period + 5)
    assert smallest_period(x) == period
    one = E.prbs(order)
    assert one.size == period
    assert (one == 1.0).sum() == 2 ** (order - 1)  # one more "1" than "0" per period


def test_prbs_levels_and_errors() -> None:
    x = E.prbs(4, levels=(2.0, 6.0), samples_per_bit=2)
    assert set(np.unique(x)) == {2.0, 6.0} and x.size == 30
    for bad in (1, 33, 2.5, True):
        with pytest.raises(ParameterError):
            E.prbs(bad)
    with pytest.raises(ParameterError, match="all zeros"):
        E.prbs(3, state=(0, 0, 0))
    with pytest.raises(ParameterError, match="pass length"):
        E.prbs(30)


@pytest.mark.parametrize("n", [5000, 5001, 777])
def test_irregular_steps_levels_and_zero_mean(n: int) -> None:
    x = E.irregular_steps(n, levels=4, amplitude=2.0, offset=1.0, seed=3)
    assert x.size == n
    assert x.mean() == pytest.approx(1.0, abs=1e-12)
    levels = np.unique(x)
    expected = 1.0 + np.array([-2.0, -1.5, -1.0, -0.5, 0.5, 1.0, 1.5, 2.0])
    if n % 2:  # the final centre sample of an odd length
        expected = np.sort(np.append(expected, 1.0))
    np.testing.assert_allclose(levels, expected)
    # the second half of the period mirrors the first around the offset
    np.testing.assert_allclose(x[: n // 2] - 1.0, -(x[n // 2 : 2 * (n // 2)] - 1.0))


def test_irregular_steps_holds_are_irregular() -> None:
    x = E.irregular_steps(6000, seed=4, levels=3)
    edges = np.flatnonzero(np.diff(x)) + 1
    runs = np.diff(np.r_[0, edges, x.size])
    assert np.unique(runs).size > 5  # not a regular clock
    assert runs.min() >= 1
    regular = E.irregular_steps(3000, seed=4, irregularity=0.0, levels=1)
    assert set(np.unique(regular)) == {-1.0, 1.0}  # binary when asked for one level
    edges = np.flatnonzero(np.diff(regular)) + 1
    assert set(np.diff(np.r_[0, edges, 3000]) % 100) == {0}  # 30 bits of exactly 100 samples


def test_irregular_steps_custom_levels_and_periods() -> None:
    x = E.irregular_steps(3000, levels=[0.3, 1.0], n_periods=4, seed=5)
    np.testing.assert_allclose(np.unique(x), [-1.0, -0.3, 0.3, 1.0])
    assert x.mean() == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ParameterError):
        E.irregular_steps(3000, levels=16)  # 16 levels, only 15 pairs
    with pytest.raises(ParameterError):
        E.irregular_steps(20)  # fewer samples than bits
    with pytest.raises(ParameterError):
        E.irregular_steps(3000, irregularity=1.0)


def test_aprbs_levels_and_holds() -> None:
    x = E.aprbs(4000, levels=5, low=-2.0, high=2.0, min_hold=20, max_hold=60, seed=6)
    assert x.size == 4000
    np.testing.assert_allclose(np.unique(x), [-2.0, -1.0, 0.0, 1.0, 2.0])
    edges = np.flatnonzero(np.diff(x)) + 1
    runs = np.diff(np.r_[0, edges])  # complete segments only
    assert runs.min() >= 20 and runs.max() <= 60
    cont = E.aprbs(2000, min_hold=10, max_hold=10, seed=7)
    assert np.unique(cont).size == 200 and cont.min() >= -1.0 and cont.max() <= 1.0
    with pytest.raises(ParameterError):
        E.aprbs(100, low=1.0, high=0.0)


def test_seeds_reproduce() -> None:
    for make in (
        lambda s: E.irregular_steps(2000, seed=s),
        lambda s: E.aprbs(2000, levels=4, min_hold=5, seed=s),
        lambda s: E.multisine(1000, 250.0, f_min=1.0, f_max=20.0, phases="random", seed=s),
    ):
        np.testing.assert_array_equal(make(11), make(11))
        assert not np.array_equal(make(11), make(12))
    gen = np.random.default_rng(1)
    a = E.aprbs(500, seed=gen)
    b = E.aprbs(500, seed=gen)  # a shared generator advances
    assert not np.array_equal(a, b)
    with pytest.raises(ParameterError):
        E.aprbs(10, seed="x")  # type: ignore[arg-type]


@pytest.mark.parametrize("phases", ["schroeder", "random"])
def test_multisine_band_and_amplitude(phases: str) -> None:
    n, fs = 1000, 250.0
    x = E.multisine(n, fs, f_min=2.0, f_max=20.0, amplitude=3.0, phases=phases, seed=1)
    assert np.max(np.abs(x)) == pytest.approx(3.0)
    spectrum = np.abs(np.fft.rfft(x))
    freqs = np.fft.rfftfreq(n, 1 / fs)
    inside = (freqs >= 2.0) & (freqs <= 20.0)
    assert np.all(spectrum[~inside] < 1e-9 * spectrum.max())
    np.testing.assert_allclose(spectrum[inside], spectrum[inside][0])  # flat amplitude
    few = E.multisine(n, fs, f_min=2.0, f_max=20.0, n_lines=5)
    assert (np.abs(np.fft.rfft(few)) > 1e-9).sum() == 5
    with pytest.raises(ParameterError):
        E.multisine(n, fs, f_min=1.0, f_max=200.0)
    with pytest.raises(ParameterError, match="no frequency line"):
        E.multisine(100, fs, f_min=0.5, f_max=1.0)


def test_schroeder_has_lower_crest_factor_than_zero_phases() -> None:
    n, k = 2000, np.arange(1, 101)
    t = np.arange(n)
    flat = np.cos(2 * np.pi * np.outer(k, t) / n).sum(axis=0)  # all phases zero
    x = E.multisine(n, float(n), f_min=1.0, f_max=100.0)

    def crest(s: np.ndarray) -> float:
        return float(np.max(np.abs(s)) / np.sqrt(np.mean(s**2)))

    assert crest(x) < 0.3 * crest(flat)


def test_chirp() -> None:
    x = E.chirp(2500, 250.0, f0=0.5, f1=20.0, amplitude=2.0)
    assert x.size == 2500 and x[0] == pytest.approx(0.0, abs=1e-12)
    assert np.max(np.abs(x)) == pytest.approx(2.0, rel=1e-3)
    # zero crossings get denser as the frequency rises
    crossings = np.flatnonzero(np.diff(np.sign(x)))
    assert (crossings < 1250).sum() < (crossings >= 1250).sum()
    log = E.chirp(1000, 250.0, f0=0.5, f1=20.0, method="logarithmic")
    assert np.isfinite(log).all()
    with pytest.raises(ParameterError):
        E.chirp(1000, 250.0, f0=0.0, f1=10.0, method="logarithmic")
    with pytest.raises(ParameterError):
        E.chirp(1000, 250.0, f0=1.0, f1=130.0)


def test_samples() -> None:
    assert E.samples(20.0, 250.0) == 5000
    with pytest.raises(ParameterError):
        E.samples(-1.0, 250.0)
