"""Compiled forward sensitivities of a simulated trajectory.

The local refiners need the residual ``r(z)`` and its Jacobian ``J = dr/dz`` many
times. Differentiating the symbolic ``mapaccum`` graph runs in CasADi's virtual
machine (seconds per IPOPT run on a 5000-sample record); here the integration step is
augmented with its forward sensitivity equations instead,

    x_{k+1} = F(x_k, u_k, p)
    S_{k+1} = dF/dx S_k + dF/dp [0 I]      S = dx/d(x0, p), S_0 = [I 0]
    dy_k    = dh/dx S_k + dh/dp [0 I]

built as one SX function (CasADi derives ``dF/dx`` and ``dF/dp`` exactly and
removes common subexpressions), compiled to native code like the simulator and
cached on disk per model, and run over the record chunk by chunk. The result is
the exact Jacobian of the discretised model with respect to the initial state
and all parameters, from which :class:`~hhra_phys.problem.Problem` coordinates
follow by the chain rule.
"""

from __future__ import annotations

import math
import weakref

import casadi as ca
import numpy as np

from hhra_phys.compile import CompiledFunction, compile_function
from hhra_phys.integrate import advance
from hhra_phys.simulate import Simulator

__all__ = [
    "TrajectorySensitivity",
]

#: Samples per compiled call (records are processed chunk after chunk).
CHUNK = 250


