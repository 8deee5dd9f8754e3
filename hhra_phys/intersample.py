"""The other inter-sample behaviours as candidates that change no physics.

A record says what its input did between samples (:attr:`Dataset.intersample
<hhra_phys.data.Dataset.intersample>`: ``"zoh"`` held, ``"foh"`` linear, ``"cubic"``
the cubic convolution). A wrong assumption leaves a typical residual: holding an input
that really moved makes the simulated output lag the measured one by about half a
sample (and interpolating an input a DAC held makes it lead), which a fitted model only
partly absorbs into its parameters. The diagnosis loop can then "discover" the artefact
as an effect (an input lead, a rate-dependent term) and refuse the true one. This module
gives the loop what it needs to test the other assumptions under its one rule:

* :func:`hold_signature`: the evidence on a fitted model's residual, the sub-sample
  shift ``lead`` (samples) that best aligns the simulated output with the measured
  one and the share of the residual variance that shift explains, and the
  ``curvature`` a straight line leaves where the input moved smoothly (no shift, an
  error along the output's second difference);
* :func:`hold_suspected`: whether that evidence is worth trying candidates;
* :func:`other_holds`: the behaviours to try (every one but the record's);
* :func:`refit_with_hold`: the same model, free set, fixed values and boxes refitted
  (warm-started, IPOPT) on the estimation part with another behaviour, scored on the
  selection part with it: a :class:`HoldCandidate` holding an ordinary
  :class:`~hhra_phys.result.FitResult` the loop judges like any candidate (selection
  RMSE, information criterion, noise allowance). The candidate has the same
  parameters as the current model, so the criterion changes only through the fit.

Usage after the base fit and in every round while the record's own behaviour holds
(what :func:`hhra_phys.diagnosis.engine.augment` does)::

    sig = hold_signature(problem.data.y, problem.simulate_values(values))
    if hold_suspected(sig):
        for kind in other_holds(problem.data.intersample):
            cand = refit_with_hold(result, problem, selection, kind=kind)
            ok, why = <the loop's acceptance rule>(rmse_cur, cand.rmse("selection"),
                                                   crit_cur, <criterion of cand.result>)
        # keep the accepted one with the lowest selection RMSE: every later fit and
        # score uses its records (cand.records(est, sel, test)) and cand.problem

Reported as what it is: ``cand.name`` is ``"intersample:<kind>"``; ``cand.evidence``
says which assumption was replaced, that no physics changed, and by what evidence.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hhra_phys.data import INTERSAMPLE, Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.problem import Problem
from hhra_phys.result import FitResult

__all__ = [
    "HoldCandidate",
    "hold_signature",
    "hold_suspected",
    "other_hold",
    "other_holds",
    "refit_with_hold",
    "LEAD_MIN",
    "EXPLAINED_MIN",
    "CURVATURE_MIN",
    "CURVATURE_MAX",
]

#: Smallest sub-sample shift [samples] :func:`hold_suspected` calls a signature (a wrong
#: hold of a record sampled near its bandwidth leaves 0.2 to 0.5).
LEAD_MIN = 0.1
#: Smallest share of the residual variance the shift (or the curvature) must explain.
EXPLAINED_MIN = 0.05
#: Range of the curvature coefficient [samples^2] :func:`hold_suspected` calls a
#: signature. Two interpolations of a smooth input differ by about ``c T^2 u''``: the
#: straight line against the true curve ``c = -1/12`` (its mean loss ``(w T)^2 / 12``),
#: a held input ``-1/24`` beside its half-sample lag; half the smaller one is the least
#: worth a refit. A coefficient of order one or more is no interpolation's (the residual
#: of a missing effect correlates with the output's curvature at any size).
CURVATURE_MIN = 1.0 / 48.0
CURVATURE_MAX = 0.25


def other_hold(kind: str) -> str:
    """The candidate behaviour for a record read with ``kind``: ``"foh"`` for ``"zoh"``,
    ``"zoh"`` for ``"foh"`` and ``"cubic"`` (a held input is the other extreme)."""
    if kind not in INTERSAMPLE:
        raise ParameterError(f"intersample must be one of {', '.join(INTERSAMPLE)}, got {kind!r}")
    return "foh" if kind == "zoh" else "zoh"


def other_holds(kind: str) -> tuple[str, ...]:
    """Every inter-sample behaviour but ``kind`` (the loop's candidates), in
    :data:`~hhra_phys.data.INTERSAMPLE` order."""
    if kind not in INTERSAMPLE:
        raise ParameterError(f"intersample must be one of {', '.join(INTERSAMPLE)}, got {kind!r}")
    return tuple(k for k in INTERSAMPLE if k != kind)


def hold_signature(y: np.ndarray, y_sim: np.ndarray) -> dict[str, float]:
    """Sub-sample alignment of a simulated output with the measured one.

    The residual ``r = y - y_sim`` is regressed on the simulated output's central
    difference ``d_k = (y_sim[k+1] - y_sim[k-1]) / 2``: ``y(k) ~ y_sim(k + lead)``
    to first order. Separately it is regressed on the second difference
    ``c_k = y_sim[k+1] - 2 y_sim[k] + y_sim[k-1]`` beside ``y_sim`` itself: an input
    interpolated by the wrong curve between samples (a straight line where it moved
    smoothly) reaches the output as ``y ~ y_sim + curvature * c``, and a fitted gain
    absorbs the part along ``y_sim``, so only the rest is evidence.

    Parameters
    ----------
    y, y_sim : ndarray, shape (N,)
        Measured and simulated output (same unit), N >= 3.

    Returns
    -------
    dict
        ``lead`` [samples]: > 0 when the measured output is ahead of the simulation (what
        holding an input that moved between samples does, about +0.5 before the fit
        absorbs part of it); ``explained``: share of the residual's variance the shift
        explains (0..1); ``rmse_after_shift``: residual RMSE left after it;
        ``curvature`` [samples^2]: the second difference's coefficient (about -1/12 when
        the input moved smoothly but is read as linear between samples);
        ``curvature_explained``: share of the residual variance it explains beside the
        gain (0..1).
    """
    y = np.asarray(y, dtype=float)
    ys = np.asarray(y_sim, dtype=float)
    if y.shape != ys.shape or y.ndim != 1 or y.size < 3:
        raise ParameterError(f"y and y_sim must be 1-D of the same length >= 3, got {y.shape}, "
                             f"{ys.shape}")
    r = (y - ys)[1:-1]
    d = 0.5 * (ys[2:] - ys[:-2])
    dd, rr = float(d @ d), float(r @ r)
    if not (np.isfinite(dd) and np.isfinite(rr)) or dd == 0.0 or rr == 0.0:
        return {"lead": 0.0, "explained": 0.0, "rmse_after_shift": math.sqrt(rr / r.size),
                "curvature": 0.0, "curvature_explained": 0.0}
    lead = float(r @ d) / dd
    left = r - lead * d
    return {"lead": lead, "explained": float(1.0 - (left @ left) / rr),
            "rmse_after_shift": math.sqrt(float(left @ left) / r.size),
            **_curvature(r, ys)}


def _curvature(r: np.ndarray, ys: np.ndarray) -> dict[str, float]:
    """The second difference's coefficient in ``r ~ a y_sim + curvature c`` (least squares)."""
    c = ys[2:] - 2.0 * ys[1:-1] + ys[:-2]
    a = np.column_stack([ys[1:-1], c])
    if not np.all(np.isfinite(a)) or float(c @ c) == 0.0:
        return {"curvature": 0.0, "curvature_explained": 0.0}
    coef, *_ = np.linalg.lstsq(a, r, rcond=None)
    left = r - a @ coef
    both = 1.0 - float(left @ left) / float(r @ r)
    g = float(r @ ys[1:-1]) / max(float(ys[1:-1] @ ys[1:-1]), np.finfo(float).tiny)
    gain_only = 1.0 - float((r - g * ys[1:-1]) @ (r - g * ys[1:-1])) / float(r @ r)
    return {"curvature": float(coef[1]), "curvature_explained": max(both - gain_only, 0.0)}


