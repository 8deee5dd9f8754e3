"""The input between samples, and the advance of the state over one sample.

What the module docstring of :mod:`hhra_phys.simulate` says about inter-sample behaviour
(``"zoh"``, ``"foh"``, ``"cubic"``), as code: the input columns a simulator reads for each
sample (:meth:`~hhra_phys.simulate.Simulator.input_rows`,
:meth:`~hhra_phys.simulate.Simulator.input_matrix`), the polynomial of the input lags over
a sample, and the symbolic step of one sample
(:meth:`~hhra_phys.simulate.Simulator.advance_sample`) with a method of
:mod:`hhra_phys.integrate`, the state augmented by the moving input under ``"foh"`` and
``"cubic"``.

Separate from :mod:`hhra_phys.simulate` because it is the one place where the record's
samples meet the continuous-time model: the compiled code, the accuracy estimate and the
reference simulation all build on it. :class:`_Sampling` is a mixin of
:class:`~hhra_phys.simulate.Simulator`.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from hhra_phys.integrate import advance

__all__: list[str] = []


class _Sampling:
    """The input between samples and one sample's advance of a
    :class:`~hhra_phys.simulate.Simulator` (a mixin: its methods read the simulator's
    ``model``, ``dt``, ``intersample``, ``method``, ``substeps`` and model functions)."""

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
