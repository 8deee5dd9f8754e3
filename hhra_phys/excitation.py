"""Excitation signals on a sample grid.

Conventions
-----------
- Lengths and hold times are in **samples**; frequencies are in Hz together with the sample
  rate ``fs`` [Hz]. :func:`samples` converts a duration [s] to a number of samples.
- Every generator that draws random numbers takes ``seed``: an ``int``, a
  :class:`numpy.random.Generator` (used as is, so several signals can share one stream) or
  ``None`` (fresh entropy, not reproducible). The same integer seed gives the same signal.
- Amplitudes are in the unit of the input (valve current [mA] for the HHRA).
- Invalid arguments raise :class:`~hhra_phys.errors.ParameterError`.

Why several amplitude levels: a binary signal visits only two input values, so a dead zone,
a saturation or any static nonlinearity is indistinguishable from a gain change. The
multi-level generators (:func:`irregular_steps`, :func:`aprbs`) exist for that reason, and
the paper's "irregular continuous step" experiment is rebuilt here with several levels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
import scipy.signal

from hhra_phys.errors import ParameterError

__all__ = [
    "PAPER_ORDER",
    "aprbs",
    "chirp",
    "inverse_m_sequence",
    "inverse_repeat",
    "irregular_steps",
    "m_sequence",
    "multisine",
    "prbs",
    "samples",
]

#: Order of the paper's M-sequence (register length 4, period 15).
PAPER_ORDER = 4
# In scipy.signal.max_len_seq's convention, 4 bits with taps [1] produce exactly the
# recurrence x_i = x_{i-3} XOR x_{i-4} (checked in tests/test_excitation.py); scipy's default
# taps for 4 bits give the mirror sequence x_i = x_{i-1} XOR x_{i-4}.
_PAPER_TAPS = (1,)
_MAX_FULL_ORDER = 24  # 2**24 - 1 samples is the largest full period we build without `length`

Seed = int | np.random.Generator | None


# --------------------------------------------------------------------------- helpers


def _rng(seed: Seed) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None or (isinstance(seed, int | np.integer) and not isinstance(seed, bool)):
        if seed is not None and seed < 0:
            raise ParameterError(f"seed must be >= 0, got {seed}")
        return np.random.default_rng(seed)
    raise ParameterError(f"seed must be an int, a numpy Generator or None, got {seed!r}")


def _positive_int(value: object, name: str, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ParameterError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _positive_float(value: object, name: str, allow_zero: bool = False) -> float:
    ok = isinstance(value, int | float | np.floating | np.integer) and not isinstance(value, bool)
    if ok:
        value = float(value)
        ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ParameterError(f"{name} must be a finite number {bound}, got {value!r}")
    return float(value)


def _finite(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(float(value)):
        raise ParameterError(f"{name} must be finite, got {value!r}")
    return float(value)


def samples(duration: float, fs: float) -> int:
    """Number of samples in ``duration`` [s] at ``fs`` [Hz]: ``round(duration * fs)``.

    >>> samples(20.0, 250.0)
    5000
    """
    return int(round(_positive_float(duration, "duration") * _positive_float(fs, "fs")))


# --------------------------------------------------------------------------- M-sequences


def _state(state: Sequence[int] | None, order: int) -> np.ndarray | None:
    if state is None:
        return None
    arr = np.asarray(state)
    if arr.shape != (order,) or not np.isin(arr, (0, 1)).all():
        raise ParameterError(f"state must be {order} bits (0/1), got {state!r}")
    if not arr.any():
        raise ParameterError("state must not be all zeros (the register would stay at zero)")
    return arr.astype(np.int8)


def m_sequence(
    length: int | None = None,
    *,
    state: Sequence[int] | None = (1, 1, 1, 1),
    samples_per_bit: int = 1,
) -> np.ndarray:
    """The paper's 4th-order M-sequence ``x_i = x_{i-3} XOR x_{i-4}`` as bits.

    Parameters
    ----------
    length : int, optional
        Number of bits (default one period, 15). Longer sequences repeat with period 15.
    state : sequence of 4 bits
        The first four bits ``x_0..x_3`` (not all zero); default all ones.
    samples_per_bit : int
        Each bit is held for this many samples.

    Returns
    -------
    numpy.ndarray of int8, shape (length * samples_per_bit,)
        Bits 0/1; one period holds eight ones and seven zeros.
    """
    n = 2**PAPER_ORDER - 1 if length is None else _positive_int(length, "length")
    bits, _ = scipy.signal.max_len_seq(
        PAPER_ORDER, state=_state(state, PAPER_ORDER), length=n, taps=_PAPER_TAPS
    )
    return np.repeat(bits.astype(np.int8), _positive_int(samples_per_bit, "samples_per_bit"))


def prbs(
    order: int,
    length: int | None = None,
    *,
    levels: tuple[float, float] = (-1.0, 1.0),
    state: Sequence[int] | None = None,
    samples_per_bit: int = 1,
) -> np.ndarray:
    """Maximal-length pseudo-random binary sequence of register length ``order``.

    Generated by :func:`scipy.signal.max_len_seq` with its table of primitive feedback taps;
    the period is ``2**order - 1`` bits.

    Parameters
    ----------
    order : int
        Register length, 2 <= order <= 32 (beyond 24 give ``length``).
    length : int, optional
        Number of bits; default one full period. Longer sequences repeat periodically.
    levels : (float, float)
        Values of bit 0 and bit 1 (input unit); default -1, +1.
    state : sequence of ``order`` bits, optional
        Initial register (the first ``order`` bits); default all ones.
    samples_per_bit : int
        Each bit is held for this many samples (the clock period of the sequence).

    Returns
    -------
    numpy.ndarray of float, shape (length * samples_per_bit,)
    """
    order = _positive_int(order, "order", minimum=2)
    if order > 32:
        raise ParameterError(f"order must be at most 32 (scipy's tap table), got {order}")
    if length is None and order > _MAX_FULL_ORDER:
        raise ParameterError(f"a full period of order {order} is too long; pass length")
    n = 2**order - 1 if length is None else _positive_int(length, "length")
    lo, hi = (_finite(v, "levels") for v in levels)
    bits, _ = scipy.signal.max_len_seq(order, state=_state(state, order), length=n)
    values = np.where(bits.astype(bool), hi, lo)
    return np.repeat(values, _positive_int(samples_per_bit, "samples_per_bit"))


def inverse_repeat(sequence: Sequence[float] | np.ndarray) -> np.ndarray:
    """Inverse-repeat form of one period of a binary sequence.

    Every other value of two periods is inverted: ``r_k = s_k * (-1)**k`` for
    ``k = 0 .. 2P-1`` with ``s`` mapped to +-1 (bit 1 -> +1, bit 0 -> -1). Because the period
    ``P`` of an M-sequence is odd, ``r_{k+P} = -r_k``: the second half of the result is the
    inverse of the first half, the mean over a period of ``2P`` is exactly zero and even
    harmonics vanish.

    Parameters
    ----------
    sequence : array_like, shape (P,)
        One period, as bits 0/1 or levels -1/+1; ``P`` must be odd.

    Returns
    -------
    numpy.ndarray of float, shape (2P,)
        Values -1/+1.
    """
    s = np.asarray(sequence, dtype=float)
    if s.ndim != 1 or s.size < 1 or s.size % 2 == 0:
        raise ParameterError(
            f"inverse_repeat needs one period of odd length (an M-sequence), got shape {s.shape}"
        )
    if np.isin(s, (0.0, 1.0)).all():
        s = 2.0 * s - 1.0
    elif not np.isin(s, (-1.0, 1.0)).all():
        raise ParameterError("inverse_repeat needs bits 0/1 or levels -1/+1")
    doubled = np.tile(s, 2)
    return doubled * np.where(np.arange(doubled.size) % 2 == 0, 1.0, -1.0)


def inverse_m_sequence(
    n_periods: int = 1,
    *,
    state: Sequence[int] | None = (1, 1, 1, 1),
    samples_per_bit: int = 1,
) -> np.ndarray:
    """The paper's 4th-order inverse-repeat M-sequence: levels -1/+1, period 30, zero mean.

    :func:`inverse_repeat` applied to one period of :func:`m_sequence`.

    Parameters
    ----------
    n_periods : int
        Number of 30-bit periods.
    state : sequence of 4 bits
        Start of the underlying M-sequence.
    samples_per_bit : int
        Each bit is held for this many samples.

    Returns
    -------
    numpy.ndarray of float, shape (30 * n_periods * samples_per_bit,)
    """
    period = inverse_repeat(m_sequence(state=state))
    bits = np.tile(period, _positive_int(n_periods, "n_periods"))
    return np.repeat(bits, _positive_int(samples_per_bit, "samples_per_bit"))


# --------------------------------------------------------------------------- multi-level steps


def _levels(levels: int | Sequence[float], amplitude: float | None) -> np.ndarray:
    """An int k -> ``amplitude * (1..k)/k``; a sequence -> those values."""
    if isinstance(levels, int | np.integer) and not isinstance(levels, bool):
        k = _positive_int(levels, "levels")
        return (amplitude if amplitude is not None else 1.0) * np.arange(1, k + 1) / k
    arr = np.asarray(levels, dtype=float)
    if arr.ndim != 1 or arr.size == 0 or not np.isfinite(arr).all():
        raise ParameterError(f"levels must be a count or a 1-D sequence of numbers, got {levels!r}")
    if np.unique(arr).size != arr.size:
        raise ParameterError(f"levels must be distinct, got {levels!r}")
    return arr


def _spread_evenly(values: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` draws from ``values`` using each value equally often (+-1), in random order."""
    tiled = np.tile(values, -(-count // values.size))[:count]
    return rng.permutation(tiled)


def _random_holds(
    count: int, total: int, irregularity: float, rng: np.random.Generator
) -> np.ndarray:
    """``count`` hold lengths >= 1 summing to ``total``, each about ``total/count`` with a
    relative spread of +-irregularity (largest-remainder rounding keeps the sum exact)."""
    weights = rng.uniform(1.0 - irregularity, 1.0 + irregularity, size=count)
    share = weights / weights.sum() * (total - count)  # one sample each is reserved
    holds = np.floor(share).astype(np.int64)
    short = (total - count) - int(holds.sum())
    holds[np.argsort(holds - share)[:short]] += 1  # largest fractional parts first
    return holds + 1


def irregular_steps(
    n: int,
    *,
    levels: int | Sequence[float] = 4,
    amplitude: float = 1.0,
    offset: float = 0.0,
    n_periods: int = 1,
    irregularity: float = 0.5,
    state: Sequence[int] | None = (1, 1, 1, 1),
    seed: Seed = None,
) -> np.ndarray:
    """The paper's "irregular continuous step" signal, with several amplitude levels.

    Construction (the paper gives only the M-sequence, so this is our reading):

    1. Take ``n_periods`` periods of the 4th-order inverse-repeat M-sequence ``r``
       (:func:`inverse_m_sequence`; 30 bits of +-1 with ``r_{k+15} = -r_k``).
    2. Pair bit ``k`` with bit ``k+15`` of each period (15 pairs per period). Each pair gets a
       random hold length and one amplitude level; both bits of a pair share them. The second
       half of every period is therefore exactly the negative of its first half, so the mean
       of the signal is exactly ``offset`` and an integrating actuator returns to its start
       angle at the end of every period.
    3. Hold lengths: about ``n / (30 * n_periods)`` samples, each scaled by a uniform random
       factor in ``[1 - irregularity, 1 + irregularity]`` and rounded so that the holds fill
       exactly ``n`` samples (an odd ``n`` ends with one sample at ``offset``).
    4. Levels are dealt to the pairs so that each level is used equally often (+-1), in
       random order: the signal takes the ``2 * len(levels)`` values ``offset +- level``.

    Parameters
    ----------
    n : int
        Number of samples (e.g. ``samples(20.0, 250.0)`` = 5000 for the paper's 20 s at 250 Hz).
    levels : int or sequence of float
        Number of amplitude levels, spread evenly in ``(0, amplitude]`` (default 4: 0.25,
        0.5, 0.75 and 1 times ``amplitude``), or the positive levels themselves [input unit].
        ``levels=1`` gives the binary signal (for comparison only).
    amplitude : float
        Largest step away from ``offset`` [input unit] when ``levels`` is a count.
    offset : float
        Centre value [input unit] (e.g. a valve null current).
    n_periods : int
        Number of 30-bit inverse-repeat periods; more periods give shorter holds.
    irregularity : float
        Relative spread of the hold lengths, 0 (all equal) <= irregularity < 1.
    state : sequence of 4 bits
        Start of the underlying M-sequence.
    seed : int, numpy.random.Generator or None
        Drives hold lengths and level assignment.

    Returns
    -------
    numpy.ndarray of float, shape (n,)
    """
    n = _positive_int(n, "n")
    n_periods = _positive_int(n_periods, "n_periods")
    amplitude = _positive_float(amplitude, "amplitude")
    offset = _finite(offset, "offset")
    irregularity = _positive_float(irregularity, "irregularity", allow_zero=True)
    if irregularity >= 1.0:
        raise ParameterError(f"irregularity must be < 1, got {irregularity}")
    amps = _levels(levels, amplitude)
    if (amps <= 0).any():
        raise ParameterError(f"levels must be positive (they are mirrored around offset): {amps}")
    rng = _rng(seed)

    half = 2**PAPER_ORDER - 1  # 15 pairs per period
    pairs = half * n_periods
    if pairs < amps.size:
        raise ParameterError(
            f"{amps.size} levels need at least {amps.size} pairs of bits; {n_periods} period(s) "
            f"give {pairs}"
        )
    if n < 2 * pairs:
        raise ParameterError(f"n = {n} samples cannot hold {2 * pairs} bits of at least 1 sample")

    holds = _random_holds(pairs, n // 2, irregularity, rng).reshape(n_periods, half)
    pair_amps = _spread_evenly(amps, pairs, rng).reshape(n_periods, half)
    bits = inverse_m_sequence(state=state).reshape(2, half)  # row 1 == -row 0
    values = (bits[None, :, :] * pair_amps[:, None, :]).ravel()
    lengths = np.broadcast_to(holds[:, None, :], (n_periods, 2, half)).ravel()
    signal = offset + np.repeat(values, lengths)
    if signal.size < n:  # odd n: one final sample at the centre keeps the mean exact
        signal = np.append(signal, offset)
    return signal


def aprbs(
    n: int,
    *,
    low: float = -1.0,
    high: float = 1.0,
    levels: int | Sequence[float] | None = None,
    min_hold: int = 1,
    max_hold: int | None = None,
    seed: Seed = None,
) -> np.ndarray:
    """Amplitude-modulated PRBS: steps of random length and random amplitude.

    Hold lengths are drawn uniformly from ``min_hold..max_hold`` samples; each step's
    amplitude is drawn uniformly from ``[low, high]`` or, with ``levels``, from a discrete set
    (never the same level twice in a row, so every drawn step is a real step).

    Parameters
    ----------
    n : int
        Number of samples.
    low, high : float
        Amplitude range [input unit].
    levels : int or sequence of float, optional
        An int k >= 2: k levels evenly spaced from ``low`` to ``high``; a sequence: those
        levels; None: continuous amplitudes.
    min_hold, max_hold : int
        Shortest and longest step [samples]; ``max_hold`` defaults to ``max(min_hold, n // 20)``.
        Choose ``min_hold`` near the settling time of the system so steps reach their level.
    seed : int, numpy.random.Generator or None

    Returns
    -------
    numpy.ndarray of float, shape (n,)
    """
    n = _positive_int(n, "n")
    low, high = _finite(low, "low"), _finite(high, "high")
    if not low < high:
        raise ParameterError(f"need low < high, got low={low}, high={high}")
    min_hold = _positive_int(min_hold, "min_hold")
    max_hold = max(min_hold, n // 20) if max_hold is None else _positive_int(max_hold, "max_hold")
    if max_hold < min_hold:
        raise ParameterError(f"max_hold ({max_hold}) < min_hold ({min_hold})")
    rng = _rng(seed)

    # Enough segments to cover n even if every hold is the shortest.
    count = -(-n // min_hold)
    holds = rng.integers(min_hold, max_hold + 1, size=count)
    count = int(np.searchsorted(np.cumsum(holds), n)) + 1
    holds = holds[:count]
    if levels is None:
        amps = rng.uniform(low, high, size=count)
    else:
        if isinstance(levels, int | np.integer) and not isinstance(levels, bool):
            table = np.linspace(low, high, _positive_int(levels, "levels", minimum=2))
        else:
            table = _levels(levels, None)
            if table.size < 2:
                raise ParameterError("aprbs needs at least 2 levels")
        # index shifts of 1..k-1 (mod k) never repeat the previous level
        shifts = rng.integers(1, table.size, size=count)
        index = (rng.integers(table.size) + np.cumsum(shifts)) % table.size
        amps = table[index]
    return np.repeat(amps, holds)[:n]


# --------------------------------------------------------------------------- periodic sweeps


def multisine(
    n: int,
    fs: float,
    *,
    f_min: float,
    f_max: float,
    amplitude: float = 1.0,
    phases: Literal["schroeder", "random"] = "schroeder",
    n_lines: int | None = None,
    seed: Seed = None,
) -> np.ndarray:
    """Multisine with equal line amplitudes on the DFT grid of ``n`` samples.

    ``x(t_k) = sum_j cos(2*pi*f_j*t_k + phi_j)``, scaled so that ``max|x| = amplitude``.
    The lines ``f_j = j * fs / n`` lie in ``[f_min, f_max]``, so the signal is exactly
    periodic in ``n`` samples (no leakage) and has zero mean.

    Parameters
    ----------
    n : int
        Number of samples (one period).
    fs : float
        Sample rate [Hz].
    f_min, f_max : float
        Band [Hz], 0 <= f_min <= f_max < fs/2; must contain at least one line ``j*fs/n``.
    amplitude : float
        Peak value [input unit].
    phases : {"schroeder", "random"}
        Schroeder phases ``phi_j = -pi*j*(j-1)/K`` (j = 1..K, a low crest factor, no
        randomness) or independent uniform phases in [0, 2*pi) drawn from ``seed``.
    n_lines : int, optional
        Use this many lines spread evenly over the band instead of every line.
    seed : int, numpy.random.Generator or None
        Only used for ``phases="random"``.

    Returns
    -------
    numpy.ndarray of float, shape (n,)
    """
    n = _positive_int(n, "n", minimum=2)
    fs = _positive_float(fs, "fs")
    f_min = _positive_float(f_min, "f_min", allow_zero=True)
    f_max = _positive_float(f_max, "f_max")
    amplitude = _positive_float(amplitude, "amplitude")
    if not f_min <= f_max < fs / 2:
        raise ParameterError(f"need 0 <= f_min <= f_max < fs/2 = {fs / 2:g} Hz")
    k = np.arange(1, (n - 1) // 2 + 1)  # positive frequencies below Nyquist
    k = k[(k * fs / n >= f_min) & (k * fs / n <= f_max)]
    if k.size == 0:
        raise ParameterError(
            f"no frequency line j*fs/n (spacing {fs / n:g} Hz) lies in [{f_min:g}, {f_max:g}] Hz"
        )
    if n_lines is not None:
        n_lines = _positive_int(n_lines, "n_lines")
        if n_lines > k.size:
            raise ParameterError(f"n_lines = {n_lines} but the band holds only {k.size} lines")
        k = k[np.round(np.linspace(0, k.size - 1, n_lines)).astype(int)]
    if phases == "schroeder":
        j = np.arange(1, k.size + 1)
        phi = -np.pi * j * (j - 1) / k.size
    elif phases == "random":
        phi = _rng(seed).uniform(0.0, 2.0 * np.pi, size=k.size)
    else:
        raise ParameterError(f"phases must be 'schroeder' or 'random', got {phases!r}")
    spectrum = np.zeros(n // 2 + 1, dtype=complex)
    spectrum[k] = np.exp(1j * phi)
    x = np.fft.irfft(spectrum, n)
    return amplitude * x / np.max(np.abs(x))


def chirp(
    n: int,
    fs: float,
    *,
    f0: float,
    f1: float,
    amplitude: float = 1.0,
    method: Literal["linear", "quadratic", "logarithmic", "hyperbolic"] = "linear",
    phi: float = -90.0,
) -> np.ndarray:
    """Swept sine from ``f0`` to ``f1`` over ``n`` samples (:func:`scipy.signal.chirp`).

    Parameters
    ----------
    n : int
        Number of samples; the sweep reaches ``f1`` at the last sample.
    fs : float
        Sample rate [Hz].
    f0, f1 : float
        Start and end frequency [Hz], below fs/2 (and > 0 for logarithmic/hyperbolic).
    amplitude : float
        Peak value [input unit].
    method : str
        Frequency law of :func:`scipy.signal.chirp`.
    phi : float
        Phase offset [deg]; the default -90 starts the sweep at 0 (a sine), so a system at rest
        sees no initial jump.

    Returns
    -------
    numpy.ndarray of float, shape (n,)
    """
    n = _positive_int(n, "n", minimum=2)
    fs = _positive_float(fs, "fs")
    f0 = _positive_float(f0, "f0", allow_zero=True)
    f1 = _positive_float(f1, "f1", allow_zero=True)
    amplitude = _positive_float(amplitude, "amplitude")
    phi = _finite(phi, "phi")
    if max(f0, f1) >= fs / 2:
        raise ParameterError(f"f0 and f1 must lie below fs/2 = {fs / 2:g} Hz")
    if method in ("logarithmic", "hyperbolic") and min(f0, f1) <= 0:
        raise ParameterError(f"a {method} chirp needs f0 > 0 and f1 > 0")
    if method not in ("linear", "quadratic", "logarithmic", "hyperbolic"):
        raise ParameterError(f"unknown chirp method {method!r}")
    t = np.arange(n) / fs
    return amplitude * scipy.signal.chirp(t, f0=f0, t1=t[-1], f1=f1, method=method, phi=phi)