def hold_suspected(signature: Mapping[str, float], lead_min: float = LEAD_MIN,
                   explained_min: float = EXPLAINED_MIN) -> bool:
    """Whether a :func:`hold_signature` points at the wrong inter-sample behaviour.

    A shift of at least ``lead_min`` samples (either sign) explaining at least
    ``explained_min`` of the residual variance, or a curvature coefficient of an
    interpolation's size (:data:`CURVATURE_MIN` to :data:`CURVATURE_MAX`, either sign)
    explaining as much. Only a reason to *try* the other holds: the loop's rule decides.
    """
    shifted = (abs(float(signature.get("lead", 0.0))) >= lead_min
               and float(signature.get("explained", 0.0)) >= explained_min)
    curved = (CURVATURE_MIN <= abs(float(signature.get("curvature", 0.0))) <= CURVATURE_MAX
              and float(signature.get("curvature_explained", 0.0)) >= explained_min)
    return shifted or curved


@dataclass
class HoldCandidate:
    """The current model refitted with the other inter-sample behaviour.

    Attributes
    ----------
    kind, was : str
        The behaviour tried and the one it replaces.
    result : FitResult
        The refit (estimation part, the other hold); ``result.metrics["val"]`` is the
        selection part scored with the same hold.
    problem : Problem
        Its problem (its ``data`` is the estimation part with the other hold): the
        loop's next fits start from it.
    signature : dict
        :func:`hold_signature` of the current fit on the estimation part.
    rmse_before : dict
        ``{"estimation", "selection"}`` RMSE of the current fit.
    """

    kind: str
    was: str
    result: FitResult
    problem: Problem
    signature: dict[str, float]
    rmse_before: dict[str, float] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """``"intersample:<kind>"``: how a report names the candidate."""
        return f"intersample:{self.kind}"

    def rmse(self, part: str = "selection") -> float:
        """RMSE of the refit on ``"estimation"`` or ``"selection"`` (output units)."""
        key = {"estimation": "est", "selection": "val"}.get(part)
        if key is None:
            raise ParameterError(f"part must be 'estimation' or 'selection', got {part!r}")
        return float(self.result.metrics.get(key, {}).get("rmse", math.nan))

    @property
    def evidence(self) -> str:
        """What changed, what did not, and the signature, in words."""
        s = self.signature
        return (f"inter-sample behaviour {self.was} -> {self.kind} (no physics changed: same "
                f"model and parameters); the measured output leads the {self.was} fit's by "
                f"{s.get('lead', 0.0):+.2f} samples, a shift explaining "
                f"{100 * s.get('explained', 0.0):.0f} % of its residual, and its curvature "
                f"term is {s.get('curvature', 0.0):+.3f} samples^2, explaining "
                f"{100 * s.get('curvature_explained', 0.0):.0f} % beside the gain")

    @property
    def reason(self) -> str:
        """:attr:`evidence` and the selection RMSE before and after."""
        return (f"{self.evidence}; selection RMSE "
                f"{self.rmse_before.get('selection', math.nan):.4g} -> "
                f"{self.rmse('selection'):.4g}")

    def records(self, *data: Dataset | None) -> tuple[Dataset | None, ...]:
        """The given records with the candidate's behaviour (``None`` stays ``None``)."""
        return tuple(None if d is None else d.with_intersample(self.kind) for d in data)

    def to_json(self) -> dict[str, Any]:
        """Summary for reports: name, kinds, evidence, scores, reason."""
        return {"name": self.name, "kind": self.kind, "was": self.was,
                "signature": dict(self.signature), "rmse_before": dict(self.rmse_before),
                "rmse": {"estimation": self.rmse("estimation"),
                         "selection": self.rmse("selection")},
                "values": dict(self.result.values), "reason": self.reason}


