"""Local refiners: IPOPT (through CasADi) and NLopt, started from a global result.

Both minimise the smooth least-squares cost ``0.5 * ||r(z)||^2`` of the free-run
residual ``r(z) = y_sim(z) - y`` over the estimation record, in the problem's
fitting coordinates ``z`` and inside its box. Derivatives come from CasADi's
algorithmic differentiation through the RK4 integrator (the same ``mapaccum``
graph the compiled simulator is generated from), so they are exact for the
discretised model.

* :func:`refine_ipopt` -- IPOPT via :func:`casadi.nlpsol`, single shooting by
  default with a Gauss-Newton Hessian ``J^T J`` (or the exact Hessian, or
  L-BFGS), or multiple shooting with continuity constraints for long or
  unstable records.
* :func:`refine_nlopt` -- NLopt with a gradient method fed by the CasADi
  gradient (``LD_LBFGS``, ``LD_SLSQP``, ...) or a derivative-free one
  (``LN_BOBYQA``, ...) evaluated with the compiled simulator.

Each returns a :class:`Stage` recording what it contributed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Literal

import casadi as ca
import numpy as np

from hhra_phys import interrupt
from hhra_phys.errors import ParameterError
from hhra_phys.problem import Problem, RecordProblem

#: Consecutive iterations without a move of more than :data:`STALL_STEP` in any fitting
#: coordinate after which the diagnosis loop's candidate refits stop IPOPT
#: (:func:`refine_ipopt`'s ``stall_iter``; off by default).
STALL_ITER = 5
#: Largest change of a fitting coordinate (decades for a log-scaled parameter, half-box
#: widths for a linear one) per iteration that counts as not moving.
STALL_STEP = 1e-6

__all__ = [
    "Stage",
    "CompiledLeastSquares",
    "least_squares_cost",
    "refine_ipopt",
    "refine_nlopt",
]


@dataclass
class Stage:
    """What one stage of a fit did.

    Attributes
    ----------
    name : str
        ``"hgwo"``, ``"ipopt"``, ``"nlopt:LD_LBFGS"`` ...
    z : ndarray
        Result in fitting coordinates.
    cost_before, cost : float
        The stage's own objective at its start and at its end (the global search
        reports the problem's cost, e.g. ITAE; refiners ``0.5*||r||^2``).
    nfev : int
        Objective (or simulation) evaluations; gradient evaluations in ``info``.
    seconds : float
        Wall time.
    info : dict
        Solver status, iterations and anything else worth keeping.
    """

    name: str
    z: np.ndarray
    cost_before: float
    cost: float
    nfev: int
    seconds: float
    info: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """JSON-able summary (without the coordinates)."""
        return {
            "name": self.name,
            "cost_before": _num(self.cost_before),
            "cost": _num(self.cost),
            "nfev": int(self.nfev),
            "seconds": float(self.seconds),
            "info": self.info,
        }


def _num(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


class CompiledLeastSquares:
    """Residual and exact Jacobian of a problem from compiled forward sensitivities.

    ``r(z) = y_sim(z) - y`` and ``J = dr/dz`` in the problem's fitting
    coordinates, from :class:`~hhra_phys.sensitivity.TrajectorySensitivity`
    (native code, milliseconds per evaluation) and the chain rule through the
    coordinate map and the initial-state rule. The last point is cached because
    IPOPT asks for cost, gradient and Hessian at the same point.

    A problem lists its records with ``blocks()``: pairs of a record's
    :class:`~hhra_phys.problem.RecordProblem` and the indices of its free
    coordinates in the stacked ones. The residuals are stacked record after record
    and each record's Jacobian fills its rows at those columns (zero elsewhere: one
    record's initial state does not move another's output).
    """

    def __init__(self, problem: Problem) -> None:
        from hhra_phys.sensitivity import TrajectorySensitivity

        self.problem = problem
        self.blocks: list[tuple[RecordProblem, np.ndarray]] = problem.blocks()
        self.sens = TrajectorySensitivity.of(self.blocks[0][0].sim)
        self._sens = [TrajectorySensitivity.of(pr.sim) for pr, _ in self.blocks]
        self.n_free = problem.n_free
        self.n_obs = int(sum(pr.y.size for pr, _ in self.blocks))
        self._key: bytes | None = None
        self._value: tuple[np.ndarray, np.ndarray] | None = None
        self._r_key: bytes | None = None
        self._r: np.ndarray | None = None
        self.n_eval = 0
        self.n_resid = 0

    def __call__(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z = np.asarray(z, dtype=float).ravel()
        key = z.tobytes()
        if key == self._key and self._value is not None:
            return self._value
        r = np.empty(self.n_obs)
        J = np.zeros((self.n_obs, self.n_free))
        row = 0
        for (pr, idx), sens in zip(self.blocks, self._sens, strict=True):
            rb, Jb = _block_least_squares(pr, sens, z[idx])
            r[row:row + rb.size] = rb
            J[row:row + rb.size, idx] = Jb
            row += rb.size
        if not (np.isfinite(r).all() and np.isfinite(J).all()):
            r = np.full_like(r, 1e150)  # IPOPT treats huge values as a failed step
            J = np.zeros_like(J)
        self.n_eval += 1
        self._key, self._value = key, (r, J)
        return r, J

    def residual(self, z: np.ndarray) -> np.ndarray:
        """``r(z)`` alone, as :meth:`__call__` gives it, without the Jacobian.

        A line search asks for the cost at trial points and for the Jacobian only at
        the accepted ones; the outputs-only trajectory function costs a fraction of
        the sensitivities (the same discretisation and expressions). Non-finite outputs
        are flagged as in :meth:`__call__`; a point whose outputs are finite but whose
        sensitivities are not is flagged only when its Jacobian is asked for (none of the
        nine candidates of ``benchmarks/bench_candidates.py`` met one in 1131 evaluations).
        """
        z = np.asarray(z, dtype=float).ravel()
        key = z.tobytes()
        if key == self._key and self._value is not None:
            return self._value[0]
        if key == self._r_key and self._r is not None:
            return self._r
        r = np.empty(self.n_obs)
        row = 0
        for (pr, idx), sens in zip(self.blocks, self._sens, strict=True):
            v = pr.from_z(z[idx])
            y = sens.outputs(pr.u, pr.full(v), pr.initial_states(v)[0])
            r[row:row + y.size] = y - pr.y
            row += y.size
        if not np.isfinite(r).all():
            r = np.full_like(r, 1e150)  # as __call__: a failed step
        self.n_resid += 1
        self._r_key, self._r = key, r
        return r


def _block_least_squares(
    pr: RecordProblem, sens: Any, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Residual (N,) and Jacobian (N, n_free) of one one-record problem at coordinates ``z``."""
    n_free = pr.n_free
    v = pr.from_z(z)
    p = pr.full(v)
    x0 = pr.initial_states(v)[0]
    y, dy = sens(pr.u, p, x0)
    nx = pr.model.nx
    # d(x0, p)/dz: analytic for p, central differences for the (cheap) x0 rule.
    dv = np.where(pr._log, np.log(10.0) * v, pr._scale)
    dp = np.zeros((pr.model.n_params, n_free))
    for k, j in enumerate(pr._model_free):
        dp[j, k] = dv[k]
    dx0 = np.zeros((nx, n_free))
    for k in range(n_free):
        step = 1e-7 * max(1.0, abs(z[k]))
        zp, zm = z.copy(), z.copy()
        zp[k] += step
        zm[k] -= step
        dx0[:, k] = (pr.initial_states(pr.from_z(zp))[0]
                     - pr.initial_states(pr.from_z(zm))[0]) / (2 * step)
    # A diverged simulation gives non-finite sensitivities: the cost is then infinite and
    # IPOPT steps back, so the Jacobian's NaN needs no warning.
    with np.errstate(invalid="ignore", over="ignore"):
        return y - pr.y, dy[:, :nx] @ dx0 + dy[:, nx:] @ dp


