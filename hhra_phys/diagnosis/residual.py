"""Residual analysis of a fitted model, and ranking of the effects it may lack.

Given a fitted model and its (estimation) record, :func:`analyse` computes

* whiteness: the residual autocorrelation with its 95 % band ``+-1.96/sqrt(N)``
  and the Ljung-Box statistic (``scipy.stats.chi2`` tail);
* the cross-correlation of the residual with the input, and the lag at which
  measured and simulated output *changes* line up best (a delay estimate);
* correlations of the residual and of its rate with candidate regressors: the
  sign of the simulated velocity, small ``|input|``, the simulated angle, recent
  direction reversals, the input level, ``|input|``, input changes and time, with
  a band widened for the residual's own correlation;
* the residual spectrum (Welch);
* for every library effect (:mod:`hhra_phys.effects`) its *evidence*: the effect's
  declared first-order change at its entry point, propagated through the model
  linearised at the fit, with what the model's own free parameters can already
  absorb projected out (their finite-difference output sensitivities), and then
  compared with the residual. ``score`` is the fraction of the residual
  variance it can explain to first order; ``detectability`` is the RMS output
  change a probe-size effect leaves after that projection, over the noise level.
  An effect whose detectability is below 1 is flagged *not identifiable from
  these data*: at a plausible size it leaves less than the noise (a fast spool
  lag in 250 Hz angle data is the classic case).

The ranking orders and explains candidates; it does not decide. Residual
statistics alone can mislead (a refit may show an effect "not indicated" here to be
the most useful one), so the loop (:mod:`hhra_phys.diagnosis.engine`) refits candidates
and scores them on validation data.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import signal as sps
from scipy import stats

from hhra_phys.data import Dataset
from hhra_phys.diagnosis.first_order import _linear_response, _project_out, nuisance_basis
from hhra_phys.effects import (
    EFFECTS,
    Effect,
    Signals,
    effect_name,
    make_effect,
)
from hhra_phys.errors import ParameterError
from hhra_phys.noise import noise_level
from hhra_phys.outputs import jsonable
from hhra_phys.problem import Problem, RecordProblem

__all__ = [
    "EffectEvidence",
    "Diagnosis",
    "whiteness",
    "cross_correlation",
    "output_delay",
    "generic_regressors",
    "regressor_table",
    "analyse",
    "combine_diagnoses",
    "diagnose_fit",
    "DETECTABLE",
]

#: Detectability (probe-size output change over noise) below which an effect is
#: reported as not identifiable from the record.
DETECTABLE = 1.0


@dataclass
class EffectEvidence:
    """Evidence for one candidate effect.

    Attributes
    ----------
    name : str
        Library name.
    score : float
        Fraction of the residual variance the effect explains to first order
        (after the model's own parameters absorb what they can), 0..1.
    detectability : float
        RMS output change after that projection, of a probe-size effect or of the
        size the residual suggests (the larger), over the noise standard deviation
        (below 1: not identifiable from these data).
    estimate : dict
        First-order estimate of the effect's parameters (a linearisation; the
        refit gives the real value).
    identifiable : bool
        ``detectability >= DETECTABLE``.
    signature : str
        What the effect is expected to leave in the residual.
    regressors : dict
        Correlations of the residual with the generic regressors the effect relates to.
    note : str
        Why it was skipped or flagged, if it was.
    """

    name: str
    score: float
    detectability: float
    estimate: dict[str, float]
    identifiable: bool
    signature: str
    regressors: dict[str, float] = field(default_factory=dict)
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        """JSON-able dictionary."""
        return jsonable(asdict(self))


@dataclass
class Diagnosis:
    """Result of :func:`analyse`. Arrays are kept for plots; :meth:`to_json` summarises."""

    n: int
    rmse: float
    noise: float
    whiteness: dict[str, Any]
    xcorr_input: dict[str, Any]
    delay_samples: float
    regressors: dict[str, dict[str, float]]
    spectrum: dict[str, Any]
    evidence: list[EffectEvidence]
    residual: np.ndarray
    t: np.ndarray
    series: dict[str, np.ndarray]

    def ranked(self) -> list[EffectEvidence]:
        """Evidence of the applicable effects, best first (identifiable ones before others)."""
        ok = [e for e in self.evidence if not e.note.startswith("skipped")]
        return sorted(ok, key=lambda e: (not e.identifiable, -e.score))

    def to_json(self) -> dict[str, Any]:
        """JSON-able summary (no long arrays)."""
        return jsonable({
            "n": self.n,
            "rmse": self.rmse,
            "noise": self.noise,
            "whiteness": {k: v for k, v in self.whiteness.items() if k != "acf"},
            "xcorr_input": {k: v for k, v in self.xcorr_input.items() if k != "values"},
            "delay_samples": self.delay_samples,
            "regressors": self.regressors,
            "spectrum": {k: v for k, v in self.spectrum.items() if k not in ("f", "pxx")},
            "evidence": [e.to_json() for e in self.ranked()],
        })

    def summary(self) -> str:
        """Short text: whiteness, delay, and the ranked effects with their evidence."""
        w = self.whiteness
        lines = [
            f"residual RMSE {self.rmse:.4g}, noise estimate {self.noise:.3g}, "
            f"Ljung-Box Q={w['ljung_box_q']:.4g} (p={w['ljung_box_p']:.2g}, {w['lags']} lags), "
            f"{100 * w['fraction_outside']:.0f} % of autocorrelations outside the band",
            f"input cross-correlation peak at lag {self.xcorr_input['peak_lag']} "
            f"(r={self.xcorr_input['peak']:.2f}); output changes align at "
            f"{self.delay_samples:+.2f} samples",
        ]
        for e in self.ranked():
            flag = "" if e.identifiable else "  [not identifiable from these data]"
            lines.append(f"  {e.name:18s} score {e.score:.3f}  detectability "
                         f"{e.detectability:.3g}{flag}")
        return "\n".join(lines)


def whiteness(residual: np.ndarray, lags: int | None = None) -> dict[str, Any]:
    """Autocorrelation with its 95 % band and the Ljung-Box test.

    Returns
    -------
    dict
        ``acf`` (lags 0..m), ``band`` (1.96/sqrt(N)), ``lags`` m,
        ``ljung_box_q``, ``ljung_box_p`` (chi-square tail with m degrees of
        freedom), ``fraction_outside`` (share of lags 1..m outside the band),
        ``white`` (p > 0.05).
    """
    r = np.asarray(residual, dtype=float) - np.mean(residual)
    n = r.size
    m = int(lags or min(40, max(5, n // 5)))
    full = sps.correlate(r, r, mode="full", method="fft")[n - 1:n + m]
    acf = full / full[0] if full[0] > 0 else np.zeros(m + 1)
    k = np.arange(1, m + 1)
    q = float(n * (n + 2) * np.sum(acf[1:] ** 2 / (n - k)))
    band = 1.96 / math.sqrt(n)
    p = float(stats.chi2.sf(q, m))
    return {"acf": acf, "band": band, "lags": m, "ljung_box_q": q, "ljung_box_p": p,
            "fraction_outside": float(np.mean(np.abs(acf[1:]) > band)), "white": p > 0.05}


def cross_correlation(a: np.ndarray, b: np.ndarray, max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised cross-correlation ``corr(a[n], b[n - lag])`` for lags ``-max_lag..max_lag``."""
    a = np.asarray(a, dtype=float) - np.mean(a)
    b = np.asarray(b, dtype=float) - np.mean(b)
    n = a.size
    full = sps.correlate(a, b, mode="full", method="fft")
    lags = sps.correlation_lags(n, n, mode="full")
    keep = np.abs(lags) <= max_lag
    denom = math.sqrt(float(np.dot(a, a) * np.dot(b, b))) or 1.0
    return lags[keep], full[keep] / denom


