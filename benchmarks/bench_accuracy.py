"""Integration accuracy chosen by the error estimate, over resonances 0.4x to 2.5x nominal.

For each of six HHRA parameter sets whose hydraulic resonance
``sqrt(g_torque*g_compress)/(2 pi)`` is 0.4, 0.6, 1, 1.5, 2 and 2.5 times the nominal
(about 15 Hz): the oil-column groups ``g_compress``, ``g_leak``, ``g_valve`` scale with
the square of the factor (a stiffer or softer column, as ``bench_integrators.py``'s
42 Hz set) and ``g_damping`` with the factor (the damping ratio stays near nominal).
On the rig's 20 s input at 250 Hz:

* the converged reference: CVODES on the same equations (``Simulator.reference``,
  rtol = atol = 1e-10, restarted at every sample);
* inputs: the rig's (``default_input``) and random steps of up to 5 mA every 0.2 s;
* a measured record: the reference plus white noise of 0.05 deg (the rig's sensor);
* **before** (stability rule only): the substeps the simulator chose at the nominal
  parameters, which every population and IPOPT used (``Problem`` before the accuracy
  rule), and the substeps a single prediction got (:meth:`Simulator.for_parameters`);
* **after**: the simulator ``Problem`` now uses, :meth:`Simulator.accurate` at the
  set's parameters with :func:`accuracy_tolerance` of the noisy record (10 % of its
  noise level estimated from the record), method chosen automatically.

Printed per set: method, substeps, the error estimate, the true largest error against
the reference and that error as a share of the noise (target: at most 10 %).

Run::

    python benchmarks/bench_accuracy.py [--seconds 20] [--seed 0] [--inputs rig steps]
        [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from hhra_phys.models.hhra import NOMINAL_GROUPS, HHRAModel
from hhra_phys.models.hhra.rig import DEFAULT_AMPLITUDE_MA, default_input
from hhra_phys.simulate import Simulator, accuracy_tolerance

FS = 250.0
NOISE = 0.05  # deg, the rig's sensor
FACTORS = (0.4, 0.6, 1.0, 1.5, 2.0, 2.5)
STEP_AMPLITUDE_MA = 5.0 * DEFAULT_AMPLITUDE_MA  # the harder input: valve well open


def parameter_set(factor: float) -> dict[str, float]:
    """Nominal groups with the hydraulic resonance moved by ``factor``."""
    n = dict(NOMINAL_GROUPS)
    k = factor ** 2
    return dict(n, g_compress=n["g_compress"] * k, g_leak=n["g_leak"] * k,
                g_valve=n["g_valve"] * k, g_damping=n["g_damping"] * factor)


def record_input(kind: str, seconds: float, seed: int) -> np.ndarray:
    """The rig's input (``"rig"``), or random steps of up to 5 mA every 0.2 s (``"steps"``).

    The steps are the harder case: every jump of the valve current excites the
    resonance and switches the valve's flow law.
    """
    if kind == "rig":
        return default_input(seconds, FS, seed=seed)
    rng = np.random.default_rng(1000 + seed)
    n, hold = int(round(seconds * FS)), int(round(0.2 * FS))
    levels = rng.uniform(-STEP_AMPLITUDE_MA, STEP_AMPLITUDE_MA, -(-n // hold))
    u = np.repeat(levels, hold)[:n]
    return u - np.mean(u)  # zero mean: the shaft drifts little


def run(seconds: float, seed: int, kind: str = "rig") -> list[dict[str, object]]:
    model = HHRAModel()
    u = record_input(kind, seconds, seed)
    rng = np.random.default_rng(seed)
    rows = []
    for factor in FACTORS:
        ps = parameter_set(factor)
        p = model.params.vector({k: v for k, v in ps.items() if k in model.params.names})
        base = Simulator(model, fs=FS)
        t0 = time.perf_counter()
        y_ref = base.reference(u, p)
        t_ref = time.perf_counter() - t0
        y_meas = y_ref + rng.normal(0.0, NOISE, y_ref.size)
        tol = accuracy_tolerance(y_meas)
        # Before: the population/IPOPT discretisation (nominal substeps) and a prediction's.
        y_pop = base.simulate(u, p[None, :])[0]
        y_one = base.simulate(u, p)
        one = (base.last_method, base.last_substeps)
        t0 = time.perf_counter()
        sim = base.accurate(u, p, tol)
        t_choice = time.perf_counter() - t0
        fixed = Simulator(model, fs=FS, substeps=sim.substeps, method=sim.method)
        y_acc = fixed.simulate(u, p[None, :])[0]
        err = float(np.max(np.abs(y_acc - y_ref)))
        rows.append({
            "input": kind,
            "factor": factor,
            "resonance_hz": math.sqrt(p[model.params.names.index("g_torque")]
                                      * p[model.params.names.index("g_compress")])
            / (2 * math.pi),
            "before_population": {"method": base.method, "substeps": base.substeps,
                                  "error": float(np.max(np.abs(y_pop - y_ref)))},
            "before_single": {"method": one[0], "substeps": int(one[1]),
                              "error": float(np.max(np.abs(y_one - y_ref)))},
            "after": {"method": sim.method, "substeps": sim.substeps,
                      "estimate": float(sim.accuracy["error_estimate"]),
                      "tolerance": tol, "error": err, "share_of_noise": err / NOISE},
            "seconds": {"choice": t_choice, "reference": t_ref},
        })
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    ap.add_argument("--inputs", nargs="+", default=["rig", "steps"], choices=["rig", "steps"])
    args = ap.parse_args()
    rows = [r for kind in args.inputs for r in run(args.seconds, args.seed, kind)]
    print(f"noise {NOISE} deg; target: error at most 10 % of it ({0.1 * NOISE:.4g} deg)")
    print("| input | resonance | before: population (method x n, error) | before: single | "
          "after: method x n | estimate | tolerance | error | share of noise | choice [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        bp, bs, a = r["before_population"], r["before_single"], r["after"]
        print(f"| {r['input']} | {r['factor']:.1f}x ({r['resonance_hz']:.1f} Hz) "
              f"| {bp['method']} x {bp['substeps']}, {bp['error']:.2e} "
              f"| {bs['method']} x {bs['substeps']}, {bs['error']:.2e} "
              f"| {a['method']} x {a['substeps']} | {a['estimate']:.2e} | {a['tolerance']:.2e} "
              f"| {a['error']:.2e} | {100 * a['share_of_noise']:.1f} % "
              f"| {r['seconds']['choice']:.2f} |")
    worst = max(r["after"]["share_of_noise"] for r in rows)
    print(f"worst share of the noise: {100 * worst:.1f} % "
          f"({'within' if worst <= 0.1 else 'ABOVE'} the 10 % target)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