class TrajectorySensitivity:
    """Outputs and their exact derivatives w.r.t. initial state and parameters.

    Parameters
    ----------
    sim : Simulator
        Simulator whose discretisation (sample time, substeps) is differentiated.
    """

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        m = sim.model
        self.nx, self.np_ = m.nx, m.n_params
        nv = self.nx + self.np_
        nu = sim.n_u  # the sample's input column (one more row under a first-order hold)
        x = ca.SX.sym("x", self.nx)
        S = ca.SX.sym("S", self.nx, nv)
        p = ca.SX.sym("p", self.np_)
        u = ca.SX.sym("u", nu)
        f, h = sim._fns["f"], sim._fns["h"]
        hh = sim.h
        # The simulator's own method, substeps and inter-sample behaviour: the exact
        # Jacobian of the same discretisation (for the Rosenbrock methods CasADi
        # differentiates through the step's Jacobian and its LU as well). One substep and
        # its sensitivity are one SX function, called ``substeps`` times per sample: the
        # generated code holds the substep once instead of unrolled (a sharp backlash's
        # ROS4 x 8 sample differentiated as a whole compiled for minutes), with the same
        # chain rule. Under a moving input the substep advances the state augmented by the
        # input's interpolation chain (Simulator.advance_sample), whose sensitivity to the
        # initial state and the parameters is zero.
        order = 0 if sim.intersample == "zoh" else len(sim._input_polynomial(u)) - 1
        if order:
            fa, ja = sim._ramp_functions(order)
            n_aug = self.nx + order * (m.n_lags + 1)
            n_r = m.n_lags + 1
        else:
            fa, ja, n_aug, n_r = f, sim._fns["jac"], self.nx, nu
        xa = ca.SX.sym("xa", n_aug)
        Sa = ca.SX.sym("Sa", n_aug, nv)
        r = ca.SX.sym("r", n_r)
        x1 = advance(sim.method, fa, ja, xa, r, p, hh, 1)
        dp = ca.horzcat(ca.SX.zeros(self.np_, self.nx), ca.SX.eye(self.np_))
        S1 = ca.mtimes(ca.jacobian(x1, xa), Sa) + ca.mtimes(ca.jacobian(x1, p), dp)
        sub = ca.Function("sens_sub", [xa, Sa, p, r], [x1, ca.densify(S1)], {"cse": True})
        y = h(x, sim.sample_input(u), p)
        dy = ca.mtimes(ca.jacobian(y, x), S) + ca.mtimes(ca.jacobian(y, p), dp)
        out = ca.Function("sens_out", [x, S, p, u], [y, ca.densify(dy)], {"cse": True})
        xm, Sm = ca.MX.sym("x", self.nx), ca.MX.sym("S", self.nx, nv)
        pm1, um = ca.MX.sym("p", self.np_), ca.MX.sym("u", nu)
        if order:
            c = sim._input_polynomial(um)
            derivs = [math.factorial(i) * c[i] / sim.dt ** i for i in range(order + 1)]
            xi = ca.vertcat(xm, *derivs[:-1])
            Si = ca.vertcat(Sm, ca.MX.zeros(n_aug - self.nx, nv))
            ri = derivs[-1]
        else:
            xi, Si, ri = xm, Sm, um
        for _ in range(int(sim.substeps)):
            xi, Si = sub(xi, Si, pm1, ri)
        xi, Si = xi[:self.nx], Si[:self.nx, :]
        ym, dym = out(xm, Sm, pm1, um)
        step = ca.Function("sens_step", [xm, Sm, pm1, um], [xi, Si, ym, dym])
        acc = step.mapaccum("sens_acc", CHUNK, [0, 1], [0, 1], {})
        x0 = ca.MX.sym("x0", self.nx)
        S0 = ca.MX.sym("S0", self.nx, nv)
        pm = ca.MX.sym("p", self.np_)
        U = ca.MX.sym("U", nu, CHUNK)
        X, SS, Y, DY = acc(x0, S0, ca.repmat(pm, 1, CHUNK), U)
        fn = ca.Function(
            "hhra_sens", [x0, S0, pm, U],
            [ca.reshape(Y, CHUNK, 1), DY.T, X[:, -1], SS[:, -nv:]],
        )
        self._fn: CompiledFunction | ca.Function = (
            (compile_function(fn) if sim.backend != "casadi" else None) or fn
        )
        # The same substep without its sensitivity, for the residual alone: a refiner's
        # line search asks for the cost at many trial points and for the Jacobian only
        # at the accepted ones (IPOPT: about 8 costs per gradient on the loop's
        # candidates). The same SX expressions of the step and output, so the outputs
        # are those of the sensitivity function. Built on first use.
        self._out_parts = (ca.Function("out_sub", [xa, p, r], [x1], {"cse": True}),
                           ca.Function("out_y", [x, p, u], [y], {"cse": True}), order)
        self._out_fn: CompiledFunction | ca.Function | None = None

    def outputs_function(self) -> CompiledFunction | ca.Function:
        """The trajectory function ``(x0, p, U) -> (Y, x_end)`` without sensitivities."""
        if self._out_fn is not None:
            return self._out_fn
        sim = self.sim
        sub, out, order = self._out_parts
        nu = sim.n_u
        xm, pm1, um = ca.MX.sym("x", self.nx), ca.MX.sym("p", self.np_), ca.MX.sym("u", nu)
        if order:
            c = sim._input_polynomial(um)
            derivs = [math.factorial(i) * c[i] / sim.dt ** i for i in range(order + 1)]
            xi, ri = ca.vertcat(xm, *derivs[:-1]), derivs[-1]
        else:
            xi, ri = xm, um
        for _ in range(int(sim.substeps)):
            xi = sub(xi, pm1, ri)
        step = ca.Function("out_step", [xm, pm1, um], [xi[:self.nx], out(xm, pm1, um)])
        acc = step.mapaccum("out_acc", CHUNK, [0], [0], {})
        x0, pm = ca.MX.sym("x0", self.nx), ca.MX.sym("p", self.np_)
        U = ca.MX.sym("U", nu, CHUNK)
        X, Y = acc(x0, ca.repmat(pm, 1, CHUNK), U)
        fn = ca.Function("hhra_sens_out", [x0, pm, U], [ca.reshape(Y, CHUNK, 1), X[:, -1]])
        self._out_fn = (compile_function(fn) if sim.backend != "casadi" else None) or fn
        return self._out_fn

    def outputs(self, u: np.ndarray, p: np.ndarray, x0: np.ndarray) -> np.ndarray:
        """Output ``y`` (N,) of one trajectory, as :meth:`__call__` gives it, without
        its derivatives (a fraction of the cost)."""
        fn = self.outputs_function()
        u = np.asarray(u, dtype=float)
        n = u.size
        n_chunks = -(-n // CHUNK)
        lags = self.sim.input_rows(u, n_chunks * CHUNK)
        x = np.asarray(x0, dtype=float)
        ys = []
        with np.errstate(all="ignore"):
            for c in range(n_chunks):
                y, x = (np.asarray(o, dtype=float)
                        for o in fn(x, p, lags[:, c * CHUNK:(c + 1) * CHUNK]))
                ys.append(y.ravel())
                x = x.ravel()
        return np.concatenate(ys)[:n]

    @classmethod
    def of(cls, sim: Simulator) -> TrajectorySensitivity:
        """The sensitivity function of ``sim``, built once per simulator object."""
        if sim not in _BUILT:
            _BUILT[sim] = cls(sim)
        return _BUILT[sim]

    def __call__(self, u: np.ndarray, p: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, ...]:
        """Output ``y`` (N,) and ``dy/d(x0, p)`` (N, nx + n_params) for one trajectory."""
        u = np.asarray(u, dtype=float)
        n = u.size
        n_chunks = -(-n // CHUNK)
        lags = self.sim.input_rows(u, n_chunks * CHUNK)
        nv = self.nx + self.np_
        x = np.asarray(x0, dtype=float)
        S = np.hstack([np.eye(self.nx), np.zeros((self.nx, self.np_))])
        ys, dys = [], []
        with np.errstate(all="ignore"):
            for c in range(n_chunks):
                Uc = lags[:, c * CHUNK:(c + 1) * CHUNK]
                out = self._fn(x, S, p, Uc)
                y, dy, x, S = (np.asarray(o, dtype=float) for o in out)
                ys.append(y.ravel())
                dys.append(dy.reshape(CHUNK, nv))
                x, S = x.ravel(), S.reshape(self.nx, nv)
        return np.concatenate(ys)[:n], np.vstack(dys)[:n]


# Refiners and the uncertainty step of a fit share one build per simulator.
_BUILT: weakref.WeakKeyDictionary[Simulator, TrajectorySensitivity] = weakref.WeakKeyDictionary()