def output_delay(y: np.ndarray, yhat: np.ndarray, max_lag: int = 20) -> float:
    """Lag [samples] by which measured output changes follow simulated ones.

    Peak of the cross-correlation of ``diff(y)`` and ``diff(yhat)``, refined by a
    parabola through the peak and its neighbours (a fractional lag).
    """
    lags, c = cross_correlation(np.diff(y), np.diff(yhat), max_lag)
    i = int(np.argmax(c))
    if 0 < i < c.size - 1:
        den = c[i - 1] - 2 * c[i] + c[i + 1]
        frac = 0.5 * (c[i - 1] - c[i + 1]) / den if den != 0 else 0.0
        return float(lags[i] + frac)
    return float(lags[i])


def _effective_band(residual: np.ndarray) -> float:
    """95 % band of a correlation with an autocorrelated residual (lag-1 ESS)."""
    n = residual.size
    rho = float(np.corrcoef(residual[:-1], residual[1:])[0, 1]) if n > 3 else 0.0
    rho = min(max(rho, 0.0), 0.999)
    n_eff = max(3.0, n * (1 - rho) / (1 + rho))
    return 1.96 / math.sqrt(n_eff)


def generic_regressors(
    u: np.ndarray, t: np.ndarray, theta: np.ndarray | None, omega: np.ndarray | None,
    fs: float,
) -> dict[str, np.ndarray]:
    """Candidate regressors from the input and the simulated motion.

    ``sign_velocity`` (sign of the simulated velocity), ``small_input`` (1 where
    ``|u| < 0.3 max|u|``), ``angle`` (simulated, deg), ``reversals`` (1 within 0.1 s
    or 5 samples after a reversal of the simulated velocity), ``input_level``,
    ``abs_input``, ``input_change`` (``|du|`` held 5 samples) and ``time``.
    """
    out: dict[str, np.ndarray] = {}
    umax = float(np.max(np.abs(u))) or 1.0
    out["input_level"] = u
    out["abs_input"] = np.abs(u)
    out["small_input"] = (np.abs(u) < 0.3 * umax).astype(float)
    hold = max(5, int(round(0.1 * fs)))
    du = np.abs(np.diff(u, prepend=u[0]))
    out["input_change"] = sps.lfilter(np.ones(hold), [1.0], du)
    out["time"] = t - t[0]
    if omega is not None:
        scale = 0.01 * (float(np.max(np.abs(omega))) or 1.0)
        s = np.sign(np.where(np.abs(omega) > scale, omega, 0.0))
        out["sign_velocity"] = s
        flips = np.zeros(u.size)
        nz = np.flatnonzero(s)
        if nz.size > 1:
            change = nz[1:][s[nz[1:]] != s[nz[:-1]]]
            flips[change] = 1.0
        out["reversals"] = np.minimum(sps.lfilter(np.ones(hold), [1.0], flips), 1.0)
    if theta is not None:
        out["angle"] = np.degrees(theta)
    return out


