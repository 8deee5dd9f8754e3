"""Profile-likelihood confidence intervals for a least-squares fit.

The Gauss-Newton intervals of :mod:`hhra_phys.result` linearise the model at the
optimum. Along a weakly determined, curved direction (the HHRA's pressure scale:
``g_valve`` and ``g_compress`` up with ``g_torque`` down) the sum of squares is
far from quadratic, and the linearised interval can miss the truth. The profile
interval of a parameter is the set of values ``c`` at which the sum of squares,
minimised over all *other* free parameters with that one held at ``c``, stays
below the likelihood-ratio threshold

    SSR_prof(c) <= SSR_min * (1 + F(level; 1, n - p) / (n - p)),

the F-test form for Gaussian errors of unknown variance (``n`` samples, ``p``
free parameters; exact for a linear model, and what the Gauss-Newton interval
approximates). Each profile point is a bounded nonlinear least-squares solve
(:func:`scipy.optimize.least_squares`, trust-region reflective) with the exact
residual Jacobian of :class:`~hhra_phys.refine.CompiledLeastSquares`, warm
started from the previous point; the crossing of the threshold is bracketed by
steps that double and then located by :func:`scipy.optimize.brentq`.

Everything happens in the problem's fitting coordinates (``log10`` for positive
groups), where the profile is closer to quadratic; intervals are mapped back to
physical units, so they are asymmetric where the profile is.

The module is named ``likelihood``, not ``profile``, so that it does not shadow the
standard library's :mod:`profile`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq, least_squares
from scipy.stats import f as f_dist

from hhra_phys.errors import ParameterError
from hhra_phys.problem import Problem
from hhra_phys.refine import CompiledLeastSquares

__all__ = [
    "Profile",
    "threshold",
    "profile_parameter",
    "profile_intervals",
]


@dataclass
class Profile:
    """Profile of one free parameter and its confidence interval.

    Attributes
    ----------
    name : str
        Parameter name.
    interval : tuple of float
        Confidence interval in physical units (``level`` coverage).
    z_interval : tuple of float
        The same interval in fitting coordinates.
    open_ends : tuple of bool
        ``(lower, upper)``: True where the profile stayed below the threshold up
        to the search box, so that end is the box bound, not a crossing.
    points : list of (float, float)
        Evaluated ``(z, SSR_prof(z))`` pairs, sorted by ``z`` (the optimum included).
    threshold : float
        Sum-of-squares threshold [output unit**2].
    n_solves : int
        Number of profile least-squares solves.
    ssr_min : float
        Sum of squares at the least-squares optimum the profile is centred on.
    moved : bool
        The given point was not a least-squares minimum: a bounded least-squares
        polish from it lowered the sum of squares by more than 1e-6 (relative),
        and the profile is centred on the polished optimum instead.
    lower_minimum : bool
        A profile solve found a sum of squares below ``ssr_min``: another, better
        minimum exists, and the interval is not trustworthy.
    """

    name: str
    interval: tuple[float, float]
    z_interval: tuple[float, float]
    open_ends: tuple[bool, bool]
    points: list[tuple[float, float]] = field(default_factory=list)
    threshold: float = float("nan")
    n_solves: int = 0
    ssr_min: float = float("nan")
    moved: bool = False
    lower_minimum: bool = False


def threshold(ssr_min: float, n_obs: int, n_free: int, level: float = 0.95) -> float:
    """Sum-of-squares threshold of the ``level`` profile interval (F-test form)."""
    if not 0 < level < 1:
        raise ParameterError(f"level must be in (0, 1), got {level}")
    dof = max(n_obs - n_free, 1)
    return float(ssr_min * (1.0 + f_dist.ppf(level, 1, dof) / dof))


_LSQ = {"method": "trf", "x_scale": "jac", "ftol": 1e-12, "xtol": 1e-12, "gtol": 1e-12}


class _Profiler:
    """Profile solves for one problem around one optimum (shares the residual engine).

    The optimum is first polished by a bounded least-squares solve over every
    free coordinate: the threshold is relative to the *minimum* sum of squares,
    and a fit refined by another cost (ITAE), stopped early, or not refined at
    all does not end exactly there.
    """

    def __init__(self, problem: Problem, z_hat: np.ndarray, engine: CompiledLeastSquares) -> None:
        self.problem = problem
        self.engine = engine
        self.box = problem.bounds_z()
        self.n_solves = 0
        z0 = np.clip(np.asarray(z_hat, dtype=float), self.box[:, 0], self.box[:, 1])
        r, _ = engine(z0)
        ssr_given = float(r @ r)
        sol = least_squares(lambda z: engine(z)[0], z0, jac=lambda z: engine(z)[1],
                            bounds=(self.box[:, 0], self.box[:, 1]), max_nfev=100, **_LSQ)
        r, _ = engine(sol.x)
        ssr_polished = float(r @ r)
        if ssr_polished < ssr_given:
            self.z_hat, self.ssr_min = np.asarray(sol.x, dtype=float), ssr_polished
        else:
            self.z_hat, self.ssr_min = z0, ssr_given
        self.moved = ssr_given - self.ssr_min > 1e-6 * ssr_given

    def solve(self, i: int, c: float, start: np.ndarray) -> tuple[float, np.ndarray]:
        """Minimal sum of squares with coordinate ``i`` held at ``c``; (SSR, full z)."""
        others = [k for k in range(self.z_hat.size) if k != i]
        lo, hi = self.box[others, 0], self.box[others, 1]
        w0 = np.clip(start[others], lo, hi)

        def full(w: np.ndarray) -> np.ndarray:
            z = np.empty(self.z_hat.size)
            z[others] = w
            z[i] = c
            return z

        self.n_solves += 1
        if not others:
            r, _ = self.engine(full(w0))
            return float(r @ r), full(w0)
        sol = least_squares(
            lambda w: self.engine(full(w))[0],
            w0,
            jac=lambda w: self.engine(full(w))[1][:, others],
            bounds=(lo, hi),
            max_nfev=60,
            **_LSQ,
        )
        z = full(sol.x)
        r, _ = self.engine(z)
        return float(r @ r), z


def profile_parameter(
    problem: Problem,
    z_hat: np.ndarray,
    name: str,
    level: float = 0.95,
    step: float | None = None,
    max_steps: int = 12,
    engine: CompiledLeastSquares | None = None,
) -> Profile:
    """Profile-likelihood interval of one free parameter.

    Parameters
    ----------
    problem : Problem
        The fitting problem (its estimation data define the sum of squares).
    z_hat : array, shape (n_free,)
        The fit's optimum in fitting coordinates (e.g. after IPOPT); it is
        polished to the least-squares minimum first (:attr:`Profile.moved`).
    name : str
        A free parameter of ``problem``.
    level : float
        Coverage of the interval.
    step : float, optional
        First step away from the optimum in fitting coordinates (default: the
        linearised 95 % half-width, or 0.01 when that is not finite).
    max_steps : int
        Steps per side, doubling each time; the last one goes to the box bound.
    engine : CompiledLeastSquares, optional
        Residual engine to reuse.

    Returns
    -------
    Profile
    """
    if name not in problem.free_names:
        raise ParameterError(f"{name!r} is not a free parameter ({', '.join(problem.free_names)})")
    prof = _Profiler(problem, z_hat, engine or CompiledLeastSquares(problem))
    return _profile(prof, name, level, step, max_steps)


def _profile(prof: _Profiler, name: str, level: float, step: float | None,
             max_steps: int) -> Profile:
    problem = prof.problem
    i = problem.free_names.index(name)
    n_obs, n_free = problem.y.size, problem.n_free
    limit = threshold(prof.ssr_min, n_obs, n_free, level)
    solves_before = prof.n_solves
    step = float(_first_step(prof, i) if step is None else step)
    points: list[tuple[float, float]] = [(float(prof.z_hat[i]), prof.ssr_min)]
    ends: list[float] = []
    open_ends: list[bool] = []
    for side in (-1.0, 1.0):
        end, is_open = _walk(prof, i, side, step, max_steps, limit, points)
        ends.append(end)
        open_ends.append(is_open)
    z_lo, z_hi = ends
    zl, zh = prof.z_hat.copy(), prof.z_hat.copy()
    zl[i], zh[i] = z_lo, z_hi
    lo_v, hi_v = problem.from_z(zl)[i], problem.from_z(zh)[i]
    return Profile(
        name=name,
        interval=(float(min(lo_v, hi_v)), float(max(lo_v, hi_v))),
        z_interval=(float(z_lo), float(z_hi)),
        open_ends=(open_ends[0], open_ends[1]),
        points=sorted(points),
        threshold=limit,
        n_solves=prof.n_solves - solves_before,
        ssr_min=prof.ssr_min,
        moved=prof.moved,
        lower_minimum=min(s for _, s in points) < prof.ssr_min * (1 - 1e-9),
    )


def _first_step(prof: _Profiler, i: int) -> float:
    """The first step of a profile of free parameter ``i`` (z units): the half-width of
    its linearised 95 % interval, or 0.01 where that is not finite and positive."""
    problem, engine = prof.problem, prof.engine
    n_obs, n_free = problem.y.size, problem.n_free
    _, J = engine(prof.z_hat)
    s2 = prof.ssr_min / max(n_obs - n_free, 1)
    with np.errstate(all="ignore"):
        cov = np.linalg.pinv(J.T @ J) * s2
    half = 1.96 * float(np.sqrt(max(cov[i, i], 0.0)))
    return half if np.isfinite(half) and half > 0 else 0.01


def _walk(prof: _Profiler, i: int, side: float, step: float, max_steps: int, limit: float,
          points: list[tuple[float, float]]) -> tuple[float, bool]:
    """Walk free parameter ``i`` from the optimum to one ``side`` (-1 or +1) in doubling
    steps until the profile SSR exceeds ``limit``; returns ``(end, open)``.

    The end is the crossing of ``limit`` (``open`` False) or, when the box bound comes
    first, the last point inside (``open`` True). Every solve is appended to ``points``.
    """
    bound = prof.box[i, 0] if side < 0 else prof.box[i, 1]
    inner_c, inner_z, inner_ssr = float(prof.z_hat[i]), prof.z_hat.copy(), prof.ssr_min
    h = step
    for k in range(max(int(max_steps), 1)):
        c = inner_c + side * h
        # The last step goes to the bound, so an open end is always the box.
        at_bound = (c - bound) * side >= 0 or k == max_steps - 1
        if at_bound:
            c = float(bound)
        if c == inner_c:  # already at the bound
            break
        ssr, z = prof.solve(i, c, inner_z)
        points.append((c, ssr))
        if ssr > limit:
            return _crossing(prof, i, (inner_c, inner_z, inner_ssr), (c, ssr), limit, step,
                             points), False
        inner_c, inner_z, inner_ssr = c, z, ssr
        if at_bound:
            break
        h *= 2.0
    return inner_c, True


def _crossing(prof: _Profiler, i: int, inner: tuple[float, np.ndarray, float],
              outer: tuple[float, float], limit: float, step: float,
              points: list[tuple[float, float]]) -> float:
    """Where the profile SSR of parameter ``i`` crosses ``limit`` between the last point
    inside (``inner``: value, solution, SSR) and the first outside (``outer``: value, SSR)."""
    inner_c, inner_z, inner_ssr = inner
    outer_c, outer_ssr = outer
    starts = {"z": inner_z}
    # brentq evaluates both bracket ends first: they are known already.
    known = {inner_c: inner_ssr, outer_c: outer_ssr}

    def g(cc: float) -> float:
        if cc in known:
            return known[cc] - limit
        val, zz = prof.solve(i, cc, starts["z"])
        points.append((cc, val))
        if val <= limit:
            starts["z"] = zz  # warm start from the inside
        return val - limit

    return float(brentq(g, inner_c, outer_c, xtol=1e-4 * step, rtol=1e-10))


def profile_intervals(
    problem: Problem,
    z_hat: np.ndarray,
    names: list[str] | None = None,
    level: float = 0.95,
) -> dict[str, Profile]:
    """Profile-likelihood intervals of several free parameters (default: all).

    See :func:`profile_parameter`; one residual engine and one polished optimum
    serve every profile.
    """
    chosen = problem.free_names if names is None else list(names)
    for n in chosen:
        if n not in problem.free_names:
            raise ParameterError(
                f"{n!r} is not a free parameter ({', '.join(problem.free_names)})")
    prof = _Profiler(problem, z_hat, CompiledLeastSquares(problem))
    return {n: _profile(prof, n, level, None, 12) for n in chosen}
