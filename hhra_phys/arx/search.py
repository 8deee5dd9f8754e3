"""ARX coefficients by search: PSO, GWO and H-GWO on the ITAE, and the paper's hybrid.

:func:`itae_cost` is the paper's fitness (the ITAE of the free-run output, vectorised over a
population); :func:`fit_metaheuristic` minimises it with an optimiser of
:mod:`hhra_phys.optim` in the paper's box (:data:`PAPER_BOX`, settings
:data:`METAHEURISTIC_OPTIONS`), and :func:`fit_ffrls_hgwo` is the paper's protocol: an FFRLS
estimate, then H-GWO in the box of eq. 29 around it (:func:`hybrid_box`). Their settings
are :class:`MetaheuristicOptions` and :class:`HybridOptions`. Separate from the regression
estimators (:mod:`.estimators`): the optimisers are imported only when a search runs.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from hhra_phys.arx.estimators import (
    FFRLS_XI0,
    FFRLS_XI_INIT,
    RLS_P0,
    RLS_THETA0,
    ARXFit,
    fit_ffrls,
    forgetting_factor,
)
from hhra_phys.arx.structure import (
    MAX_POLE_RADIUS,
    ARXModel,
    _history,
    _orders,
    _pair,
    simulate_population,
)
from hhra_phys.errors import DataError, ParameterError
from hhra_phys.options import with_overrides

__all__ = ["DEFAULT_ZETA_S", "METAHEURISTIC_OPTIONS", "PAPER_BOX", "HybridOptions",
           "MetaheuristicOptions", "fit_ffrls_hgwo", "fit_metaheuristic", "hybrid_box",
           "itae_cost"]

#: The paper's search box for PSO, GWO and H-GWO, every coefficient.
PAPER_BOX = (-5.0, 5.0)
#: Default expansion gain zeta_s of the hybrid's box (eq. 29); the paper gives none.
DEFAULT_ZETA_S = 0.5
#: Optimiser settings of the paper's identification experiment (section 4.3), per method.
METAHEURISTIC_OPTIONS: dict[str, dict[str, Any]] = {
    "pso": {"w_start": 0.9, "w_end": 0.1, "c1": 2.0, "c2": 2.0},
    "gwo": {},
    "hgwo": {"F": 0.5, "lam": 0.25},
}


def itae_cost(
    u: Any,
    y: Any,
    t: Any = None,
    na: int = 3,
    nb: int = 3,
    nk: int = 1,
    y_init: Any = None,
    u_init: Any = None,
    *,
    max_pole_radius: float | None = MAX_POLE_RADIUS,
) -> Callable[[np.ndarray], np.ndarray]:
    """The paper's fitness: ITAE of the free-run output, as a vectorised cost of ``theta`` rows.

    Parameters
    ----------
    u, y : array_like, shape (N,), or lists of them
        Measured input and output; lists of several records' signals (and ``t`` a
        list of their time axes) give the sum of the records' ITAEs, each record's
        free run starting at rest at its own first output (:func:`fit_metaheuristic`
        and :func:`fit_ffrls_hgwo` accept such lists too).
    t : array_like, shape (N,), optional
        Time axis [s] (ITAE in sample units without it).
    na, nb, nk : int
        Structure.
    y_init, u_init : scalar or array_like, optional
        Samples before the record. Default: the record starts at rest at its first measured
        output (past outputs ``y[0]``, past inputs 0).
    max_pole_radius : float or None
        Unstable candidates (a pole beyond this radius) cost ``inf`` without being simulated.

    Returns
    -------
    callable
        ``cost(theta)`` with ``theta`` of shape (m, na + nb) returns shape (m,) [output unit *
        s^2]; ``inf`` for unstable, diverging or non-finite candidates, never an exception.
    """
    from hhra_phys.metrics import itae

    na, nb, nk = _orders(na, nb, nk)
    if isinstance(u, (list, tuple)) and isinstance(y, (list, tuple)):
        # Several records: the sum of their ITAEs, each free run from its own start.
        ts = list(t) if isinstance(t, (list, tuple)) else [None] * len(u)
        if y_init is not None or u_init is not None or not (len(u) == len(y) == len(ts)) \
                or not u:
            raise ParameterError("several records: give as many inputs, outputs and time "
                                 "axes, and no y_init/u_init (each record starts at rest)")
        costs = [itae_cost(uk, yk, tk, na, nb, nk, max_pole_radius=max_pole_radius)
                 for uk, yk, tk in zip(u, y, ts, strict=True)]
        return lambda theta: np.sum([c(theta) for c in costs], axis=0)
    uu, yy = _pair(u, y)
    tt = None if t is None else np.asarray(t, dtype=float)
    y_hist = _history(yy[0] if y_init is None else y_init, na, "y_init")
    u_hist = _history(u_init, nk + nb - 1, "u_init")

    def cost(theta: np.ndarray) -> np.ndarray:
        sims = simulate_population(
            theta, uu, na, nb, nk, y_hist, u_hist, max_pole_radius=max_pole_radius
        )
        return np.atleast_1d(np.asarray(itae(yy, sims, tt), dtype=float))

    return cost


def _bounds(bounds: Any, p: int) -> np.ndarray:
    arr = np.asarray(bounds, dtype=float)
    if arr.shape == (2,):
        arr = np.tile(arr, (p, 1))
    if arr.shape != (p, 2) or not np.isfinite(arr).all() or np.any(arr[:, 0] >= arr[:, 1]):
        raise ParameterError(
            f"bounds must be (lo, hi) or a ({p}, 2) array of finite limits with lo < hi, "
            f"got {bounds!r}"
        )
    return arr


@dataclass(frozen=True)
class _SearchOptions:
    """Settings both metaheuristic ARX fits share (see :class:`MetaheuristicOptions`)."""

    na: int = 3
    nb: int = 3
    nk: int = 1
    pop_size: int = 100
    max_iter: int = 200
    seed: int | None = 0
    optimizer_options: Mapping[str, Any] | None = None
    y_init: Any = None
    u_init: Any = None
    max_pole_radius: float | None = MAX_POLE_RADIUS
    progress: bool = False

    def _validate_search(self) -> None:
        _orders(self.na, self.nb, self.nk)
        for name in ("pop_size", "max_iter"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ParameterError(f"{name} must be an integer >= 1, got {value!r}")
        if self.optimizer_options is not None and not isinstance(self.optimizer_options, Mapping):
            raise ParameterError(f"optimizer_options (options=) must be a dict of the "
                                 f"optimiser's settings, got {self.optimizer_options!r}")
        r = self.max_pole_radius
        if r is not None and not (isinstance(r, int | float) and math.isfinite(r) and r > 0):
            raise ParameterError(f"max_pole_radius must be a positive number or None, got {r!r}")


def _search_options(cls: type[Any], options: Any, settings: dict[str, Any], what: str) -> Any:
    """``options`` (an instance of ``cls``, or a dict of optimiser settings as the old
    ``options=``) with ``settings`` applied, validated."""
    if options is None or isinstance(options, cls):
        base = options if options is not None else cls()
    elif isinstance(options, Mapping):
        base = cls(optimizer_options=dict(options))
    else:
        raise ParameterError(f"options must be a {cls.__name__} or a dict of the optimiser's "
                             f"settings, got {options!r}")
    return with_overrides(base, settings, what).validate()


@dataclass(frozen=True)
class MetaheuristicOptions(_SearchOptions):
    """Settings of :func:`fit_metaheuristic`, validated as a whole.

    Every field is also a keyword of :func:`fit_metaheuristic`, which overrides the options
    it is given (``fit_metaheuristic(u, y, t, options=MetaheuristicOptions(method="pso"),
    seed=2)``).

    Attributes
    ----------
    method : str
        Optimiser, a key of :data:`hhra_phys.optim.registry.METHODS` (the paper's ``"pso"``,
        ``"gwo"``, ``"hgwo"``; ``"de"`` works too).
    na, nb, nk : int
        Structure.
    bounds : (lo, hi) or array of shape (na + nb, 2)
        Search box (default the paper's [-5, 5] for every coefficient).
    pop_size, max_iter : int
        Population size and iterations (paper: 100 and 200).
    seed : int or None
        Seed of the optimiser; the same seed reproduces the fit.
    optimizer_options : dict, optional
        Optimiser options (the functions' ``options={...}``), merged over
        :data:`METAHEURISTIC_OPTIONS` for the method.
    x0 : array_like, optional
        Warm-start points, see :func:`hhra_phys.optim.minimize`.
    y_init, u_init : scalar or array_like, optional
        Samples before the record (default: at rest at ``y[0]``), see :func:`itae_cost`.
    max_pole_radius : float or None
        Stability limit of candidates.
    progress : bool
        Show a progress bar.
    """

    method: str = "hgwo"
    bounds: Any = PAPER_BOX
    x0: Any = None

    def validate(self) -> MetaheuristicOptions:
        """Check every setting before any work; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        from hhra_phys.optim.registry import optimiser_class

        self._validate_search()
        optimiser_class(self.method)
        _bounds(self.bounds, self.na + self.nb)
        return self


@dataclass(frozen=True)
class HybridOptions(_SearchOptions):
    """Settings of the paper's hybrid :func:`fit_ffrls_hgwo`, validated as a whole.

    Every field is also a keyword of :func:`fit_ffrls_hgwo`, which overrides the options it
    is given.

    Attributes
    ----------
    na, nb, nk, pop_size, max_iter, seed
        As in :class:`MetaheuristicOptions`, for the H-GWO stage (paper: 100, 200).
    optimizer_options, y_init, u_init, max_pole_radius, progress
        As in :class:`MetaheuristicOptions` (H-GWO's paper options: ``F = 0.5``,
        ``lam = 0.25``).
    zeta_s : float
        Expansion gain of the box (:func:`hybrid_box`), in (0, 1].
    warm_start : bool
        Also put the FFRLS estimate itself into the first population. The paper only uses it
        to place the box, so the default is False.
    xi0, xi_init, p0, theta0
        FFRLS settings, see :func:`fit_ffrls`.
    """

    zeta_s: float = DEFAULT_ZETA_S
    warm_start: bool = False
    xi0: float = FFRLS_XI0
    xi_init: float = FFRLS_XI_INIT
    p0: float = RLS_P0
    theta0: Any = RLS_THETA0

    def validate(self) -> HybridOptions:
        """Check every setting before any work; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        self._validate_search()
        z = self.zeta_s
        if not (isinstance(z, int | float) and math.isfinite(z) and 0.0 < z <= 1.0):
            raise ParameterError(f"zeta_s must lie in (0, 1], got {z!r}")
        forgetting_factor(1, self.xi0, self.xi_init)
        return self


def fit_metaheuristic(
    u: Any,
    y: Any,
    t: Any = None,
    *,
    options: MetaheuristicOptions | Mapping[str, Any] | None = None,
    **settings: Any,
) -> ARXFit:
    """ARX coefficients by PSO, GWO or H-GWO minimising the ITAE of the free-run output.

    The paper's setting (section 4.3): box [-5, 5] for every coefficient, population 100, 200
    iterations; PSO with inertia from 0.9 to 0.1 and ``c1 = c2 = 2``; H-GWO with ``F = 0.5``,
    ``lam = 0.25``, ``Cr = 0.5 (1 + rand)`` (:data:`METAHEURISTIC_OPTIONS`). The whole population
    is evaluated in one call (:func:`itae_cost`); unstable candidates cost ``inf``.

    Parameters
    ----------
    u, y : array_like, shape (N,)
        Measured input and output (estimation data).
    t : array_like, shape (N,), optional
        Time axis [s] for the ITAE.
    options : MetaheuristicOptions or dict, optional
        The fit's settings (default :class:`MetaheuristicOptions`'s); a plain dict holds only
        the optimiser's own options (``optimizer_options``).
    **settings
        Any field of :class:`MetaheuristicOptions`, overriding ``options``: ``method``
        (``"pso"``, ``"gwo"``, ``"hgwo"``), ``na``, ``nb``, ``nk``, ``bounds``, ``pop_size``,
        ``max_iter``, ``seed``, ``x0``, ``y_init``, ``u_init``, ``max_pole_radius``,
        ``progress``.

    Returns
    -------
    ARXFit
        With ``nfev``, ``noi``, ``convergence`` and ``info["best_itae"]``.

    Raises
    ------
    ParameterError
        On bad bounds, an unknown method or option, or any bad setting (before any work).
    DataError
        If no candidate with a finite cost was found (e.g. every one unstable).
    """
    from hhra_phys.optim import minimize

    o = _search_options(MetaheuristicOptions, options, settings, "fit_metaheuristic")
    na, nb, nk = _orders(o.na, o.nb, o.nk)
    box = _bounds(o.bounds, na + nb)
    key = str(o.method).lower()
    opts = {**METAHEURISTIC_OPTIONS.get(key, {}), **dict(o.optimizer_options or {})}
    cost = itae_cost(u, y, t, na, nb, nk, o.y_init, o.u_init, max_pole_radius=o.max_pole_radius)
    start = time.perf_counter()
    res = minimize(
        cost,
        box,
        method=key,
        pop_size=o.pop_size,
        max_iter=o.max_iter,
        seed=o.seed,
        vectorized=True,
        options=opts,
        progress=o.progress,
        x0=o.x0,
    )
    seconds = time.perf_counter() - start
    if not np.isfinite(res.fun):
        raise DataError(
            f"{key}: no candidate in the box gave a finite ITAE (all unstable or diverging); "
            "widen or move the box"
        )
    hist = res.history.as_arrays()
    return ARXFit(
        ARXModel.from_theta(res.x, na, nb, nk),
        key,
        nfev=int(res.nfev),
        noi=int(res.noi),
        seconds=seconds,
        convergence=hist["best"],
        convergence_nfev=hist["nfev"],
        info={
            "best_itae": float(res.fun),
            "nit": int(res.nit),
            "bounds": box.tolist(),
            "options": {k: v for k, v in opts.items() if np.isscalar(v)},
            "pop_size": int(o.pop_size),
            "seed": o.seed,
            "message": str(res.message),
        },
    )


def hybrid_box(
    theta_hat: Any, zeta_s: float = DEFAULT_ZETA_S, min_half_width: float | None = None
) -> np.ndarray:
    """The hybrid's search box, eq. 29: ``theta_hat -/+ zeta_s * |theta_hat|``.

    Parameters
    ----------
    theta_hat : array_like, shape (p,)
        Interim estimate (FFRLS).
    zeta_s : float
        Expansion gain in (0, 1] (the paper allows [0, 1]; 0 would fix every coefficient). The
        paper does not give the value it used; the default is 0.5.
    min_half_width : float, optional
        Smallest half-width of any interval, so that a zero component still gives a valid (if
        tiny) interval, i.e. stays essentially fixed at 0 as eq. 29 implies. Default
        ``1e-12 * max(1, max|theta_hat|)``.

    Returns
    -------
    numpy.ndarray, shape (p, 2)
        ``[lo, hi]`` per coefficient, ``lo < hi``.
    """
    th = np.asarray(theta_hat, dtype=float).ravel()
    if th.size == 0 or not np.isfinite(th).all():
        raise ParameterError(f"theta_hat must be a non-empty finite vector, got {th}")
    if not (np.isfinite(zeta_s) and 0.0 < zeta_s <= 1.0):
        raise ParameterError(f"zeta_s must lie in (0, 1], got {zeta_s!r}")
    floor = 1e-12 * max(1.0, float(np.abs(th).max())) if min_half_width is None else min_half_width
    if not (np.isfinite(floor) and floor > 0):
        raise ParameterError(f"min_half_width must be a positive number, got {min_half_width!r}")
    half = np.maximum(zeta_s * np.abs(th), floor)
    return np.column_stack([th - half, th + half])


def fit_ffrls_hgwo(
    u: Any,
    y: Any,
    t: Any = None,
    *,
    options: HybridOptions | Mapping[str, Any] | None = None,
    **settings: Any,
) -> ARXFit:
    """The paper's hybrid: FFRLS estimate, then H-GWO on the box of eq. 29 around it.

    Parameters
    ----------
    u, y, t : array_like
        As in :func:`fit_metaheuristic`.
    options : HybridOptions or dict, optional
        The fit's settings (default :class:`HybridOptions`'s); a plain dict holds only
        H-GWO's own options (``optimizer_options``).
    **settings
        Any field of :class:`HybridOptions`, overriding ``options``: ``na``, ``nb``, ``nk``,
        ``zeta_s``, ``pop_size``, ``max_iter``, ``seed``, ``warm_start``, ``xi0``,
        ``xi_init``, ``p0``, ``theta0``, ``y_init``, ``u_init``, ``max_pole_radius``,
        ``progress``.

    Returns
    -------
    ARXFit
        Method ``"ffrls_hgwo"``; ``info`` adds ``ffrls_theta``, ``zeta_s`` and the box; seconds
        include the FFRLS step.

    Notes
    -----
    H-GWO's mutation pulls toward ``lam * X_alpha``, i.e. toward the coordinate origin (see
    ``docs/benchmarks.md``). Here the coordinates are the raw coefficients, as in the paper,
    so the pull points toward zero coefficients, which lie outside the box when ``zeta_s < 1``
    (the excess is re-drawn inside the box).
    """
    o = _search_options(HybridOptions, options, settings, "fit_ffrls_hgwo")
    start = time.perf_counter()
    ff = fit_ffrls(u, y, o.na, o.nb, o.nk, xi0=o.xi0, xi_init=o.xi_init, p0=o.p0,
                   theta0=o.theta0)
    theta_hat = ff.model.theta
    box = hybrid_box(theta_hat, o.zeta_s)
    search = {f.name: getattr(o, f.name) for f in fields(_SearchOptions)}
    fit = fit_metaheuristic(
        u,
        y,
        t,
        method="hgwo",
        bounds=box,
        x0=theta_hat[None, :] if o.warm_start else None,
        **search,
    )
    fit.method = "ffrls_hgwo"
    fit.seconds = time.perf_counter() - start
    fit.info.update(
        ffrls_theta=theta_hat.tolist(),
        zeta_s=o.zeta_s,
        warm_start=o.warm_start,
        ffrls_stable=ff.model.is_stable(),
    )
    return fit
