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
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from hhra_phys.compile import CompiledFunction, compile_function
from hhra_phys.data.dataset import INTERSAMPLE
from hhra_phys.errors import ParameterError, SimulationError
from hhra_phys.integrate import METHODS, advance
from hhra_phys.model import Model
from hhra_phys.options import with_overrides
from hhra_phys.vectorize import SimdTarget, simd_target, supports

__all__ = [
    "CodeOptions",
    "Simulator",
    "step_doubling_error",
    "accuracy_tolerance",
]

#: Largest number of RK4 steps unrolled in one compiled step function
#: (substeps x block x lanes); the block and then the lanes shrink to respect it.
UNROLL_BUDGET = 80

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


#: Status codes of :attr:`Simulator.last_status`.
STATUS_OK = 0
STATUS_UNSTABLE = 1  # spectral radius times substep above rho_max: not simulated reliably
STATUS_DIVERGED = 2  # non-finite or exploding output


@dataclass
class _Compiled:
    fn: CompiledFunction | ca.Function
    n_members: int  # population padded to whole groups per thread
    lanes: int  # members interleaved in one straight-line step (scalar code)
    native: bool
    width: int = 1  # members per SIMD vector (vector code)


@dataclass(frozen=True)
class CodeOptions:
    """How a :class:`Simulator`'s compiled code is laid out: speed, not the integration.

    Every field is also a keyword of :class:`Simulator` (``Simulator(model, simd=None)``),
    overriding the options it is given.

    Attributes
    ----------
    threads : int
        Threads used for a population (CasADi thread map).
    block : int
        Samples advanced per call of the compiled step (amortises call overhead).
    lanes : int
        Scalar code only: population members advanced together in one
        straight-line step, so the CPU overlaps their latency-bound arithmetic
        (populations are padded to a multiple of ``lanes * threads``; single
        simulations use one lane).
    chunk : int
        Samples per compiled call (rounded to a multiple of ``block``). Records of
        any length are simulated chunk after chunk, so one compiled function per
        population size serves every record length.
    simd : "auto", int or None
        Members per SIMD vector for populations: ``"auto"`` takes the machine's
        width (:func:`hhra_phys.vectorize.simd_target`, 8 with AVX-512, 4 with
        AVX2), an integer (a power of two) forces a width, ``None`` or 1 uses scalar
        code. Vector code needs a C++ compiler and a model whose operations all have
        lane-wise versions; otherwise the scalar code is used. Populations are padded
        to a multiple of ``simd * threads``.
    """

    threads: int = 2
    block: int = 10
    lanes: int = 4
    chunk: int = 500
    simd: int | str | None = "auto"

    def validate(self) -> CodeOptions:
        """Check every setting; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        for name in ("threads", "block", "lanes", "chunk"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ParameterError(f"{name} must be a positive integer, got {value!r}")
        simd = self.simd
        if simd not in ("auto", None) and (
                isinstance(simd, bool) or not isinstance(simd, (int, np.integer)) or simd < 1):
            raise ParameterError(f"simd must be 'auto', a positive integer or None, got "
                                 f"{simd!r}")
        if isinstance(simd, (int, np.integer)) and simd & (simd - 1):
            raise ParameterError(f"simd must be a power of two, got {simd}")
        return self


class Simulator:
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

    def _fit_unroll_budget(self) -> None:
        """Shrink the block, then the lanes, so the unrolled step stays within
        :data:`UNROLL_BUDGET` RK4 steps: a stiff model needing many substeps would
        otherwise generate megabytes of C (slow to compile, no faster to run)."""
        while self.substeps * self.block * self.lanes > UNROLL_BUDGET and self.block > 1:
            self.block = max(1, UNROLL_BUDGET // (self.substeps * self.lanes))
            if self.substeps * self.block * self.lanes > UNROLL_BUDGET:
                self.block = 1
        while self.substeps * self.block * self.lanes > UNROLL_BUDGET and self.lanes > 1:
            self.lanes //= 2

    def _simd_target(self, simd: int | str | None) -> SimdTarget | None:
        if self.backend == "casadi" or simd is None:
            return None
        if simd == "auto":
            return simd_target()
        if isinstance(simd, (int, np.integer)) and not isinstance(simd, bool) and simd >= 1:
            if simd == 1:
                return None
            if simd & (simd - 1):
                raise ParameterError(f"simd must be a power of two, got {simd}")
            detected = simd_target()
            if detected is None:
                return None  # no C++ compiler (or disabled by HHRA_PHYS_SIMD)
            return SimdTarget(int(simd), detected.compiler, detected.flags)
        raise ParameterError(f"simd must be 'auto', a positive integer or None, got {simd!r}")

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

    def accurate(self, u: np.ndarray, p: np.ndarray, tolerance: float,
                 x0: np.ndarray | None = None, coarsest: bool = False,
                 finest: int = MAX_AUTO_SUBSTEPS) -> Simulator:
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

    def _build_step(self, states: bool, lanes: int = 1) -> ca.Function:
        """SX function advancing ``block`` samples of ``lanes`` members.

        ``(x[nx, lanes], p[n_params, lanes], U) -> (x_next[nx, lanes], y[block, lanes][, X])``.
        The members share the input. Several lanes in one straight-line function
        let the CPU overlap their independent dependency chains (the square roots
        and divisions of the valve law are latency-bound in a scalar loop).
        """
        m = self.model
        nu = self.n_u
        x = ca.SX.sym("x", m.nx, lanes)
        p = ca.SX.sym("p", m.n_params, lanes)
        U = ca.SX.sym("U", nu * self.block)
        h = self._fns["h"]
        x_next, y_cols, x_cols = [], [], []
        for lane in range(lanes):
            xk, pk = x[:, lane], p[:, lane]
            ys, xs = [], []
            for k in range(self.block):
                uk = U[k * nu:(k + 1) * nu]
                ys.append(h(xk, self.sample_input(uk), pk))
                xs.append(xk)
                xk = self.advance_sample(xk, uk, pk)
            x_next.append(xk)
            y_cols.append(ca.vertcat(*ys))
            x_cols.append(ca.horzcat(*xs))
        # Outputs as (lanes, block): CasADi orders the generated code by a depth-first
        # walk from the outputs in column-major order, so this interleaves the lanes
        # sample by sample, which is what lets the CPU overlap them.
        outs = [ca.horzcat(*x_next), ca.horzcat(*y_cols).T]
        if states:
            outs.append(ca.horzcat(*x_cols))
        # CSE merges what the stages recompute from the same held input
        # (e.g. the valve's smoothed sign): about 13 % fewer instructions.
        return ca.Function("step", [x, p, U], outs, {"cse": True})

    def _step(self, states: bool, lanes: int) -> ca.Function:
        """The block step of :meth:`_build_step`, built once per (states, lanes)."""
        key = (states, lanes)
        if key not in self._steps:
            self._steps[key] = self._build_step(states=states, lanes=lanes)
        return self._steps[key]

    def trajectory_function(
        self, n: int, states: bool = False, lanes: int = 1, final: bool = False
    ) -> ca.Function:
        """CasADi function of ``lanes`` trajectories over ``n`` samples (for AD and IPOPT).

        Returns
        -------
        casadi.Function
            ``(x0[nx, lanes], p[n_params, lanes], U[n_u*block, n_blocks]) -> y``
            with ``y`` of shape (1, n_blocks*block) for one lane (raw block layout
            otherwise, see :meth:`_unpack`), then the states ``X[nx, n_blocks*block]``
            if ``states`` (one lane only), then the state after the last sample
            ``xf[nx, lanes]`` if ``final``. Build ``U`` with :meth:`input_matrix`.
            The function is symbolic (MX), so it can be embedded in cost functions
            and differentiated.
        """
        if states and lanes != 1:
            raise ParameterError("state trajectories are available for one lane only")
        step = self._step(states, lanes)
        nb = self._n_blocks(n)
        acc = step.mapaccum("traj_acc", nb, [0], [0], {})
        x0 = ca.MX.sym("x0", self.model.nx, lanes)
        p = ca.MX.sym("p", self.model.n_params, lanes)
        U = ca.MX.sym("U", self.n_u * self.block, nb)
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

    @property
    def _lead_trail(self) -> tuple[int, int]:
        """Samples after and before the lags an input column also holds."""
        return {"zoh": (0, 0), "foh": (1, 0), "cubic": (2, 1)}[self.intersample]

    @property
    def n_u(self) -> int:
        """Input rows per sample: ``n_lags + 1``, plus 1 under ``"foh"``, 3 under ``"cubic"``."""
        return self.model.n_lags + 1 + sum(self._lead_trail)

    def input_rows(self, u: np.ndarray, length: int | None = None) -> np.ndarray:
        """The input of every sample as :meth:`advance_sample` reads it, shape (n_u, length).

        Column ``k`` holds ``u[k+lead], ..., u[k], u[k-1], ..., u[k-n_lags-trail]``: the
        current and ``n_lags`` past inputs, preceded by the ``lead`` next ones and
        followed by ``trail`` older ones the interpolation needs (``"foh"``: 1 and 0,
        ``"cubic"``: 2 and 1). Before the record starts the input is taken equal to
        its first value, after it equal to its last (columns past the record, up to
        ``length``, pad it).
        """
        u = np.asarray(u, dtype=float)
        n = u.size
        length = n if length is None else int(length)
        lead, trail = self._lead_trail
        nl = self.model.n_lags + trail
        padded = np.concatenate([np.full(nl, u[0]), u, np.full(length + lead - n, u[-1])])
        return np.stack([padded[nl - j: nl - j + length] for j in range(-lead, nl + 1)])

    def sample_input(self, uk: ca.SX) -> ca.SX:
        """The input lags at the sample instant (``u[k], u[k-1], ...``) of a column ``uk``."""
        lead = self._lead_trail[0]
        return uk[lead:lead + self.model.n_lags + 1]

    def _input_polynomial(self, uk: ca.SX) -> list[ca.SX]:
        """Coefficients ``c_i`` of the lags over the sample, ``L(s) = sum c_i s^i``, s in [0, 1]."""
        lead, nu = self._lead_trail[0], self.model.n_lags + 1
        p1 = uk[lead:lead + nu]
        if self.intersample == "zoh":
            return [p1]
        p2 = uk[lead - 1:lead - 1 + nu]
        if self.intersample == "foh":
            return [p1, p2 - p1]
        p0, p3 = uk[lead + 1:lead + 1 + nu], uk[lead - 2:lead - 2 + nu]
        return [p1, 0.5 * (p2 - p0), p0 - 2.5 * p1 + 2 * p2 - 0.5 * p3,
                0.5 * (3 * p1 - p0 - 3 * p2 + p3)]

    def advance_sample(self, x: ca.SX, uk: ca.SX, p: ca.SX, method: str | None = None,
                       substeps: int | None = None) -> ca.SX:
        """Symbolic state one sample on from ``x``, the input as :attr:`intersample` says.

        Parameters
        ----------
        x : casadi.SX or MX, shape (nx,)
            State at the sample instant.
        uk : casadi.SX or MX, shape (n_u,)
            The sample's column of :meth:`input_rows`.
        p : casadi.SX or MX, shape (n_params,)
            Parameters.
        method, substeps : optional
            Integrator and steps per sample (default: this simulator's; the accuracy
            estimate varies them).
        """
        f, jac = self._fns["f"], self._fns["jac"]
        method = method or self.method
        substeps = int(substeps or self.substeps)
        h = self.dt / substeps
        if self.intersample == "zoh":
            return advance(method, f, jac, x, uk, p, h, substeps)
        # Integrate [x; v; dv/dt; ...] with v the interpolated lags (module docstring):
        # the chain starts at the polynomial's derivatives at the sample instant and
        # ends in its constant highest derivative.
        c = self._input_polynomial(uk)
        order = len(c) - 1
        derivs = [math.factorial(i) * c[i] / self.dt ** i for i in range(order + 1)]
        fa, ja = self._ramp_functions(order)
        xa = advance(method, fa, ja, ca.vertcat(x, *derivs[:-1]), derivs[-1], p, h, substeps)
        return xa[:self.model.nx]

    def _ramp_functions(self, order: int) -> tuple[ca.Function, ca.Function]:
        """Right-hand side and Jacobian of the state augmented by the moving input.

        ``(xa, rate, p)`` with ``xa = [x; v; v'; ...]`` (``order`` blocks of lags) and
        ``rate`` the constant ``order``-th derivative of the lags.
        """
        ramps: dict[int, tuple[ca.Function, ca.Function]] = self.__dict__.setdefault(
            "_ramps", {})
        if order not in ramps:
            m = self.model
            x, v, p = m.symbols()
            nu = m.n_lags + 1
            chain = [v, *[ca.SX.sym(f"v{i}", nu) for i in range(1, order)]]
            rate = ca.SX.sym("rate", nu)
            xa = ca.vertcat(x, *chain)
            fa = ca.vertcat(self._fns["f"](x, v, p), *chain[1:], rate)
            ramps[order] = (
                ca.Function(f"ramp{order}_f", [xa, rate, p], [fa]),
                ca.Function(f"ramp{order}_jac", [xa, rate, p], [ca.densify(ca.jacobian(fa, xa))]))
        return ramps[order]

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

    def input_matrix(self, u: np.ndarray) -> np.ndarray:
        """Arrange an input record for :meth:`trajectory_function`.

        Column ``b`` holds, for each of the ``block`` samples ``k`` of block ``b``,
        the sample's column of :meth:`input_rows` (the current input and ``n_lags``
        past inputs ``u[k], u[k-1], ...``, after the next one under ``"foh"``). Before
        the record starts the input is taken equal to its first value; the last
        block is padded with the last value (its outputs are discarded).
        """
        u = np.asarray(u, dtype=float)
        nb = self._n_blocks(u.size)
        lags = self.input_rows(u, nb * self.block)
        return lags.T.reshape(nb, self.block * self.n_u).T

    def _layout(self, n_pop: int, kind: str, width: int = 1) -> tuple[int, int]:
        """(lanes, padded population): populations are padded to whole groups per thread."""
        if width > 1:
            unit = width * self.threads
            return 1, -(-n_pop // unit) * unit
        if n_pop == 1:
            return 1, 1
        lanes = self.lanes if kind == "y" else 1
        unit = lanes * self.threads
        return lanes, -(-n_pop // unit) * unit

    def _use_simd(self) -> bool:
        """Whether the model's step can run as vector code (checked once)."""
        if self._simd_ok is None:
            self._simd_ok = self.simd is not None and supports(self._step(False, 1))
        return self._simd_ok

    def _entry(self, n_pop: int, kind: str) -> _Compiled:
        """The compiled population function (and its layout) for ``n_pop`` members."""
        key = (n_pop, kind)
        if key in self._entries:
            return self._entries[key]
        entry = None
        # Any population of two or more in vector code: padded to width x threads it still
        # runs faster than the scalar lanes, and compiles faster (docs/performance.md).
        if self.simd is not None and n_pop > 1 and self._use_simd():
            lanes, n_members = self._layout(n_pop, kind, self.simd.width)
            entry = self._population_function(n_members, lanes, kind, self.simd)
            if not entry.native:  # vector code did not compile: scalar code instead
                self._simd_ok = False
                entry = None
        if entry is None:
            lanes, n_members = self._layout(n_pop, kind)
            entry = self._population_function(n_members, lanes, kind)
        self._entries[key] = entry
        return entry

    def _cost_trajectory(self, loss: str) -> ca.Function:
        """One chunk of a trajectory reduced to its cost: ``(xa0, p, U, Ym, Wt, M) -> xa``.

        ``xa = [x; J; peak]`` carries, next to the state, the running cost
        ``J += sum_k Wt_k * loss(Ym_k - y_k)`` (``loss`` ``"abs"`` or ``"sq"``)
        and the running peak ``max_k |y_k|``, so a population's cost leaves the
        compiled code as a few numbers per member instead of whole trajectories.
        Only samples with ``M_k != 0`` count: the padding after the record's last
        sample must not add to either (not even a NaN through ``0 * NaN``).
        """
        m = self.model
        nu = self.n_u
        step = self._step(False, 1)
        xa = ca.SX.sym("xa", m.nx + 2)
        p = ca.SX.sym("p", m.n_params)
        U = ca.SX.sym("U", nu * self.block)
        Ym = ca.SX.sym("Ym", self.block)
        Wt = ca.SX.sym("Wt", self.block)
        M = ca.SX.sym("M", self.block)
        x_next, y = step(xa[:m.nx], p, U)
        e = Ym - y.T
        J, peak = xa[m.nx], xa[m.nx + 1]
        for k in range(self.block):
            term = Wt[k] * (ca.fabs(e[k]) if loss == "abs" else e[k] * e[k])
            J = J + ca.if_else(M[k], term, 0)
            peak = ca.fmax(peak, ca.if_else(M[k], ca.fabs(y[k]), 0))
        cstep = ca.Function("cost_step", [xa, p, U, Ym, Wt, M],
                            [ca.vertcat(x_next, J, peak)], {"cse": True})
        nb = self.chunk // self.block
        acc = cstep.mapaccum("cost_acc", nb, [0], [0], {})
        ins = [ca.MX.sym("xa0", m.nx + 2), ca.MX.sym("p", m.n_params),
               ca.MX.sym("U", nu * self.block, nb), ca.MX.sym("Ym", self.block, nb),
               ca.MX.sym("Wt", self.block, nb), ca.MX.sym("M", self.block, nb)]
        res = acc(ins[0], ca.repmat(ins[1], 1, nb), *ins[2:])
        return ca.Function("cost_traj", ins, [res[:, -1]])

    def _population_function(
        self, n_members: int, lanes: int, kind: str, simd: SimdTarget | None = None
    ) -> _Compiled:
        """Compiled simulation of one chunk of ``chunk`` samples for a padded population.

        ``kind`` ``"y"`` maps (initial states, parameters, input chunk) to
        (outputs, final states), ``"x"`` to (outputs, states, final states), and
        ``"abs"``/``"sq"`` map (augmented states, parameters, input, measured
        output, weights, sample mask) to the augmented states of :meth:`_cost_trajectory`. Any
        record length is simulated by chaining chunks: one compiled function per
        population size serves every record. With ``simd`` each instance of the
        trajectory is a vector of ``simd.width`` members.
        """
        width = 1 if simd is None else simd.width
        key = (n_members, lanes, width, kind)
        if key in self._compiled:
            return self._compiled[key]
        groups = n_members // (lanes * width)
        if kind in ("y", "x"):
            traj = self.trajectory_function(self.chunk, states=kind == "x", lanes=lanes,
                                            final=True)
            shared = [2]
        else:
            traj = self._cost_trajectory(kind)
            shared = [2, 3, 4, 5]
        threads = max(1, min(self.threads, groups))
        name = f"hhra_sim_{kind}_{n_members}_{lanes}" + (f"_v{width}" if width > 1 else "")
        if groups == 1:
            pop = ca.Function(name, traj.mx_in(), traj.call(traj.mx_in()))
        else:
            # Exactly `threads` threads, each running a serial loop over its groups (a
            # thread map over all groups would start one thread per group per call).
            inner = traj.map("popgroups", "serial", groups // threads, shared, [])
            mapped = (inner.map("popmap", "thread", threads, shared, []) if threads > 1
                      else inner)
            pop = ca.Function(name, mapped.mx_in(), mapped.call(mapped.mx_in()))
        compiled = None
        if simd is not None:
            compiled = compile_function(pop, quiet=True, simd=simd)
            if compiled is None:
                return _Compiled(pop, n_members, lanes, False, width)  # caller falls back
        elif self.backend in ("auto", "native"):
            compiled = compile_function(pop, quiet=self.backend == "auto")
            if compiled is None and self.backend == "native":
                raise SimulationError("backend='native' but the simulator could not be compiled")
        entry = _Compiled(compiled if compiled is not None else pop, n_members, lanes,
                          compiled is not None, width)
        self._compiled[key] = entry
        return entry

    @property
    def native(self) -> bool | None:
        """Whether the last-built population function runs compiled native code."""
        if not self._compiled:
            return None
        return next(reversed(self._compiled.values())).native

    def vector_width(self, n_pop: int) -> int:
        """Members per SIMD vector used for a population of ``n_pop`` (1: scalar code).

        Builds (or loads) the compiled population function if needed.
        """
        return self._entry(int(n_pop), "y").width

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
