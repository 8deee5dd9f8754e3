"""The compiled code of a :class:`~hhra_phys.simulate.Simulator`: how it is laid out and built.

Steps 1 to 4 of the construction in :mod:`hhra_phys.simulate`'s docstring: the block step
(``block`` samples of ``lanes`` members in one straight-line SX function), the trajectory
over a chunk (``mapaccum``), the thread map over a population padded to whole groups, the
fused cost of :meth:`~hhra_phys.simulate.Simulator.simulate_cost`, and the C code
compiled once per population size (scalar, or SIMD vectors of :mod:`hhra_phys.vectorize`).
:class:`CodeOptions` says how the code is laid out (speed, not the integration).

Separate from :mod:`hhra_phys.simulate` because it is about speed only: the numbers a
simulation gives are set by the model, the method and the substeps, and the layout here
changes none of them. :class:`_CodeGen` is a mixin of
:class:`~hhra_phys.simulate.Simulator`; every name here is also importable from
:mod:`hhra_phys.simulate`.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from hhra_phys.compile import CompiledFunction, compile_function
from hhra_phys.errors import ParameterError, SimulationError
from hhra_phys.vectorize import SimdTarget, simd_target, supports

__all__ = [
    "CodeOptions",
]


#: Largest number of RK4 steps unrolled in one compiled step function
#: (substeps x block x lanes); the block and then the lanes shrink to respect it.
UNROLL_BUDGET = 80


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


class _CodeGen:
    """The compiled population code of a :class:`~hhra_phys.simulate.Simulator` (a mixin:
    its methods read the simulator's model, block, lanes, threads, chunk and backend)."""

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
