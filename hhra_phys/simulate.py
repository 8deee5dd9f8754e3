"""Fast fixed-step simulation of whole parameter populations.

:class:`Simulator` turns a :class:`~hhra_phys.model.Model` into a compiled
simulator of the sampled system: the input is held constant over each sample
(zero-order hold), the state is advanced with ``substeps`` steps per sample of
a fixed-step method of :mod:`hhra_phys.integrate` (classical Runge-Kutta 4, or
the linearly implicit Rosenbrock method ROS4 for stiff models), and the output
is read at the sample instants (``y[k] = h(x(t_k))``, so ``y[0]`` is the output
of the initial state).

Inter-sample behaviour (``intersample``, a property of the record,
:attr:`hhra_phys.data.Dataset.intersample`). ``"zoh"`` holds each input sample
over its sample. ``"foh"`` moves the input linearly from one sample to the next,
``u(t) = u_k + (t - t_k)/T * (u_{k+1} - u_k)``, and every input lag with it (a
part reading ``u[k-j]`` sees ``u(t - j*T)``, so delays stay delays); after the
last sample the input is held. ``"cubic"`` is the cubic convolution
(Catmull-Rom, Keys' ``a = -1/2``) through ``u_{k-1} .. u_{k+2}``: it passes
through the samples, reproduces quadratics, and approximates a band-limited
input (one with nothing above the Nyquist frequency) to third order, where a
first-order hold attenuates it by ``sinc^2(f T)``. Under ``"foh"`` and
``"cubic"`` the state is augmented by the interpolated input lags ``v`` and
their derivatives in time, a chain ending in a constant (``dv/dt = (L_{k+1} -
L_k)/T`` for foh), and the same method integrates the augmented state: RK4
then evaluates the input exactly at its stage times (the chain is a polynomial
of degree at most 3), and the Rosenbrock methods get the time derivative of the
right-hand side (``df/du * dv/dt``) through the augmented Jacobian, which is how
a Rosenbrock method treats a non-autonomous system; derivatives (IPOPT, NLopt,
sensitivities) differentiate the same step.

Method and substeps (``method="auto"``, ``substeps="auto"``). The state
Jacobian of the nominal model is evaluated at rest; RK4 keeps the integration
error of the rig far below its noise while ``|lambda| * h <= 0.25``
(``docs/performance.md``), so it gets ``ceil(rho*dt/0.25)`` substeps (at least
2). A model for which that would be more than :data:`RK4_MAX_SUBSTEPS` is
*stiff* (a friction switching within a few thousandths of a rad/s adds a real
eigenvalue of ``-level/width``, tens of thousands per second): it is integrated
with ROS4, a fourth-order Rosenbrock method that is A-stable and damps a stiff
real mode by a factor of 3 per step whatever its speed, so only the remaining
modes (oscillatory, or slower than the sample) set the substeps. A part whose
stiffness does not show at rest (a backlash carried at its contact relaxes at
``|omega|/width``) names the states where it is stiffest with
:meth:`hhra_phys.parts.Part.stiff_states`
(:meth:`hhra_phys.effects.Backlash.stiff_states`); their Jacobians count as
rest's. :attr:`Simulator.method` and :attr:`Simulator.method_reason` say what was
chosen and why.

Single parameter vectors follow their parameters. A simulation of one
parameter vector (``simulate(u, p)`` with ``p`` of shape ``(n_params,)``, and
so every fitted model's prediction) re-applies the rule above to the given
parameters when the simulator was built with ``substeps="auto"`` (never
coarser than the simulator's own choice), and, whatever the settings, refines
the substeps (or switches to ROS4) when the stability check below fails for
them, with a ``RuntimeWarning``. :attr:`Simulator.last_method` and
:attr:`Simulator.last_substeps` say what the last call used. Populations
(optimiser candidates) are never refined: unstable rows are NaN (infinite cost)
so that every candidate of a search is scored by the same discretisation.

Construction (CasADi):

1. ``step``: an SX function advancing one *block* of ``block`` samples (RK4
   substeps unrolled; blocking amortises the per-call overhead of the loop);
2. ``mapaccum`` of the step over the blocks of a chunk (500 samples by default),
   returning the outputs and the final state, so records of any length are
   simulated chunk after chunk;
3. ``map(n_pop, "thread")`` over the population, the input shared by all;
4. C code generation, compiled once per population size by
   :mod:`hhra_phys.compile` and cached on disk. For populations the same code
   is compiled with ``casadi_real`` a SIMD vector (:mod:`hhra_phys.vectorize`),
   so each instance of the step advances ``simd`` members at once (4 to 8 on
   x86 with AVX); results are bit for bit those of the scalar code.

Without a C compiler the same CasADi functions run in CasADi's virtual machine.

Stability. Explicit RK4 is stable only while ``|lambda| * h`` stays below about
2.8 for every eigenvalue ``lambda`` of the state Jacobian (ROS4 at any step). The
hydraulic natural frequency grows with ``sqrt(g_torque*g_compress)``, and the orifice becomes stiff
near the supply pressure, so a candidate from a wide search box can leave the
stable region. Before simulating, every candidate's Jacobian is evaluated at rest
and at high load pressure with the largest input of the record; a candidate
whose spectral radius times the substep exceeds ``rho_max`` (RK4 only) is *flagged*: its
row of the output is NaN and :attr:`Simulator.last_status` says why. Rows whose
simulation overflows or diverges are flagged too. Nothing raises inside a
population evaluation.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import casadi as ca
import numpy as np

# The compiled code, the input between samples, and the method/substeps/accuracy rules
# live in modules of their own (issue 34); their names stay importable from here.
from hhra_phys.codegen import (  # noqa: F401  (re-exported)
    UNROLL_BUDGET,
    CodeOptions,
    _CodeGen,
    _Compiled,
)
from hhra_phys.compile import CompiledFunction
from hhra_phys.data.dataset import INTERSAMPLE
from hhra_phys.errors import ParameterError, SimulationError
from hhra_phys.integrate import METHODS
from hhra_phys.model import Model
from hhra_phys.options import with_overrides
from hhra_phys.sampling import _Sampling
from hhra_phys.substeps import (  # noqa: F401  (re-exported)
    ACCURACY_CHUNK,
    ACCURACY_SHARE,
    MAX_ACCURACY_SUBSTEPS,
    MAX_AUTO_SUBSTEPS,
    RK4_ACCURACY,
    RK4_MAX_SUBSTEPS,
    ROS4_ACCURACY,
    ROS4_MIN_STIFF,
    STIFF_REAL,
    VM_MEMO,
    _StepRule,
    accuracy_tolerance,
    step_doubling_error,
)

__all__ = [
    "CodeOptions",
    "Simulator",
    "step_doubling_error",
    "accuracy_tolerance",
]


#: Status codes of :attr:`Simulator.last_status`.
STATUS_OK = 0
STATUS_UNSTABLE = 1  # spectral radius times substep above rho_max: not simulated reliably
STATUS_DIVERGED = 2  # non-finite or exploding output


class Simulator(_Sampling, _StepRule, _CodeGen):
    """Compiled fixed-step simulator of a model for a fixed sample rate.

    Parameters
    ----------
    model : Model
        The model (e.g. :class:`~hhra_phys.model.HHRAModel`).
    fs : float
        Sample rate [Hz] of the input and output.
    substeps : int or "auto"
        Integration steps per sample. ``"auto"`` chooses them for the method
        (module docstring): for RK4 the smallest number (at least 2) for which
        the spectral radius of the nominal model at rest times the substep is at
        most 0.25, which kept the integration error of the simulated rig below
        1e-4 deg against CVODES (``docs/performance.md``). A number is used as
        given, except that with ``method="auto"`` on a stiff model it is a floor
        under the ROS4 rule (at least :data:`ROS4_MIN_STIFF`).
    method : {"auto", "rk4", "ros2", "ros4"}
        Integration method (:mod:`hhra_phys.integrate`). ``"auto"``: RK4 unless
        the nominal model is stiff (module docstring), then ROS4.
    backend : {"auto", "native", "casadi"}
        ``"native"`` compiles with the C compiler (error if impossible),
        ``"casadi"`` uses CasADi's virtual machine, ``"auto"`` compiles when a
        compiler is available.
    rho_max : float
        With RK4, candidates whose spectral radius times the substep exceeds
        this are flagged (RK4's stability limit is about 2.8 on the real and
        imaginary axes; the default leaves a margin because the check samples
        the state space). ROS4 is stable at any step: nothing is flagged.
    diverge_limit : float
        An output magnitude beyond this flags the row as diverged.
    intersample : {"zoh", "foh", "cubic"}
        What the input does between samples (module docstring): held (``"zoh"``,
        default), linear from one sample to the next (``"foh"``), or the cubic
        convolution through four samples (``"cubic"``). Normally the
        record's :attr:`~hhra_phys.data.Dataset.intersample`;
        :meth:`with_intersample` gives the same simulator with the other one.
    code : CodeOptions, optional
        How the compiled code is laid out (default :class:`CodeOptions`'s).
    **code_settings
        Any field of :class:`CodeOptions` (``threads``, ``block``, ``lanes``, ``chunk``,
        ``simd``), overriding ``code``.

    Attributes
    ----------
    method : str
        The integration method used (``"rk4"``, ``"ros4"``, or ``"ros2"`` if asked for).
    method_reason : str
        Why it was chosen (stiffness figures of the nominal model).
    substeps : int
        Steps per sample.
    last_method, last_substeps : str, int
        What the last :meth:`simulate` call used (a single parameter vector may
        have been refined for its parameters, module docstring).

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
        *,
        method: str = "auto",
        backend: str = "auto",
        intersample: str = "zoh",
        rho_max: float = 2.0,
        diverge_limit: float = 1e8,
        code: CodeOptions | None = None,
        **code_settings: Any,
    ) -> None:
        self._check_settings(fs, substeps, method, backend, intersample)
        lay = with_overrides(code if code is not None else CodeOptions(), code_settings,
                             "simulator code").validate()
        #: How the compiled code is laid out (as given; block and lanes may shrink below).
        self.code = lay
        #: What the input does between samples: "zoh" (held), "foh" (linear), "cubic".
        self.intersample = intersample
        self.model = model
        self.fs = float(fs)
        self.dt = 1.0 / self.fs
        self.threads = int(lay.threads)
        self.block = int(lay.block)
        self.backend = backend
        self.rho_max = float(rho_max)
        self.diverge_limit = float(diverge_limit)
        self.simd = self._simd_target(lay.simd)
        self._simd_arg = lay.simd
        self._threads_arg, self._lanes_arg = int(lay.threads), int(lay.lanes)
        self._block_arg, self._chunk_arg = int(lay.block), int(lay.chunk)
        self._fns = model.functions(self.dt)
        #: Whether the substeps were chosen by the rule (single vectors then follow
        #: their parameters) rather than given.
        self.substeps_auto = substeps == "auto"
        self._choose_method(method, substeps)
        self.h = self.dt / self.substeps
        self.lanes = int(lay.lanes)
        self._fit_unroll_budget()
        #: Samples per compiled call (a multiple of the block); records are
        #: simulated chunk after chunk.
        self.chunk = max(1, int(lay.chunk) // self.block) * self.block
        self._steps: dict[tuple[bool, int], ca.Function] = {}
        # Keyed by (members, lanes, width, kind) and (population, kind); kind is
        # "y" (outputs), "x" (outputs and states), "abs"/"sq" (fused cost).
        self._compiled: dict[tuple[int, int, int, str], _Compiled] = {}
        self._entries: dict[tuple[int, str], _Compiled] = {}
        self._simd_ok: bool | None = None
        self._stab: dict[int, CompiledFunction | ca.Function] = {}
        #: Status per row of the last :meth:`simulate` call (``STATUS_*`` codes).
        self.last_status: np.ndarray = np.zeros(0, dtype=int)
        #: Spectral radius times substep per row of the last call.
        self.last_rho: np.ndarray = np.zeros(0)
        self.last_method: str = self.method
        self.last_substeps: int = self.substeps
        self._derived: dict[tuple[str, int | str], Simulator] = {}
        #: What :meth:`accurate` chose (empty until it was asked).
        self.accuracy: dict[str, object] = {}
        self._vm_maps: dict[tuple[str, int], ca.Function] = {}
        # The last few step-doubling outputs: a fit estimates the error at its fitted
        # values twice (the accuracy check, then the result's error_at_fit).
        self._vm_memo: dict[tuple[Any, ...], np.ndarray] = {}

    # -- construction -------------------------------------------------------------
    @staticmethod
    def _check_settings(fs: float, substeps: int | str, method: str, backend: str,
                        intersample: str) -> None:
        """The constructor's own settings, each checked before any work."""
        if intersample not in INTERSAMPLE:
            raise ParameterError(
                f"intersample must be one of {', '.join(map(repr, INTERSAMPLE))} (input held "
                f"over each sample, linear or cubic between samples), got {intersample!r}")
        if not (isinstance(fs, (int, float)) and math.isfinite(fs) and fs > 0):
            raise ParameterError(f"fs must be a positive sample rate in Hz, got {fs!r}")
        if backend not in ("auto", "native", "casadi"):
            raise ParameterError(f"backend must be 'auto', 'native' or 'casadi', got {backend!r}")
        if method not in ("auto", *METHODS):
            raise ParameterError(
                f"method must be 'auto' or one of {', '.join(METHODS)}, got {method!r}")
        if substeps != "auto" and (
                not isinstance(substeps, (int, np.integer)) or isinstance(substeps, bool)
                or substeps < 1):
            raise ParameterError(
                f"substeps must be a positive integer or 'auto', got {substeps!r}"
            )

    def _choose_method(self, method: str, substeps: int | str) -> None:
        """Set :attr:`method`, :attr:`method_reason` and :attr:`substeps` (module docstring).

        Refuses (before anything is compiled) a rule that asks for more than
        :data:`MAX_AUTO_SUBSTEPS`, and warns from twice :data:`RK4_MAX_SUBSTEPS`.
        """
        chosen, n_auto, why = self.plan(self.model.nominal(),
                                        method=None if method == "auto" else method)
        self.method = chosen
        self.method_reason = why if method == "auto" else f"{method} requested; {why}"
        if substeps == "auto":
            self.substeps = n_auto
        elif method == "auto" and chosen != "rk4":
            # A given count is meant for RK4 on a model that is not stiff; for a
            # stiff one it is a floor under the rule's (ROS4_MIN_STIFF), itself at most
            # MAX_AUTO_SUBSTEPS: a loop candidate's start asked for 459,462 ROS4 substeps
            # (a mode far off the model's range) and its sensitivity's code grew to
            # gigabytes; ROS4 damps what it does not resolve, and the population's check
            # and the accuracy rule see the fitted values.
            self.substeps = max(int(substeps), min(n_auto, MAX_AUTO_SUBSTEPS))
            if n_auto > self.substeps:
                self.method_reason += (f"; the rule's {n_auto} substeps capped at "
                                       f"{self.substeps}")
        else:
            self.substeps = int(substeps)
        if self.substeps_auto and n_auto > MAX_AUTO_SUBSTEPS:
            # Refused before anything is compiled: such a model generates megabytes of C
            # and the cause is nearly always a time axis in the wrong unit.
            raise SimulationError(
                f"the sample period {self.dt:.4g} s needs {n_auto} {chosen.upper()} substeps "
                f"per sample ({why}; at most {MAX_AUTO_SUBSTEPS} are allowed): is the time "
                "column in ms? Pass --time-unit ms (CLI) or divide t by 1000; a record in "
                "sample units needs Model.time_scaled"
            )
        if self.substeps_auto and n_auto > 2 * RK4_MAX_SUBSTEPS:
            # Usually a unit mismatch: nominal values per second on data in samples.
            warnings.warn(
                f"the model's modes that must be resolved need {n_auto} {chosen.upper()} "
                f"substeps per {self.dt:.3g} s sample ({why}); check that the model's time "
                "units match the data's (Model.time_scaled for records in sample units)",
                RuntimeWarning, stacklevel=3,
            )

    def with_substeps(self, n: int, method: str | None = None) -> Simulator:
        """This simulator with ``n`` fixed substeps of ``method`` (default: its own;
        ``self`` when it has them): the same settings otherwise, built once per method
        and count and kept."""
        method = method or self.method
        if n == self.substeps and method == self.method:
            return self
        key = (method, int(n))
        if key not in self._derived:
            self._derived[key] = Simulator(
                self.model, self.fs, substeps=int(n), method=method,
                threads=self._threads_arg, block=self._block_arg, lanes=self._lanes_arg,
                chunk=self._chunk_arg, backend=self.backend, rho_max=self.rho_max,
                diverge_limit=self.diverge_limit, simd=self._simd_arg,
                intersample=self.intersample)
            # Same model, rate and hold: the estimate's VM maps and outputs are the same
            # functions (a fit estimates again with the derived simulator at its fitted
            # values; building a ROS4 x 16 sample graph costs a tenth of a second).
            self._derived[key]._vm_maps = self._vm_maps
            self._derived[key]._vm_memo = self._vm_memo
        return self._derived[key]

    def for_parameters(self, p: np.ndarray, umax: float = 1.0) -> Simulator:
        """The simulator a single parameter vector ``p`` is simulated with.

        ``self`` when its method and substeps suit ``p``, else a simulator with the
        same settings and the method and substeps of :meth:`plan` for ``p`` (built
        once and kept). With ``substeps="auto"`` the rule is re-applied to ``p``
        (never coarser than ``self``); otherwise ``self`` is kept unless the
        stability check fails for ``p``, which gives a ``RuntimeWarning``. A rule
        asking for more than :data:`MAX_AUTO_SUBSTEPS` also keeps ``self`` (its
        population check flags such ``p`` as unstable under RK4).

        Parameters
        ----------
        p : array, shape (n_params,)
            Parameters.
        umax : float
            Largest input magnitude of the record (input units).
        """
        p = self.model.params.check_population(p)[0]
        unstable = bool(self._stability_status(p[None, :], np.array([umax]))[1][0]
                        == STATUS_UNSTABLE)
        if not (unstable or self.substeps_auto):
            return self
        if self.method != "rk4":
            method, n, why = self.plan(p, umax, method=self.method)
        else:
            method, n, why = self.plan(p, umax)
        if method == self.method:
            n = max(n, self.substeps)
            if n == self.substeps:
                return self
        if n > MAX_AUTO_SUBSTEPS:
            # Parameters far off the model's range (a discovered term's coefficient in the
            # millions gave a mode asking for 587,127 ROS4 substeps: one sample's graph
            # grew to gigabytes before any code was generated). Simulated as a population
            # member instead: RK4 flags them (NaN, an infinite cost), ROS4 damps the mode
            # it cannot resolve, as it does a stiff one.
            if unstable:
                warnings.warn(
                    f"these parameters are unstable for {self.method.upper()} with "
                    f"{self.substeps} substeps per sample and would need {n} "
                    f"{method.upper()} substeps, more than {MAX_AUTO_SUBSTEPS} ({why}): "
                    "flagged, not simulated", RuntimeWarning, stacklevel=3)
            return self
        sim = self.with_substeps(n, method)
        if unstable:
            warnings.warn(
                f"these parameters are unstable for {self.method.upper()} with {self.substeps} "
                f"substeps per sample (spectral radius x substep above rho_max "
                f"{self.rho_max:g}): simulated with {method.upper()} and {n} substeps ({why})",
                RuntimeWarning, stacklevel=3,
            )
        return sim

    def with_intersample(self, kind: str) -> Simulator:
        """This simulator with inter-sample behaviour ``kind`` (``self`` if it has it).

        The sibling has the same settings, method and substeps; it is built once and kept.
        """
        if kind == self.intersample:
            return self
        if kind not in INTERSAMPLE:
            raise ParameterError(
                f"intersample must be one of {', '.join(map(repr, INTERSAMPLE))}, got {kind!r}")
        key = ("intersample", kind)
        if key not in self._derived:
            self._derived[key] = Simulator(
                self.model, self.fs, substeps=self.substeps, method=self.method,
                threads=self._threads_arg, block=self._block_arg, lanes=self._lanes_arg,
                chunk=self._chunk_arg, backend=self.backend, rho_max=self.rho_max,
                diverge_limit=self.diverge_limit, simd=self._simd_arg, intersample=kind)
            self._derived[key].substeps_auto = self.substeps_auto
        return self._derived[key]

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

    def _stability_status(self, P: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rho, status): RK4 candidates beyond ``rho_max`` are flagged before simulating."""
        rho = self.stability_index(P, float(np.max(np.abs(u))))
        limit = self.rho_max if self.method == "rk4" else math.inf
        return rho, np.where(rho > limit, STATUS_UNSTABLE, STATUS_OK)

    def _pack(self, X: np.ndarray, P: np.ndarray, entry: _Compiled) -> tuple[np.ndarray, ...]:
        """Initial states (rows, n_pop) and parameters (n_pop, n_params) in the entry's layout.

        The population is padded to ``entry.n_members`` with copies of its last
        member. Vector code: element ``e`` of group ``g``, lane ``l`` (member
        ``g*width + l``) goes to ``[g*n_el + e, l]``.
        """
        pad = entry.n_members - P.shape[0]
        if pad:
            X = np.hstack([X, np.repeat(X[:, -1:], pad, axis=1)])
            P = np.vstack([P, np.repeat(P[-1:], pad, axis=0)])
        width = entry.width
        if width == 1:
            return X, np.ascontiguousarray(P.T)
        groups = entry.n_members // width
        return (X.reshape(X.shape[0], groups, width).transpose(1, 0, 2).reshape(-1, width),
                P.reshape(groups, width, -1).transpose(0, 2, 1).reshape(-1, width))

    def _input_chunks(self, u: np.ndarray) -> tuple[np.ndarray, int, int]:
        """(input matrix padded to whole chunks, blocks per chunk, number of chunks)."""
        U = self.input_matrix(u)
        cb = self.chunk // self.block
        n_chunks = -(-U.shape[1] // cb)
        U = np.hstack([U, np.repeat(U[:, -1:], n_chunks * cb - U.shape[1], axis=1)])
        return U, cb, n_chunks

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
            Input samples (valve current [mA] for the HHRA); between samples as
            :attr:`intersample` says (held by default).
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
        if single:
            sim = self.for_parameters(P[0], float(np.max(np.abs(u))))
            if sim is not self:
                out = sim.simulate(u, P[0], x0=X0[:, 0], states=states)
                self.last_status, self.last_rho = sim.last_status, sim.last_rho
                self.last_method, self.last_substeps = sim.method, sim.substeps
                return out
        self.last_method, self.last_substeps = self.method, self.substeps
        n, n_pop = u.size, P.shape[0]
        rho, status = self._stability_status(P, u)
        entry = self._entry(n_pop, "x" if states else "y")
        lanes, n_members, width = entry.lanes, entry.n_members, entry.width
        groups = n_members // (lanes * width)
        nx = self.model.nx
        x, PT = self._pack(X0, P, entry)
        U, cb, n_chunks = self._input_chunks(u)
        # Padded members are rows past n_pop, so Y = Ypad[:n_pop] is a contiguous view.
        Ypad = np.empty((n_members, n))
        Xpad = np.empty((n_members, n, nx)) if states else None
        with np.errstate(all="ignore"):
            for c in range(n_chunks):
                Uc = U[:, c * cb:(c + 1) * cb]
                if entry.native:
                    outs = entry.fn(x, PT, Uc)  # type: ignore[operator]
                else:
                    raw = entry.fn(x, PT, Uc)  # type: ignore[operator]
                    outs = [np.array(o) for o in raw]
                lo = c * self.chunk
                m = min(self.chunk, n - lo)
                if width > 1:
                    Ypad.reshape(groups, width, n)[:, :, lo:lo + m] = np.asarray(
                        outs[0]).reshape(groups, self.chunk, width)[:, :m].transpose(0, 2, 1)
                    if Xpad is not None:
                        Xpad.reshape(groups, width, n, nx)[:, :, lo:lo + m] = np.asarray(
                            outs[1]).reshape(groups, self.chunk, nx, width)[:, :m].transpose(
                            0, 3, 1, 2)
                else:
                    if lanes == 1:
                        yc = np.asarray(outs[0]).reshape(n_members, self.chunk)
                    else:
                        yc = self._unpack(outs[0], n_members, lanes, cb)
                    Ypad[:, lo:lo + m] = yc[:, :m]
                    if Xpad is not None:
                        # Column j*chunk + k holds sample k of member j.
                        Xpad[:, lo:lo + m] = np.asarray(outs[1]).reshape(
                            nx, self.chunk, n_members, order="F")[:, :m].transpose(2, 1, 0)
                x = np.asarray(outs[-1])
            Y = Ypad[:n_pop]
            # One pass: NaN, Inf and runaway values all fail "peak <= limit".
            bad = ~(np.max(np.abs(Y), axis=1) <= self.diverge_limit)
        status[(status == STATUS_OK) & bad] = STATUS_DIVERGED
        Y[status != STATUS_OK] = np.nan
        self.last_status, self.last_rho = status, rho
        if Xpad is not None:
            X = Xpad[:n_pop]
            X[status != STATUS_OK] = np.nan
            return (Y[0], X[0]) if single else (Y, X)
        return Y[0] if single else Y

    def simulate_cost(
        self,
        u: np.ndarray,
        P: np.ndarray,
        y: np.ndarray,
        weights: np.ndarray | None = None,
        loss: str = "sq",
        x0: np.ndarray | None = None,
    ) -> np.ndarray | float:
        """Weighted output error of every member, summed inside the compiled code.

        Equal (up to summation order) to ``sum(weights * loss(y - simulate(u, P, x0)))``
        per member, but the trajectories never leave the compiled code, which
        makes a population's cost cheaper than simulating it and scoring the
        outputs in NumPy.

        Parameters
        ----------
        u : array, shape (N,)
            Input samples (valve current [mA] for the HHRA).
        P : array, shape (n_pop, n_params) or (n_params,)
            Parameter vectors in the order of ``model.params.names``.
        y : array, shape (N,)
            Measured output (output unit, e.g. degrees).
        weights : array, shape (N,), optional
            Weight of each sample's loss (default 1): e.g. ``(t_k - t_0) * dt``
            for the ITAE, ``1/N`` for the mean squared error.
        loss : {"sq", "abs"}
            Squared or absolute error.
        x0 : array, shape (nx,) or (n_pop, nx), optional
            Initial states (default: the model's, at rest).

        Returns
        -------
        ndarray, shape (n_pop,), or float
            The costs; ``inf`` for members flagged unstable, non-finite or
            diverging (see :attr:`last_status`).
        """
        u, P, X0, single = self._prepare(u, P, x0)
        n, n_pop = u.size, P.shape[0]
        if loss not in ("sq", "abs"):
            raise ParameterError(f"loss must be 'sq' or 'abs', got {loss!r}")
        yy = np.asarray(y, dtype=float)
        if yy.shape != (n,):
            raise ParameterError(f"measured output y has shape {yy.shape}, expected ({n},)")
        if not np.isfinite(yy).all():
            raise ParameterError("measured output y has non-finite samples")
        w = np.ones(n) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != (n,) or not np.isfinite(w).all():
            raise ParameterError(f"weights must be {n} finite numbers, got shape {w.shape}")
        rho, status = self._stability_status(P, u)
        entry = self._entry(n_pop, loss)
        n_members, width = entry.n_members, entry.width
        groups = n_members // width
        nx = self.model.nx
        # The state is augmented by the running cost and peak, both starting at 0.
        xa, PT = self._pack(np.vstack([X0, np.zeros((2, n_pop))]), P, entry)
        U, cb, n_chunks = self._input_chunks(u)
        # Samples past the record weigh nothing (the input is held at its last value).
        total = n_chunks * self.chunk
        Ym = np.concatenate([yy, np.zeros(total - n)]).reshape(-1, self.block).T
        Wt = np.concatenate([w, np.zeros(total - n)]).reshape(-1, self.block).T
        Mk = np.concatenate([np.ones(n), np.zeros(total - n)]).reshape(-1, self.block).T
        with np.errstate(all="ignore"):
            for c in range(n_chunks):
                cols = slice(c * cb, (c + 1) * cb)
                outs = entry.fn(xa, PT, U[:, cols], Ym[:, cols], Wt[:, cols],  # type: ignore[operator]
                                Mk[:, cols])
                xa = np.asarray(outs[0] if entry.native else outs)
            if width > 1:
                xa = xa.reshape(groups, nx + 2, width).transpose(1, 0, 2).reshape(nx + 2, -1)
            xa = xa.reshape(nx + 2, n_members, order="F" if width == 1 else "C")
            J, peak = xa[nx, :n_pop], xa[nx + 1, :n_pop]
            bad = ~(np.isfinite(J) & (peak <= self.diverge_limit))
        status[(status == STATUS_OK) & bad] = STATUS_DIVERGED
        self.last_status, self.last_rho = status, rho
        cost = np.where(status == STATUS_OK, J, np.inf)
        return float(cost[0]) if single else cost

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
        stepping over the jumps (a single call across them is measurably wrong);
        under ``"foh"`` the input is the exact ramp between the sample's values.
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
        x = ca.SX.sym("x", m.nx)
        ps = ca.SX.sym("p", m.n_params)
        us = ca.SX.sym("u", self.n_u)
        t = ca.SX.sym("t")
        # The lags over the sample: held, the exact ramp, or the cubic.
        now = sum((ci * (t / self.dt) ** i for i, ci in enumerate(self._input_polynomial(us))),
                  ca.SX.zeros(m.n_lags + 1))
        ode = self._fns["f"](x, now, ps)
        integ = ca.integrator(
            "ref", "cvodes", {"x": x, "t": t, "p": ca.vertcat(ps, us), "ode": ode}, 0.0,
            self.dt, {"abstol": atol, "reltol": rtol, "max_num_steps": 100000},
        )
        n = u.size
        acc = integ.mapaccum("ref_acc", n, ["x0"], ["xf"], {})
        rows = self.input_rows(u)  # (n_u, n): the input of every sample
        lead = self._lead_trail[0]
        lags = rows[lead:lead + m.n_lags + 1]
        pv = P[0]
        res = acc(x0=X0[:, 0], p=np.vstack([np.repeat(pv[:, None], n, axis=1), rows]))
        xf = np.array(res["xf"])  # states after each sample
        Xs = np.hstack([X0[:, :1], xf[:, :-1]])  # states at the sample instants
        y = np.array(self._fns["h"].map(n)(Xs, lags, np.repeat(pv[:, None], n, axis=1))).ravel()
        if states:
            return y, Xs.T
        return y
