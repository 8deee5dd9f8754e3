"""Fast fixed-step simulation of whole parameter populations.

:class:`Simulator` turns a :class:`~hhra_phys.model.Model` into a compiled
simulator of the sampled system: the input is held constant over each sample
(zero-order hold), the state is advanced with classical Runge-Kutta 4 using
``substeps`` steps per sample, and the output is read at the sample instants
(``y[k] = h(x(t_k))``, so ``y[0]`` is the output of the initial state).

Construction (CasADi):

1. ``step``: an SX function advancing one *block* of ``block`` samples (RK4
   substeps unrolled; blocking amortises the per-call overhead of the loop);
2. ``mapaccum`` of the step over the blocks of a chunk (500 samples by default),
   returning the outputs and the final state, so records of any length are
   simulated chunk after chunk;
3. ``map(n_pop, "thread")`` over the population, the input shared by all;
4. C code generation, compiled once per population size by
   :mod:`hhra_phys.compile` and cached on disk.

Without a C compiler the same CasADi functions run in CasADi's virtual machine.

Stability. Explicit RK4 is stable only while ``|lambda| * h`` stays below about
2.8 for every eigenvalue ``lambda`` of the state Jacobian. The hydraulic natural
frequency grows with ``sqrt(g_torque*g_compress)``, and the orifice becomes stiff
near the supply pressure, so a candidate from a wide search box can leave the
stable region. Before simulating, every candidate's Jacobian is evaluated at rest
and at high load pressure with the largest input of the record; a candidate
whose spectral radius times the substep exceeds ``rho_max`` is *flagged*: its
row of the output is NaN and :attr:`Simulator.last_status` says why. Rows whose
simulation overflows or diverges are flagged too. Nothing raises inside a
population evaluation.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import casadi as ca
import numpy as np

from hhra_phys.compile import CompiledFunction, compile_function
from hhra_phys.errors import ParameterError, SimulationError
from hhra_phys.model import Model

#: Largest number of RK4 steps unrolled in one compiled step function
#: (substeps x block x lanes); the block and then the lanes shrink to respect it.
UNROLL_BUDGET = 80

#: Status codes of :attr:`Simulator.last_status`.
STATUS_OK = 0
STATUS_UNSTABLE = 1  # spectral radius times substep above rho_max: not simulated reliably
STATUS_DIVERGED = 2  # non-finite or exploding output


@dataclass
class _Compiled:
    fn: CompiledFunction | ca.Function
    n_members: int  # population padded to a multiple of lanes
    lanes: int
    native: bool


class Simulator:
    """Compiled RK4 simulator of a model for a fixed sample rate.

    Parameters
    ----------
    model : Model
        The model (e.g. :class:`~hhra_phys.model.HHRAModel`).
    fs : float
        Sample rate [Hz] of the input and output.
    substeps : int or "auto"
        RK4 steps per sample. ``"auto"`` chooses the smallest number (at least 2)
        for which the spectral radius of the nominal model at rest times the
        substep is at most 0.25, which kept the integration error of the
        simulated rig below 1e-4 deg against CVODES (``docs/performance.md``).
    threads : int
        Threads used for a population (CasADi thread map).
    block : int
        Samples advanced per call of the compiled step (amortises call overhead).
    lanes : int
        Population members advanced together in one straight-line step, so the
        CPU overlaps their latency-bound arithmetic (populations are padded to a
        multiple of ``lanes * threads``; single simulations use one lane).
    chunk : int
        Samples per compiled call (rounded to a multiple of ``block``). Records of
        any length are simulated chunk after chunk, so one compiled function per
        population size serves every record length.
    backend : {"auto", "native", "casadi"}
        ``"native"`` compiles with the C compiler (error if impossible),
        ``"casadi"`` uses CasADi's virtual machine, ``"auto"`` compiles when a
        compiler is available.
    rho_max : float
        Candidates whose spectral radius times the substep exceeds this are
        flagged (RK4's stability limit is about 2.8 on the real and imaginary
        axes; the default leaves a margin because the check samples the
        state space).
    diverge_limit : float
        An output magnitude beyond this flags the row as diverged.

    Examples
    --------
    >>> from hhra_phys import HHRAModel, Simulator
    >>> model = HHRAModel()
    >>> sim = Simulator(model, fs=250.0)
    >>> y = sim.simulate(u, model.nominal())        # doctest: +SKIP
    >>> Y = sim.simulate(u, P)                       # P: (n_pop, n_params)  # doctest: +SKIP
    """

    def __init__(
        self,
        model: Model,
        fs: float = 250.0,
        substeps: int | str = "auto",
        threads: int = 2,
        block: int = 10,
        lanes: int = 4,
        chunk: int = 500,
        backend: str = "auto",
        rho_max: float = 2.0,
        diverge_limit: float = 1e8,
    ) -> None:
        if not (isinstance(fs, (int, float)) and math.isfinite(fs) and fs > 0):
            raise ParameterError(f"fs must be a positive sample rate in Hz, got {fs!r}")
        if backend not in ("auto", "native", "casadi"):
            raise ParameterError(f"backend must be 'auto', 'native' or 'casadi', got {backend!r}")
        if int(threads) < 1 or int(block) < 1 or int(lanes) < 1:
            raise ParameterError("threads, block and lanes must be positive integers")
        self.model = model
        self.fs = float(fs)
        self.dt = 1.0 / self.fs
        self.threads = int(threads)
        self.block = int(block)
        self.backend = backend
        self.rho_max = float(rho_max)
        self.diverge_limit = float(diverge_limit)
        self._fns = model.functions(self.dt)
        if substeps == "auto":
            self.substeps = self._auto_substeps()
        else:
            if not isinstance(substeps, (int, np.integer)) or substeps < 1:
                raise ParameterError(
                    f"substeps must be a positive integer or 'auto', got {substeps!r}"
                )
            self.substeps = int(substeps)
        self.h = self.dt / self.substeps
        self.lanes = int(lanes)
        # Keep the unrolled step small: a stiff model needing many substeps would
        # otherwise generate megabytes of C (slow to compile, no faster to run).
        while self.substeps * self.block * self.lanes > UNROLL_BUDGET and self.block > 1:
            self.block = max(1, UNROLL_BUDGET // (self.substeps * self.lanes))
            if self.substeps * self.block * self.lanes > UNROLL_BUDGET:
                self.block = 1
        while self.substeps * self.block * self.lanes > UNROLL_BUDGET and self.lanes > 1:
            self.lanes //= 2
        if int(chunk) < 1:
            raise ParameterError("chunk must be a positive number of samples")
        #: Samples per compiled call (a multiple of the block); records are
        #: simulated chunk after chunk.
        self.chunk = max(1, int(chunk) // self.block) * self.block
        self._steps: dict[tuple[bool, int], ca.Function] = {}
        self._compiled: dict[tuple[int, int, bool], _Compiled] = {}
        self._stab: dict[int, CompiledFunction | ca.Function] = {}
        #: Status per row of the last :meth:`simulate` call (``STATUS_*`` codes).
        self.last_status: np.ndarray = np.zeros(0, dtype=int)
        #: Spectral radius times substep per row of the last call.
        self.last_rho: np.ndarray = np.zeros(0)

    # -- construction -------------------------------------------------------------
    def _auto_substeps(self) -> int:
        x = self.model.x0()
        u = np.zeros(self.model.n_lags + 1)
        jac = np.array(self._fns["jac"](x, u, self.model.nominal()))
        rho = float(np.max(np.abs(np.linalg.eigvals(jac)))) if jac.size else 0.0
        n = max(2, math.ceil(rho * self.dt / 0.25))
        if n > 16:
            # Usually a unit mismatch: nominal values per second on data in samples.
            warnings.warn(
                f"the model's fastest eigenvalue ({rho:.3g} 1/s) needs {n} RK4 substeps per "
                f"{self.dt:.3g} s sample; check that the model's time units match the data's "
                "(Model.time_scaled for records in sample units)",
                RuntimeWarning, stacklevel=3,
            )
        return n

    def _build_step(self, states: bool, lanes: int = 1) -> ca.Function:
        """SX function advancing ``block`` samples of ``lanes`` members.

        ``(x[nx, lanes], p[n_params, lanes], U) -> (x_next[nx, lanes], y[block, lanes][, X])``.
        The members share the input. Several lanes in one straight-line function
        let the CPU overlap their independent dependency chains (the square roots
        and divisions of the valve law are latency-bound in a scalar loop).
        """
        m = self.model
        nu = m.n_lags + 1
        x = ca.SX.sym("x", m.nx, lanes)
        p = ca.SX.sym("p", m.n_params, lanes)
        U = ca.SX.sym("U", nu * self.block)
        f, h = self._fns["f"], self._fns["h"]
        hh = self.h
        x_next, y_cols, x_cols = [], [], []
        for lane in range(lanes):
            xk, pk = x[:, lane], p[:, lane]
            ys, xs = [], []
            for k in range(self.block):
                uk = U[k * nu:(k + 1) * nu]
                ys.append(h(xk, uk, pk))
                xs.append(xk)
                for _ in range(self.substeps):
                    k1 = f(xk, uk, pk)
                    k2 = f(xk + hh / 2 * k1, uk, pk)
                    k3 = f(xk + hh / 2 * k2, uk, pk)
                    k4 = f(xk + hh * k3, uk, pk)
                    xk = xk + hh / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            x_next.append(xk)
            y_cols.append(ca.vertcat(*ys))
            x_cols.append(ca.horzcat(*xs))
        # Outputs as (lanes, block): CasADi orders the generated code by a depth-first
        # walk from the outputs in column-major order, so this interleaves the lanes
        # sample by sample, which is what lets the CPU overlap them.
        outs = [ca.horzcat(*x_next), ca.horzcat(*y_cols).T]
        if states:
            outs.append(ca.horzcat(*x_cols))
        # CSE merges what the RK4 stages recompute from the same held input
        # (e.g. the valve's smoothed sign): about 13 % fewer instructions.
        return ca.Function("step", [x, p, U], outs, {"cse": True})

    def trajectory_function(
        self, n: int, states: bool = False, lanes: int = 1, final: bool = False
    ) -> ca.Function:
        """CasADi function of ``lanes`` trajectories over ``n`` samples (for AD and IPOPT).

        Returns
        -------
        casadi.Function
            ``(x0[nx, lanes], p[n_params, lanes], U[(n_lags+1)*block, n_blocks]) -> y``
            with ``y`` of shape (1, n_blocks*block) for one lane (raw block layout
            otherwise, see :meth:`_unpack`), then the states ``X[nx, n_blocks*block]``
            if ``states`` (one lane only), then the state after the last sample
            ``xf[nx, lanes]`` if ``final``. Build ``U`` with :meth:`input_matrix`.
            The function is symbolic (MX), so it can be embedded in cost functions
            and differentiated.
        """
        if states and lanes != 1:
            raise ParameterError("state trajectories are available for one lane only")
        key = (states, lanes)
        if key not in self._steps:
            self._steps[key] = self._build_step(states=states, lanes=lanes)
        step = self._steps[key]
        nb = self._n_blocks(n)
        acc = step.mapaccum("traj_acc", nb, [0], [0], {})
        x0 = ca.MX.sym("x0", self.model.nx, lanes)
        p = ca.MX.sym("p", self.model.n_params, lanes)
        U = ca.MX.sym("U", (self.model.n_lags + 1) * self.block, nb)
        res = acc(x0, ca.repmat(p, 1, nb), U)
        y = ca.reshape(res[1], 1, nb * self.block) if lanes == 1 else res[1]  # (lanes, block*nb)
        outs, names = [y], ["y"]
        if states:
            outs.append(ca.reshape(res[2], self.model.nx, nb * self.block))
            names.append("X")
        if final:
            outs.append(res[0][:, -lanes:])
            names.append("xf")
        return ca.Function("traj", [x0, p, U], outs, ["x0", "p", "U"], names)

    def _unpack(self, raw: np.ndarray, n_members: int, lanes: int, nb: int) -> np.ndarray:
        """Population output in block layout -> (n_members, nb*block).

        Group ``g`` of ``lanes`` members writes a (lanes, block*nb) matrix whose
        column ``b*block + k`` holds sample ``b*block + k`` of every lane; the
        groups are stacked horizontally.
        """
        groups = n_members // lanes
        arr = np.asarray(raw).reshape(lanes, self.block, nb, groups, order="F")
        return arr.transpose(3, 0, 2, 1).reshape(n_members, nb * self.block)

    def _n_blocks(self, n: int) -> int:
        return -(-n // self.block)

    def input_matrix(self, u: np.ndarray) -> np.ndarray:
        """Arrange an input record for :meth:`trajectory_function`.

        Column ``b`` holds, for each of the ``block`` samples ``k`` of block ``b``,
        the current input and ``n_lags`` past inputs ``u[k], u[k-1], ...``. Before
        the record starts the input is taken equal to its first value; the last
        block is padded with the last value (its outputs are discarded).
        """
        u = np.asarray(u, dtype=float)
        n = u.size
        nl = self.model.n_lags
        nb = self._n_blocks(n)
        padded = np.concatenate([np.full(nl, u[0]), u, np.full(nb * self.block - n, u[-1])])
        lags = np.stack([padded[nl - j: nl - j + nb * self.block] for j in range(nl + 1)])
        return lags.T.reshape(nb, self.block * (nl + 1)).T

    def _layout(self, n_pop: int, states: bool) -> tuple[int, int]:
        """(lanes, padded population): populations are padded to whole groups per thread."""
        if n_pop == 1:
            return 1, 1
        lanes = 1 if states else self.lanes
        unit = lanes * self.threads
        return lanes, -(-n_pop // unit) * unit

    def _population_function(self, n_members: int, lanes: int, states: bool) -> _Compiled:
        """Compiled simulation of one chunk of ``chunk`` samples for a padded population.

        The function maps (initial states, parameters, input chunk) to (outputs,
        [states,] final states), so any record length is simulated by chaining
        chunks: one compiled function per population size serves every record.
        """
        key = (n_members, lanes, states)
        if key in self._compiled:
            return self._compiled[key]
        groups = n_members // lanes
        traj = self.trajectory_function(self.chunk, states=states, lanes=lanes, final=True)
        threads = max(1, min(self.threads, groups))
        name = f"hhra_sim_{'x' if states else 'y'}_{n_members}_{lanes}"
        if groups == 1:
            pop = ca.Function(name, traj.mx_in(), traj.call(traj.mx_in()))
        else:
            # Exactly `threads` threads, each running a serial loop over its groups (a
            # thread map over all groups would start one thread per group per call).
            inner = traj.map("popgroups", "serial", groups // threads, [2], [])
            mapped = inner.map("popmap", "thread", threads, [2], []) if threads > 1 else inner
            pop = ca.Function(name, mapped.mx_in(), mapped.call(mapped.mx_in()))
        compiled = None
        if self.backend in ("auto", "native"):
            compiled = compile_function(pop, quiet=self.backend == "auto")
            if compiled is None and self.backend == "native":
                raise SimulationError("backend='native' but the simulator could not be compiled")
        entry = _Compiled(compiled if compiled is not None else pop, n_members, lanes,
                          compiled is not None)
        self._compiled[key] = entry
        return entry

    @property
    def native(self) -> bool | None:
        """Whether the last-built population function runs compiled native code."""
        if not self._compiled:
            return None
        return next(reversed(self._compiled.values())).native

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

    # -- simulation ------------------------------------------------------------------------
    def _prepare(self, u: np.ndarray, P: np.ndarray, x0: np.ndarray | None):
        u = np.asarray(u, dtype=float)
        if u.ndim != 1 or u.size < 1:
            raise ParameterError(f"input u must be a non-empty 1-D array, got shape {u.shape}")
        if not np.isfinite(u).all():
            bad = np.flatnonzero(~np.isfinite(u))
            raise ParameterError(
                f"input u has {bad.size} non-finite samples (first at index {bad[0]})"
            )
        single = np.ndim(P) == 1
        P = self.model.params.check_population(P)
        n_pop = P.shape[0]
        nx = self.model.nx
        if x0 is None:
            X0 = np.tile(self.model.x0()[:, None], (1, n_pop))
        else:
            x0a = np.asarray(x0, dtype=float)
            if x0a.shape == (nx,):
                X0 = np.tile(x0a[:, None], (1, n_pop))
            elif x0a.shape == (n_pop, nx):
                X0 = x0a.T.copy()
            else:
                raise ParameterError(
                    f"x0 has shape {x0a.shape}, expected ({nx},) or ({n_pop}, {nx}) for states "
                    f"{', '.join(self.model.state_names)}"
                )
        return u, P, X0, single

    def simulate(
        self,
        u: np.ndarray,
        P: np.ndarray,
        x0: np.ndarray | None = None,
        states: bool = False,
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Simulate the output for one parameter vector or a whole population.

        Parameters
        ----------
        u : array, shape (N,)
            Input samples (valve current [mA] for the HHRA), held over each sample.
        P : array, shape (n_pop, n_params) or (n_params,)
            Parameter vectors in the order of ``model.params.names``.
        x0 : array, shape (nx,) or (n_pop, nx), optional
            Initial states (default: the model's, at rest).
        states : bool
            Also return the state trajectories.

        Returns
        -------
        Y : ndarray, shape (n_pop, N) or (N,)
            Outputs (degrees for the angle output). Rows of flagged candidates
            (unstable for the integrator, or diverging) are NaN; see
            :attr:`last_status`.
        X : ndarray, shape (n_pop, N, nx) or (N, nx)
            State trajectories, only when ``states=True``.
        """
        u, P, X0, single = self._prepare(u, P, x0)
        n, n_pop = u.size, P.shape[0]
        rho = self.stability_index(P, float(np.max(np.abs(u))))
        status = np.where(rho > self.rho_max, STATUS_UNSTABLE, STATUS_OK)
        lanes, n_members = self._layout(n_pop, states)
        entry = self._population_function(n_members, lanes, states)
        pad = n_members - n_pop
        if pad:  # fill the last groups with copies of the last member
            X0 = np.hstack([X0, np.repeat(X0[:, -1:], pad, axis=1)])
            Pin = np.vstack([P, np.repeat(P[-1:], pad, axis=0)])
        else:
            Pin = P
        U = self.input_matrix(u)
        cb = self.chunk // self.block  # blocks per chunk
        n_chunks = -(-U.shape[1] // cb)
        U = np.hstack([U, np.repeat(U[:, -1:], n_chunks * cb - U.shape[1], axis=1)])
        Ys, Xs = [], []
        x = X0
        PT = np.ascontiguousarray(Pin.T)
        with np.errstate(all="ignore"):
            for c in range(n_chunks):
                Uc = U[:, c * cb:(c + 1) * cb]
                if entry.native:
                    outs = entry.fn(x, PT, Uc)  # type: ignore[operator]
                else:
                    raw = entry.fn(x, PT, Uc)  # type: ignore[operator]
                    outs = [np.array(o) for o in raw]
                if lanes == 1:
                    Ys.append(np.asarray(outs[0]).reshape(n_members, self.chunk))
                else:
                    Ys.append(self._unpack(outs[0], n_members, lanes, cb))
                if states:
                    Xs.append(np.asarray(outs[1]).reshape(
                        self.model.nx, n_members, self.chunk, order="F"))
                x = np.asarray(outs[-1])
            Y = np.hstack(Ys) if len(Ys) > 1 else Ys[0]
            if Y.shape != (n_pop, n):
                Y = np.ascontiguousarray(Y[:n_pop, :n])
            # One pass: NaN, Inf and runaway values all fail "peak <= limit".
            bad = ~(np.max(np.abs(Y), axis=1) <= self.diverge_limit)
        status[(status == STATUS_OK) & bad] = STATUS_DIVERGED
        Y[status != STATUS_OK] = np.nan
        self.last_status, self.last_rho = status, rho
        if states:
            X = np.concatenate(Xs, axis=2).transpose(1, 2, 0)[:n_pop, :n, :].copy()
            X[status != STATUS_OK] = np.nan
            return (Y[0], X[0]) if single else (Y, X)
        return Y[0] if single else Y

    def reference(
        self,
        u: np.ndarray,
        p: np.ndarray,
        x0: np.ndarray | None = None,
        rtol: float = 1e-10,
        atol: float = 1e-10,
        states: bool = False,
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Accurate reference simulation with CVODES, restarted at every sample.

        The zero-order hold makes the right-hand side jump at every sample, so the
        variable-step integrator is re-initialised at each sample instead of
        stepping over the jumps (a single call across them is measurably wrong).
        Slow (about 0.1 ms per sample): meant for accuracy checks and tests.

        Parameters
        ----------
        u : array, shape (N,)
            Input samples.
        p : array, shape (n_params,)
            One parameter vector.
        x0 : array, shape (nx,), optional
            Initial state.
        rtol, atol : float
            CVODES tolerances.
        states : bool
            Also return the states, shape (N, nx).

        Returns
        -------
        ndarray, shape (N,)
            Output at the sample instants.
        """
        u, P, X0, _ = self._prepare(u, p, x0)
        if P.shape[0] != 1:
            raise ParameterError("reference() takes a single parameter vector")
        m = self.model
        nu = m.n_lags + 1
        x = ca.SX.sym("x", m.nx)
        ps = ca.SX.sym("p", m.n_params)
        us = ca.SX.sym("u", nu)
        ode = self._fns["f"](x, us, ps)
        integ = ca.integrator(
            "ref", "cvodes", {"x": x, "p": ca.vertcat(ps, us), "ode": ode}, 0.0, self.dt,
            {"abstol": atol, "reltol": rtol, "max_num_steps": 100000},
        )
        n = u.size
        acc = integ.mapaccum("ref_acc", n, ["x0"], ["xf"], {})
        U = self.input_matrix(u)  # (nu*block, nb)
        lags = U.T.reshape(-1, nu)[:n].T  # (nu, n): lags of every sample
        pv = P[0]
        res = acc(x0=X0[:, 0], p=np.vstack([np.repeat(pv[:, None], n, axis=1), lags]))
        xf = np.array(res["xf"])  # states after each sample
        Xs = np.hstack([X0[:, :1], xf[:, :-1]])  # states at the sample instants
        y = np.array(self._fns["h"].map(n)(Xs, lags, np.repeat(pv[:, None], n, axis=1))).ravel()
        if states:
            return y, Xs.T
        return y
