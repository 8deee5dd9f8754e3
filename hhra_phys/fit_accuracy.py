"""Accuracy at the fitted values: finer substeps when the fit's optimum needs them.

A fit's substeps are chosen at its start values (:meth:`~hhra_phys.simulate.Simulator.accurate`);
after the search this checks the integration error at the optimum, gives the problem the
simulator that keeps it within the tolerance, and refines again only when the finer
simulator would move the optimum by a noticeable share of its own uncertainty
(:data:`ACCURACY_REFIT_SHIFT`). Separate from :mod:`hhra_phys.fit` because it is the one
step of a fit about the discretisation rather than the data; every name here is also
importable from :mod:`hhra_phys.fit`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from hhra_phys.fit_options import _IPOPT_KEYS, _refiner_names
from hhra_phys.problem import Problem
from hhra_phys.refine import CompiledLeastSquares, Stage, refine_ipopt
from hhra_phys.simulate import MAX_ACCURACY_SUBSTEPS

__all__: list[str] = []


def _integration(problem: Problem, z: np.ndarray) -> dict[str, Any]:
    """The simulator's accuracy choice and its error estimate at the fitted values ``z``."""
    if not problem.sim.accuracy or problem.sim.accuracy.get("error_estimate") is None:
        # Substeps given (or inherited, as the loop's candidates keep the base fit's):
        # no estimate here, which would cost a few seconds for a stiff candidate.
        return {"method": problem.sim.method, "substeps": problem.sim.substeps,
                "error_estimate": None,
                "note": str(problem.sim.accuracy.get("reason", "substeps given, not chosen "
                                                               "for accuracy"))}
    info = dict(problem.sim.accuracy)
    v = problem.from_z(z)
    try:
        info["error_at_fit"] = problem.sim.integration_error(
            problem.u, problem.full(v), x0=problem.initial_states(v)[0])
    except Exception as exc:  # noqa: BLE001 - a diverged fit has no estimate
        info["error_at_fit"] = float("nan")
        info["error_note"] = str(exc)
    return info


def _accurate_at_fit(problem: Problem, z: np.ndarray, stages: list[Stage], refine: Any,
                     refine_options: Mapping[str, Any] | None) -> tuple[Problem, np.ndarray]:
    """Refine again with finer substeps if the fitted values need them for accuracy.

    The substeps were chosen at the start values (:meth:`Problem.__init__`); when the
    error estimate at the fitted values exceeds the tolerance, the problem gets the
    simulator :meth:`~hhra_phys.simulate.Simulator.accurate` gives there (up to
    :data:`~hhra_phys.simulate.MAX_ACCURACY_SUBSTEPS` in its finest run, four times the
    search's) and IPOPT (when it is among the refiners) refines once more from ``z``.
    """
    acc = problem.sim.accuracy
    tol = float(acc.get("tolerance", np.inf)) if acc else np.inf
    if (not np.isfinite(tol) or acc.get("error_estimate") is None
            or "ipopt" not in _refiner_names(refine)):
        return problem, z
    v = problem.from_z(z)
    x0 = problem.initial_states(v)[0]
    sim = problem.sim.accurate(problem.u, problem.full(v), tol, x0=x0,
                               finest=MAX_ACCURACY_SUBSTEPS)
    if sim is problem.sim or sim.substeps <= problem.sim.substeps:
        return problem, z
    new = problem.with_simulator(sim)
    shift = _accuracy_shift(problem, new, z)
    sim.accuracy["refit_shift"] = shift
    if shift < ACCURACY_REFIT_SHIFT:
        return new, z
    ropts = dict(refine_options or {})
    st = refine_ipopt(new, z, **{k: val for k, val in ropts.items() if k in _IPOPT_KEYS})
    st.name += f" (accuracy: {sim.method} x {sim.substeps})"
    stages.append(st)
    return new, st.z


#: Predicted move of the optimum under finer substeps, in the fit's own uncertainty
#: (:func:`_accuracy_shift`), below which the accuracy rule's refit is not run: the
#: finer simulator is kept (intervals, scores and later stages use it) at the values
#: found. 0.1 is a move of about a third of a standard deviation in the worst direction.
ACCURACY_REFIT_SHIFT = 0.1


def _accuracy_shift(coarse: Problem, fine: Problem, z: np.ndarray) -> float:
    """How far the optimum at ``z`` moves when ``coarse``'s simulator gives way to ``fine``'s
    (finer substeps), in the fit's own uncertainty: ``|P_J e|^2 / s^2``.

    ``e`` is the change of the residual at ``z`` between the two simulators (their
    integration error there), ``P_J`` the projection on the columns of the finer
    residual's Jacobian ``J``, ``s^2 = |r|^2 / (N - n_free)`` the residual variance:
    ``P_J e`` is what the Gauss-Newton step of the parameters can follow of the change,
    so the ratio is the squared move of the optimum in the metric of its confidence
    ellipsoid (at most ``|e|^2 / s^2``). Why: the integration error matters only as far
    as it is coherent with the parameters' directions and only against the residual the
    model leaves. A fit at the noise level moves by several standard deviations (the
    refit is needed); a model lacking an effect, whose residual is many times the noise,
    moves by a small fraction of one (measured: a base fit lacking a dead zone, whose
    refit took 3634 IPOPT evaluations for a relative gain below 1e-8). ``inf`` when it
    cannot be computed (the refit then runs, as before).
    """
    r_c, _ = CompiledLeastSquares(coarse)(z)
    r, J = CompiledLeastSquares(fine)(z)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J)) and np.all(np.isfinite(r_c))):
        return np.inf
    var = float(r @ r) / max(r.size - fine.n_free, 1)
    if var <= 0:
        return np.inf
    e = r - r_c
    coef, *_ = np.linalg.lstsq(J, e, rcond=1e-10)
    pe = J @ coef
    return float(pe @ pe) / var
