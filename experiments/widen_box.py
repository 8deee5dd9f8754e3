"""A group outside its default box: does widening the box automatically recover it?

In a probe of an earlier version (docs/fitting.md), an actuator whose damping group is
28 times the nominal value (the default box spans a factor of 10 each way) made
``hhra-phys fit`` stop at the box edge, push the leakage to its edge too, and miss the
transfer function's ``b/c`` by 23 %, while the validation error looked fine. This study
simulates such a rig (the viscous friction ``B_c`` raised until ``g_damping`` is 28x
nominal), fits it with and without the automatic widening of :func:`hhra_phys.fit.fit`
(``widen_bounds``), and reports per seed the widened sides, the error of ``b/c`` and of
every group, and the validation RMSE.

    python experiments/widen_box.py [--seeds 5] [--duration 8] [--pop 30] [--iters 40]
                                    [--path fit|loop|records]

``--path`` picks the fit path: a single-record ``fit`` (default), the base fit of the
diagnosis loop (``augment`` with no candidates: ``fit`` of a given ``Problem``), or a fit
of two records at once (two seeds of the rig, each ``--duration`` long).

Prints a Markdown table (pasted into docs/fitting.md) and writes ``--out`` as JSON.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from hhra_phys.fit import fit
from hhra_phys.models.hhra.model import NOMINAL_GROUPS, HHRAModel
from hhra_phys.models.hhra.physical import PhysicalParameters
from hhra_phys.models.hhra.rig import simulate_rig

#: How many times the nominal damping group the simulated actuator has (docs/fitting.md).
DAMPING_FACTOR = 28.0


def heavy_damping(factor: float = DAMPING_FACTOR) -> PhysicalParameters:
    """Physical parameters of the rig with ``g_damping`` = ``factor`` x nominal.

    ``g_damping`` is affine in the viscous coefficient ``B_c``; solve for it.
    """
    g1 = PhysicalParameters(B_c=1500.0).groups()["g_damping"]
    g2 = PhysicalParameters(B_c=3000.0).groups()["g_damping"]
    b_c = 1500.0 + (factor * NOMINAL_GROUPS["g_damping"] - g1) / ((g2 - g1) / 1500.0)
    return PhysicalParameters(B_c=b_c)


PATHS = ("fit", "loop", "records")


def fit_path(path: str, seed: int, widen: bool, duration: float, pop: int, iters: int):
    """(record used for the truth, FitResult) of one fit of the heavily damped rig."""
    data = simulate_rig(seed=seed, duration=duration, physical=heavy_damping())
    if path == "fit":
        return data, fit(data, pop_size=pop, max_iter=iters, seed=seed, widen_bounds=widen)
    if path == "loop":
        if not widen:
            raise ValueError("the loop's base fit always widens (there is no switch)")
        from hhra_phys.diagnosis.engine import augment

        res = augment(data, HHRAModel(), candidates=[], pop_size=pop, max_iter=iters,
                      seed=seed, test=0.0, discover=False)
        return data, res.base
    second = simulate_rig(seed=seed + 100, duration=duration, physical=heavy_damping())
    return data, fit([data, second], model=HHRAModel(), pop_size=pop, max_iter=iters,
                     seed=seed, widen_bounds=widen)


def one(seed: int, widen: bool, duration: float, pop: int, iters: int,
        path: str = "fit") -> dict:
    """Fit the heavily damped rig by ``path``; errors against its truth."""
    t0 = time.perf_counter()
    data, res = fit_path(path, seed, widen, duration, pop, iters)
    truth = data.metadata["true_params"]
    tf_true = HHRAModel().tf_coefficients_of(truth)
    bc = res.tf["b"] / res.tf["c"]
    bc_true = tf_true["b"] / tf_true["c"]
    return {
        "seed": seed, "widen": widen, "seconds": time.perf_counter() - t0,
        "widened": [f"{w['name']} {w['side']}" for w in res.settings.get("widened", [])],
        "bc_error": bc / bc_true - 1,
        "ratio": {k: res.values[k] / truth[k] for k in res.free if k in truth and truth[k]},
        "val_rmse": res.metrics["val"].get("rmse", float("nan")),
        "edge_warnings": sum("ended at its" in w for w in res.warnings),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--pop", type=int, default=30)
    ap.add_argument("--iters", type=int, default=40)
    ap.add_argument("--path", choices=PATHS, default="fit")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    modes = (True,) if a.path == "loop" else (False, True)
    rows = [one(s, w, a.duration, a.pop, a.iters, a.path) for s in range(a.seeds)
            for w in modes]
    print(f"g_damping = {DAMPING_FACTOR:g} x nominal; path {a.path}; {a.duration:g} s records, "
          f"pop {a.pop}, {a.iters} it. + IPOPT\n")
    print("| seed | widening | widened sides | b/c error | g_damping / truth | g_leak / truth "
          "| val RMSE [deg] | groups at an edge | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['seed']} | {'on' if r['widen'] else 'off'} | "
              f"{', '.join(r['widened']) or '-'} | {100 * r['bc_error']:+.1f} % | "
              f"{r['ratio']['g_damping']:.3f} | {r['ratio']['g_leak']:.3f} | "
              f"{r['val_rmse']:.4f} | {r['edge_warnings']} | {r['seconds']:.1f} |")
    for w in modes:
        err = np.abs([r["bc_error"] for r in rows if r["widen"] == w])
        print(f"\nwidening {'on' if w else 'off'}: |b/c error| median "
              f"{100 * np.median(err):.1f} %, max {100 * err.max():.1f} %, "
              f"below 5 % in {int((err < 0.05).sum())}/{err.size}")
    if a.out:
        with open(a.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