def regressor_table(
    residual: np.ndarray, regressors: Mapping[str, np.ndarray], fs: float
) -> dict[str, dict[str, float]]:
    """Correlation of the residual and of its rate with each regressor.

    The rate is a Savitzky-Golay derivative: an effect acting on the velocity
    (friction, a dead zone) shows in the rate of the angle residual more clearly
    than in the residual itself. ``band`` is the 95 % band for the residual
    with its own autocorrelation taken into account (lag-1 effective sample size).
    """
    r = np.asarray(residual, dtype=float)
    win = min(r.size - (1 - r.size % 2), max(5, int(round(0.05 * fs)) | 1))
    rate = sps.savgol_filter(r, win, 2, deriv=1) if win >= 5 else np.gradient(r)
    band_r, band_d = _effective_band(r), _effective_band(rate)
    out = {}
    for name, x in regressors.items():
        if np.std(x) == 0:
            continue
        out[name] = {
            "r_residual": float(np.corrcoef(r, x)[0, 1]),
            "r_rate": float(np.corrcoef(rate, x)[0, 1]),
            "band_residual": band_r,
            "band_rate": band_d,
        }
    return out


def analyse(
    problem: Problem | RecordProblem,
    values: np.ndarray,
    candidates: Iterable[str] | None = None,
    effect_kw: Mapping[str, Mapping[str, Any]] | None = None,
) -> Diagnosis:
    """Analyse the residual of a fitted problem and rank candidate effects.

    Parameters
    ----------
    problem : Problem or RecordProblem
        The fitting problem (model and estimation records) of the fit, or one record's
        part of it; each record is analysed alone and, with several, the evidence summed
        (:func:`combine_diagnoses`).
    values : array, shape (n_free,)
        Fitted free values (physical units), in ``problem.free_names`` order.
    candidates : iterable of str, optional
        Library names to rank (default: all of :data:`~hhra_phys.effects.EFFECTS`
        not already in the model).
    effect_kw : dict, optional
        ``{name: {field: value}}`` passed to :func:`~hhra_phys.effects.make_effect`.

    Returns
    -------
    Diagnosis
    """
    values = np.asarray(values, dtype=float)
    return combine_diagnoses([_analyse_record(pr, values[idx], candidates, effect_kw)
                              for pr, idx in problem.blocks()])


