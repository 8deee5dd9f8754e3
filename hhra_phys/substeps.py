"""How a :class:`~hhra_phys.simulate.Simulator` integrates: method, substeps, accuracy.

The rules of the simulator's module docstring (:mod:`hhra_phys.simulate`), apart from
the code that runs them:

* :meth:`~hhra_phys.simulate.Simulator.plan`: the method and substeps for a parameter
  vector, from the eigenvalues of the state Jacobian at rest (and at the check points of
  the stability index), RK4 unless the model is stiff, then ROS4;
* :meth:`~hhra_phys.simulate.Simulator.stability_index`: the spectral radius times the
  substep at the check points, by which a population flags its unstable members;
* the accuracy rule: :func:`step_doubling_error` estimates the output error from the same
  simulation with 2x and 4x the steps, :func:`accuracy_tolerance` is the share of the
  record's noise a fit can ignore, and :meth:`~hhra_phys.simulate.Simulator.accurate`
  doubles the substeps until the estimate is within it.

Separate from :mod:`hhra_phys.simulate` so that the rule (what to integrate with, and how
finely) reads on its own, without the compiled population code. :class:`_StepRule` is a
mixin of :class:`~hhra_phys.simulate.Simulator` (its methods read the simulator's model,
sample period, method and substeps); every name here is also importable from
:mod:`hhra_phys.simulate`.
"""

from __future__ import annotations

import math
from typing import TypeVar

import casadi as ca
import numpy as np

from hhra_phys.compile import CompiledFunction, compile_function

#: The simulator a method of the mixin is called on (its return is another of the same class;
#: a TypeVar, not an import of hhra_phys.simulate, which imports this module).
_Sim = TypeVar("_Sim")

__all__ = [
    "step_doubling_error",
    "accuracy_tolerance",
]


#: Most RK4 substeps per sample the automatic choice uses; a model needing more is
#: stiff and integrated with ROS4 instead.
RK4_MAX_SUBSTEPS = 8

#: Accuracy rule: largest ``|lambda| * h`` of the modes a method must resolve
#: (RK4: every mode; ROS4: every mode but the stiff real ones, see
#: :meth:`Simulator.plan`). Measured in ``docs/performance.md``.
RK4_ACCURACY = 0.25
ROS4_ACCURACY = 0.25

#: Fewest ROS4 substeps per sample for a model with a stiff mode.
ROS4_MIN_STIFF = 8

#: A real eigenvalue (``|Im| < 0.1 |lambda|``) with ``|lambda| * dt`` above this
#: relaxes within a sample: ROS4 (A-stable, damping it) need not resolve it.
STIFF_REAL = 2.0

#: Most substeps per sample ``substeps="auto"`` may choose; more is refused
#: (:class:`SimulationError`) as a sign of a time axis in the wrong unit.
MAX_AUTO_SUBSTEPS = 64

#: Accuracy rule (:meth:`Simulator.accurate`): the estimated integration error of the
#: output at most this share of the record's noise level.
ACCURACY_SHARE = 0.1

#: Finest run of the step-doubling estimate at a fit's values (``accurate(finest=...)``):
#: the rule may then choose up to a quarter of it, 64 substeps. At start values the
#: estimate stops at :data:`MAX_AUTO_SUBSTEPS` (a search's substeps, up to 16, set its
#: cost before its values are known); at fitted values the result's bias is at stake.
#: Why: a drive's Coulomb friction sharpened to 1e-4 m/s, fitted at ROS4 x 16 with an
#: error estimate of 1.5x the tolerance, tested at 2.3x the noise; refitted at x 64 at
#: 1.02x (the true structure's refit 1.00x).
MAX_ACCURACY_SUBSTEPS = 4 * MAX_AUTO_SUBSTEPS

#: Samples per call of the error estimate's CasADi-VM map.
ACCURACY_CHUNK = 500
#: Step-doubling outputs kept per simulator (:meth:`Simulator.integration_error`).
VM_MEMO = 12


