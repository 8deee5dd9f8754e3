"""The measurement-noise level of a residual, for white, coloured and quantised noise.

A residual ``r = y - yhat`` of a fitted model holds two things: the part the model
gets wrong (a function of the input) and the sensor's noise (independent of it).
The loop stops when the residual is at the noise level, and a candidate effect must
remove more than the noise allows, so the noise level decides what is left to model.

Sample-to-sample differences (:func:`difference_level`, the earlier estimate) assume
white noise and a slow model error: they read AR(1) noise with coefficient 0.9 at
about 0.23 of its size (``sqrt((1 - a) / 1)``, the differences of a slow process are
small) and read high-frequency model error (a fast resonance, a wrong inter-sample
assumption) as noise. :func:`noise_level` instead separates the two by what they are
correlated with: the part of the residual spectrum that is *coherent* with the input
(and with the simulated output, which carries the model's own nonlinearity) is model
error; the rest, at every frequency, is noise. Per frequency (Welch averages of ``K``
Hann segments, cross-spectra ``S``)::

    S_vv(f) = S_rr(f) - S_rx(f) S_xx(f)^-1 S_xr(f)        (x: the regressors)

and the noise variance is the integral of ``S_vv``, corrected for the share ``m/K``
that ``m`` regressors remove from ``K`` averages of pure noise by chance. This is the
noise spectrum of a Box-Jenkins / prediction-error view (``r = G u + H e``: what
``G`` cannot explain is ``H e``), computed without fitting a parametric ``H``.

What it cannot do: a model error that is not linearly coherent with the regressors
(part of a nonlinear effect's residual, a drift) counts as noise. For a drift that is
what is wanted (a sensor that drifts adds nothing the plant's model should explain);
for a nonlinear effect it makes the estimate an upper bound (measured in
``docs/measuring.md``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import optimize, stats

__all__ = ["coloured_covariance", "difference_level", "fit_noise_model", "interval_factor",
           "noise_level",
           "noise_spectrum"]

#: Welch segment length [samples] for records long enough (shorter ones use N/8).
SEGMENT = 256
#: Fewest segments the coherence is averaged over.
MIN_SEGMENTS = 8
#: Quantile of the input-free periodogram the noise spectrum is fitted to.
QUANTILE = 0.25
#: Largest pole of the noise model: a noise slower than this (time constant of 1000
#: samples) is not told apart from a drift or a model error on a record.
POLE_MAX = 0.999
POLE_SEGMENT = 2.0


def difference_level(residual: np.ndarray) -> float:
    """White-noise standard deviation from the sample-to-sample differences.

    ``MAD(diff(r)) / 0.6745 / sqrt(2)``: removes slow model error, but reads coloured
    noise too small (AR(1) with coefficient ``a``: ``sqrt(1 - a)`` of its size) and
    fast model error as noise.
    """
    d = np.diff(np.asarray(residual, dtype=float))
    return float(stats.median_abs_deviation(d, scale="normal") / math.sqrt(2))


def _segments(n: int, nperseg: int | None) -> tuple[int, int]:
    """Segment length and step (50 % overlap) for ``n`` samples."""
    L = int(nperseg) if nperseg else min(SEGMENT, max(16, (2 * n) // (MIN_SEGMENTS + 1)))
    L = max(8, min(L, n))
    return L, max(1, L // 2)


def noise_spectrum(residual: np.ndarray, inputs: Sequence[np.ndarray] = (),
                   fs: float = 1.0, nperseg: int | None = None) -> dict[str, Any]:
    """The residual's spectrum split into a part coherent with ``inputs`` and noise.

    Parameters
    ----------
    residual : array, shape (N,)
        Measured minus simulated output (output units).
    inputs : sequence of arrays, shape (N,)
        Regressors the model error is a function of (the input, the simulated
        output). Empty: every bit of the residual counts as noise.
    fs : float
        Sample rate [Hz] (only scales the frequency axis and densities).
    nperseg : int, optional
        Welch segment length (default: 256, fewer on short records so that at least
        8 segments are averaged).

    Returns
    -------
    dict
        ``f`` [Hz], ``residual`` and ``noise`` (one-sided densities, output unit^2/Hz),
        ``coherence`` (multiple coherence with the regressors, 0..1), ``segments``
        (effective number of independent averages), ``variance`` (residual) and
        ``noise_variance`` (corrected for chance coherence), output unit^2.
    """
    r = np.asarray(residual, dtype=float)
    X = [np.asarray(x, dtype=float) for x in inputs]
    n = r.size
    keep = [x - x.mean() for x in X if x.shape == r.shape and np.all(np.isfinite(x))
            and np.ptp(x) > 0]
    sig = np.vstack([r - r.mean()] + keep)  # (1 + m, N)
    m = len(keep)
    L, step = _segments(n, nperseg)
    starts = np.arange(0, n - L + 1, step)
    w = np.hanning(L + 2)[1:-1]  # no zero ends: every sample counts
    seg = np.stack([sig[:, s:s + L] for s in starts], axis=0) * w  # (K, 1+m, L)
    F = np.fft.rfft(seg, axis=-1)  # (K, 1+m, nf)
    S = np.einsum("kif,kjf->fij", F, F.conj()) / len(starts)  # (nf, 1+m, 1+m)
    srr = S[:, 0, 0].real
    if m:
        sxx = S[:, 1:, 1:]
        sxr = S[:, 1:, 0]
        # Per frequency (batched); a regressor with no power at a frequency drops out
        # there (the pseudo-inverse's cut-off).
        coef = np.linalg.pinv(sxx, rcond=1e-10) @ sxr[:, :, None]
        explained = np.real(np.einsum("fi,fi->f", sxr.conj(), coef[:, :, 0]))
        svv = np.clip(srr - explained, 0.0, None)
    else:
        svv = srr.copy()
    # Weights turning one-sided bins into the two-sided sum (Parseval) and the
    # window's power into a variance.
    c = np.full(srr.size, 2.0)
    c[0] = 1.0
    if L % 2 == 0:
        c[-1] = 1.0
    norm = L * float(np.sum(w ** 2))
    var_r = float(np.sum(c * srr) / norm)
    var_v = float(np.sum(c * svv) / norm)
    # Hann windows overlapping by half: the K averages count as K / (1 + 2 * 0.167^2)
    # independent ones (Welch). m regressors remove m of them from pure noise by chance.
    k_eff = len(starts) / (1.0 + 2.0 * 0.1667 ** 2) if len(starts) > 1 else 1.0
    if m:
        var_v *= k_eff / max(k_eff - m, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = np.where(srr > 0, 1.0 - svv / srr, 0.0)
    f = np.fft.rfftfreq(L, 1.0 / fs)
    scale = 1.0 / (fs * float(np.sum(w ** 2)))
    return {"f": f, "residual": c * srr * scale, "noise": c * svv * scale,
            "coherence": np.clip(coh, 0.0, 1.0), "segments": k_eff, "regressors": m,
            "variance": var_r, "noise_variance": min(var_v, var_r),
            "omega": 2 * np.pi * np.arange(srr.size) / L,
            "periodogram": svv / float(np.sum(w ** 2))}


def _arma_log_spectrum(theta: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``log`` of ``lam |1 + c e^-iw|^2 / |1 - a e^-iw|^2`` for ``theta = (log lam, a, c)``."""
    lam, a, c = theta
    num = 1.0 + c * c + 2.0 * c * np.cos(omega)
    den = 1.0 + a * a - 2.0 * a * np.cos(omega)
    return lam + np.log(np.maximum(num, 1e-300)) - np.log(den)


