"""Forward sensitivities of candidate models: compile time and run time, per substep or unrolled.

The refiners (IPOPT, the intervals) use :class:`hhra_phys.sensitivity.TrajectorySensitivity`:
one sample of the integrator with its forward sensitivity equations, compiled. It is built
per substep (one substep and its sensitivity are one function, called ``substeps`` times per
sample). The earlier form differentiated the whole sample with its substeps unrolled, which
for a stiff candidate (ROS4 with 8 substeps, every step holding the state Jacobian and its
LU) generated code that took minutes to compile. This script builds both forms side by side
for the loop's candidate models (the HHRA with one library effect, a candidate simulator as
the loop builds it) with an empty compile cache, and reports for each: method x substeps,
build + compile time, time per call on a 2500-sample record, and the largest difference of
the derivatives (relative to their largest magnitude).

Run::

    python benchmarks/bench_sensitivity.py [--effects gravity_load coulomb_friction backlash]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings

import casadi as ca
import numpy as np


class Unrolled:
    """The earlier form: the whole sample (substeps unrolled) differentiated at once."""

    def __init__(self, sim) -> None:
        from hhra_phys.compile import compile_function
        from hhra_phys.integrate import advance
        from hhra_phys.sensitivity import CHUNK

        m = sim.model
        self.nx, self.np_ = m.nx, m.n_params
        nv, nu = self.nx + self.np_, m.n_lags + 1
        x, S = ca.SX.sym("x", self.nx), ca.SX.sym("S", self.nx, nv)
        p, u = ca.SX.sym("p", self.np_), ca.SX.sym("u", nu)
        f, h = sim._fns["f"], sim._fns["h"]
        xk = advance(sim.method, f, sim._fns["jac"], x, u, p, sim.h, sim.substeps)
        y = h(x, u, p)
        dp = ca.horzcat(ca.SX.zeros(self.np_, self.nx), ca.SX.eye(self.np_))
        S_next = ca.mtimes(ca.jacobian(xk, x), S) + ca.mtimes(ca.jacobian(xk, p), dp)
        dy = ca.mtimes(ca.jacobian(y, x), S) + ca.mtimes(ca.jacobian(y, p), dp)
        step = ca.Function("sens_step_unrolled", [x, S, p, u],
                           [xk, ca.densify(S_next), y, ca.densify(dy)], {"cse": True})
        acc = step.mapaccum("sens_acc", CHUNK, [0, 1], [0, 1], {})
        x0, S0 = ca.MX.sym("x0", self.nx), ca.MX.sym("S0", self.nx, nv)
        pm, U = ca.MX.sym("p", self.np_), ca.MX.sym("U", nu, CHUNK)
        X, SS, Y, DY = acc(x0, S0, ca.repmat(pm, 1, CHUNK), U)
        fn = ca.Function("hhra_sens_unrolled", [x0, S0, pm, U],
                         [ca.reshape(Y, CHUNK, 1), DY.T, X[:, -1], SS[:, -nv:]])
        self._fn = compile_function(fn) or fn
        self.sim = sim

    __call__ = None  # set below: the package's own chunk loop


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--effects", nargs="+",
                    default=["gravity_load", "coulomb_friction", "backlash"])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    os.environ["HHRA_PHYS_CACHE"] = tempfile.mkdtemp(prefix="hhra-sens-bench-")
    from hhra_phys.diagnosis.fits import CANDIDATE_BLOCK
    from hhra_phys.effects import make_effect
    from hhra_phys.models.hhra import HHRAModel
    from hhra_phys.reference import reference_record
    from hhra_phys.sensitivity import TrajectorySensitivity
    from hhra_phys.simulate import Simulator

    Unrolled.__call__ = TrajectorySensitivity.__call__  # same chunk loop, other function
    warnings.simplefilter("ignore", RuntimeWarning)
    ds = reference_record(seed=1, duration=20.0, effects={"valve_deadzone": {"i_dead": 0.1}})
    est = ds.split(0.5)[0]
    print(f"load average at start: {os.getloadavg()[0]:.1f}; record {est.n} samples")
    print("| candidate | method x substeps | form | build + compile [s] | call [ms] |")
    print("|---|---|---|---|---|")
    for name in args.effects:
        model = HHRAModel(effects=[make_effect(name, data=ds)])
        # The loop's candidate simulator: the base fit's substeps (2 here), a short block.
        sim = Simulator(model, fs=est.fs, substeps=2, block=CANDIDATE_BLOCK)
        p, x0 = model.nominal(), model.x0()
        out = {}
        for form, cls in (("per substep", TrajectorySensitivity), ("unrolled", Unrolled)):
            t0 = time.perf_counter()
            sens = cls(sim)
            t_build = time.perf_counter() - t0
            sens(est.u, p, x0)
            t0 = time.perf_counter()
            for _ in range(args.repeats):
                out[form] = sens(est.u, p, x0)
            t_call = (time.perf_counter() - t0) / args.repeats
            print(f"| {name} | {sim.method.upper()} x {sim.substeps} | {form} | {t_build:.1f} "
                  f"| {1000 * t_call:.0f} |", flush=True)
        d_new, d_old = out["per substep"][1], out["unrolled"][1]
        rel = np.max(np.abs(d_new - d_old)) / np.max(np.abs(d_old))
        print(f"|   | derivatives differ by {rel:.1e} (relative) | | | |")
    print(f"load average at end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