class _ResidualCallback(ca.Callback):
    """``r(z)`` as a CasADi function, with the compiled Jacobian as its derivative."""

    def __init__(self, engine: CompiledLeastSquares) -> None:
        ca.Callback.__init__(self)
        self.engine = engine
        self._jac: _JacobianCallback | None = None
        self.construct("residual_compiled", {})

    def get_n_in(self) -> int:
        return 1

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.engine.n_free, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.engine.n_obs, 1)

    # Buffers instead of DM: converting a 5000-sample residual element by element
    # cost more than computing it.
    def has_eval_buffer(self) -> bool:
        return True

    def eval_buffer(self, arg: list[Any], res: list[Any]) -> int:
        interrupt.check()  # after Ctrl-C every evaluation fails, so IPOPT stops at once
        z = np.frombuffer(arg[0], dtype=np.float64)
        np.frombuffer(res[0], dtype=np.float64)[:] = self.engine.residual(z)
        return 0

    def has_jacobian(self) -> bool:
        return True

    def get_jacobian(self, name: str, inames: list[str], onames: list[str],
                     opts: dict[str, Any]) -> ca.Callback:
        self._jac = _JacobianCallback(self.engine, name, opts)  # kept alive here
        return self._jac


class _JacobianCallback(ca.Callback):
    def __init__(self, engine: CompiledLeastSquares, name: str, opts: dict[str, Any]) -> None:
        ca.Callback.__init__(self)
        self.engine = engine
        self.construct(name, opts)

    def get_n_in(self) -> int:
        return 2

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        n = self.engine.n_free if i == 0 else self.engine.n_obs
        return ca.Sparsity.dense(n, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.engine.n_obs, self.engine.n_free)

    def has_eval_buffer(self) -> bool:
        return True

    def eval_buffer(self, arg: list[Any], res: list[Any]) -> int:
        interrupt.check()
        z = np.frombuffer(arg[0], dtype=np.float64)
        np.frombuffer(res[0], dtype=np.float64)[:] = self.engine(z)[1].ravel(order="F")
        return 0