def fit_noise_model(spec: dict[str, Any], quantile: float | None = None) -> dict[str, float]:
    """ARMA(1,1) noise spectrum under the residual's input-free spectrum (its lower part).

    Model error only adds power to the noise, so the noise spectrum is fitted to the
    ``quantile`` of the input-free periodogram (:func:`noise_spectrum`) in log scale
    (pinball loss), with the offset that quantile has for a Welch average of pure
    noise (chi-square with ``2 (K - m)`` degrees of freedom). Bins a model error
    inflates (the low frequencies of an integrating plant's error) lie above the
    fit and do not move it; a noise that is coloured all over (AR) sets its shape.

    Returns
    -------
    dict
        ``lam`` (innovation variance), ``a`` (pole), ``c`` (zero) and ``variance``
        (``lam (1 + 2 a c + c^2) / (1 - a^2)``), output unit^2.
    """
    quantile = QUANTILE if quantile is None else float(quantile)
    omega = spec["omega"][1:]
    pv = spec["periodogram"][1:]
    # A pole slower than the segments resolve is not a stationary noise they can see.
    pole_max = min(POLE_MAX, 1.0 - POLE_SEGMENT * float(omega[0]))
    ok = pv > 0
    if ok.sum() < 4:
        v = float(spec["noise_variance"])
        return {"lam": v, "a": 0.0, "c": 0.0, "variance": v}
    omega, logp = omega[ok], np.log(pv[ok])
    k, m = float(spec["segments"]), int(spec["regressors"])
    nu = 2.0 * max(k - m, 1.0)
    offset = math.log(stats.chi2.ppf(quantile, nu) / (2.0 * k))
    target = logp - offset

    def loss(x: np.ndarray) -> float:
        th = (x[0], pole_max * math.tanh(x[1]), math.tanh(x[2]))
        e = target - _arma_log_spectrum(np.asarray(th), omega)
        return float(np.sum(np.maximum(quantile * e, (quantile - 1.0) * e)))

    best = None
    lam0 = float(np.median(target))
    for a0 in (0.0, 0.5, 0.9, 0.99):
        a_start = min(a0, 0.99 * pole_max)
        x0 = np.array([lam0 + 2 * math.log(1 - a_start), math.atanh(a_start / pole_max), 0.0])
        r = optimize.minimize(loss, x0, method="Nelder-Mead",
                              options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 2000})
        if best is None or r.fun < best.fun:
            best = r
    lam, a, c = math.exp(best.x[0]), pole_max * math.tanh(best.x[1]), math.tanh(best.x[2])
    var = lam * (1.0 + 2.0 * a * c + c * c) / (1.0 - a * a)
    return {"lam": lam, "a": a, "c": c, "variance": float(var)}


