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

import weakref

import casadi as ca
import numpy as np

from hhra_phys.compile import CompiledFunction, compile_function
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
        h = sim._fns["h"]
        # The simulator's own method, substeps and inter-sample behaviour: the exact
        # Jacobian of the same discretisation (for ROS2 CasADi differentiates through
        # the step's Jacobian and its LU as well).
        xk = sim.advance_sample(x, u, p)
        y = h(x, sim.sample_input(u), p)
        dp = ca.horzcat(ca.SX.zeros(self.np_, self.nx), ca.SX.eye(self.np_))
        S_next = ca.mtimes(ca.jacobian(xk, x), S) + ca.mtimes(ca.jacobian(xk, p), dp)
        dy = ca.mtimes(ca.jacobian(y, x), S) + ca.mtimes(ca.jacobian(y, p), dp)
        step = ca.Function("sens_step", [x, S, p, u], [xk, ca.densify(S_next), y,
                                                       ca.densify(dy)], {"cse": True})
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
