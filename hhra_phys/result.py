"""The result of a physical fit, its uncertainty, and saving/loading it.

Uncertainty. At the optimum the residual Jacobian ``J = dr/dz`` (exact, from
CasADi) gives the Gauss-Newton covariance of the fitting coordinates,
``cov_z = s^2 (J^T J)^-1`` with ``s^2 = ||r||^2 / (N - n_free)``. 95 % confidence
intervals are ``z +- 1.96 sigma_z`` mapped back to physical units (so they are
asymmetric for log-scaled groups and never cross zero). They assume white
residuals; :mod:`hhra_phys.diagnosis.residual` checks that assumption. When ``J^T J`` is
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
(:meth:`hhra_phys.diagnosis.result.DiagnosisResult.to_json`) go through them.

Where the code is: :class:`FitResult` here; the uncertainty's linear algebra in
:mod:`hhra_phys.identifiability`, typed estimates in :mod:`hhra_phys.estimates`, the fit
JSON's checks in :mod:`hhra_phys.result_json` (issue 34: short modules). Their names are
importable from here too.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.errors import DataError

# Typed estimates, identifiability and the fit JSON's checks live in modules of their own
# (issue 34); their names stay importable from here.
from hhra_phys.estimates import (  # noqa: F401  (re-exported)
    Z95,
    Estimate,
    Status,
    _delta,
    _num,
    derived_estimates,
    physical_covariance,
)
from hhra_phys.identifiability import (  # noqa: F401  (re-exported)
    CORRELATION_LIMIT,
    IDENTIFIABILITY_COND,
    WEAK_SHARE,
    _correlation,
    _inverse,
    _unresolved,
    uncertainty,
    weak_directions,
)
from hhra_phys.model import Model
from hhra_phys.outputs import atomic_write_text, check_output_path, format_metric, jsonable
from hhra_phys.result_json import (  # noqa: F401  (re-exported)
    _EDIT,
    FAR_OUTSIDE,
    FORMAT_NAME,
    FORMAT_VERSION,
    _check_covariance,
    _check_header,
    _check_records,
    _free_names,
    _model_of,
    _values,
)
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

    def report(self, path: str | Path, data: Any, overwrite: bool = False) -> Path:
        """Write the Markdown report and its figure (``hhra-phys fit --report``'s;
        :func:`hhra_phys.fit_report.fit_report`): parameters with their 95 % intervals, the
        derived quantities, the errors, the warnings and ``<stem>_fit.png`` beside it.

        Parameters
        ----------
        path : str or path-like
            The report (``.md``).
        data : Dataset or sequence of Dataset
            The record(s) the fit ran on (a result does not keep them).
        overwrite : bool
            Replace existing files.

        Returns
        -------
        pathlib.Path
        """
        from hhra_phys.fit_report import fit_report

        return fit_report(self, path, data, overwrite=overwrite)

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


def _finite(values: Any) -> bool:
    return all(v is not None and np.isfinite(v) for v in values)


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