def noise_level(residual: np.ndarray, inputs: Sequence[np.ndarray] | None = None,
                *, nperseg: int | None = None, method: str = "arma") -> float:
    """Standard deviation of the measurement noise in a residual (output units).

    Parameters
    ----------
    residual : array, shape (N,)
        Measured minus simulated output.
    inputs : sequence of arrays, optional
        What the model error is a function of: the record's input and the simulated
        output (the loop passes both). Given: the residual's variance that is not
        coherent with them, at every frequency (:func:`noise_spectrum`), so coloured
        (AR) noise, quantisation and drift count in full and model error at any
        frequency does not. Not given: :func:`difference_level` (white noise only).
    nperseg : int, optional
        Welch segment length (:func:`noise_spectrum`).
    """
    r = np.asarray(residual, dtype=float)
    if inputs is None or r.size < 32:
        return difference_level(r)
    spec = noise_spectrum(r, inputs, nperseg=nperseg)
    if method == "coherence":
        return float(math.sqrt(max(spec["noise_variance"], 0.0)))
    fitm = fit_noise_model(spec)
    return float(math.sqrt(max(min(fitm["variance"], spec["variance"]), 0.0)))


def interval_factor(residual: np.ndarray, inputs: Sequence[np.ndarray] = ()) -> dict[str, float]:
    """How much too narrow white-noise intervals are under the residual's noise colour.

    Linearised (Gauss-Newton) intervals assume white residuals. Under coloured noise
    the variance of a parameter whose output sensitivity varies slowly grows by the
    ratio of the noise's long-run variance to its variance, ``S(0) / var``; for the
    ARMA(1,1) noise model (:func:`fit_noise_model`)
    ``(1 + c)^2 (1 - a^2) / ((1 - a)^2 (1 + 2ac + c^2))``, 19 for AR(1) with ``a = 0.9``.

    Returns
    -------
    dict
        ``factor`` (the square root of that ratio: how much wider an honest interval
        of such a parameter is), ``a``, ``c``.
    """
    r = np.asarray(residual, dtype=float)
    if r.size < 64 or not np.all(np.isfinite(r)):
        return {"factor": 1.0, "a": 0.0, "c": 0.0}
    m = fit_noise_model(noise_spectrum(r, inputs))
    a, c = m["a"], m["c"]
    ratio = (1 + c) ** 2 * (1 - a * a) / ((1 - a) ** 2 * (1 + 2 * a * c + c * c))
    return {"factor": float(math.sqrt(max(ratio, 0.0))), "a": a, "c": c}


def coloured_covariance(J: np.ndarray, r: np.ndarray, cov: np.ndarray,
                        model: dict[str, float]) -> np.ndarray:
    """Covariance of an output-error fit's coordinates under ARMA(1,1) noise (sandwich).

    The output-error estimate stays consistent under coloured noise, but its
    covariance is ``M J^T Sigma J M`` with ``M = (J^T J)^-1``, not ``s^2 M``: the
    noise covariance ``Sigma`` is that of the residual's noise model
    ``v = sqrt(lam) (1 + c q^-1) / (1 - a q^-1) e``, scaled to the residual's own
    variance ``s^2 = r.r / (N - n)``. ``J^T Sigma J = lam' G^T G`` with ``G = H^T J``,
    each column of ``J`` filtered by the noise model backwards in time. For white
    noise (``a = c = 0``) it is the usual ``s^2 M``.

    Parameters
    ----------
    J : ndarray, shape (N, n)
        Residual Jacobian at the optimum (fitting coordinates).
    r : ndarray, shape (N,)
        Residuals at the optimum.
    cov : ndarray, shape (n, n)
        The white-noise covariance ``s^2 M`` of the same coordinates (finite).
    model : dict
        ``a`` and ``c`` of the noise model (:func:`fit_noise_model`,
        :func:`interval_factor`).

    Returns
    -------
    ndarray, shape (n, n)
    """
    from scipy import signal as sps

    J = np.asarray(J, dtype=float)
    r = np.asarray(r, dtype=float)
    n_obs, n = J.shape
    s2 = float(r @ r) / max(n_obs - n, 1)
    a, c = float(model["a"]), float(model["c"])
    lam = s2 * (1 - a * a) / (1 + 2 * a * c + c * c)
    G = sps.lfilter([1.0, c], [1.0, -a], J[::-1], axis=0)[::-1]
    M = np.asarray(cov, dtype=float) / s2
    out = lam * (M @ (G.T @ G) @ M)
    return 0.5 * (out + out.T)
