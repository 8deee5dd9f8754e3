"""``hhra-phys demo``: the main job end to end on the built-in simulated rig."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from hhra_phys.cli._common import report_error
from hhra_phys.cli._guards import seed
from hhra_phys.data import check_save_path, save_csv, sidecar_path
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
            "print a results table and write a plot and the fit as JSON. Then close the loop: "
            "simulate a second rig record (independent reference implementation) with an "
            "effect the model does not declare, drawn from the seed, diagnose it and report "
            "the error before and after on the held-out test part with the named effect."
        ),
    )
    p.add_argument("--out", default=None, metavar="DIR",
                   help="output directory (default: a new hhra-demo-<time> directory)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the rig and the search")
    p.add_argument("--quick", action="store_true",
                   help="short record and small search (a smoke run, about a minute)")
    p.add_argument("--overwrite", action="store_true", help="replace files in an existing --out")
    p.set_defaults(func=run)


def _step(i: int, n: int, text: str) -> None:
    print(f"[{i}/{n}] {text}", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    """Run the demo; returns the exit code."""
    out = Path(args.out) if args.out else Path(f"hhra-demo-{time.strftime('%Y%m%d-%H%M%S')}")
    files = {"plot": out / "demo_fit.png", "json": out / "demo_fit.json",
             "data": out / "demo_rig.csv", "loop_plot": out / "demo_loop.png",
             "loop_json": out / "demo_loop.json", "loop_data": out / "demo_loop_rig.csv"}
    created = not out.exists()
    try:  # every output checked before the first simulation
        out.mkdir(parents=True, exist_ok=True)
        check_save_path(files["data"], args.overwrite)
        check_save_path(files["loop_data"], args.overwrite)
        check_output_path(files["json"], overwrite=args.overwrite)
        check_output_path(files["loop_json"], overwrite=args.overwrite)
        check_output_path(files["plot"], overwrite=args.overwrite, suffixes=FIGURE_SUFFIXES)
        check_output_path(files["loop_plot"], overwrite=args.overwrite,
                          suffixes=FIGURE_SUFFIXES)
    except (HHRAError, OSError) as exc:
        _remove(out, [], created)
        code = report_error("demo", exc)
        print("hhra-phys demo: (or choose another --out)", file=sys.stderr)
        return code
    # Every file the run may write, and whether it was there before (--overwrite).
    paths = [p for f in files.values() for p in (f, sidecar_path(f)) if f.suffix == ".csv"]
    paths += [f for f in files.values() if f.suffix != ".csv"]
    new = [p for p in paths if not p.exists()]
    try:
        return _run(args, out, files, new)
    except (HHRAError, OSError) as exc:  # nothing of this run stays
        _remove(out, new, created)
        return report_error("demo", exc)
    except BaseException:  # Ctrl-C too
        _remove(out, new, created)
        raise


def _remove(out: Path, new: list[Path], created: bool) -> None:
    """Remove the files this run created (``new``: those not there before it), and ``out``
    if this run created it (and it is then empty)."""
    for p in new:
        p.unlink(missing_ok=True)
    if created:
        try:
            out.rmdir()
        except OSError:
            pass  # not empty: someone else's files


def _run(args: argparse.Namespace, out: Path, files: dict[str, Path],
         new: list[Path]) -> int:
    """The demo's work, then its files written together at the end (``new``: those that
    were not there before, removed again if the writing fails)."""
    from hhra_phys.fit import fit
    from hhra_phys.models.hhra.rig import simulate_rig
    from hhra_phys.plots import plot_fit

    duration, pop, iters = (8.0, 30, 40) if args.quick else (20.0, 100, 200)
    n_steps = 6
    _step(1, n_steps, f"simulating the rig: {duration:.0f} s at 250 Hz, seed {args.seed}")
    data = simulate_rig(seed=args.seed, duration=duration)
    _step(2, n_steps, f"fitting the physical model: H-GWO (pop {pop}, {iters} it.) + IPOPT")
    res = fit(data, seed=args.seed, pop_size=pop, max_iter=iters, progress=True)
    _step(3, n_steps, "fitting black-box ARX models (LS, RLS, FFRLS) on the same split")
    arx_rows = _arx_rows(data)
    _step(4, n_steps, "linearising the fitted model for controller design (python-control)")
    design = _linear_summary(res, data)
    hidden, truth_e = hidden_effect(args.seed)
    _step(5, n_steps, "closing the loop: a rig record with an effect the model does not "
                      "declare (drawn from the seed), diagnosed with the effect library")
    loop, loop_data = _close_loop(args, duration, pop, iters, hidden, truth_e)
    _step(6, n_steps, f"writing results to {out}/")
    save_csv(data, files["data"], overwrite=args.overwrite)
    res.save(files["json"], overwrite=args.overwrite)
    est, val = data.split(0.5)
    plot_fit(files["plot"], [("estimation", est, res.predict(est)),
                             ("validation", val, res.predict(val))],
             res.history, title="hhra-phys demo: simulated rig", overwrite=args.overwrite,
             stages=res.stages)
    _write_loop(args, files, loop, loop_data, hidden)

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
    _print_loop(loop, hidden, truth_e)
    print(f"\nwrote {files['plot']}, {files['json']}, {files['data']}, {files['loop_plot']}, "
          f"{files['loop_json']}, {files['loop_data']}")
    return 0


#: Effects the demo may hide in its second record, with a size the loop finds on
#: the full 20 s record (docs/diagnosis.md): drawn from the seed.
DEMO_EFFECTS: tuple[tuple[str, dict[str, float]], ...] = (
    ("valve_deadzone", {"i_dead": 0.1}),
    ("input_delay", {"delay": 3.0}),
    ("valve_saturation", {"i_sat": 0.7}),
    ("gravity_load", {"g_grav_cos": 5.0, "g_grav_sin": -8.0}),
)


def hidden_effect(seed: int) -> tuple[str, dict[str, float]]:
    """The effect (library name, its true parameters) the demo hides for ``seed``."""
    import numpy as np

    name, params = DEMO_EFFECTS[int(np.random.default_rng(seed).integers(len(DEMO_EFFECTS)))]
    return name, dict(params)


def _write_loop(args: argparse.Namespace, files: dict[str, Path], res: Any, data: Any,
                hidden: str) -> None:
    """Write the loop's record, JSON and figure."""
    import json

    from hhra_phys.outputs import atomic_write_text

    save_csv(data, files["loop_data"], overwrite=args.overwrite)
    atomic_write_text(files["loop_json"], json.dumps(res.to_json(), indent=2))
    plot_loop(res, data, files["loop_plot"], hidden, args.overwrite)


