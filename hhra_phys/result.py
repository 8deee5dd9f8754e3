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
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.errors import DataError
from hhra_phys.model import Model
from hhra_phys.outputs import atomic_write_text, check_output_path, jsonable
from hhra_phys.simulate import Simulator

__all__ = [
    "FitResult",
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
    dof = max(n_obs - n, 1)
    warnings: list[str] = []
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        # A diverged simulation: no curvature to read, every interval is undetermined.
        warnings.append("the residual or its Jacobian is not finite at the result (the "
                        "simulation diverges there): confidence intervals are undetermined")
        cov = np.full((n, n), np.nan)
        np.fill_diagonal(cov, np.inf)
        return cov, np.eye(n), warnings
    s2 = float(r @ r) / dof
    info = J.T @ J
    scale = np.sqrt(np.diag(info))
    dead = np.array([not (np.isfinite(scale[i]) and scale[i] > 0) for i in range(n)], dtype=bool)
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
    if cond > IDENTIFIABILITY_COND or dead.any():
        if cond > IDENTIFIABILITY_COND and not dead.all():
            weak = np.abs(eigvec[:, 0])
            involved = [names[i] for i in np.argsort(-weak) if weak[i] > 0.3]
            warnings.append(
                f"information matrix near singular (condition {cond:.2e}): "
                f"{', '.join(involved)} are not identifiable separately from these data"
            )
        cov_n = np.linalg.pinv(normed, rcond=1e-12)
    else:
        try:
            cov_n = np.linalg.inv(normed)
        except np.linalg.LinAlgError:  # exactly singular although well scaled
            cov_n = np.linalg.pinv(normed, rcond=1e-12)
    # Parameters along a direction the data cannot determine: the pseudo-inverse
    # gives them a finite variance set by its cut-off, not by the data. Their
    # correlations are kept from it (they say which parameters trade off), their
    # variances become infinite (no interval).
    unresolved = np.zeros(n, dtype=bool)
    if cond > IDENTIFIABILITY_COND and not dead.all():
        for k in range(n):
            if eigval[-1] / max(eigval[k], np.finfo(float).tiny) <= IDENTIFIABILITY_COND:
                break
            unresolved |= np.abs(eigvec[:, k]) >= WEAK_SHARE
        unresolved &= ~dead
    cov = s2 * cov_n / np.outer(scale, scale)
    # A parameter the output does not see has no variance to report: infinite, so its
    # interval is marked undetermined rather than given the pseudo-inverse's zero.
    cov[dead, :] = np.nan
    cov[:, dead] = np.nan
    cov[dead, dead] = np.inf
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    corr = np.where(np.isfinite(np.outer(sd, sd)), corr, 0.0)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    if unresolved.any():
        cov[unresolved, unresolved] = np.inf
        warnings.append(
            f"{', '.join(names[i] for i in np.flatnonzero(unresolved))}: no confidence "
            "interval, the data do not determine them (a direction of the information "
            "matrix with condition above "
            f"{IDENTIFIABILITY_COND:.0e}; see the warning above)")
    for i in range(n):
        for j in range(i + 1, n):
            if abs(corr[i, j]) > CORRELATION_LIMIT:
                warnings.append(
                    f"{names[i]} and {names[j]} are correlated {corr[i, j]:+.4f}: "
                    "the data hardly separate them"
                )
    return cov, corr, warnings


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
    def params(self) -> dict[str, dict[str, Any]]:
        """``{name: {"value", "unit", "ci95", "free"}}`` for every parameter."""
        out = {}
        for name, value in self.values.items():
            ci = self.ci95.get(name)
            out[name] = {
                "value": value,
                "unit": self.units.get(name, ""),
                "ci95": list(ci) if ci is not None else None,
                "free": name in self.free,
            }
        for name in self.free:
            if name not in out:  # initial-state and per-record parameters
                out[name] = {"value": self.x0_param(name), "unit": self.units.get(name, ""),
                             "ci95": list(self.ci95[name]), "free": True}
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
        for part in ("est", "val"):
            m = self.metrics.get(part) or {}
            if m:
                lines.append(
                    f"{'estimation' if part == 'est' else 'validation':<10}: "
                    f"RMSE {_fmt(m.get('rmse'))}, VAF {_fmt(m.get('vaf'), '.4f')} %, "
                    f"MSE {_fmt(m.get('mse'))}, ITAE {_fmt(m.get('itae'))}"
                )
        if self.status != "ok":
            lines.append(f"status: {self.status.upper()} (see the warnings; do not use these "
                         "values)")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    # -- persistence --------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """JSON-able dictionary (the layout the CLI writes)."""
        return {
            "format": "hhra-phys fit result",
            "version": FORMAT_VERSION,
            "status": self.status,
            "params": self.params,
            "tf": self.tf,
            "est": self.metrics.get("est", {}),
            "val": self.metrics.get("val", {}),
            "stages": self.stages,
            "seed": self.seed,
            "free": self.free,
            "std_fit_coordinates": self.std,
            "correlation": np.asarray(self.correlation).tolist(),
            "warnings": self.warnings,
            "history": self.history,
            "x0": self.x0,
            "settings": self.settings,
            "physical": self.physical,
            "model": self.model_spec,
            "created": self.created,
            "intervals": self.intervals,
            **({"records": self.records} if self.records else {}),
        }

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the result as JSON; an existing file is kept unless ``overwrite``."""
        p = check_output_path(path, overwrite=overwrite, what="fit result")
        atomic_write_text(p, json.dumps(jsonable(self.to_json()), indent=1))
        return p

    @classmethod
    def load(cls, path: str | Path) -> FitResult:
        """Read a result written by :meth:`save`; the model is rebuilt from it."""
        p = Path(path)
        if not p.exists():
            raise DataError(f"{p}: no such fit result file")
        try:
            d = json.loads(p.read_text())
        except json.JSONDecodeError as exc:
            raise DataError(f"{p}: not a JSON fit result ({exc})") from None
        if d.get("format") != "hhra-phys fit result":
            raise DataError(f"{p}: not an hhra-phys fit result (missing 'format')")
        params = d["params"]
        model = Model.from_json(d["model"])
        values = {n: float(params[n]["value"]) for n in model.params.names}
        return cls(
            model_spec=d["model"],
            values=values,
            free=list(d["free"]),
            units={n: v["unit"] for n, v in params.items()},
            ci95={n: tuple(np.nan if c is None else c for c in v["ci95"])
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
        )


def _finite(values: Any) -> bool:
    return all(v is not None and np.isfinite(v) for v in values)


def _fmt(value: Any, spec: str = ".4g") -> str:
    """A metric for the summary; a diverged fit's missing or non-finite one as "-"."""
    return format(value, spec) if value is not None and np.isfinite(value) else "-"


