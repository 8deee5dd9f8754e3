"""The result of a physical fit, its uncertainty, and saving/loading it.

Uncertainty. At the optimum the residual Jacobian ``J = dr/dz`` (exact, from
CasADi) gives the Gauss-Newton covariance of the fitting coordinates,
``cov_z = s^2 (J^T J)^-1`` with ``s^2 = ||r||^2 / (N - n_free)``. 95 % confidence
intervals are ``z +- 1.96 sigma_z`` mapped back to physical units (so they are
asymmetric for log-scaled groups and never cross zero). They assume white
residuals; :mod:`hhra_phys.diagnose` checks that assumption. When ``J^T J`` is
near singular the parameters along its weak directions (eigenvalues below
``1/IDENTIFIABILITY_COND`` of the largest, scaled) are named in a warning and get
no interval (infinite variance, ``(nan, nan)`` in :attr:`FitResult.ci95`): the data
cannot tell them apart, and the pseudo-inverse's finite variance along such a
direction would only reflect its cut-off, not the data. :func:`weak_directions`
lists those directions; :func:`redundant` refuses a candidate whose new parameters
only move along one with a parameter the model already had.

Typed estimates. :attr:`FitResult.estimates` gives every parameter as an
:class:`Estimate` (value, unit, 95 % interval, status ``free``/``fixed``/``at-edge``);
:attr:`FitResult.derived` the quantities the model derives from its parameters
(:meth:`~hhra_phys.model.Model.derived_quantities`, the HHRA's ``a``, ``b``, ``c``,
``kv``) with intervals by the delta method (:func:`derived_estimates`): the exact
gradient of the quantity (CasADi) times the covariance of the free parameters,
:attr:`FitResult.covariance`.

Serialising. :meth:`FitResult.to_json` / :meth:`FitResult.from_json` are the one pair
that turns a result into the fit JSON and back; :meth:`FitResult.save`,
:meth:`FitResult.load`, the CLI and the loop's result
(:meth:`hhra_phys.loop.LoopResult.to_json`) go through them.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import casadi as ca
import numpy as np

from hhra_phys.errors import DataError, ModelError
from hhra_phys.model import DerivedQuantity, Model
from hhra_phys.outputs import atomic_write_text, check_output_path, jsonable
from hhra_phys.simulate import Simulator

__all__ = [
    "Estimate",
    "FitResult",
    "derived_estimates",
    "format_metric",
    "redundant",
    "uncertainty",
    "weak_directions",
]

#: Condition number of the scaled information matrix beyond which parameters are
#: reported as not identifiable from the data.
IDENTIFIABILITY_COND = 1e10
#: |correlation| beyond which a pair is reported as practically not separable.
CORRELATION_LIMIT = 0.999
#: Share of a weak direction (its unit eigenvector's component) from which a
#: parameter counts as involved in it.
WEAK_SHARE = 0.3
#: Two-sided 95 % quantile of the normal distribution (the intervals' half-width in
#: standard deviations).
Z95 = 1.96

Status = Literal["free", "fixed", "at-edge"]


@dataclass(frozen=True)
class Estimate:
    """One estimated (or held) quantity of a fit.

    Attributes
    ----------
    value : float
        The value, in ``unit``.
    unit : str
        Its unit.
    ci95 : (float, float) or None
        95 % confidence interval (``None`` for a fixed quantity; ``(nan, nan)`` when the
        data do not determine it).
    status : {"free", "fixed", "at-edge"}
        ``"fixed"``: held, not fitted (a derived quantity: it depends on no free
        parameter); ``"at-edge"``: fitted, but it ended at an edge of its box (for a
        derived quantity: one of the free parameters it depends on did), so the
        value and interval are not meaningful; ``"free"``: fitted.
    std : float or None
        Standard deviation in ``unit`` (linearised; ``None`` when not computed).
    description : str
        What it is (derived quantities).
    """

    value: float
    unit: str = ""
    ci95: tuple[float, float] | None = None
    status: Status = "free"
    std: float | None = None
    description: str = ""

    @property
    def free(self) -> bool:
        """Fitted (``"free"`` or ``"at-edge"``), not held."""
        return self.status != "fixed"

    @property
    def determined(self) -> bool:
        """Has a finite interval."""
        return self.ci95 is not None and all(math.isfinite(c) for c in self.ci95)

    def to_json(self) -> dict[str, Any]:
        """``value``, ``unit``, ``ci95`` (``None`` for fixed, ``[null, null]``
        undetermined), ``free``, ``status``, and ``std``/``description`` when set."""
        out: dict[str, Any] = {"value": self.value, "unit": self.unit,
                               "ci95": list(self.ci95) if self.ci95 is not None else None,
                               "free": self.free, "status": self.status}
        if self.std is not None:
            out["std"] = self.std
        if self.description:
            out["description"] = self.description
        return out

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Estimate:
        """The estimate of :meth:`to_json` (``null`` numbers read as NaN)."""
        ci = d.get("ci95")
        status = d.get("status") or ("free" if d.get("free", True) else "fixed")
        std = d.get("std")
        return cls(value=_num(d["value"]), unit=d.get("unit", ""),
                   ci95=None if ci is None else (_num(ci[0]), _num(ci[1])),
                   status=status, std=None if "std" not in d else _num(std),
                   description=d.get("description", ""))


def derived_estimates(
    quantities: Mapping[str, DerivedQuantity],
    values: Mapping[str, float],
    free: Sequence[str],
    covariance: np.ndarray | None,
    at_edge: Sequence[str] = (),
) -> dict[str, Estimate]:
    """Values and 95 % intervals of derived quantities by the delta method.

    Each quantity ``g(theta)`` is built once with CasADi symbols for the free
    parameters (every other parameter at its value), its exact gradient ``dg`` taken
    by automatic differentiation, and its variance is ``dg C dg^T`` with ``C`` the
    covariance of the free parameters (physical units). The delta method is invariant
    to the fitting coordinates to first order, so the log-scaled groups need no
    special care. A quantity declared ``positive`` gets its interval on its logarithm,
    ``g exp(+-1.96 sd/g)``; the others ``g +- 1.96 sd``.

    Parameters
    ----------
    quantities : mapping of str to DerivedQuantity
        What to derive (:meth:`~hhra_phys.model.Model.derived_quantities`).
    values : mapping of str to float
        Every parameter the quantities use, by name.
    free : sequence of str
        Names of the free parameters, in the order of ``covariance``; names that are
        not keys of ``values`` (initial states, another record's parameters) are
        skipped.
    covariance : ndarray, shape (len(free), len(free)), or None
        Covariance of the free parameters, physical units (``inf``/``nan`` where the
        data do not determine them). ``None``: no intervals.
    at_edge : sequence of str
        Free parameters that ended at a box edge (their quantities are ``"at-edge"``).

    Returns
    -------
    dict of str to Estimate
        A quantity that uses an undetermined parameter has interval ``(nan, nan)``;
        one that uses no free parameter is ``"fixed"``; one that cannot be
        evaluated (a parameter missing) is left out.
    """
    idx = [i for i, n in enumerate(free) if n in values]
    names = [free[i] for i in idx]
    sym = ca.SX.sym("theta", len(names))
    env: dict[str, Any] = dict(values)
    env.update({n: sym[k] for k, n in enumerate(names)})
    point = np.array([float(values[n]) for n in names])
    cov = (np.asarray(covariance, dtype=float)[np.ix_(idx, idx)] if covariance is not None
           else None)
    out: dict[str, Estimate] = {}
    for key, q in quantities.items():
        try:
            expr = ca.SX(q.function(env))
        except (KeyError, TypeError):
            continue
        fn = ca.Function("g", [sym], [expr, ca.jacobian(expr, sym)])
        val, grad = (np.asarray(a, dtype=float).ravel() for a in fn(point))
        out[key] = _delta(q, float(val[0]), grad, cov,
                          [names[k] for k in np.flatnonzero(grad)], at_edge)
    return out


def _delta(q: DerivedQuantity, value: float, grad: np.ndarray, cov: np.ndarray | None,
           uses: list[str], at_edge: Sequence[str]) -> Estimate:
    """The :class:`Estimate` of one derived quantity from its gradient."""
    if not uses:
        return Estimate(value, q.unit, None, "fixed", None, q.description)
    status: Status = "at-edge" if any(n in at_edge for n in uses) else "free"
    if cov is None:
        return Estimate(value, q.unit, None, status, None, q.description)
    used = np.flatnonzero(grad)
    sub = cov[np.ix_(used, used)]
    if not np.all(np.isfinite(sub)):  # a parameter the data do not determine
        return Estimate(value, q.unit, (math.nan, math.nan), status, math.inf, q.description)
    sd = float(math.sqrt(max(float(grad[used] @ sub @ grad[used]), 0.0)))
    if q.positive and value > 0:
        # exp of a huge relative spread (a quantity the fit hardly determines) overflows:
        # its upper end is then infinite, not an error.
        with np.errstate(over="ignore"):
            spread = float(np.exp(Z95 * sd / value))
        ci = (value / spread, value * spread)
    else:
        ci = (value - Z95 * sd, value + Z95 * sd)
    return Estimate(value, q.unit, ci, status, sd, q.description)


def physical_covariance(cov_z: np.ndarray, slopes: np.ndarray) -> np.ndarray:
    """Covariance in physical units from the fitting coordinates' (``D cov_z D``).

    Parameters
    ----------
    cov_z : ndarray, shape (n, n)
        Covariance of the fitting coordinates (:func:`uncertainty`).
    slopes : ndarray, shape (n,)
        ``d theta_i / d z_i`` at the optimum (the coordinate maps are elementwise).
    """
    d = np.asarray(slopes, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.asarray(cov_z, dtype=float) * np.outer(d, d)


def weak_directions(J: np.ndarray, names: list[str]) -> list[dict[str, Any]]:
    """Directions of parameter space the data cannot determine.

    Parameters
    ----------
    J : ndarray, shape (N, n)
        Residual Jacobian at the optimum (fitting coordinates).
    names : list of str
        Free parameter names.

    Returns
    -------
    list of dict
        One per eigenvector of the scaled information matrix ``J^T J`` whose
        eigenvalue is below ``1/IDENTIFIABILITY_COND`` of the largest, weakest first:
        ``condition`` (largest eigenvalue over this one), ``params`` (name to the
        eigenvector's component, for components of at least ``WEAK_SHARE``) and
        ``reason`` (words). Parameters the output does not see at all are one
        direction each (``condition`` ``inf``). Empty when the matrix is well
        conditioned or not finite.
    """
    J = np.asarray(J, dtype=float)
    if J.ndim != 2 or J.shape[1] == 0 or not np.all(np.isfinite(J)):
        return []
    info = J.T @ J
    scale = np.sqrt(np.diag(info))
    out: list[dict[str, Any]] = []
    dead = ~(np.isfinite(scale) & (scale > 0))
    for i in np.flatnonzero(dead):
        out.append({"condition": float("inf"), "params": {names[i]: 1.0},
                    "reason": f"{names[i]} does not change the output at the optimum"})
    live = np.flatnonzero(~dead)
    if live.size < 2:
        return out
    normed = info[np.ix_(live, live)] / np.outer(scale[live], scale[live])
    eigval, eigvec = np.linalg.eigh(normed)
    top = max(float(eigval[-1]), np.finfo(float).tiny)
    for k in range(live.size):
        lam = float(eigval[k])
        cond = top / lam if lam > 0 else float("inf")  # rounding can make it <= 0
        if cond <= IDENTIFIABILITY_COND:
            break
        v = eigvec[:, k] / np.max(np.abs(eigvec[:, k]))
        v = v * np.sign(v[np.argmax(np.abs(v))])
        weights = {names[live[i]]: float(v[i]) for i in np.argsort(-np.abs(v))
                   if abs(eigvec[i, k]) >= WEAK_SHARE}
        if len(weights) < 1:
            continue
        combo = " with ".join(f"{n} ({w:+.3g})" for n, w in weights.items())
        out.append({"condition": float(cond), "params": weights,
                    "reason": f"moving {combo} together leaves the output unchanged "
                              f"(information-matrix condition {cond:.2g}): the data cannot "
                              "tell them apart"})
    return out


def redundant(result: FitResult, new_params: list[str] | tuple[str, ...]) -> str | None:
    """Why a candidate only reparametrises the model, or ``None`` if it does not.

    A candidate's new parameters (a discovered term's coefficients, an effect's
    parameters) are redundant when the fit with them has a direction the data
    cannot determine (:func:`weak_directions`, recorded in
    ``result.intervals["weak_directions"]``) that joins a new parameter with one the
    model already had: the candidate then changes nothing the model could not
    already do (a term ``a*u`` beside an input gain), and whatever gain it shows is
    the refit's, not the term's. A high correlation alone is not enough (an
    integrating plant's initial state and an output offset are correlated near 1
    on one record and still separate through position-dependent terms).

    Parameters
    ----------
    result : FitResult
        The candidate's fit.
    new_params : sequence of str
        The candidate's new parameter names.

    Returns
    -------
    str or None
        The reason (naming the parameters and the condition), or ``None``.
    """
    new = [n for n in new_params if n in result.free]
    old = [n for n in result.free if n not in new]
    for d in result.intervals.get("weak_directions", []):
        involved = list(d.get("params", {}))
        a = [n for n in involved if n in new]
        b = [n for n in involved if n in old]
        if a and b:
            return (f"only reparametrises the model ({', '.join(a)} against "
                    f"{', '.join(b)}): {d['reason']}")
    return None

FORMAT_NAME = "hhra-phys fit result"
FORMAT_VERSION = 1


def uncertainty(
    J: np.ndarray, r: np.ndarray, names: list[str]
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Gauss-Newton covariance in fitting coordinates, correlation matrix, warnings.

    Parameters
    ----------
    J : ndarray, shape (N, n)
        Residual Jacobian at the optimum (fitting coordinates).
    r : ndarray, shape (N,)
        Residuals at the optimum.
    names : list of str
        Free parameter names (for the warnings).

    Returns
    -------
    cov : ndarray, shape (n, n)
        Covariance of the fitting coordinates (``inf`` on the diagonal of
        unidentifiable directions).
    corr : ndarray, shape (n, n)
        Correlation matrix.
    warnings : list of str
    """
    n_obs, n = J.shape
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        # A diverged simulation: no curvature to read, every interval is undetermined.
        cov = np.full((n, n), np.nan)
        np.fill_diagonal(cov, np.inf)
        return cov, np.eye(n), [
            "the residual or its Jacobian is not finite at the result (the simulation "
            "diverges there): confidence intervals are undetermined"]
    s2 = float(r @ r) / max(n_obs - n, 1)
    info = J.T @ J
    scale = np.sqrt(np.diag(info))
    dead = ~(np.isfinite(scale) & (scale > 0))
    warnings: list[str] = []
    if dead.any():
        warnings.append(
            f"parameters {', '.join(names[i] for i in np.flatnonzero(dead))} do not affect the "
            "output at the optimum: not identifiable from these data (intervals undetermined)"
        )
        scale = np.where(dead, 1.0, scale)
    normed = info / np.outer(scale, scale)
    eigval, eigvec = np.linalg.eigh(normed)
    with np.errstate(over="ignore"):  # an exactly singular matrix: condition inf
        cond = eigval[-1] / max(eigval[0], np.finfo(float).tiny)
    weak = cond > IDENTIFIABILITY_COND and not dead.all()
    if weak:
        w = np.abs(eigvec[:, 0])
        involved = [names[i] for i in np.argsort(-w) if w[i] > 0.3]
        warnings.append(
            f"information matrix near singular (condition {cond:.2e}): "
            f"{', '.join(involved)} are not identifiable separately from these data"
        )
    cov = s2 * _inverse(normed, singular=cond > IDENTIFIABILITY_COND or dead.any()) / np.outer(
        scale, scale)
    # A parameter the output does not see has no variance to report: infinite, so its
    # interval is marked undetermined rather than given the pseudo-inverse's zero.
    cov[dead, :] = np.nan
    cov[:, dead] = np.nan
    cov[dead, dead] = np.inf
    corr = _correlation(cov)
    # Parameters along a direction the data cannot determine: the pseudo-inverse
    # gives them a finite variance set by its cut-off, not by the data. Their
    # correlations are kept from it (they say which parameters trade off), their
    # variances become infinite (no interval).
    unresolved = _unresolved(eigval, eigvec) & ~dead if weak else np.zeros(n, dtype=bool)
    if unresolved.any():
        cov[unresolved, unresolved] = np.inf
        warnings.append(
            f"{', '.join(names[i] for i in np.flatnonzero(unresolved))}: no confidence "
            "interval, the data do not determine them (a direction of the information "
            "matrix with condition above "
            f"{IDENTIFIABILITY_COND:.0e}; see the warning above)")
    warnings += [f"{names[i]} and {names[j]} are correlated {corr[i, j]:+.4f}: "
                 "the data hardly separate them"
                 for i in range(n) for j in range(i + 1, n)
                 if abs(corr[i, j]) > CORRELATION_LIMIT]
    return cov, corr, warnings


def _inverse(normed: np.ndarray, singular: bool) -> np.ndarray:
    """Inverse of the scaled information matrix (pseudo-inverse when singular)."""
    if not singular:
        try:
            return np.linalg.inv(normed)
        except np.linalg.LinAlgError:  # exactly singular although well scaled
            pass
    return np.linalg.pinv(normed, rcond=1e-12)


def _unresolved(eigval: np.ndarray, eigvec: np.ndarray) -> np.ndarray:
    """Parameters with a share of at least ``WEAK_SHARE`` in a too-weak direction."""
    out = np.zeros(eigval.size, dtype=bool)
    for k in range(eigval.size):
        with np.errstate(over="ignore"):  # an exactly singular direction: condition inf
            cond = eigval[-1] / max(eigval[k], np.finfo(float).tiny)
        if cond <= IDENTIFIABILITY_COND:
            break
        out |= np.abs(eigvec[:, k]) >= WEAK_SHARE
    return out


def _correlation(cov: np.ndarray) -> np.ndarray:
    """Correlation matrix of ``cov`` (0 where a variance is not finite)."""
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    corr = np.where(np.isfinite(np.outer(sd, sd)), corr, 0.0)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    return corr


@dataclass
class FitResult:
    """Everything a fit produced, enough to reproduce and reuse it.

    Attributes
    ----------
    model_spec : dict
        The model (:meth:`Model.to_json`), rebuilt by :attr:`model`.
    values : dict of str to float
        Every model parameter (free and fixed), physical units.
    free : list of str
        Names of the fitted parameters (may include ``x0_theta``).
    units : dict of str to str
        Unit of each parameter.
    ci95 : dict of str to (float, float)
        95 % confidence interval of each free parameter (physical units):
        linearised (Gauss-Newton) by default, profile likelihood when the fit
        asked for ``intervals="profile"`` (see :attr:`intervals`).
    std : dict of str to float
        Standard deviation in fitting coordinates (log10 units for log groups).
    correlation : ndarray
        Correlation matrix of the free parameters.
    warnings : list of str
        Identifiability warnings and anything else the user must know.
    metrics : dict
        ``{"est": {...}, "val": {...}}`` from :func:`hhra_phys.metrics.score` of
        the free-run simulation (``val`` empty without validation data).
    stages : list of dict
        Per stage (global search, refiners): name, cost before/after, evaluations,
        seconds and solver info.
    history : list of float
        Best global-search cost per iteration.
    tf : dict
        The paper's linearised transfer function ``kv / (a s^3 + b s^2 + c s)``
        at rest, from the fitted groups (``a = 1``; only ratios are identifiable).
    x0 : dict
        Initial state used on the estimation record.
    settings : dict
        What reproduces the fit: optimiser, refiner, population, iterations,
        cost, ``lam``, split, free and fixed parameters, data description.
    seed : int or None
        Seed of the global search.
    physical : dict or None
        Physical symbols recovered from the groups with a datasheet (see
        :meth:`hhra_phys.models.hhra.physical.PhysicalParameters.from_groups`), if one was given.
    problem : Problem or None
        The live fitting problem (model, estimation data, simulator) the result
        came from; ``None`` for a result read with :meth:`load` (the model is then
        rebuilt from :attr:`model_spec`). Not saved.
    intervals : dict
        How :attr:`ci95` was obtained: ``{"method": "linear"}``, or for profile
        intervals ``{"method": "profile", "linear": {name: [lo, hi]}, "open_ends":
        {name: [lower, upper]}, "solves": n, "seconds": s}`` (the linearised
        intervals kept for comparison). ``"undetermined"`` lists the parameters whose
        interval could not be computed (singular information matrix, diverged
        simulation); their :attr:`ci95` is ``(nan, nan)`` (``[null, null]`` in JSON).
    status : {"ok", "diverged"}
        ``"diverged"`` when the simulation with the fitted parameters does not stay
        finite on the estimation record: the values are where the search stopped, the
        metrics are not finite and the result must not be used (a warning says why).
    records : list of dict
        One entry per record (name, sizes, initial state, per-record values, ``est`` and
        ``val`` metrics), then one per whole validation record (:func:`hhra_phys.fit.fit`).
    covariance : ndarray or None
        Linearised covariance of the free parameters in physical units, in the order
        of :attr:`free` (``inf`` on the diagonal of parameters the data do not
        determine); ``None`` for a result saved before it was kept.
    derived : dict of str to Estimate
        The model's derived quantities (:meth:`~hhra_phys.model.Model.derived_quantities`;
        the HHRA's transfer-function coefficients ``a``, ``b``, ``c``, ``kv``) with 95 %
        intervals by the delta method (:func:`derived_estimates`).
    """

    model_spec: dict[str, Any]
    values: dict[str, float]
    free: list[str]
    units: dict[str, str]
    ci95: dict[str, tuple[float, float]]
    std: dict[str, float]
    correlation: np.ndarray
    warnings: list[str]
    metrics: dict[str, dict[str, float]]
    stages: list[dict[str, Any]]
    history: list[float]
    tf: dict[str, float]
    x0: dict[str, float]
    settings: dict[str, Any]
    seed: int | None
    physical: dict[str, float] | None = None
    created: str = field(default_factory=lambda: time.strftime("%Y-%m-%dT%H:%M:%S"))
    intervals: dict[str, Any] = field(default_factory=lambda: {"method": "linear"})
    problem: Any = field(default=None, repr=False, compare=False)
    status: str = "ok"
    records: list[dict[str, Any]] = field(default_factory=list)
    covariance: np.ndarray | None = field(default=None, repr=False)
    derived: dict[str, Estimate] = field(default_factory=dict)

    # -- reuse ------------------------------------------------------------------------
    @property
    def model(self) -> Model:
        """The fitted model: the live one of :attr:`problem`, or rebuilt from its specification."""
        if self.problem is not None:
            return self.problem.model
        cached = self.__dict__.get("_model")
        if cached is None:
            cached = Model.from_json(self.model_spec)
            self.__dict__["_model"] = cached
        return cached

    def __getstate__(self) -> dict[str, Any]:
        # The live problem holds compiled code (ctypes handles) that cannot cross a
        # process boundary: a pickled result (fit_many on an executor) carries its
        # specification and rebuilds the model on the other side.
        state = dict(self.__dict__)
        state["problem"] = None
        state.pop("_model", None)
        state.pop("_sims", None)
        return state

    def simulator(self, fs: float | None = None, intersample: str | None = None) -> Simulator:
        """A simulator of the fitted model at ``fs`` [Hz] (the fit's own when it matches).

        ``intersample`` (``"zoh"`` or ``"foh"``, default: the fit's record's) says what
        the input does between samples.
        """
        fs = float(fs or self.settings["fs"])
        kind = intersample or self.settings.get("intersample", "zoh")
        pr = self.problem
        if pr is not None and abs(pr.sim.fs - fs) <= 1e-9 * fs:
            return pr.sim.with_intersample(kind)
        sims = self.__dict__.setdefault("_sims", {})
        if fs not in sims:
            # The fit's method and substeps (a result saved before methods existed
            # used RK4 or the automatic choice); a single parameter vector is still
            # refined if the stability check fails for it (Simulator.for_parameters).
            sims[fs] = Simulator(self.model, fs=fs,
                                 substeps=self.settings.get("substeps", "auto"),
                                 method=self.settings.get("method", "auto"))
        return sims[fs].with_intersample(kind)

    def parameter_vector(self) -> np.ndarray:
        """Full parameter vector in the model's order."""
        model = self.model
        return np.array([self.values[n] for n in model.params.names])

    def simulate(
        self, u: np.ndarray, fs: float | None = None, x0: np.ndarray | dict | None = None
    ) -> np.ndarray:
        """Simulate the fitted model on a new input.

        Parameters
        ----------
        u : array, shape (N,)
            Input (valve current [mA] for the HHRA).
        fs : float, optional
            Sample rate [Hz] (default: the fit's).
        x0 : array or dict, optional
            Initial state (default: rest, the model's ``x0``).

        Returns
        -------
        ndarray, shape (N,)
        """
        model = self.model
        sim = self.simulator(fs)
        if isinstance(x0, dict):
            x = model.x0()
            for k, v in x0.items():
                x[model.state_names.index(k)] = v
            x0 = x
        return sim.simulate(np.asarray(u, dtype=float), self.parameter_vector(), x0=x0)

    def predict(self, data: Any, estimate_x0: bool = True) -> np.ndarray:
        """Free-run prediction of a record's output from its input.

        Parameters
        ----------
        data : Dataset
            Any record of the same actuator (e.g. unseen validation data).
        estimate_x0 : bool
            Estimate the initial state on the record by least squares with the
            parameters fixed (default), or start at rest from the first sample.

        Returns
        -------
        ndarray, shape (N,)
        """
        from hhra_phys.problem import estimate_initial_state, initial_guess

        model = self.model
        sim = self.simulator(data.fs, data.intersample)
        p = self.parameter_vector()
        x0 = initial_guess(model, float(data.y[0]), p, float(data.u[0]), 1.0 / data.fs)
        if estimate_x0:
            x0 = estimate_initial_state(sim, data.u, data.y, p, x0)
        return sim.simulate(data.u, p, x0=x0)

    @property
    def estimates(self) -> dict[str, Estimate]:
        """Every parameter as an :class:`Estimate`: the model's (free and fixed), then the
        fitted initial-state and per-record parameters."""
        edges = self.intervals.get("at_edge", {})
        names = list(self.values) + [n for n in self.free if n not in self.values]
        sd = self._physical_std()
        out = {}
        for name in names:
            value = self.values[name] if name in self.values else self.x0_param(name)
            unit = self.units.get(name, "")
            if name not in self.free:
                out[name] = Estimate(value, unit, None, "fixed")
                continue
            ci = self.ci95.get(name, (math.nan, math.nan))
            out[name] = Estimate(value, unit, (float(ci[0]), float(ci[1])),
                                 "at-edge" if name in edges else "free", sd.get(name))
        return out

    def _physical_std(self) -> dict[str, float]:
        if self.covariance is None or np.shape(self.covariance) != (len(self.free),) * 2:
            return {}
        var = np.diag(np.asarray(self.covariance, dtype=float))
        return {n: float(math.sqrt(v)) if v >= 0 else math.nan
                for n, v in zip(self.free, var, strict=True)}

    @property
    def params(self) -> dict[str, dict[str, Any]]:
        """``{name: {"value", "unit", "ci95", "free", "status"}}`` for every parameter
        (the fit JSON's ``params``; :attr:`estimates` as dictionaries)."""
        out = {}
        for name, est in self.estimates.items():
            out[name] = {"value": est.value, "unit": est.unit,
                         "ci95": list(est.ci95) if est.ci95 is not None else None,
                         "free": est.free, "status": est.status}
        return out

    def x0_param(self, name: str) -> float:
        """Value of a fitted initial-state parameter ``x0_<state>``.

        Also of a per-record parameter of a multi-record fit,
        ``x0_<state>_rec<k>`` or ``<name>_rec<k>`` (record ``k`` from 1).
        """
        from hhra_phys.parameters import split_record_name

        base, k = split_record_name(name)
        if k is not None and k <= len(self.records):
            rec = self.records[k - 1]
            if base.startswith("x0_") and base[3:] in rec.get("x0", {}):
                return float(rec["x0"][base[3:]])
            return float(rec["values"][base])
        return float(self.x0[name[3:]])

    # -- reporting ----------------------------------------------------------------------------
    def summary(self) -> str:
        """A plain-text table: parameter, value, unit, 95 % CI; then the metrics."""
        head = "95 % CI" + (" (profile)" if self.intervals.get("method") == "profile" else "")
        lines = [f"{'parameter':<12} {'value':>13} {'unit':<10} {head:>29}"]
        for name, info in self.params.items():
            if not info["free"] and info["value"] == 0.0:
                continue
            ci = info["ci95"]
            ci_text = "fixed" if not ci else (
                f"[{ci[0]:.6g}, {ci[1]:.6g}]" if _finite(ci) else "undetermined")
            lines.append(f"{name:<12} {info['value']:>13.6g} {info['unit']:<10} {ci_text:>29}")
        lines += self._derived_lines()
        fm = format_metric
        for part in ("est", "val"):
            m = self.metrics.get(part) or {}
            if m:
                lines.append(
                    f"{'estimation' if part == 'est' else 'validation':<10}: "
                    f"RMSE {fm(m.get('rmse'))}, VAF {fm(m.get('vaf'), '.4f')} %, "
                    f"MSE {fm(m.get('mse'))}, ITAE {fm(m.get('itae'))}"
                )
        if self.status != "ok":
            lines.append(f"status: {self.status.upper()} (see the warnings; do not use these "
                         "values)")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def _derived_lines(self) -> list[str]:
        """The summary's rows of derived quantities (delta-method intervals)."""
        if not self.derived:
            return []
        lines = [f"{'derived':<12} {'value':>13} {'unit':<10} {'95 % CI (delta method)':>29}"]
        for name, est in self.derived.items():
            ci = est.ci95
            ci_text = ("fixed" if ci is None else
                       f"[{ci[0]:.6g}, {ci[1]:.6g}]" if est.determined else "undetermined")
            lines.append(f"{name:<12} {est.value:>13.6g} {est.unit:<10} {ci_text:>29}")
        return lines

    # -- persistence --------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """The fit JSON (strict JSON types, NaN and infinities as ``null``).

        Its keys are kept across versions (outside checks use ``params`` -> ``value``,
        ``ci95``, ``free``); ``derived`` holds the derived quantities
        (:attr:`derived`), ``covariance`` the free parameters' (:attr:`covariance`).
        :meth:`from_json` reads it back.
        """
        return jsonable({
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "status": self.status,
            "params": self.params,
            "derived": {k: v.to_json() for k, v in self.derived.items()},
            "tf": self.tf,
            "est": self.metrics.get("est", {}),
            "val": self.metrics.get("val", {}),
            "stages": self.stages,
            "seed": self.seed,
            "free": self.free,
            "std_fit_coordinates": self.std,
            "correlation": np.asarray(self.correlation).tolist(),
            "covariance": (None if self.covariance is None
                           else np.asarray(self.covariance).tolist()),
            "warnings": self.warnings,
            "history": self.history,
            "x0": self.x0,
            "settings": self.settings,
            "physical": self.physical,
            "model": self.model_spec,
            "created": self.created,
            "intervals": self.intervals,
            **({"records": self.records} if self.records else {}),
        })

    @classmethod
    def from_json(cls, d: Mapping[str, Any], source: str = "fit result") -> FitResult:
        """The result of :meth:`to_json`'s dictionary; the model is rebuilt from it.

        ``null`` numbers (NaN, infinities) come back as NaN. ``source`` names the
        input in errors.

        Raises
        ------
        DataError
            Not a fit result (no ``format``), or a key it needs is missing.
        """
        _check_header(d, source)
        try:
            params = d["params"]
            model = _model_of(d["model"], source)
            values = _values(params, model, source)
            free = _free_names(d["free"], model, source)
        except KeyError as exc:
            raise DataError(f"{source}: not a complete hhra-phys fit result (no {exc}); "
                            "give the JSON a fit wrote (FitResult.save, 'hhra-phys fit "
                            "--json')") from None
        cov = d.get("covariance")
        _check_covariance(cov, len(free), source)
        _check_records(d.get("records"), source)
        return cls(
            model_spec=d["model"],
            values=values,
            free=free,
            units={n: v["unit"] for n, v in params.items()},
            ci95={n: (_num(v["ci95"][0]), _num(v["ci95"][1]))
                  for n, v in params.items() if v.get("ci95")},
            std=d.get("std_fit_coordinates", {}),
            correlation=np.array(d.get("correlation", [])),
            warnings=list(d.get("warnings", [])),
            metrics={"est": d.get("est", {}), "val": d.get("val", {})},
            stages=list(d.get("stages", [])),
            history=list(d.get("history", [])),
            tf=d.get("tf", {}),
            x0=d.get("x0", {}),
            settings=d.get("settings", {}),
            seed=d.get("seed"),
            physical=d.get("physical"),
            created=d.get("created", ""),
            intervals=d.get("intervals", {"method": "linear"}),
            status=d.get("status", "ok"),
            records=list(d.get("records", [])),
            covariance=None if cov is None else np.array(
                [[_num(c) for c in row] for row in cov], dtype=float).reshape(
                    len(free), len(free)),
            derived={k: Estimate.from_json(v) for k, v in (d.get("derived") or {}).items()},
        )

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the result as JSON (:meth:`to_json`); an existing file is kept unless
        ``overwrite``."""
        p = check_output_path(path, overwrite=overwrite, what="fit result")
        atomic_write_text(p, json.dumps(self.to_json(), indent=1))
        return p

    @classmethod
    def load(cls, path: str | Path) -> FitResult:
        """Read a result written by :meth:`save` (:meth:`from_json`); the model is rebuilt."""
        p = Path(path)
        if not p.exists():
            raise DataError(f"{p}: no such fit result file")
        try:
            d = json.loads(p.read_text())
        except json.JSONDecodeError as exc:
            raise DataError(f"{p}: not a JSON fit result ({exc})") from None
        if not isinstance(d, dict):
            raise DataError(f"{p}: not an hhra-phys fit result (missing 'format')")
        return cls.from_json(d, source=str(p))


#: A saved value this many times beyond its parameter's box is refused: no fit ends there
#: (a box is widened by a few decades at most), and the model's Jacobian overflows.
FAR_OUTSIDE = 1e12

_EDIT = "; give the JSON a fit wrote (FitResult.save, 'hhra-phys fit --json'), unedited"


def _check_header(d: Mapping[str, Any], source: str) -> None:
    """``format`` and ``version`` of a fit result: present, ours, and one this reads."""
    if "format" not in d:
        raise DataError(f"{source}: not an hhra-phys fit result (missing 'format')")
    if d["format"] != FORMAT_NAME:
        raise DataError(f"{source}: 'format' is {d['format']!r:.60}, not {FORMAT_NAME!r}: "
                        "not an hhra-phys fit result")
    version = d.get("version", FORMAT_VERSION)
    if isinstance(version, bool) or not isinstance(version, int) or not (
            1 <= version <= FORMAT_VERSION):
        raise DataError(f"{source}: 'version' is {version!r:.40}; this hhra-phys reads fit "
                        f"results of version 1 to {FORMAT_VERSION}{_EDIT}")


def _model_of(spec: Any, source: str) -> Model:
    """The model of a fit result's ``model`` entry; an unknown class is an error (it was
    silently rebuilt as a plain Model)."""
    if not isinstance(spec, Mapping) or not isinstance(spec.get("parts"), list):
        raise DataError(f"{source}: 'model' must be an object with a list of 'parts'{_EDIT}")
    from hhra_phys.model import MODEL_TYPES

    cls = spec.get("class", "Model")
    if cls != "Model" and cls not in MODEL_TYPES:
        raise DataError(f"{source}: 'model.class' {cls!r:.60} is not a known model (known: "
                        f"Model, {', '.join(sorted(MODEL_TYPES))}); import the module that "
                        "defines it first" + _EDIT)
    try:
        return Model.from_json(dict(spec))
    except (TypeError, AttributeError, ValueError) as exc:
        if isinstance(exc, ModelError):
            raise ModelError(f"{source}: 'model': {exc}") from None
        raise DataError(f"{source}: 'model' cannot be rebuilt ({exc}){_EDIT}") from None


def _values(params: Any, model: Model, source: str) -> dict[str, float]:
    """Each model parameter's ``params.NAME.value``: a finite number, positive for a
    log-scaled (positive) quantity."""
    if not isinstance(params, Mapping):
        raise DataError(f"{source}: 'params' must be an object{_EDIT}")
    values = {}
    for par in model.params:
        entry = params[par.name]
        value = entry.get("value") if isinstance(entry, Mapping) else None
        key = f"'params.{par.name}.value'"
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise DataError(f"{source}: {key} must be a number, got {value!r:.40}{_EDIT}")
        if not math.isfinite(value) or (par.scale == "log" and value <= 0):
            raise DataError(f"{source}: {key} is {value!r}; {par.name} is a "
                            + ("positive quantity" if par.scale == "log" else "finite number")
                            + _EDIT)
        span = max(abs(par.lower), abs(par.upper))
        far = (value > par.upper * FAR_OUTSIDE or value < par.lower / FAR_OUTSIDE
               if par.scale == "log" else abs(value) > span * FAR_OUTSIDE)
        if far:  # no fit ends there (boxes widen by a few decades at most)
            raise DataError(f"{source}: {key} is {value!r}, {FAR_OUTSIDE:.0e} times beyond "
                            f"{par.name}'s box [{par.lower:g}, {par.upper:g}]{_EDIT}")
        values[par.name] = float(value)
    return values


def _free_names(free: Any, model: Model, source: str) -> list[str]:
    """``free``: names of the model's parameters or initial states (``x0_<state>``), per
    record or shared."""
    from hhra_phys.parameters import split_record_name

    if not isinstance(free, list) or not all(isinstance(n, str) for n in free):
        raise DataError(f"{source}: 'free' must be a list of names, got {free!r:.60}{_EDIT}")
    known = set(model.params.names) | {f"x0_{s}" for s in model.state_names}
    for name in free:
        if split_record_name(name)[0] not in known:
            raise DataError(f"{source}: 'free' names {name!r}, not a parameter or initial "
                            f"state of the model {model.name!r}{_EDIT}")
    if len(set(free)) != len(free):
        raise DataError(f"{source}: 'free' lists a name twice{_EDIT}")
    return list(free)


def _check_covariance(cov: Any, n: int, source: str) -> None:
    """``covariance``: null, or an n x n list of numbers (null for NaN), n = len(free)."""
    if cov is None:
        return
    ok = isinstance(cov, list) and len(cov) == n and all(
        isinstance(row, list) and len(row) == n and all(
            c is None or (isinstance(c, int | float) and not isinstance(c, bool))
            for c in row) for row in cov)
    if not ok:
        shape = (f"{len(cov)} rows" if isinstance(cov, list) else type(cov).__name__)
        raise DataError(f"{source}: 'covariance' must be a {n} x {n} matrix of numbers (one "
                        f"row and column per name in 'free'), got {shape}{_EDIT}")


def _check_records(records: Any, source: str) -> None:
    """``records``: a list of objects whose ``fs`` (if any) is a sample rate > 0."""
    if records is None:
        return
    if not isinstance(records, list) or not all(isinstance(r, Mapping) for r in records):
        raise DataError(f"{source}: 'records' must be a list of objects{_EDIT}")
    for k, rec in enumerate(records):
        fs = rec.get("fs")
        if fs is not None and (isinstance(fs, bool) or not isinstance(fs, int | float)
                               or not math.isfinite(fs) or fs <= 0):
            raise DataError(f"{source}: 'records[{k}].fs' must be a sample rate > 0 Hz, "
                            f"got {fs!r:.40}{_EDIT}")


def _num(x: Any) -> float:
    """A JSON number; ``null`` (NaN or an infinity when written) as NaN."""
    return math.nan if x is None else float(x)


def _finite(values: Any) -> bool:
    return all(v is not None and np.isfinite(v) for v in values)


def format_metric(value: Any, spec: str = ".4g") -> str:
    """A metric for a summary (``spec``, default four significant digits); a diverged
    fit's missing or non-finite one as ``"-"``."""
    return format(value, spec) if value is not None and np.isfinite(value) else "-"