class _Derivatives:
    """Symbolic residual, cost and Jacobian of a problem (CasADi's AD of the graph)."""

    def __init__(self, problem: Problem) -> None:
        z = ca.MX.sym("z", problem.n_free)
        r = problem.residual_function()(z)
        self.z = z
        self.f = 0.5 * ca.sumsqr(r)
        self.J = ca.jacobian(r, z)


def least_squares_cost(problem: Problem, z: np.ndarray) -> float:
    """``0.5 * ||y_sim(z) - y||^2`` with the compiled simulator (``inf`` if flagged)."""
    r = problem.simulate_values(problem.from_z(np.asarray(z, dtype=float))) - problem.y
    val = 0.5 * float(np.dot(r, r))
    return val if np.isfinite(val) else np.inf


def refine_ipopt(
    problem: Problem,
    z0: np.ndarray,
    hessian: Literal["gauss-newton", "exact", "lbfgs"] = "gauss-newton",
    shooting: Literal["single", "multiple"] = "single",
    segments: int = 10,
    max_iter: int = 200,
    tol: float = 1e-8,
    verbose: bool = False,
    derivatives: Literal["compiled", "casadi"] = "compiled",
    stall_iter: int = 0,
    stall_step: float = STALL_STEP,
) -> Stage:
    """Refine with IPOPT through ``casadi.nlpsol``.

    Parameters
    ----------
    problem : Problem
        The fitting problem.
    z0 : ndarray, shape (n_free,)
        Start in fitting coordinates (e.g. the global search's best).
    hessian : {"gauss-newton", "exact", "lbfgs"}
        ``"gauss-newton"``: ``J^T J`` from the exact residual Jacobian (default;
        positive semi-definite and cheap); ``"exact"``: CasADi's second-order
        derivatives; ``"lbfgs"``: IPOPT's limited-memory quasi-Newton.
    shooting : {"single", "multiple"}
        Single shooting over the whole record, or multiple shooting: the record
        is cut into ``segments`` pieces whose initial states are decision
        variables tied by continuity constraints (robust for long records or
        unstable models; single shooting is faster for this actuator).
    segments : int
        Number of shooting segments.
    max_iter : int
        IPOPT iteration limit.
    tol : float
        IPOPT convergence tolerance.
    verbose : bool
        Print IPOPT's log.
    derivatives : {"compiled", "casadi"}
        Where the exact residual Jacobian comes from: compiled forward
        sensitivities (:mod:`hhra_phys.sensitivity`, default, milliseconds per
        evaluation) or CasADi's AD of the symbolic graph in its virtual machine.
        Both are exact for the discretised model; the exact Hessian and multiple
        shooting always use the symbolic graph.
    stall_iter : int
        Stop (single shooting) once the iterate has moved less than ``stall_step`` in
        every fitting coordinate for this many consecutive iterations (0, default: never;
        the diagnosis loop's candidate refits use :data:`STALL_ITER`). Such
        iterations are a line search cut down to steps of ``1e-7`` and less: the cost
        is flat there to its rounding (a converged fit whose tolerance the rounding of
        a 5000-sample sum cannot meet) or has a kink the Gauss-Newton model does not
        see, and each of them costs up to 20-27 cost evaluations (the backlash refit of
        ``benchmarks/bench_candidates.py``, seed 2: 400 of 506 in its ROS4 x 8 run,
        the objective the same to 8 digits over its last 25 iterations). The stage's
        ``info["stalled"]`` says whether it stopped so. Plain fits keep running: the
        stop moves a converged optimum by up to about ``1e-5`` in fitting coordinates,
        which after the loop's base fit was enough to change what discovery proposed.
    stall_step : float
        Largest per-iteration change of a fitting coordinate that counts as not moving.

    Returns
    -------
    Stage
    """
    _check_ipopt_choices(derivatives, hessian, shooting)
    t0 = time.perf_counter()
    z0 = np.asarray(z0, dtype=float)
    bz = problem.bounds_z()
    z0 = np.clip(z0, bz[:, 0], bz[:, 1])
    if shooting == "multiple":
        if len(problem.records) > 1:
            raise ParameterError("multiple shooting fits one record; use shooting='single' "
                                 "for several records")
        return _ipopt_multiple_shooting(problem.records[0], z0, hessian, segments, max_iter,
                                        tol, verbose, t0)
    use_compiled = derivatives == "compiled" and hessian != "exact"
    callback = None
    if use_compiled:
        callback = _ResidualCallback(CompiledLeastSquares(problem))
        zsym = ca.MX.sym("z", problem.n_free)
        r = callback(zsym)
        d_z, d_f, d_J = zsym, 0.5 * ca.sumsqr(r), ca.jacobian(r, zsym)
    else:
        d = _Derivatives(problem)
        d_z, d_f, d_J = d.z, d.f, d.J
    cost_before = least_squares_cost(problem, z0)
    opts = _ipopt_options(max_iter, tol, verbose)
    stall = _Stall(problem.n_free, stall_iter, stall_step) if stall_iter > 0 else None
    if stall is not None:
        opts["iteration_callback"] = stall
    nlp = {"x": d_z, "f": d_f}
    if hessian == "gauss-newton":
        opts["hess_lag"] = _gauss_newton_hessian(d_z, d_J)
    elif hessian == "lbfgs":
        opts["ipopt.hessian_approximation"] = "limited-memory"
    solver = ca.nlpsol("refine_ipopt", "ipopt", nlp, opts)
    with interrupt.interruptible():  # CasADi swallows a Ctrl-C raised in the callbacks
        sol = solver(x0=z0, lbx=bz[:, 0], ubx=bz[:, 1])
    stats = dict(solver.stats())
    stalled = stall is not None and stall.stopped
    if stalled:
        stats["return_status"] = "Stalled"  # not "User_Requested_Stop": no user asked
    return _ipopt_stage(problem, z0, cost_before, np.array(sol["x"]).ravel(), stats,
                        t0, hessian=hessian, shooting="single",
                        derivatives="compiled" if use_compiled else "casadi", stalled=stalled)