def refit_with_hold(result: FitResult, problem: Problem, selection: Dataset | None = None,
                    kind: str | None = None, refine: str = "ipopt", max_iter: int = 200,
                    seed: int | None = 0, signature: Mapping[str, float] | None = None,
                    ) -> HoldCandidate:
    """Refit the current model with the other inter-sample behaviour (module docstring).

    Parameters
    ----------
    result : FitResult
        The current fit (its values warm-start the refit).
    problem : Problem
        Its problem on the estimation part (one record; free set, fixed values, boxes,
        initial-state rule and simulator are kept).
    selection : Dataset, optional
        The selection part (scored as ``result.metrics["val"]`` with the same hold).
    kind : {"zoh", "foh"}, optional
        The behaviour to try (default: the other one than the estimation part's).
    refine : str
        Refiner of :func:`hhra_phys.fit.fit` (no global search: the physics is the same,
        only the input between samples changes, so the current values are a close start).
    max_iter : int
        Its iteration limit.
    seed : int or None
        Seed passed to the fit.
    signature : dict, optional
        :func:`hold_signature` of ``result`` on the estimation part when the caller has
        it (the loop computed it to decide whether to try); computed here otherwise.

    Returns
    -------
    HoldCandidate
    """
    from hhra_phys.fit import fit

    if len(problem.records) > 1:
        raise ParameterError("refit_with_hold takes the one-record Problem of the current fit "
                             f"(got one of {len(problem.records)} records)")
    est = problem.data
    kind = kind or other_hold(est.intersample)
    if kind not in INTERSAMPLE:
        raise ParameterError(f"intersample must be one of {', '.join(INTERSAMPLE)}, got {kind!r}")
    values = np.array([result.values[n] if n in result.values else result.x0_param(n)
                       for n in problem.free_names])
    signature = (dict(signature) if signature is not None
                 else hold_signature(est.y, problem.simulate_values(values)))
    est2 = est.with_intersample(kind)
    sel2 = None if selection is None else selection.with_intersample(kind)
    start = {n: float(v) for n, v in zip(problem.free_names, values, strict=True)}
    explicit = {p.name: (p.lower, p.upper) for p in problem.free_params
                if p.name in problem.explicit_bounds}
    boxes = {p.name: (p.lower, p.upper) for p in problem.free_params
             if not p.name.startswith("x0_") and p.name not in problem.explicit_bounds}
    pr2 = Problem(problem.model, est2, cost=problem.cost,  # type: ignore[arg-type]
                  free=[n for n in problem.free_names if not n.startswith("x0_")],
                  fixed=problem.fixed, bounds=explicit, default_bounds=boxes,
                  initial_state=problem.initial_state,  # type: ignore[arg-type]
                  simulator=problem.sim, start=start, allow_outside_box=True)
    res2 = fit(est2, problem=pr2, validation=sel2, optimizer="none", refine=refine,
               refine_options={"max_iter": int(max_iter)}, seed=seed, widen_bounds=False)
    before = {"estimation": float(result.metrics.get("est", {}).get("rmse", math.nan))}
    if selection is not None:  # the current fit on the selection part, with its own hold
        y_sel = problem.simulate_values(values, selection)
        before["selection"] = float(np.sqrt(np.mean((selection.y - y_sel) ** 2)))
    return HoldCandidate(kind, est.intersample, res2, pr2, signature, before)