def _analyse_record(
    problem: RecordProblem,
    values: np.ndarray,
    candidates: Iterable[str] | None = None,
    effect_kw: Mapping[str, Mapping[str, Any]] | None = None,
) -> Diagnosis:
    """:func:`analyse` of one record's problem at its free values."""
    data = problem.data
    values = np.asarray(values, dtype=float)
    P = problem.full(values)
    X0 = problem.initial_states(values)[0]
    yhat, X = problem.sim.simulate(data.u, P, x0=X0, states=True)
    if not np.isfinite(yhat).all():
        raise ParameterError("the fitted model cannot be simulated on its record")
    r = data.y - yhat
    fs = data.fs
    names = problem.model.state_names
    states = {n: X[:, i] for i, n in enumerate(names)}
    # The velocity and position bound by role (omega and theta on the HHRA).
    motion = problem.model.motion
    theta, omega = states.get(motion.position or ""), states.get(motion.velocity or "")
    # The input and the simulated output carry the model error; the rest is noise.
    noise = noise_level(r, (data.u, yhat))
    white = whiteness(r)
    max_lag = int(min(50, data.n // 10))
    xcorr = _input_xcorr(r, data, max_lag)
    delay = output_delay(data.y, yhat, max_lag=min(20, max_lag))
    regs = generic_regressors(data.u, data.t, theta, omega, fs)
    table = regressor_table(r, regs, fs)
    spectrum = _residual_spectrum(r, data)

    # Nuisance: what the model's own free parameters (the fitted initial state
    # among them) can absorb. No constant of its own: a constant residual is
    # absorbed only where the model can make one (an integrating output's initial
    # value), otherwise it is evidence of an offset.
    Q = nuisance_basis(problem, values, yhat)
    r_p = _project_out(Q, r[:, None])[:, 0]
    fit = _FittedResidual(
        problem=problem, P=P, data=data, fitted=problem.model.params.as_dict(P),
        sig=Signals(u=data.u, dt=data.dt, output=data.output_unit or "", states=states, y=yhat,
                    velocity=omega, position=theta),
        table=table, Q=Q, r_p=r_p, r_norm2=float(r_p @ r_p) or 1e-300, noise=noise,
        umax=float(np.max(np.abs(data.u))) or 1.0)
    names_c = (list(dict.fromkeys(effect_name(n) for n in candidates))
               if candidates is not None else list(EFFECTS))
    evidence = [_candidate_evidence(name, dict((effect_kw or {}).get(name, {})), fit)
                for name in names_c]
    series = {"yhat": yhat, "y": data.y, "u": data.u}
    if theta is not None:
        series["angle" if motion.rotary else "position"] = (
            np.degrees(theta) if motion.rotary else theta)
    if omega is not None:
        series["omega" if motion.rotary else "velocity"] = omega
    return Diagnosis(
        n=data.n, rmse=float(np.sqrt(np.mean(r ** 2))), noise=noise, whiteness=white,
        xcorr_input=xcorr, delay_samples=delay, regressors=table, spectrum=spectrum,
        evidence=evidence, residual=r, t=data.t, series=series,
    )


def _input_xcorr(r: np.ndarray, data: Dataset, max_lag: int) -> dict[str, Any]:
    """The residual's cross-correlation with the input, its peak and the white 95 % band."""
    lags, xc = cross_correlation(r, data.u, max_lag)
    ip = int(np.argmax(np.abs(xc)))
    return {"lags": lags.tolist(), "values": xc, "peak_lag": int(lags[ip]),
            "peak": float(xc[ip]), "band": 1.96 / math.sqrt(data.n)}


def _residual_spectrum(r: np.ndarray, data: Dataset) -> dict[str, Any]:
    """Welch spectrum of the residual, its peak and the fraction below a tenth of Nyquist."""
    fs = data.fs
    f, pxx = sps.welch(r - r.mean(), fs=fs, nperseg=min(256, max(16, data.n // 4)))
    low = f <= 0.1 * fs / 2
    return {"f": f, "pxx": pxx, "peak_frequency": float(f[int(np.argmax(pxx[1:])) + 1]),
            "low_fraction": float(pxx[low].sum() / pxx.sum()) if pxx.sum() > 0 else 0.0,
            "unit": "Hz" if data.time_unit != "samples" else "1/sample"}


@dataclass(frozen=True)
class _FittedResidual:
    """What every candidate of :func:`analyse` is ranked against (one record's fit).

    ``Q`` spans what the model's own free parameters absorb; ``r_p`` is the residual
    with that projected out and ``r_norm2`` its squared norm (kept above zero).
    """

    problem: Problem
    P: np.ndarray
    data: Dataset
    fitted: dict[str, float]
    sig: Signals
    table: dict[str, dict[str, float]]
    Q: np.ndarray
    r_p: np.ndarray
    r_norm2: float
    noise: float
    umax: float

    def perp(self, M: np.ndarray) -> np.ndarray:
        """``M`` with what the model's own parameters absorb projected out."""
        return _project_out(self.Q, M)


def _candidate_evidence(name: str, kw: dict[str, Any], fit: _FittedResidual) -> EffectEvidence:
    """Evidence for one candidate: skipped (cannot be built, not applicable, no first-order
    signature) or its projected first-order fit of the residual."""
    try:
        eff: Effect = make_effect(name, data=fit.data, values=fit.fitted,
                                  model=fit.problem.model, **kw)
    except Exception as exc:  # noqa: BLE001 - a user's effect may fail to build
        return EffectEvidence(name, 0.0, 0.0, {}, False, "",
                              note=f"skipped: cannot be built ({exc})")
    why = eff.applicable(fit.problem.model)
    if why:
        return EffectEvidence(name, 0.0, 0.0, {}, False, eff.signature,
                              note=f"skipped: {why}")
    entry = eff.entry_at(fit.problem.model)
    rel = {k: fit.table[k]["r_rate" if entry != "output" else "r_residual"]
           for k in eff.regressors if k in fit.table}
    try:
        cols = eff.first_order(fit.sig)
        if cols is None:
            return EffectEvidence(
                name, 0.0, float("nan"), {}, True, eff.signature, rel,
                note="no first-order signature declared: ranked last, decided by its refit")
        cols = np.asarray(cols, dtype=float).reshape(fit.data.n, -1)
        S = _linear_response(fit.problem, fit.P, entry, cols, fit.umax)
    except Exception as exc:  # noqa: BLE001 - report, do not abort the ranking
        return EffectEvidence(name, 0.0, float("nan"), {}, False, eff.signature,
                              rel, note=f"no first-order signature: {exc}")
    if not np.isfinite(S).all():
        # A fit whose linearisation is unstable at this entry (a discovered term with a
        # positive slope, accepted on a long record): the response grows without bound
        # over the record, and a least-squares fit of it fails (SVD does not converge).
        return EffectEvidence(
            name, 0.0, float("nan"), {}, True, eff.signature, rel,
            note=(f"no first-order signature: the model linearised at the fit is unstable "
                  f"at {eff.entry} (its response grows without bound over the record): "
                  "ranked last, decided by its refit"))
    return _projected_evidence(name, eff, S, cols.shape[1], rel, fit)


def _projected_evidence(name: str, eff: Effect, S: np.ndarray, n_cols: int,
                        rel: dict[str, float], fit: _FittedResidual) -> EffectEvidence:
    """Score, detectability and first-order estimate of an effect whose output response
    to its ``n_cols`` first-order columns is ``S``."""
    noise = fit.noise
    S_p = fit.perp(S)
    rms_raw = float(np.sqrt(np.mean(S ** 2)))
    rms_p = float(np.max(np.sqrt(np.mean(S_p ** 2, axis=0))))
    shown = 0.0
    if rms_p <= 1e-6 * max(rms_raw, 1e-300):
        score, est = 0.0, {}
        note = "its output signature is absorbed by the model's own parameters"
    else:
        beta, *_ = np.linalg.lstsq(S_p, fit.r_p, rcond=None)
        fit_p = S_p @ beta
        score = float(np.clip(fit_p @ fit_p / fit.r_norm2, 0.0, 1.0))
        shown = float(np.sqrt(np.mean(fit_p ** 2)))
        probe = eff.probe()
        pnames = [p.name for p in eff.parameters]
        est = {}
        if len(pnames) >= n_cols:
            for j in range(n_cols):
                est[pnames[j]] = float(beta[j] * probe[pnames[j]])
        note = ""
    # Detectable if either a plausible (probe) size or the size the residual
    # itself suggests changes the output by more than the noise.
    detect = max(rms_p, shown) / noise if noise > 0 else float("inf")
    ident = detect >= DETECTABLE
    if not ident:
        note = (note + "; " if note else "") + (
            f"a probe-size effect changes the output by {rms_p:.2g} RMS and the residual "
            f"shows {shown:.2g} of it after the base parameters absorb what they can, "
            f"below the noise {noise:.2g}: not identifiable from these data")
    return EffectEvidence(name, score, detect, est, ident, eff.signature, rel, note)


def combine_diagnoses(diags: Sequence[Diagnosis]) -> Diagnosis:
    """One diagnosis of several records from each record's own (evidence summed).

    Each record is analysed alone (:func:`analyse` on its one-record problem at the
    joint fit, the model's parameters projected out on that record), and then:

    * ``score``: the fraction of the records' residual variance, all together, the
      effect explains to first order, ``sum_k score_k E_k / sum_k E_k`` with
      ``E_k`` record ``k``'s residual sum of squares;
    * ``detectability``: the RMS over all samples of each record's output change,
      over the pooled noise level (``sqrt(sum_k n_k sigma_k^2 / N)``);
      ``identifiable`` from it (:data:`DETECTABLE`);
    * first-order ``estimate``s and regressor correlations: sample-weighted means;
      a skip or a note of one record is kept, prefixed by the record's number;
    * the residual, series, input cross-correlation and spectrum are those of the
      records one after another (time continued across them), whiteness likewise
      but with the Ljung-Box statistic and degrees of freedom summed over the
      records (independent records), the output delay the sample-weighted mean.

    Parameters
    ----------
    diags : sequence of Diagnosis
        One per record, the same candidates in the same order.

    Returns
    -------
    Diagnosis
    """
    diags = list(diags)
    if len(diags) == 1:
        return diags[0]
    n = np.array([d.n for d in diags], dtype=float)
    w = n / n.sum()
    energy = np.array([d.n * d.rmse ** 2 for d in diags])
    noise = float(np.sqrt(np.sum(w * np.array([d.noise for d in diags]) ** 2)))
    evidence = []
    for per in zip(*(d.evidence for d in diags), strict=True):
        first = per[0]
        notes = [f"record {k}: {e.note}" for k, e in enumerate(per, start=1) if e.note]
        skip = next((e.note for e in per if e.note.startswith("skipped")), "")
        if skip:
            evidence.append(EffectEvidence(first.name, 0.0, 0.0, {}, False, first.signature,
                                           note=skip))
            continue
        tot = float(energy.sum()) or 1e-300
        score = float(sum(e.score * en for e, en in zip(per, energy, strict=True)) / tot)
        change2 = [(e.detectability * d.noise) ** 2 for e, d in zip(per, diags, strict=True)]
        detect = (float(np.sqrt(np.nansum(w * np.array(change2)))) / noise
                  if noise > 0 else float("inf"))
        est = {k: float(sum(wk * e.estimate.get(k, 0.0) for wk, e in zip(w, per, strict=True)))
               for k in dict.fromkeys(k for e in per for k in e.estimate)}
        regs = {k: float(sum(wk * e.regressors.get(k, 0.0) for wk, e in zip(w, per, strict=True)))
                for k in dict.fromkeys(k for e in per for k in e.regressors)}
        evidence.append(EffectEvidence(first.name, score, detect, est, detect >= DETECTABLE,
                                       first.signature, regs, "; ".join(notes)))
    r = np.concatenate([d.residual for d in diags])
    t_parts, offset = [], 0.0
    for d in diags:
        step = float(d.t[1] - d.t[0]) if d.t.size > 1 else 1.0
        t_parts.append(d.t - d.t[0] + offset)
        offset = float(t_parts[-1][-1]) + step
    white = whiteness(r)
    q = float(sum(d.whiteness["ljung_box_q"] for d in diags))
    dof = int(sum(d.whiteness["lags"] for d in diags))
    p = float(stats.chi2.sf(q, dof))
    white.update(ljung_box_q=q, ljung_box_p=p, white=p > 0.05, lags=dof)
    u = np.concatenate([d.series["u"] for d in diags])
    max_lag = int(min(50, r.size // 10))
    lags, xc = cross_correlation(r, u, max_lag)
    ip = int(np.argmax(np.abs(xc)))
    first = diags[0]
    f, pxx = sps.welch(r - r.mean(), fs=1.0 / max(float(first.t[1] - first.t[0]), 1e-300),
                       nperseg=min(256, max(16, r.size // 4)))
    spectrum = dict(first.spectrum, f=f, pxx=pxx)
    keys = set.intersection(*(set(d.series) for d in diags))
    regs_all = {k: {kk: float(sum(wk * d.regressors[k][kk] for wk, d in zip(w, diags,
                                                                           strict=True)))
                    for kk in first.regressors[k]}
                for k in first.regressors if all(k in d.regressors for d in diags)}
    return Diagnosis(
        n=int(n.sum()), rmse=float(np.sqrt(np.mean(r ** 2))), noise=noise, whiteness=white,
        xcorr_input={"lags": lags.tolist(), "values": xc, "peak_lag": int(lags[ip]),
                     "peak": float(xc[ip]), "band": 1.96 / math.sqrt(r.size)},
        delay_samples=float(np.sum(w * np.array([d.delay_samples for d in diags]))),
        regressors=regs_all, spectrum=spectrum, evidence=evidence, residual=r,
        t=np.concatenate(t_parts),
        series={k: np.concatenate([d.series[k] for d in diags]) for k in keys},
    )


def diagnose_fit(result: Any, data: Dataset, split: float | None = None,
                 candidates: Sequence[str] | None = None) -> Diagnosis:
    """Analyse a :class:`~hhra_phys.result.FitResult` on (the estimation part of) ``data``.

    Parameters
    ----------
    result : FitResult
        A fit (its model, free parameters and values are used).
    data : Dataset
        The whole record; its first ``split`` fraction (the fit's by default) is used.
    split : float, optional
        Estimation fraction (default: ``result.settings["split"]``).
    candidates : sequence of str, optional
        Effects to rank (default: all).
    """
    frac = float(split if split is not None else result.settings.get("split", 0.5))
    est = data.split(frac)[0] if frac < 1 else data
    model = result.model
    free = [n for n in result.free if not n.startswith("x0_")]
    fixed = {k: v for k, v in result.values.items() if k not in free}
    init = result.settings.get("initial_state", "fit")
    problem = Problem(model, est, free=free, fixed=fixed, initial_state=init,
                      start=result.values, allow_outside_box=True)  # the fit's own values
    vals = [result.values[n] if not n.startswith("x0_") else result.x0_param(n)
            for n in problem.free_names]
    return analyse(problem, np.array(vals), candidates=candidates)