def _check_ipopt_choices(derivatives: str, hessian: str, shooting: str) -> None:
    """:func:`refine_ipopt`'s named choices, each checked before any work."""
    if derivatives not in ("compiled", "casadi"):
        raise ParameterError(f"derivatives must be 'compiled' or 'casadi', got {derivatives!r}")
    if hessian not in ("gauss-newton", "exact", "lbfgs"):
        raise ParameterError(f"hessian must be 'gauss-newton', 'exact' or 'lbfgs', got {hessian!r}")
    if shooting not in ("single", "multiple"):
        raise ParameterError(f"shooting must be 'single' or 'multiple', got {shooting!r}")


class _Stall(ca.Callback):
    """IPOPT's iteration callback: stop after ``window`` consecutive iterations that moved
    the iterate by less than ``step`` in every coordinate (:func:`refine_ipopt`)."""

    def __init__(self, n: int, window: int, step: float) -> None:
        ca.Callback.__init__(self)
        self.n, self.window, self.step = int(n), int(window), float(step)
        self._x: np.ndarray | None = None
        self._still = 0
        self.stopped = False
        self.construct("stall", {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        name = ca.nlpsol_out(i)
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.n, 1)
        return ca.Sparsity.dense(1, 1) if name == "f" else ca.Sparsity(0, 0)

    def eval(self, arg: list[Any]) -> list[Any]:
        x = np.array(arg[0], dtype=float).ravel()
        moved = self._x is None or not bool(np.max(np.abs(x - self._x)) < self.step)
        self._still = 0 if moved else self._still + 1
        self._x = x
        self.stopped = self._still >= self.window
        return [1 if self.stopped else 0]


def _ipopt_options(max_iter: int, tol: float, verbose: bool) -> dict[str, Any]:
    return {
        "ipopt.max_iter": int(max_iter),
        "ipopt.tol": float(tol),
        "ipopt.print_level": 5 if verbose else 0,
        "print_time": bool(verbose),
        "ipopt.sb": "yes",
        # A trial point where the model blows up is an infinite cost IPOPT steps back
        # from (as a failed simulation in a population): not a warning for the user.
        "show_eval_warnings": bool(verbose),
    }


def _ipopt_stage(
    problem: Problem,
    z0: np.ndarray,
    cost_before: float,
    z: np.ndarray,
    stats: dict[str, Any],
    t0: float,
    **info: Any,
) -> Stage:
    """The IPOPT stage, never handing back something worse than its start."""
    cost = least_squares_cost(problem, z)
    if not cost <= cost_before:
        z, cost = z0, cost_before
    return Stage(
        "ipopt", z, cost_before, cost,
        nfev=int(stats.get("n_call_nlp_f", 0)),
        seconds=time.perf_counter() - t0,
        info={
            "status": stats.get("return_status"),
            "success": bool(stats.get("success", False)),
            "iterations": int(stats.get("iter_count", 0)),
            "n_grad": int(stats.get("n_call_nlp_grad_f", 0)),
            **info,
        },
    )


def _gauss_newton_hessian(z: ca.MX, J: ca.MX) -> ca.Function:
    lam_f = ca.MX.sym("lam_f")
    H = lam_f * ca.mtimes(J.T, J)
    return ca.Function(
        "gn_hess", [z, ca.MX.sym("p", 0), lam_f, ca.MX.sym("lam_g", 0)], [ca.triu(H)],
        ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"],
    )


def _ipopt_multiple_shooting(
    problem: RecordProblem,
    z0: np.ndarray,
    hessian: str,
    segments: int,
    max_iter: int,
    tol: float,
    verbose: bool,
    t0: float,
) -> Stage:
    """Multiple shooting: segment initial states are variables, continuity is a constraint."""
    n = problem.y.size
    segments = int(segments)
    if segments < 2 or n // segments < 5:
        raise ParameterError(f"segments must be >= 2 with at least 5 samples each, got {segments}")
    sim = problem.sim
    m = problem.model
    nx = m.nx
    edges = np.linspace(0, n, segments + 1).astype(int)
    # Start the shooting states on the single-shooting trajectory of z0.
    v0 = problem.from_z(z0)
    _, X_init = sim.simulate(problem.u, problem.full(v0),
                             x0=problem.initial_states(v0)[0], states=True)
    z = ca.MX.sym("z", problem.n_free)
    p_full, x_first = problem.symbolic(z)
    S = [ca.MX.sym(f"s{i}", nx) for i in range(1, segments)]
    starts = [x_first, *S]
    residuals, gaps = [], []
    for i in range(segments):
        a, b = edges[i], edges[i + 1]
        last = i == segments - 1
        length = b - a if last else b - a + 1  # one more sample gives the end state
        traj = sim.trajectory_function(length, states=not last)
        U = sim.input_matrix(problem.u[a:a + length])
        out = traj.call([starts[i], p_full, ca.DM(U)])
        residuals.append(ca.vec(out[0])[: b - a] - ca.DM(problem.y[a:b]))
        if not last:
            X = out[1]
            gaps.append(X[:, b - a] - S[i])
    r = ca.vertcat(*residuals)
    f = 0.5 * ca.sumsqr(r)
    w = ca.vertcat(z, *S)
    g = ca.vertcat(*gaps)
    w0 = np.concatenate([z0, *[X_init[edges[i]] for i in range(1, segments)]])
    bz = problem.bounds_z()
    lbw = np.concatenate([bz[:, 0], np.full(nx * (segments - 1), -np.inf)])
    ubw = np.concatenate([bz[:, 1], np.full(nx * (segments - 1), np.inf)])
    opts = _ipopt_options(max_iter, tol, verbose)
    if hessian == "gauss-newton":
        lam_f = ca.MX.sym("lam_f")
        lam_g = ca.MX.sym("lam_g", g.numel())
        Jr = ca.jacobian(r, w)
        # Gauss-Newton for the cost; the constraints' curvature is dropped (GN-SQP style).
        H = lam_f * ca.mtimes(Jr.T, Jr)
        opts["hess_lag"] = ca.Function("gn_hess_ms", [w, ca.MX.sym("p", 0), lam_f, lam_g],
                                       [ca.triu(H)])
    elif hessian == "lbfgs":
        opts["ipopt.hessian_approximation"] = "limited-memory"
    solver = ca.nlpsol("refine_ipopt_ms", "ipopt", {"x": w, "f": f, "g": g}, opts)
    cost_before = least_squares_cost(problem, z0)
    with interrupt.interruptible():
        sol = solver(x0=w0, lbx=lbw, ubx=ubw, lbg=0, ubg=0)
    zs = np.array(sol["x"]).ravel()[: problem.n_free]
    return _ipopt_stage(problem, z0, cost_before, zs, solver.stats(), t0, hessian=hessian,
                        shooting="multiple", segments=segments)


#: NLopt algorithms offered by name; ``LD_*`` use the CasADi gradient.
NLOPT_ALGORITHMS: tuple[str, ...] = (
    "LD_LBFGS", "LD_SLSQP", "LD_MMA", "LD_TNEWTON", "LN_BOBYQA", "LN_NELDERMEAD", "LN_SBPLX",
    "LN_COBYLA",
)


def refine_nlopt(
    problem: Problem,
    z0: np.ndarray,
    algorithm: str = "LD_LBFGS",
    max_eval: int = 500,
    xtol_rel: float = 1e-10,
    ftol_rel: float = 1e-12,
) -> Stage:
    """Refine with NLopt.

    Parameters
    ----------
    problem : Problem
        The fitting problem.
    z0 : ndarray, shape (n_free,)
        Start in fitting coordinates.
    algorithm : str
        NLopt algorithm name (see :data:`NLOPT_ALGORITHMS`): gradient-based
        ``LD_*`` methods get the exact gradient ``J^T r`` from the compiled
        forward sensitivities (CasADi derivatives); derivative-free ``LN_*``
        methods evaluate the compiled simulator only.
    max_eval : int
        Evaluation budget.
    xtol_rel, ftol_rel : float
        NLopt's relative tolerances on the coordinates and the cost.

    Returns
    -------
    Stage
    """
    import nlopt

    algorithm = algorithm.upper()
    if algorithm not in NLOPT_ALGORITHMS:
        raise ParameterError(
            f"algorithm must be one of {', '.join(NLOPT_ALGORITHMS)}, got {algorithm!r}"
        )
    t0 = time.perf_counter()
    bz = problem.bounds_z()
    z0 = np.clip(np.asarray(z0, dtype=float), bz[:, 0], bz[:, 1])
    gradient_based = algorithm.startswith("LD_")
    engine = CompiledLeastSquares(problem) if gradient_based else None
    counter = {"f": 0, "g": 0}

    def objective(x: np.ndarray, grad: np.ndarray) -> float:
        interrupt.check()
        counter["f"] += 1
        if grad.size > 0 and engine is not None:
            counter["g"] += 1
            r, J = engine(x)
            fval = 0.5 * float(r @ r)
            g = J.T @ r
            if not (np.isfinite(fval) and fval < 1e299 and np.isfinite(g).all()):
                grad[:] = 0.0
                return np.inf
            grad[:] = g
            return fval
        return least_squares_cost(problem, x)

    opt = nlopt.opt(getattr(nlopt, algorithm), problem.n_free)
    opt.set_lower_bounds(bz[:, 0])
    opt.set_upper_bounds(bz[:, 1])
    opt.set_min_objective(objective)
    opt.set_maxeval(int(max_eval))
    opt.set_xtol_rel(float(xtol_rel))
    opt.set_ftol_rel(float(ftol_rel))
    if not gradient_based:
        opt.set_initial_step(np.minimum(0.05, 0.25 * (bz[:, 1] - bz[:, 0])))
    cost_before = least_squares_cost(problem, z0)
    try:
        with interrupt.interruptible():  # NLopt may turn a Ctrl-C into a forced stop
            z = opt.optimize(z0)
        status = int(opt.last_optimize_result())
    except (nlopt.RoundoffLimited, RuntimeError, ValueError) as exc:
        z = z0
        status = f"{type(exc).__name__}: {exc}"
    cost = least_squares_cost(problem, z)
    if not cost <= cost_before:
        z, cost = z0, cost_before
    return Stage(
        f"nlopt:{algorithm}", np.asarray(z, dtype=float), cost_before, cost,
        nfev=counter["f"],
        seconds=time.perf_counter() - t0,
        info={"status": status, "n_grad": counter["g"], "algorithm": algorithm},
    )