def _close_loop(args: argparse.Namespace, duration: float, pop: int, iters: int,
                hidden: str, truth: dict[str, float]) -> tuple[Any, Any]:
    """Simulate the record with the hidden effect and run the loop; (result, record)."""
    from hhra_phys.diagnosis.engine import diagnose
    from hhra_phys.fit import default_model
    from hhra_phys.reference import reference_record

    # The independent implementation: the data are not the model checked against itself.
    data = reference_record(seed=args.seed + 1, duration=duration, effects={hidden: truth})
    from hhra_phys.cluster import executor

    model, bounds = default_model(data)
    # Candidate refits in one process per core, as `hhra-phys diagnose` does by default
    # (results identical to a serial run).
    with executor("auto") as ex:
        res = diagnose(data, model, bounds=bounds, pop_size=pop, max_iter=iters,
                       max_effects=2, seed=args.seed, executor=ex,
                       progress=lambda s: print("    " + s.splitlines()[0], file=sys.stderr,
                                                flush=True) if s.startswith(("  tried", "round"))
                       and "ranking" not in s else None)
    return res, data


def _print_loop(res: Any, hidden: str, truth: dict[str, float]) -> None:
    print(f"\nClosing the loop: the second record hides {hidden} "
          f"({', '.join(f'{k}={v:g}' for k, v in truth.items())}), not declared in the model")
    found = ", ".join(res.chosen) or "nothing"
    verdict = ("the hidden effect, named" if res.chosen == [hidden] else
               "includes the hidden effect" if hidden in res.chosen else "NOT the hidden effect")
    print(f"effects added: {found} ({verdict})")
    for k in truth:
        if k in res.final.values:
            lo, hi = res.final.ci95.get(k, (float("nan"), float("nan")))
            print(f"  {k:<11} true {truth[k]:>8.4g}  fitted {res.final.values[k]:>8.4g}  "
                  f"95 % CI [{lo:.4g}, {hi:.4g}]")
    b, f = res.test_scores.get("base", {}), res.test_scores.get("final", {})
    if b and f:
        print(f"error on the held-out test part (not used to choose): RMSE {b['rmse']:.4g} -> "
              f"{f['rmse']:.4g} deg, VAF {b['vaf']:.4f} -> {f['vaf']:.4f} %")
    print(f"loop: {res.settings['stop']}; {res.settings['seconds']:.1f} s")


def plot_loop(res: Any, data: Any, path: Path, hidden: str, overwrite: bool) -> Path:
    """Test part of the loop's record: measured, base and final model, and their errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hhra_phys.diagnosis.selection import split_record
    from hhra_phys.outputs import atomic_path

    check_output_path(path, overwrite=overwrite, suffixes=FIGURE_SUFFIXES)
    _, _, test = split_record(data, res.settings["split"], res.settings["test"])
    y_base, y_final = res.base.predict(test), res.final.predict(test)
    b, f = res.test_scores["base"], res.test_scores["final"]
    label = f"final (+ {', '.join(res.chosen)})" if res.chosen else "final (nothing added)"
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax1.plot(test.t, test.y, color="0.6", lw=1.5, label="measured")
    ax1.plot(test.t, y_base, color="tab:red", lw=1, label=f"base, RMSE {b['rmse']:.3g} deg")
    ax1.plot(test.t, y_final, color="tab:blue", lw=1, ls="--",
             label=f"{label}, RMSE {f['rmse']:.3g} deg")
    ax1.set_ylabel("angle [deg]")
    ax1.legend(loc="best", fontsize=8)
    ax1.set_title(f"hhra-phys demo: closing the loop (hidden: {hidden}), test part only")
    ax2.plot(test.t, test.y - y_base, color="tab:red", lw=0.8, label="base")
    ax2.plot(test.t, test.y - y_final, color="tab:blue", lw=0.8, label="final")
    ax2.set_ylabel("error [deg]")
    ax2.set_xlabel("time [s]")
    ax2.legend(loc="best", fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return Path(path)


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
