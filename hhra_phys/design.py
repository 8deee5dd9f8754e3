"""Experiment design: the input that pins the free parameters down.

A fit tells which parameter directions its record left weakly determined (on rig
records with small pressure excursions, the pressure scale: ``g_valve`` and
``g_compress`` up with ``g_torque`` down). The model can say which input would
have determined them, because it has exact sensitivities: for an input ``u`` the
Fisher information of the fitting coordinates ``z`` is

    F(u) = J(u)^T J(u) / sigma^2,     J = d y_sim / d z     (N x n)

with ``J`` from the compiled forward sensitivities
(:class:`~hhra_phys.refine.CompiledLeastSquares` on a one-record
:class:`~hhra_phys.problem.Problem` of the candidate input, so the coordinates
are the fit's: log10 for positive groups, scaled for signed ones) and ``sigma``
the fit's residual RMS. The record's initial angle is fitted too
(``initial_state="fit"``), so it is a nuisance parameter: the criterion is on
the covariance of the model parameters with it marginalised, ``C = [F^-1]_MM``:

``"d"`` (default)
    ``log det C`` (the volume of the confidence ellipsoid, D-optimal);
``"a"``
    ``trace C`` (the mean squared interval half-width, in decades for log groups);
``"e"``
    the largest eigenvalue of ``C`` (the worst direction).

All are minimised. Robustness to the fit's own uncertainty: the criterion is
averaged over the fitted values and ``draws`` parameter sets drawn from the
fit's covariance (seeded, clipped to the fit's box; a draw whose simulation
diverges for a candidate is skipped for it).

Limits (all checked on the final design, :meth:`Design.check`): ``|u| <=
max_input`` (default: the largest ``|u|`` of the fitted record), every hold
(switching time) at least ``min_hold`` seconds (the last hold may be cut by the
end of the record), the duration, and ``|y| <= output_limit`` when the model is
simulated from rest at ``y = 0`` with the fitted values and with every draw (the
HHRA turns within +-90 deg; the default limit of 80 deg keeps a margin).

Search: candidates of the signal families of :mod:`hhra_phys.excitation`
(the paper's multi-level irregular steps, APRBS, Schroeder multisines) with
random parameters, and free piecewise-constant inputs on the ``min_hold`` grid;
a candidate whose simulated output leaves the range is scaled down once to fit.
The best piecewise-constant candidate is then improved by a seeded local search
over the levels of its holds.

The part the fit estimates from (``split``): a fit of a record estimates from its
first ``round(split * N)`` samples and validates on the rest (``hhra-phys fit``'s
``--split``, 0.5 by default). Information in the validation part does not narrow
the fit's intervals, so the design searches only the estimation part (from rest)
and the predicted widths are those of a fit of that part. The validation part is
filled with the paper's irregular multi-level steps (or APRBS) within the same
limits, so the record can be fitted as it is and validated on an input unlike the
one it was estimated from. ``split=1`` designs the whole record (then fit it with
``--split 1`` and validate on another record).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hhra_phys.data import DataChecks, Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.excitation import aprbs, irregular_steps, multisine
from hhra_phys.options import with_overrides
from hhra_phys.problem import Problem
from hhra_phys.refine import CompiledLeastSquares

__all__ = [
    "CRITERIA",
    "FAMILIES",
    "Design",
    "DesignOptions",
    "InformationModel",
    "criterion_value",
    "design_input",
    "estimation_split",
    "shortest_hold",
]

#: Design criteria (module docstring).
CRITERIA: tuple[str, ...] = ("d", "a", "e")
#: Signal families searched.
FAMILIES: tuple[str, ...] = ("steps", "aprbs", "multisine", "free")
#: Default output limit [deg]: the HHRA turns within +-90 deg, with a margin.
OUTPUT_LIMIT_DEG = 80.0
#: Default shortest hold (switching time) of a designed input [s].
MIN_HOLD_S = 0.1


@dataclass
class Design:
    """A designed input and what it is predicted to give.

    Attributes
    ----------
    u : ndarray, shape (N,)
        The input, sampled at ``fs`` (input units, valve current [mA] for the HHRA).
    fs : float
        Sample rate [Hz].
    criterion : str
        ``"d"``, ``"a"`` or ``"e"``.
    value : float
        The robust criterion (mean over the fitted values and the draws).
    family : str
        Family of the design (``"free"`` after the local search).
    widths : dict of str to float
        Predicted relative 95 % interval width of each free model parameter at
        the fitted values (``hi/lo`` spread divided by the value), for a fit of
        the estimation part (the first ``n_est`` samples).
    limits : dict
        ``max_input``, ``min_hold`` [s], ``output_limit``, ``duration`` [s].
    peak_output : float
        Largest ``|y|`` over the fitted values and the draws, from rest at 0.
    evaluations : int
        Candidate inputs evaluated.
    split : float
        Share of the record the fit will estimate from (1: the whole record).
    n_est : int
        Samples of the estimation part (``round(split * N)``, as
        :meth:`~hhra_phys.data.Dataset.split` cuts); 0 means all of them.
    widths_whole : dict of str to float
        The widths if the whole record were used for estimation (``--split 1``).
    """

    u: np.ndarray
    fs: float
    criterion: str
    value: float
    family: str
    widths: dict[str, float]
    limits: dict[str, float]
    peak_output: float
    evaluations: int = 0
    history: list[float] = field(default_factory=list)
    split: float = 1.0
    n_est: int = 0
    widths_whole: dict[str, float] = field(default_factory=dict)

    @property
    def t(self) -> np.ndarray:
        """Time axis [s], shape (N,)."""
        return np.arange(self.u.size) / self.fs

    def check(self) -> list[str]:
        """Limits the input breaks (empty when it respects them all)."""
        bad = []
        lim = self.limits
        if np.max(np.abs(self.u)) > lim["max_input"] * (1 + 1e-12):
            bad.append(f"|u| reaches {np.max(np.abs(self.u)):.6g} > {lim['max_input']:.6g}")
        if abs(self.u.size - round(lim["duration"] * self.fs)) > 0:
            bad.append(f"{self.u.size} samples for {lim['duration']} s at {self.fs} Hz")
        short = shortest_hold(self.u)
        # A multisine has no holds: its band is kept below 1/(2*min_hold) instead.
        if self.family != "multisine" and short < round(lim["min_hold"] * self.fs):
            bad.append(f"a hold of {short} samples is shorter than {lim['min_hold']} s")
        if self.peak_output > lim["output_limit"]:
            bad.append(f"|y| reaches {self.peak_output:.4g} > {lim['output_limit']:.4g}")
        return bad


def estimation_split(result: Any) -> float:
    """The share of its record a fit estimated from: its ``split``, or 1 if it used it whole.

    A fit given validation records estimates from every sample of its own
    (``settings["data"]``: ``n_est == n``); the first record decides for several.
    """
    described = result.settings.get("data")
    first = described[0] if isinstance(described, list) and described else described or {}
    n, n_est = first.get("n"), first.get("n_est")
    if isinstance(n, int) and isinstance(n_est, int) and n_est >= n:
        return 1.0
    split = result.settings.get("split", 0.5)
    return float(split) if isinstance(split, int | float) and 0 < split <= 1 else 0.5


def shortest_hold(u: np.ndarray) -> int:
    """Shortest number of samples the input holds a value, the last hold excluded.

    (The record's end may cut the last hold; a constant input gives its length.)
    """
    u = np.asarray(u, dtype=float)
    change = np.flatnonzero(np.diff(u) != 0) + 1
    if change.size == 0:
        return int(u.size)
    edges = np.concatenate([[0], change])
    return int(np.diff(edges).min())


class InformationModel:
    """Fisher information of candidate inputs for a fit's free parameters.

    Parameters
    ----------
    result : FitResult
        The fit (live or loaded from JSON): model, values, free parameters,
        their boxes (which fix the coordinates of signed parameters) and the
        residual RMS of its estimation data (``sigma``).
    fs : float, optional
        Sample rate of the inputs [Hz] (default: the fit's).
    """

    def __init__(self, result: Any, fs: float | None = None) -> None:
        model = result.model
        self.model = model
        self.fs = float(fs or result.settings["fs"])
        self.free = [n for n in result.free if n in model.params.names]
        if not self.free:
            raise ParameterError("the fit has no free model parameters to design for")
        boxes = result.settings.get("bounds", {})
        self.bounds = {n: (float(boxes[n][0]), float(boxes[n][1])) for n in self.free if n in boxes}
        self.values = {n: float(result.values[n]) for n in model.params.names}
        self.fixed = {n: v for n, v in self.values.items() if n not in self.free}
        self.sigma = float(result.metrics.get("est", {}).get("rmse") or 1.0)
        self.sim = result.simulator(self.fs)
        self._x0 = model.x0()
        # Coordinates of the fitted values, and the covariance of the draws.
        # Coordinates of the fitted values (the record's x0 coordinates follow the free ones).
        self._coords = self._problem(np.zeros(20 * (len(self.free) + 1)))
        self.z_hat = self._coords.to_z(self._coords.start_values())
        names = list(result.free)
        idx = [names.index(n) for n in self.free]
        sd = np.array([float(result.std.get(n, 0.0)) for n in self.free])
        corr = np.asarray(result.correlation, dtype=float)
        square = corr.shape == (len(names), len(names))
        corr = corr[np.ix_(idx, idx)] if square else np.eye(len(idx))
        cov = corr * np.outer(sd, sd)
        self.cov_z = np.where(np.isfinite(cov), cov, 0.0)

    def _problem(self, u: np.ndarray, values: dict[str, float] | None = None) -> Problem:
        vals = values or self.values
        p = np.array([vals[n] for n in self.model.params.names])
        y = self.sim.simulate(u, p, x0=self._x0)
        if not np.isfinite(y).all():
            y = np.zeros_like(u)
        # A candidate is not measured data: the data checks (excitation, clipping) do not apply.
        ds = Dataset(np.arange(u.size) / self.fs, u, y, name="design",
                     checks=DataChecks(require_excitation=False))
        return Problem(self.model, ds, cost="ssr", free=self.free, fixed=self.fixed,
                       bounds=self.bounds, initial_state="fit", simulator=self.sim,
                       allow_outside_box=True,  # fixed: the fit's own values
                       start={n: vals[n] for n in self.free})

    def output(self, u: np.ndarray, values: dict[str, float] | None = None
               ) -> np.ndarray | None:
        """Output simulated from rest with input ``u`` (None if it diverges)."""
        vals = values or self.values
        p = np.array([vals[n] for n in self.model.params.names])
        y = self.sim.simulate(np.asarray(u, dtype=float), p, x0=self._x0)
        return y if np.isfinite(y).all() else None

    def peak(self, u: np.ndarray, values: dict[str, float] | None = None) -> float:
        """Largest ``|y|`` simulated from rest with input ``u`` (``inf`` if it diverges)."""
        y = self.output(u, values)
        return math.inf if y is None else float(np.max(np.abs(y)))

    def draws(self, n: int, seed: int | np.random.Generator | None) -> list[dict[str, float]]:
        """The fitted values and ``n`` parameter sets drawn from the fit's covariance.

        Drawn in the fitting coordinates and clipped to the fit's box.
        """
        out = [dict(self.values)]
        if n <= 0:
            return out
        rng = np.random.default_rng(seed)
        w, V = np.linalg.eigh(self.cov_z)
        L = V * np.sqrt(np.clip(w, 0, None))
        m = len(self.free)
        box = self._coords.bounds_z()[:m]
        for _ in range(n):
            z = self.z_hat.copy()
            # Within the fit's box: a weakly determined fit's covariance reaches far outside.
            z[:m] = np.clip(z[:m] + L @ rng.standard_normal(m), box[:, 0], box[:, 1])
            v = self._coords.from_z(z)[:m]
            out.append({**self.values, **dict(zip(self.free, map(float, v), strict=True))})
        return out

    def covariance(self, u: np.ndarray, values: dict[str, float] | None = None
                   ) -> tuple[np.ndarray, float]:
        """Covariance of the free model parameters' coordinates for input ``u``, and max |y|.

        The initial angle is a fitted nuisance parameter and is marginalised.
        """
        pr = self._problem(np.asarray(u, dtype=float), values)
        z = pr.to_z(pr.start_values())
        r, J = CompiledLeastSquares(pr)(z)
        peak = float(np.max(np.abs(pr.y)))
        info = J.T @ J / self.sigma**2
        if not np.isfinite(info).all() or np.all(r >= 1e149):
            return np.full((len(self.free),) * 2, np.inf), np.inf
        try:
            cov = np.linalg.inv(info)
        except np.linalg.LinAlgError:
            return np.full((len(self.free),) * 2, np.inf), peak
        m = len(self.free)
        return cov[:m, :m], peak

    def widths(self, u: np.ndarray, values: dict[str, float] | None = None) -> dict[str, float]:
        """Predicted relative 95 % interval width of each free model parameter for input ``u``."""
        cov, _ = self.covariance(u, values)
        m = len(self.free)
        sd = np.zeros(self.z_hat.size)
        sd[:m] = np.sqrt(np.clip(np.diag(cov), 0, None))
        pr = self._coords if values is None else self._problem(self._coords.u, values)
        z = pr.to_z(pr.start_values())
        out = {}
        for i, name in enumerate(self.free):
            lo = pr.from_z(z - 1.96 * sd)[i]
            hi = pr.from_z(z + 1.96 * sd)[i]
            value = pr.from_z(z)[i]
            out[name] = float(abs(hi - lo) / abs(value)) if value != 0 else float("inf")
        return out


def criterion_value(cov: np.ndarray, criterion: str) -> float:
    """The design criterion of a covariance (smaller is better; ``inf`` if singular)."""
    if not np.isfinite(cov).all():
        return math.inf
    if criterion == "d":
        sign, logdet = np.linalg.slogdet(cov)
        return float(logdet) if sign > 0 else math.inf
    if criterion == "a":
        return float(np.trace(cov))
    w = np.linalg.eigvalsh(0.5 * (cov + cov.T))
    return float(w[-1]) if w[0] > 0 else math.inf


def _candidate(family: str, rng: np.random.Generator, n: int, fs: float, amp: float,
               hold: int) -> np.ndarray | None:
    """One random input of a family, or None if its parameters cannot meet the hold."""
    if family == "aprbs":
        max_hold = hold * int(rng.integers(1, 9))
        levels = None if rng.random() < 0.5 else [-amp, amp]
        return aprbs(n, low=-amp, high=amp, levels=levels, min_hold=hold,
                     max_hold=max_hold, seed=rng)
    if family == "steps":
        irr = float(rng.uniform(0.0, 0.5))
        most = int(n * (1 - irr) / (30 * hold))
        if most < 1:
            return None
        u = irregular_steps(n, levels=int(rng.integers(1, 6)), amplitude=amp,
                            n_periods=int(rng.integers(1, most + 1)), irregularity=irr, seed=rng)
        return u if shortest_hold(u) >= hold else None
    if family == "multisine":
        f_top = min(0.45 * fs, fs / (2.0 * hold))  # no faster than the switching time allows
        f_min = fs / n
        f_max = float(np.exp(rng.uniform(np.log(max(2 * f_min, 0.2)), np.log(f_top))))
        if f_max <= f_min:
            return None
        return multisine(n, fs, f_min=f_min, f_max=f_max, amplitude=amp, phases="random",
                         seed=rng)
    k = -(-n // hold)  # "free": piecewise constant on the hold grid
    levels = rng.choice([-1.0, 1.0], size=k) if rng.random() < 0.5 else rng.uniform(-1, 1, k)
    return np.repeat(amp * levels, hold)[:n]


@dataclass(frozen=True)
class DesignOptions:
    """Settings of :func:`design_input`, validated as a whole.

    Every field is also a keyword of :func:`design_input`, which overrides the options it
    is given (``design_input(res, 10.0, options=DesignOptions(criterion="a"), seed=2)``).

    Attributes
    ----------
    max_input : float, optional
        Largest ``|u|`` (input units); default: the largest ``|u|`` of
        ``reference_input`` (the fitted record's input), required without it.
    output_limit : float
        Largest ``|y|`` (output units) when simulated from rest at 0.
    min_hold : float
        Shortest hold (switching time) [s].
    criterion : {"d", "a", "e"}
        Design criterion (module docstring).
    seed : int or None
        Seeds the candidates, the draws and the local search.
    fs : float, optional
        Sample rate [Hz] (default: the fit's).
    families : sequence of str
        Families searched (:data:`FAMILIES`).
    candidates : int
        Random candidates per family.
    local_steps : int
        Steps of the local search on the best piecewise-constant candidate.
    draws : int
        Parameter sets from the fit's covariance the criterion is averaged over
        (besides the fitted values).
    split : float, optional
        Share of the record the fit will estimate from, ``0 < split <= 1``
        (``hhra-phys fit --split``; module docstring); default: the share the
        fit designed from estimated from (:func:`estimation_split`: 0.5 for a
        default fit, 1 for one made with ``split=1`` or validation records).
        Below 1 the first ``round(split * N)`` samples are designed and the rest
        is a validation input within the same limits.
    """

    max_input: float | None = None
    output_limit: float = OUTPUT_LIMIT_DEG
    min_hold: float = MIN_HOLD_S
    criterion: str = "d"
    seed: int | None = 0
    fs: float | None = None
    families: tuple[str, ...] = FAMILIES
    candidates: int = 48
    local_steps: int = 120
    draws: int = 4
    split: float | None = None

    def validate(self) -> DesignOptions:
        """Check every setting before any simulation; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        if self.criterion not in CRITERIA:
            raise ParameterError(f"criterion must be one of {', '.join(CRITERIA)}, got "
                                 f"{self.criterion!r}")
        unknown = sorted(set(self.families) - set(FAMILIES))
        if unknown or not self.families:
            raise ParameterError(f"families must be among {', '.join(FAMILIES)}, got "
                                 f"{list(self.families)}")
        if self.split is not None and not (isinstance(self.split, int | float)
                                           and 0.0 < self.split <= 1.0):
            raise ParameterError(f"split must be a fraction in (0, 1], got {self.split!r}")
        _check_positive(output_limit=self.output_limit, min_hold=self.min_hold,
                        **{k: v for k, v in (("max_input", self.max_input), ("fs", self.fs))
                           if v is not None})
        for name in ("candidates", "local_steps", "draws"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
                raise ParameterError(f"{name} must be an integer >= 0, got {value!r}")
        return self

    @classmethod
    def of(cls, options: DesignOptions | None = None, **overrides: Any) -> DesignOptions:
        """``options`` (default: the defaults) with ``overrides`` applied, validated.

        Raises
        ------
        ParameterError
            An override that is not a setting (with the settings' names), or a bad value.
        """
        return with_overrides(options if options is not None else cls(), overrides, "design",
                              ("families",)).validate()


def _check_positive(**values: Any) -> None:
    """Each value a finite number > 0, else an error naming it."""
    for name, value in values.items():
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ParameterError(f"{name} must be a finite number > 0, got {value!r}")


def design_input(
    result: Any,
    duration: float,
    *,
    options: DesignOptions | None = None,
    reference_input: np.ndarray | None = None,
    **settings: Any,
) -> Design:
    """Design the input that maximises the information about a fit's free parameters.

    Parameters
    ----------
    result : FitResult
        The fit to design from (its values, free parameters, noise level).
    duration : float
        Length of the designed record [s].
    options : DesignOptions, optional
        The design's settings (default :class:`DesignOptions`'s).
    reference_input : ndarray, optional
        The fitted record's input (for the default ``max_input``).
    **settings
        Any field of :class:`DesignOptions` (``max_input``, ``output_limit``, ``min_hold``,
        ``criterion``, ``seed``, ``fs``, ``families``, ``candidates``, ``local_steps``,
        ``draws``, ``split``), overriding ``options``.

    Returns
    -------
    Design

    Raises
    ------
    ParameterError
        Bad limits, criterion or family, before any simulation.
    """
    o = DesignOptions.of(options, **settings)
    max_input = o.max_input
    if max_input is None:
        if reference_input is None:
            raise ParameterError("max_input is needed when the fitted record's input is unknown")
        max_input = float(np.max(np.abs(reference_input)))
    split = estimation_split(result) if o.split is None else o.split
    _check_positive(duration=duration, max_input=max_input)
    info = InformationModel(result, o.fs)
    fs = info.fs
    n_total, n, hold = _samples(duration, fs, split, o.min_hold, len(info.free))
    rng = np.random.default_rng(o.seed)
    points = info.draws(o.draws, rng)
    score = _Scorer(info, points, o.criterion, max_input, o.output_limit)
    best = _random_search(score, o.families, o.candidates, rng, n, fs, max_input, hold)
    steps_ok = [b for f, b in best.items() if f != "multisine" and math.isfinite(b[0])]
    if steps_ok and o.local_steps > 0:
        start = min(steps_ok, key=lambda b: b[0])
        best["free"] = _local_search(score, start, o.local_steps, rng, max_input, hold)
    value, peak, u, family = min(best.values(), key=lambda b: b[0])
    u_est = u
    if n < n_total:
        u, peak = _with_validation(info, u_est, n_total - n, points, rng, fs, max_input, hold,
                                   o.output_limit)
    return Design(
        u=u, fs=fs, criterion=o.criterion, value=value, family=family,
        widths=info.widths(u_est), peak_output=peak, evaluations=score.evaluations,
        history=score.history,
        limits={"max_input": float(max_input), "min_hold": float(o.min_hold),
                "output_limit": float(o.output_limit), "duration": float(duration)},
        split=float(min(split, 1.0)), n_est=n,
        widths_whole=info.widths(u) if n < n_total else {},
    )


def _samples(duration: float, fs: float, split: float, min_hold: float, n_free: int
             ) -> tuple[int, int, int]:
    """Samples of the record and of its designed (estimation) part, and of the shortest hold.

    The fit cuts its estimation part as :meth:`Dataset.split` does: ``round(split * N)``.
    """
    n_total = int(round(duration * fs))
    n = n_total if split >= 1.0 else int(round(split * n_total))
    hold = max(1, int(math.ceil(min_hold * fs - 1e-9)))
    if n < 2 * hold or n < 20 * (n_free + 1) or (n < n_total and n_total - n < hold):
        raise ParameterError(f"duration {duration} s is too short for min_hold {min_hold} s "
                             f"and {n_free} free parameters"
                             + (f" with split {split}" if split < 1 else ""))
    return n_total, n, hold


#: A scored candidate: (robust criterion, peak |y|, the input used, family).
_Scored = tuple[float, float, np.ndarray, str]


class _Scorer:
    """The robust criterion of candidate inputs, each rescaled once to fit the output limit.

    Counts the candidates simulated (:attr:`evaluations`) and keeps every value scored
    (:attr:`history`).
    """

    def __init__(self, info: InformationModel, points: list[dict[str, float]],
                 criterion: str, max_input: float, output_limit: float) -> None:
        self.info, self.points, self.criterion = info, points, criterion
        self.max_input, self.output_limit = max_input, output_limit
        self.evaluations = 0
        self.history: list[float] = []

    def __call__(self, u: np.ndarray) -> tuple[float, float, np.ndarray]:
        """(robust criterion, peak |y|, the input actually used).

        Draws whose simulation diverges are skipped; the fitted values must not.
        """
        value, peak, u = self._score(np.clip(u, -self.max_input, self.max_input))
        self.history.append(value)
        return value, peak, u

    def _score(self, u: np.ndarray) -> tuple[float, float, np.ndarray]:
        for attempt in range(2):
            self.evaluations += 1
            results = [self.info.covariance(u, vals) for vals in self.points]
            if not math.isfinite(results[0][1]):
                return math.inf, math.inf, u
            ok = [(criterion_value(c, self.criterion), pk) for c, pk in results
                  if math.isfinite(pk)]
            peak = max(pk for _, pk in ok)
            if peak <= self.output_limit:
                return float(np.mean([c for c, _ in ok])), peak, u
            if attempt == 0:
                u = u * (0.97 * self.output_limit / peak)
        return math.inf, peak, u


def _random_search(score: _Scorer, families: Sequence[str], candidates: int,
                   rng: np.random.Generator, n: int, fs: float, max_input: float, hold: int
                   ) -> dict[str, _Scored]:
    """The best of ``candidates`` random inputs of each family, by family."""
    best: dict[str, _Scored] = {}
    for family in families:
        for _ in range(int(candidates)):
            u = _candidate(family, rng, n, fs, max_input, hold)
            if u is None:
                continue
            value, peak, used = score(u)
            if value < best.get(family, (math.inf,))[0]:
                best[family] = (value, peak, used, family)
    if not best or all(not math.isfinite(b[0]) for b in best.values()):
        raise ParameterError("no candidate input keeps the output within the limit; "
                             "raise output_limit or lower max_input")
    return best


def _hold_edges(u: np.ndarray) -> np.ndarray:
    """Sample indices where the holds of ``u`` start, and its length."""
    return np.concatenate([[0], np.flatnonzero(np.diff(u) != 0) + 1, [u.size]])


def _local_search(score: _Scorer, start: _Scored, steps: int, rng: np.random.Generator,
                  max_input: float, hold: int) -> _Scored:
    """Improve a piecewise-constant candidate by changing one hold's level at a time."""
    value, peak, u, family = start
    u = u.copy()
    levels = np.array([-1.0, -0.5, 0.5, 1.0]) * max_input
    edges = _hold_edges(u)
    for _ in range(int(steps)):
        k = int(rng.integers(0, edges.size - 1))
        trial = u.copy()
        trial[edges[k]:edges[k + 1]] = rng.choice(levels)
        if shortest_hold(trial) < hold:
            continue
        v, pk, used = score(trial)
        if v < value and np.array_equal(used, np.clip(trial, -max_input, max_input)):
            value, peak, u, family = v, pk, used, "free"
            edges = _hold_edges(u)
    return value, peak, u, family


def _with_validation(info: InformationModel, u_est: np.ndarray, n_val: int,
                     points: list[dict[str, float]], rng: np.random.Generator, fs: float,
                     max_input: float, hold: int, output_limit: float
                     ) -> tuple[np.ndarray, float]:
    """The designed estimation part followed by a validation input of ``n_val`` samples.

    The designed part often ends near the output limit (it uses the range). So the
    validation part first brings the output back towards 0 (a hold at the largest
    input, against the output's sign, until the simulated output is nearest 0),
    then runs the paper's irregular steps (or APRBS) at the largest scale, found
    by bisection, that keeps the whole record, simulated from rest with the
    fitted values and every draw, within ``output_limit``. Returns the record's
    input and its peak ``|y|``.
    """
    head = _complete_last_hold(u_est, n_val, hold)
    head = _back_towards_zero(info, head, u_est.size + n_val, hold, max_input, output_limit)
    rest = u_est.size + n_val - head.size
    best: tuple[float, np.ndarray, float] = (0.0, np.concatenate([head, np.zeros(rest)]), 0.0)
    for attempt in range(8 if rest >= hold else 0):
        v = _candidate("steps" if attempt < 4 else "aprbs", rng, rest, fs, max_input, hold)
        if v is None:
            continue
        best = _largest_scale(info, points, head, v, output_limit, best)
        if best[0] >= 0.5:
            break
    if best[0] == 0.0:  # no validation input fits: rest after the designed part
        return best[1], _peak_over(info, points, best[1])
    return best[1], best[2]


def _complete_last_hold(u_est: np.ndarray, n_val: int, hold: int) -> np.ndarray:
    """``u_est`` with its last hold completed to ``hold`` samples (within ``n_val`` more).

    The record's end may have cut the designed part's last hold; the record goes on, so
    that hold is completed before the validation input starts.
    """
    last = u_est.size - (np.flatnonzero(np.diff(u_est) != 0)[-1] + 1
                         if np.any(np.diff(u_est) != 0) else 0)
    return np.concatenate([u_est, np.full(min(max(0, hold - last), n_val), u_est[-1])])


def _back_towards_zero(info: InformationModel, head: np.ndarray, n_record: int, hold: int,
                       max_input: float, output_limit: float) -> np.ndarray:
    """``head`` and, if its output ends far from 0, the shortest whole number of holds at
    the largest input against the output's sign after which ``|y|`` is smallest (leaving
    at least one hold of the ``n_record`` samples for the validation steps)."""
    y = info.output(head)
    room = n_record - head.size - hold
    if y is None or abs(y[-1]) <= 0.25 * output_limit or room <= hold:
        return head
    back = np.full(room, -np.sign(y[-1]) * max_input)
    y_back = info.output(np.concatenate([head, back]))
    if y_back is None:
        return head
    tail = np.abs(y_back[head.size:])
    k = max(hold, int(math.ceil((int(np.argmin(tail)) + 1) / hold)) * hold)
    return np.concatenate([head, back[:min(k, room)]])


def _peak_over(info: InformationModel, points: list[dict[str, float]], u: np.ndarray) -> float:
    """Largest ``|y|`` over the fitted values and the draws (``inf`` if the fitted values
    diverge; diverging draws are skipped)."""
    peaks = [info.peak(u, vals) for vals in points]
    if not math.isfinite(peaks[0]):
        return math.inf
    return max(pk for pk in peaks if math.isfinite(pk))


def _largest_scale(info: InformationModel, points: list[dict[str, float]], head: np.ndarray,
                   v: np.ndarray, output_limit: float, best: tuple[float, np.ndarray, float]
                   ) -> tuple[float, np.ndarray, float]:
    """``best`` or, if larger, the largest scale of ``v`` after ``head`` (full scale, else
    bisection) within ``output_limit``: (scale, record input, its peak)."""
    lo, hi = 0.0, 1.0
    for scale in [1.0] + [None] * 8:
        scale = scale or 0.5 * (lo + hi)
        u = np.concatenate([head, scale * v])
        pk = _peak_over(info, points, u)
        if pk <= output_limit:
            lo = scale
            if scale > best[0]:
                best = (scale, u, pk)
            if scale == 1.0:
                break
        else:
            hi = scale
    return best
