"""The uncertainty of a fit at its optimum: intervals, covariance and their warnings.

:func:`_intervals` gives the :class:`Intervals` of a fit: Gauss-Newton (linearised) 95 %
intervals from the exact residual Jacobian (:func:`hhra_phys.result.uncertainty`), or
profile-likelihood ones (:func:`hhra_phys.likelihood.profile_intervals`), recomputed under
the residual's noise colour when white-noise ones would be too narrow
(:data:`COLOURED_FACTOR`), with the weak directions and the parameters at a box edge.
Separate from :mod:`hhra_phys.fit` because it is what a fit says about its values once
they are found, not how they are found; every name here is also importable from
:mod:`hhra_phys.fit`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from hhra_phys.likelihood import profile_intervals
from hhra_phys.noise import coloured_covariance, interval_factor
from hhra_phys.refine import CompiledLeastSquares
from hhra_phys.result import physical_covariance, uncertainty, weak_directions
from hhra_phys.widen import at_edges

__all__ = [
    "Intervals",
]


#: Intervals at least this much too narrow under the residual's noise colour are
#: recomputed with the noise model (:func:`hhra_phys.noise.coloured_covariance`) and
#: warned about (:func:`hhra_phys.noise.interval_factor`).
COLOURED_FACTOR = 2.0


@dataclass
class Intervals:
    """The uncertainty of a fit at its optimum (:func:`_intervals`).

    Attributes
    ----------
    ci95 : dict of str to (float, float)
        95 % interval of each free parameter, physical units.
    std : dict of str to float
        Standard deviation in fitting coordinates.
    correlation : ndarray, shape (n_free, n_free)
    covariance : ndarray, shape (n_free, n_free)
        Linearised covariance in physical units (the delta method's input).
    warnings : list of str
    info : dict
        :attr:`~hhra_phys.result.FitResult.intervals` (method, undetermined, weak
        directions, coloured noise, ``at_edge``: free parameters at a box edge by side).
    """

    ci95: dict[str, tuple[float, float]]
    std: dict[str, float]
    correlation: np.ndarray
    covariance: np.ndarray
    warnings: list[str]
    info: dict[str, Any]


def _intervals(problem: Any, z: np.ndarray, intervals: str) -> Intervals:
    """95 % intervals, standard deviations, correlation, covariance, warnings and
    interval info at ``z``.

    For any number of records (intervals from all records together).
    """
    # Uncertainty from the exact residual Jacobian at the optimum.
    r, J = CompiledLeastSquares(problem)(z)
    cov, corr, warnings = uncertainty(J, r, problem.free_names)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    ci95, std = _linear_intervals(problem, z, sd)
    info: dict[str, Any] = {"method": "linear"}
    diverged = not (np.all(np.isfinite(r)) and np.all(np.isfinite(J)))
    if intervals == "profile" and diverged:
        warnings.append("profile intervals skipped: the fit diverged")
    elif intervals == "profile":
        info = _profile(problem, z, ci95, warnings)
    undetermined = [n for i, n in enumerate(problem.free_names) if not np.isfinite(sd[i])]
    if undetermined:
        info["undetermined"] = undetermined
    if not diverged:
        cov = _coloured(problem, z, (J, r, cov), ci95, std, warnings, info)
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    weak = weak_directions(J, list(problem.free_names))
    if weak:
        # Which parameters trade off, and why their intervals are missing.
        info["weak_directions"] = weak
        info["reasons"] = {
            name: next(d["reason"] for d in weak if name in d["params"])
            for name in undetermined if any(name in d["params"] for d in weak)}
    edges = _edge_warnings(problem, z, sd, warnings)
    if edges:
        info["at_edge"] = edges
    return Intervals(ci95, std, corr, physical_covariance(cov, _slopes(problem, z)),
                     warnings, info)


def _linear_intervals(problem: Any, z: np.ndarray, sd: np.ndarray
                      ) -> tuple[dict[str, tuple[float, float]], dict[str, float]]:
    """``z +- 1.96 sd`` mapped to physical units (NaN where ``sd`` is not finite)."""
    ci95: dict[str, tuple[float, float]] = {}
    std: dict[str, float] = {}
    for i, name in enumerate(problem.free_names):
        if not np.isfinite(sd[i]):
            ci95[name] = (float("nan"), float("nan"))
        else:
            lo, hi = problem.from_z(z - 1.96 * sd)[i], problem.from_z(z + 1.96 * sd)[i]
            ci95[name] = (float(min(lo, hi)), float(max(lo, hi)))
        std[name] = float(sd[i])
    return ci95, std


def _slopes(problem: Any, z: np.ndarray) -> np.ndarray:
    """``d theta_i / d z_i`` at ``z``: ``ln(10) theta`` for log-scaled parameters, the
    scale (the map at ``z = 1``, exact as it is linear) for the others."""
    log = np.array([p.scale == "log" for p in problem.free_params], dtype=bool)
    return np.where(log, np.log(10.0) * problem.from_z(z), problem.from_z(np.ones(len(z))))


def _profile(problem: Any, z: np.ndarray, ci95: dict[str, tuple[float, float]],
             warnings: list[str]) -> dict[str, Any]:
    """Profile-likelihood intervals into ``ci95`` (the linear ones kept in the info)."""
    t0 = time.perf_counter()
    profiles = profile_intervals(problem, z)
    info: dict[str, Any] = {
        "method": "profile",
        "linear": {n: list(v) for n, v in ci95.items()},
        "open_ends": {n: list(p.open_ends) for n, p in profiles.items()},
        "solves": sum(p.n_solves for p in profiles.values()),
        "seconds": time.perf_counter() - t0,
    }
    first = next(iter(profiles.values()), None)
    if first is not None and first.moved:
        info["polished_ssr"] = first.ssr_min
        warnings.append(
            "the fit did not end at the least-squares minimum (no or unconverged "
            "refinement): the profile intervals are centred on a polished optimum "
            f"(sum of squares {first.ssr_min:.6g}), not on the reported values"
        )
    for name, prof in profiles.items():
        ci95[name] = prof.interval
        if prof.lower_minimum:
            warnings.append(
                f"{name}: its profile found a lower sum of squares than the optimum "
                "(another minimum exists), so the profile intervals are not reliable"
            )
        warnings += [
            f"{name}: the profile stays below the 95 % threshold up to the {side} "
            "end of the search box, so the interval is open there"
            for side, is_open in zip(("lower", "upper"), prof.open_ends, strict=True)
            if is_open]
    return info


def _coloured(problem: Any, z: np.ndarray, fit: tuple[np.ndarray, np.ndarray, np.ndarray],
              ci95: dict[str, tuple[float, float]], std: dict[str, float],
              warnings: list[str], info: dict[str, Any]) -> np.ndarray:
    """The covariance of the fitting coordinates under the residual's noise colour.

    ``fit`` is the residual Jacobian ``J``, the residual ``r`` and the white-noise
    covariance. When the residual's ARMA(1,1) noise model says white-noise intervals are
    more than :data:`COLOURED_FACTOR` too narrow, linear intervals (``ci95``, ``std``,
    updated in place) come from the sandwich covariance with that noise model
    (:func:`hhra_phys.noise.coloured_covariance`), which is returned: white-noise ones
    covered the truth on under half the records with AR(1) 0.9 noise (docs/measuring.md).
    Profile intervals and undetermined directions keep theirs (and a warning says by how
    much white-noise ones understate the spread); otherwise the given covariance returns.
    """
    J, r, cov = fit
    colour = interval_factor(r)
    if colour["factor"] <= COLOURED_FACTOR:
        return cov
    info["coloured_noise"] = colour
    if info["method"] != "linear" or not np.all(np.isfinite(cov)):
        warnings.append(
            f"the residual is coloured (noise model pole {colour['a']:.2f}, zero "
            f"{colour['c']:+.2f}): the intervals assume white residuals and are up "
            f"to {colour['factor']:.1f}x too narrow")
        return cov
    cov_c = coloured_covariance(J, r, cov, colour)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    sd_c = np.sqrt(np.clip(np.diag(cov_c), 0, None))
    names = list(problem.free_names)
    colour["widened"] = {n: float(sd_c[i] / sd[i]) if sd[i] > 0 else 1.0
                         for i, n in enumerate(names)}
    ci95.update(_linear_intervals(problem, z, sd_c)[0])
    std.update({n: float(sd_c[i]) for i, n in enumerate(names)})
    widest = max(colour["widened"].values(), default=1.0)
    warnings.append(
        f"the residual is coloured (noise model pole {colour['a']:.2f}, zero "
        f"{colour['c']:+.2f}): the linearised intervals take it into account "
        f"(sandwich covariance with that noise model, up to {widest:.1f}x wider "
        "than white-noise ones)")
    return cov_c


def _edge_warnings(problem: Any, z: np.ndarray, sd: np.ndarray,
                   warnings: list[str]) -> dict[str, str]:
    """Warnings on parameters at a box edge or spanning decades; ``{name: side}`` at edges."""
    edges = dict(at_edges(problem, z))
    for i, name in enumerate(problem.free_names):
        if i in edges:
            warnings.append(
                f"{name} ended at its {edges[i]} bound: the data push it out of the box, so its "
                "value and interval are not meaningful (widen the bound or fix it)"
            )
        elif problem.free_params[i].scale == "log" and np.isfinite(sd[i]) and sd[i] > 0.5:
            decades = 2 * 1.96 * sd[i]
            warnings.append(
                f"{name} is poorly determined by these data: its 95 % interval spans "
                f"{decades:.3g} decades"
            )
    return {problem.free_names[i]: side for i, side in edges.items()}