def step_doubling_error(y1: np.ndarray, y2: np.ndarray, y4: np.ndarray) -> float:
    """Largest error of ``y1`` estimated from the same simulation with 2x and 4x the steps.

    With ``d1 = max|y1 - y2|`` and ``d2 = max|y2 - y4|`` the observed ratio
    ``r = d1/d2`` (clipped to ``[2, 16]``, orders 1 to 4) gives the error of ``y1``
    as the geometric series ``d1 * r / (r - 1)``. The clip keeps the estimate
    honest where the order is not the method's: a switching friction or valve
    sign converges at first order (``r = 2``: twice ``d1``), a smooth model at
    fourth (``r = 16``: ``d1`` and a fifteenth).

    Parameters
    ----------
    y1, y2, y4 : array, shape (N,)
        Outputs with ``n``, ``2n`` and ``4n`` steps per sample.

    Returns
    -------
    float
        The estimate (output units); ``inf`` if any output is not finite.
    """
    y1, y2, y4 = (np.asarray(y, dtype=float) for y in (y1, y2, y4))
    if not (np.isfinite(y1).all() and np.isfinite(y2).all() and np.isfinite(y4).all()):
        return math.inf
    d1 = float(np.max(np.abs(y1 - y2), initial=0.0))
    d2 = float(np.max(np.abs(y2 - y4), initial=0.0))
    if d1 == 0.0:
        return 0.0
    r = min(max(d1 / d2 if d2 > 0 else 16.0, 2.0), 16.0)
    return d1 * r / (r - 1.0)


def accuracy_tolerance(y: np.ndarray, share: float = ACCURACY_SHARE) -> float:
    """``share`` of a record's noise level: the integration error a fit can ignore.

    The noise level is the robust standard deviation of the third differences of
    the measured output divided by ``sqrt(20)`` (white noise of standard deviation
    ``s`` has third differences of standard deviation ``sqrt(20) s``; a smooth
    output's contribution falls with the cube of the sample period). A record
    without noise (a simulated one) gets ``share`` of 1e-4 of its range instead.

    Parameters
    ----------
    y : array, shape (N,)
        Measured output (output units).
    share : float
        Share of the noise level.

    Returns
    -------
    float
        Tolerance in output units (positive).
    """
    y = np.asarray(y, dtype=float)
    y = y[np.isfinite(y)]
    if y.size < 8:
        return math.inf
    d = np.diff(y, 3)
    noise = float(np.median(np.abs(d - np.median(d)))) * 1.4826 / math.sqrt(20.0)
    floor = 1e-4 * float(np.ptp(y))
    level = max(noise, floor)
    return share * level if level > 0 else math.inf


