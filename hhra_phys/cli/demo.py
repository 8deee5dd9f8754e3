"""``hhra-phys demo``: the main job end to end on the built-in simulated rig."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from hhra_phys.cli._common import report_error
from hhra_phys.data import check_save_path, save_csv
from hhra_phys.errors import HHRAError
from hhra_phys.outputs import FIGURE_SUFFIXES, check_output_path


def register(subparsers: Any) -> None:
    """Add the ``demo`` sub-command."""
    p = subparsers.add_parser(
        "demo",
        help="simulate the paper's experiment on the built-in rig, fit it, report",
        description=(
            "Simulate the reference paper's identification experiment on the built-in rig "
            "(250 Hz, 20 s, irregular multi-level current steps, 0.05 deg encoder noise), fit the "
            "physical model (H-GWO then IPOPT) and the black-box ARX models where available, "
            "print a results table and write a plot and the fit as JSON."
        ),
    )
    p.add_argument("--out", default=None, metavar="DIR",
                   help="output directory (default: a new hhra-demo-<time> directory)")
    p.add_argument("--seed", type=int, default=0, help="seed of the rig and the search")
    p.add_argument("--quick", action="store_true",
                   help="short record and small search (a smoke run, about a minute)")
    p.add_argument("--overwrite", action="store_true", help="replace files in an existing --out")
    p.set_defaults(func=run)


def _step(i: int, n: int, text: str) -> None:
    print(f"[{i}/{n}] {text}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    """Run the demo; returns the exit code."""
    from hhra_phys.fit import fit
    from hhra_phys.models.hhra.rig import simulate_rig
    from hhra_phys.plots import plot_fit

    out = Path(args.out) if args.out else Path(f"hhra-demo-{time.strftime('%Y%m%d-%H%M%S')}")
    files = {"plot": out / "demo_fit.png", "json": out / "demo_fit.json",
             "data": out / "demo_rig.csv"}
    try:  # every output checked before the first simulation
        out.mkdir(parents=True, exist_ok=True)
        check_save_path(files["data"], args.overwrite)
        check_output_path(files["json"], overwrite=args.overwrite)
        check_output_path(files["plot"], overwrite=args.overwrite, suffixes=FIGURE_SUFFIXES)
    except (HHRAError, OSError) as exc:
        code = report_error("demo", exc)
        print("hhra-phys demo: (or choose another --out)", file=sys.stderr)
        return code
    duration, pop, iters = (8.0, 30, 40) if args.quick else (20.0, 100, 200)
    n_steps = 5
    try:
        _step(1, n_steps, f"simulating the rig: {duration:.0f} s at 250 Hz, seed {args.seed}")
        data = simulate_rig(seed=args.seed, duration=duration)
        save_csv(data, files["data"], overwrite=args.overwrite)
        _step(2, n_steps, f"fitting the physical model: H-GWO (pop {pop}, {iters} it.) + IPOPT")
        res = fit(data, seed=args.seed, pop_size=pop, max_iter=iters, progress=True)
        _step(3, n_steps, "fitting black-box ARX models (LS, RLS, FFRLS) on the same split")
        arx_rows = _arx_rows(data)
        _step(4, n_steps, "linearising the fitted model for controller design (python-control)")
        design = _linear_summary(res, data)
        _step(5, n_steps, f"writing results to {out}/")
        res.save(files["json"], overwrite=args.overwrite)
        est, val = data.split(0.5)
        plot_fit(files["plot"], [("estimation", est, res.predict(est)),
                                 ("validation", val, res.predict(val))],
                 res.history, title="hhra-phys demo: simulated rig", overwrite=args.overwrite,
                 stages=res.stages)
    except (HHRAError, OSError) as exc:
        return report_error("demo", exc)

    truth = data.metadata["true_params"]
    print("\nParameter groups: truth, fit and 95 % confidence interval")
    print(f"{'group':<11} {'unit':<9} {'truth':>10} {'fitted':>10} {'95 % CI':>24} {'in CI':>6}")
    for name in res.free:
        if name not in truth:
            continue
        lo, hi = res.ci95[name]
        inside = "yes" if lo <= truth[name] <= hi else "no"
        print(f"{name:<11} {res.units[name]:<9} {truth[name]:>10.4g} {res.values[name]:>10.4g} "
              f"{f'[{lo:.4g}, {hi:.4g}]':>24} {inside:>6}")
    print("\nFree-run scores (angle in deg; rig noise "
          f"{data.metadata['noise_deg']} deg)")
    print(f"{'method':<22} {'est RMSE':>9} {'est VAF %':>10} {'val RMSE':>9} {'val VAF %':>10}")
    rows = [("physical H-GWO+IPOPT", res.metrics["est"], res.metrics["val"])] + arx_rows
    for label, e, v in rows:
        print(f"{label:<22} {e['rmse']:>9.4g} {e['vaf']:>10.4f} {v['rmse']:>9.4g} "
              f"{v['vaf']:>10.4f}")
    if design:
        print("\nLinear model at rest for controller design (hhra_phys.control.linearize):")
        for line in design:
            print("  " + line)
    total = sum(s["seconds"] for s in res.stages)
    print("\nStages: " + "; ".join(f"{s['name']} {s['seconds']:.1f} s ({s['nfev']} evaluations)"
                                  for s in res.stages) + f"; total {total:.1f} s")
    for w in res.warnings:
        print(f"warning: {w}")
    print(f"\nwrote {files['plot']}, {files['json']}, {files['data']}")
    return 0


def _linear_summary(res: Any, data: Any) -> list[str]:
    """Resonance and damping of the fitted and the true linearised actuator."""
    import control
    import numpy as np

    from hhra_phys.control import linearize
    from hhra_phys.models.hhra.physical import PhysicalParameters
    from hhra_phys.models.hhra.rig import rig_model

    def resonance(sys: Any) -> tuple[float, float]:
        with np.errstate(invalid="ignore", divide="ignore"):  # the integrator's pole at 0
            wn, zeta, _ = control.damp(sys, doprint=False)
        i = int(np.argmax(wn))
        return float(wn[i]) / (2 * np.pi), float(zeta[i])

    f_fit, z_fit = resonance(linearize(res))
    true_model, p_true = rig_model(PhysicalParameters(**data.metadata["physical"]))
    f_true, z_true = resonance(linearize(true_model, params=p_true))
    tf = res.tf
    return [
        f"G(s) = kv / (s^3 + b s^2 + c s), theta in rad, current in mA: "
        f"b = {tf['b']:.4g}, c = {tf['c']:.4g}, kv = {tf['kv']:.4g}",
        f"hydraulic resonance {f_fit:.3f} Hz (truth {f_true:.3f} Hz), "
        f"damping ratio {z_fit:.4f} (truth {z_true:.4f})",
    ]


def _arx_rows(data: Any) -> list[tuple[str, dict, dict]]:
    """LS, RLS and FFRLS ARX rows from the comparison module, when it is installed."""
    try:
        from hhra_phys.compare import compare
    except ImportError:
        return []
    out = compare(data, split=0.5, methods=["ls", "rls", "ffrls"])
    rows = []
    for name, m in out["methods"].items():
        rows.append((f"ARX {name.upper()}", m["est"], m["val"]))
    return rows