class _StepRule:
    """The method, substeps, stability and accuracy rules of a
    :class:`~hhra_phys.simulate.Simulator` (a mixin: its methods read the simulator's
    ``model``, ``dt``, ``h``, ``method``, ``substeps``, ``rho_max`` and compiled functions)."""

    def _eigenvalues(self, p: np.ndarray, umax: float | None) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues of the state Jacobian (1/s): at rest, and at every check point.

        ``umax=None``: at rest only (both arrays the same).
        """
        fn = self._fns["jac"]
        nl = self.model.n_lags + 1
        if umax is None:
            xs, us = self.model.x0()[None, :], np.zeros(1)
        else:
            xs, us = self._check_points(float(umax))
        # The parts' own stiffest states count as rest: a stiffness that only shows
        # in motion (a sharp backlash carried at contact) must set the method too.
        extra = self._part_stiff_states(p)
        out = []
        for x, u in zip([*extra, *xs], [0.0] * len(extra) + list(us), strict=True):
            jac = np.array(fn(x, np.full(nl, u), p), dtype=float)
            out.append(np.linalg.eigvals(jac) if jac.size and np.isfinite(jac).all()
                       else np.array([np.inf]))
        return np.concatenate(out[: len(extra) + 1]), np.concatenate(out)

    def _part_stiff_states(self, p: np.ndarray) -> list[np.ndarray]:
        """State vectors from the parts' ``stiff_states(values)`` (rest elsewhere).

        Each part's :meth:`~hhra_phys.parts.Part.stiff_states`: where it is
        stiffest and rest does not show it (the backlash's contact in motion,
        :meth:`hhra_phys.effects.Backlash.stiff_states`).
        """
        m = self.model
        values = dict(zip(m.params.names, np.asarray(p, dtype=float).tolist(), strict=True))
        out = []
        for part in m.parts:
            for named in part.stiff_states(values):
                x = m.x0().astype(float)
                for name, v in named.items():
                    # "@velocity": the model's velocity state, bound by role.
                    name = m.motion.velocity if name == "@velocity" else name
                    x[m.state_names.index(name)] = v
                out.append(x)
        return out

    def plan(self, p: np.ndarray, umax: float | None = None,
             method: str | None = None) -> tuple[str, int, str]:
        """Method and substeps this simulator's rule gives for parameters ``p``.

        Parameters
        ----------
        p : array, shape (n_params,)
            One parameter vector.
        umax : float, optional
            Largest input magnitude of the record (input units): RK4's substeps
            then also keep every check point of :meth:`stability_index` below
            ``rho_max/2``. ``None``: the rest state only.
        method : {"rk4", "ros2", "ros4"}, optional
            Force the method (default: RK4 unless it would need more than
            :data:`RK4_MAX_SUBSTEPS`).

        Returns
        -------
        method : str
        substeps : int
        reason : str
            The figures behind the choice.
        """
        p = np.asarray(p, dtype=float)
        rest, points = self._eigenvalues(p, umax)
        dt = self.dt
        rho_rest = float(np.max(np.abs(rest)))
        rho_pts = float(np.max(np.abs(points)))
        if not math.isfinite(rho_rest) or not math.isfinite(rho_pts):  # before any ceil(inf)
            return (method or "rk4", 2, "non-finite state Jacobian")
        n_rk4 = max(2, math.ceil(rho_rest * dt / RK4_ACCURACY))
        if umax is not None:
            n_rk4 = max(n_rk4, math.ceil(rho_pts * dt / (0.5 * self.rho_max)))
        # ROS4 need not resolve stiff real modes (they relax within a sample); the
        # others, oscillatory or slow, set its substeps (at rest, like RK4's rule).
        mod = np.abs(rest)
        stiff = (np.abs(rest.imag) < 0.1 * mod) & (mod * dt > STIFF_REAL)
        rho_ns = float(np.max(mod[~stiff])) if (~stiff).any() else 0.0
        # A stiff mode is damped by R(-inf) = 1/3 per ROS4 step, and each friction
        # reversal is resolved to first order only: at least 8 steps per sample
        # (docs/performance.md: 2.7e-2 deg with 2, 2e-3 to 1e-2 with 4, 3e-4 with 8).
        n_ros = max(ROS4_MIN_STIFF if stiff.any() else 2,
                    math.ceil(rho_ns * dt / ROS4_ACCURACY))
        if not math.isfinite(rho_rest) or not math.isfinite(rho_pts):
            return (method or "rk4", 2, "non-finite state Jacobian")
        figures = (f"spectral radius at rest {rho_rest:.4g} 1/s, over the check points "
                   f"{rho_pts:.4g} 1/s, of the non-stiff modes {rho_ns:.4g} 1/s")
        if method is None:
            # ROS4 pays off only when stiff real modes are what RK4 would resolve.
            method = "rk4" if n_rk4 <= RK4_MAX_SUBSTEPS or n_ros >= n_rk4 else "ros4"
            if method == "rk4":
                why = (f"not stiff (RK4 needs {n_rk4} substeps"
                       + (")" if n_rk4 <= RK4_MAX_SUBSTEPS else
                          ", its fastest modes are not real: ROS4 would need as many)")
                       + f": {figures}")
            else:
                why = (f"stiff (RK4 would need {n_rk4} substeps, more than "
                       f"{RK4_MAX_SUBSTEPS}): {figures}")
        else:
            why = figures
        return method, (n_rk4 if method == "rk4" else n_ros), why

    # -- accuracy ------------------------------------------------------------------------
    def _sample_map(self, method: str, substeps: int) -> ca.Function:
        """CasADi-VM map of one sample of ``substeps`` steps over :data:`ACCURACY_CHUNK` samples.

        ``(x0[nx], rows[n_u, chunk], p[n_params]) -> (x_end[nx], y[1, chunk])`` with the
        columns of :meth:`input_rows`, so the input moves between samples as
        :attr:`intersample` says: the error estimate runs outside the compiled code, so
        it needs no compilation of its own.
        """
        key = (method, int(substeps))
        cache = self._vm_maps
        if key not in cache:
            m = self.model
            x = ca.SX.sym("x", m.nx)
            u = ca.SX.sym("u", self.n_u)
            p = ca.SX.sym("p", m.n_params)
            x_next = self.advance_sample(x, u, p, method=method, substeps=int(substeps))
            one = ca.Function("sample", [x, u, p],
                              [x_next, self._fns["h"](x, self.sample_input(u), p)], {"cse": True})
            cache[key] = one.mapaccum("samples", ACCURACY_CHUNK, [0], [0], {})
        return cache[key]

    def _vm_output(self, u: np.ndarray, p: np.ndarray, x0: np.ndarray, method: str,
                   substeps: int) -> np.ndarray:
        """Output of one parameter vector with ``method`` x ``substeps`` (CasADi VM)."""
        key = (u.tobytes(), np.asarray(p, dtype=float).tobytes(),
               np.asarray(x0, dtype=float).tobytes(), method, int(substeps))
        if key in self._vm_memo:
            return self._vm_memo[key]
        y = self._vm_output_of(u, p, x0, method, substeps)
        y.setflags(write=False)  # shared by the callers that ask again
        if len(self._vm_memo) >= VM_MEMO:
            del self._vm_memo[next(iter(self._vm_memo))]
        self._vm_memo[key] = y
        return y

    def _vm_output_of(self, u: np.ndarray, p: np.ndarray, x0: np.ndarray, method: str,
                      substeps: int) -> np.ndarray:
        n = u.size
        fn = self._sample_map(method, substeps)
        n_chunks = -(-n // ACCURACY_CHUNK)
        lags = self.input_rows(u, n_chunks * ACCURACY_CHUNK)
        y = np.empty(n_chunks * ACCURACY_CHUNK)
        x = np.asarray(x0, dtype=float)
        with np.errstate(all="ignore"):
            for c in range(n_chunks):
                cols = slice(c * ACCURACY_CHUNK, (c + 1) * ACCURACY_CHUNK)
                xe, yc = fn(x, lags[:, cols], p)
                x = np.asarray(xe, dtype=float)[:, -1]
                y[cols] = np.asarray(yc, dtype=float).ravel()
                if not np.isfinite(x).all():
                    y[cols.stop:] = np.nan
                    break
        return y[:n]

    def integration_error(self, u: np.ndarray, p: np.ndarray, x0: np.ndarray | None = None,
                          substeps: int | None = None, method: str | None = None) -> float:
        """Estimated largest output error of simulating ``u`` with ``p`` (step doubling).

        The record is simulated with ``n``, ``2n`` and ``4n`` steps per sample
        (:func:`step_doubling_error`); the estimate is that of the ``n``-step output.

        Parameters
        ----------
        u : array, shape (N,)
            Input record (input units).
        p : array, shape (n_params,)
            One parameter vector.
        x0 : array, shape (nx,), optional
            Initial state (default: the model's).
        substeps : int, optional
            ``n`` (default: this simulator's).
        method : str, optional
            Integrator (default: this simulator's).

        Returns
        -------
        float
            Error estimate in output units (``inf`` if a simulation does not stay finite).
        """
        u, P, X0, _ = self._prepare(u, p, x0)
        n = int(substeps or self.substeps)
        meth = method or self.method
        ys = [self._vm_output(u, P[0], X0[:, 0], meth, k * n) for k in (1, 2, 4)]
        return step_doubling_error(*ys)

    def accurate(self: _Sim, u: np.ndarray, p: np.ndarray, tolerance: float,
                 x0: np.ndarray | None = None, coarsest: bool = False,
                 finest: int = MAX_AUTO_SUBSTEPS) -> _Sim:
        """The simulator whose substeps keep the output error of ``(u, p)`` below ``tolerance``.

        Starts from this simulator's substeps when they are stable for ``p`` (the
        population's check, :meth:`stability_index` at most ``rho_max``), else from the
        stability rule's (:meth:`plan` at ``p`` with the record's largest input), and
        doubles them while the step-doubling estimate (:meth:`integration_error`)
        exceeds ``tolerance``, up to a quarter of ``finest`` (the estimate's finest run
        then has that many); parameters whose stability rule
        alone needs more than :data:`MAX_AUTO_SUBSTEPS` are not estimated
        (``error_estimate`` ``None``). The method stays this simulator's (chosen by
        stiffness). The returned simulator (``self`` when its substeps suffice, else one
        with fixed substeps, built once and kept) carries :attr:`accuracy`: ``method``,
        ``substeps``, ``error_estimate``, ``tolerance``, ``rule_substeps`` (the stability
        rule's), ``start_substeps`` and ``within`` (whether the estimate is at most the
        tolerance).

        Parameters
        ----------
        u : array, shape (N,)
            Input record (input units).
        p : array, shape (n_params,)
            The parameters being simulated (a fit's start or result).
        tolerance : float
            Largest acceptable output error (output units), e.g. 10 % of the record's
            noise level (:func:`accuracy_tolerance`).
        x0 : array, shape (nx,), optional
            Initial state.
        coarsest : bool
            Start from the fewest substeps the method allows for ``p`` instead, so the
            estimate may also choose fewer than this simulator's: the stability rule's
            at ``p`` for RK4, 2 for the Rosenbrock methods (A-stable: the step is stable
            at any size, and the estimate alone says how coarse it may be; a sharp
            backlash whose record ROS4 x 4 integrates within the tolerance, where the
            stiff rule asks for at least :data:`ROS4_MIN_STIFF`).
        finest : int
            Substeps per sample of the estimate's finest run (default
            :data:`MAX_AUTO_SUBSTEPS`; :data:`MAX_ACCURACY_SUBSTEPS` at a fit's values).
        """
        u, P, X0, _ = self._prepare(u, p, x0)
        pv, xv = P[0], X0[:, 0]
        umax = float(np.max(np.abs(u)))
        _, n_rule, _ = self.plan(pv, umax, method=self.method)
        if coarsest:
            n = int(n_rule) if self.method == "rk4" else 2
        else:
            # Start at this simulator's substeps where they are stable for p (the
            # population's flagging rule), else at the stability rule's: the error
            # estimate, not the rule's margin, decides whether more are needed.
            stable = (self.method != "rk4"
                      or float(self.stability_index(P, umax)[0]) <= self.rho_max)
            n = (self.substeps if stable or not self.substeps_auto
                 else max(int(n_rule), self.substeps))
        n_start = n
        if n > MAX_AUTO_SUBSTEPS:
            # Parameters the stability rule cannot serve (a held value far off the
            # model's range): the population's stability check flags them; estimating
            # the error would simulate thousands of substeps per sample.
            self.accuracy = {"method": self.method, "substeps": self.substeps,
                             "error_estimate": None, "tolerance": float(tolerance),
                             "rule_substeps": int(n_rule), "within": False,
                             "reason": f"the stability rule needs {n_rule} substeps, more than "
                                       f"{MAX_AUTO_SUBSTEPS}: not estimated"}
            return self
        outs: dict[int, np.ndarray] = {}

        def out(k: int) -> np.ndarray:
            if k not in outs:
                outs[k] = self._vm_output(u, pv, xv, self.method, k)
            return outs[k]

        err = step_doubling_error(out(n), out(2 * n), out(4 * n))
        # A simulation that does not stay finite is the stability check's business
        # (its rows are flagged), not a reason for more substeps.
        # At most `finest` steps per sample in the estimate's finest run.
        while math.isfinite(err) and err > tolerance and 8 * n <= finest:
            n *= 2
            err = step_doubling_error(out(n), out(2 * n), out(4 * n))
        sim = self.with_substeps(n)
        sim.accuracy = {"method": self.method, "substeps": int(n),
                        "error_estimate": float(err), "tolerance": float(tolerance),
                        "rule_substeps": int(n_rule), "start_substeps": int(n_start),
                        "within": bool(err <= tolerance),
                        "reason": self.method_reason}
        return sim

    # -- stability -------------------------------------------------------------------
    def _check_points(self, umax: float) -> tuple[np.ndarray, np.ndarray]:
        """Operating points (states, inputs) at which candidates' Jacobians are checked.

        Rest with no input (the hydraulic resonance), and with a load pressure of
        90 % and 99 % of the supply pressure at the record's largest input of the
        same sign (where the orifice law is stiffest).
        """
        m = self.model
        x0 = m.x0()
        xs, us = [x0], [0.0]
        if "p" in m.state_names:
            ip = m.state_names.index("p")
            for level in (0.9, 0.99):
                for sgn in (1.0, -1.0):
                    x = x0.copy()
                    x[ip] = sgn * level
                    xs.append(x)
                    us.append(sgn * umax)
        else:
            xs += [x0, x0]
            us += [umax, -umax]
        return np.array(xs), np.array(us)

    def stability_index(self, P: np.ndarray, umax: float = 1.0) -> np.ndarray:
        """Spectral radius of the state Jacobian times the RK4 substep, per candidate.

        Parameters
        ----------
        P : array, shape (n_pop, n_params) or (n_params,)
            Parameter vectors.
        umax : float
            Largest input magnitude of the record (input units).

        Returns
        -------
        ndarray, shape (n_pop,)
            ``max |lambda| * h`` over the check points; RK4 needs it below ~2.8.
        """
        P = self.model.params.check_population(P)
        xs, us = self._check_points(float(umax))
        npts = len(us)
        nl = self.model.n_lags + 1
        n_pop = P.shape[0]
        count = npts * n_pop
        if count not in self._stab:
            mapped = self._fns["jac"].map(count)
            fn = mapped if self.backend == "casadi" else compile_function(mapped)
            self._stab[count] = fn if fn is not None else mapped
        X = np.tile(xs.T, (1, n_pop))
        Uv = np.tile(np.repeat(us[None, :], nl, axis=0), (1, n_pop))
        PP = np.repeat(P.T, npts, axis=1)
        J = np.asarray(self._stab[count](X, Uv, PP)[0] if isinstance(
            self._stab[count], CompiledFunction) else self._stab[count](X, Uv, PP))
        nx = self.model.nx
        # Horizontally stacked (nx, nx) blocks -> (count, nx, nx).
        J = J.reshape(nx, nx, count, order="F").transpose(2, 0, 1)
        with np.errstate(all="ignore"):
            finite = np.isfinite(J).all(axis=(1, 2))
            lam = np.zeros(J.shape[0])
            lam[finite] = np.max(np.abs(np.linalg.eigvals(J[finite])), axis=1)
            lam[~finite] = np.inf
        return lam.reshape(n_pop, npts).max(axis=1) * self.h
