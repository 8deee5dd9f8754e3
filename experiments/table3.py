"""Reproduce the reference paper's identification comparison (Table 3, Figures 10-16).

Runs every registered comparison method (LS, RLS, FFRLS, PSO, GWO, H-GWO, FFRLS+H-GWO and any
plug-ins, e.g. the physical-model fits) plus a few controls on

* the simulated rig (:func:`hhra_phys.models.hhra.rig.simulate_rig`, the paper's 20 s at
  250 Hz, 0.05 deg encoder noise), one record per seed, split in halves (``rig_perturbed``:
  the same with the truth drawn away from the model's nominal values by
  :func:`hhra_phys.models.hhra.rig.perturbed_physical`, so that no method starts at the
  answer); and
* the public measured hydraulic-actuator record (valve opening -> oil pressure, sample units),
  split at sample 512 as its README says, once per seed (only the metaheuristics depend on it).

Controls (registered here, so they appear as extra rows):

``pso_2x``, ``gwo_2x``
    PSO and GWO with ``2 * iters + 1`` iterations: the same number of objective evaluations as
    H-GWO, which spends two per member and iteration plus ``2 * pop`` at initialisation.
``ffrls_hgwo_ws``
    The hybrid with the FFRLS estimate injected into the first population (warm start).
``ffrls_hgwo_z01``, ``ffrls_hgwo_z1``
    The hybrid with expansion gain ``zeta_s`` 0.1 and 1.0 (default 0.5; the paper gives none).

Writes to ``--out`` (default ``out/table3``, ignored by git): one JSON report per record
(``rig_seed<k>.json``, ``public_seed<k>.json``), ``summary.json`` (mean, spread and range over
seeds), ``tables.md``, and per record the figures ``*_outputs.png`` (measured against
simulated output) and ``*_errors.png`` (simulation error), both for the seed ``--figure-seed``,
and ``*_convergence.png`` (every seed). Controls are left out of the figures. With
``--figures DIR`` the figures are also written as ``DIR/identification_<record>_<kind>.png``.
By default every registered method runs, which includes the physical-model rows when their
plug-in is installed (minutes per record); ``--methods`` restricts the list (controls are
added unless ``--no-controls``). The numbers in ``docs/identification.md`` come from::

    python experiments/table3.py --out out/table3 --figures docs/figures \
        --methods ls,rls,ffrls,pso,gwo,hgwo,ffrls_hgwo
    python experiments/table3.py --out out/table3_phys --seeds 0 --no-controls
    python experiments/table3.py --out out/table3_perturbed --seeds 0 --no-controls \
        --records rig_perturbed --methods \
        ls,ffrls,ffrls_hgwo,phys_hgwo,phys_hgwo_ipopt,phys_hgwo_nlopt,phys_ipopt

Existing outputs are never replaced unless ``--overwrite`` is given.
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys import arx
from hhra_phys import compare as C
from hhra_phys.data import Dataset, load_public_actuator
from hhra_phys.errors import HHRAError, ParameterError
from hhra_phys.metrics import mse
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.models.hhra.rig import DEFAULT_NOISE_DEG, perturbed_physical, simulate_rig

#: Rows of the paper's table plus plain H-GWO, in this order.
PAPER_ROWS = C.ARX_METHODS
#: Figures per record.
FIGURES = ("outputs", "errors", "convergence")
#: Control rows registered by this script.
CONTROLS = ("pso_2x", "gwo_2x", "ffrls_hgwo_ws", "ffrls_hgwo_z01", "ffrls_hgwo_z1")
#: Records the comparison can run on (``tustin`` is the inverse-map check).
RECORDS = ("rig", "rig_perturbed", "public", "tustin")


def _variant(base: str, changes: Callable[[C.CompareSettings], dict[str, Any]]) -> C.MethodFn:
    """The registered method ``base`` run with some of its settings changed."""

    def run(est: Dataset, val: Dataset, s: C.CompareSettings) -> C.MethodOutcome:
        return C.METHODS[base](est, val, replace(s, **changes(s)))

    return run


def _hybrid_warm_start(est: Dataset, val: Dataset, s: C.CompareSettings) -> C.MethodOutcome:
    """The hybrid with the FFRLS estimate injected into its first population."""
    fit = arx.fit_ffrls_hgwo(
        est.u,
        est.y,
        est.t,
        zeta_s=s.zeta_s,
        warm_start=True,
        pop_size=s.pop_size,
        max_iter=s.max_iter,
        seed=s.seed,
        optimizer_options=s.options.get("ffrls_hgwo"),
        progress=s.progress,
        na=s.na,
        nb=s.nb,
        nk=s.nk,
    )
    return C.arx_outcome(fit, est, val)


def register_controls() -> None:
    """Register the control rows (idempotent)."""
    labels = {
        "pso_2x": "PSO, H-GWO's evals",
        "gwo_2x": "GWO, H-GWO's evals",
        "ffrls_hgwo_ws": "FFRLS+H-GWO warm start",
        "ffrls_hgwo_z01": "FFRLS+H-GWO zeta 0.1",
        "ffrls_hgwo_z1": "FFRLS+H-GWO zeta 1",
    }
    fns = {
        # H-GWO spends two evaluations per member and iteration plus 2 * pop at the start.
        "pso_2x": _variant("pso", lambda s: {"max_iter": 2 * s.max_iter + 1}),
        "gwo_2x": _variant("gwo", lambda s: {"max_iter": 2 * s.max_iter + 1}),
        "ffrls_hgwo_ws": _hybrid_warm_start,
        "ffrls_hgwo_z01": _variant("ffrls_hgwo", lambda s: {"zeta_s": 0.1}),
        "ffrls_hgwo_z1": _variant("ffrls_hgwo", lambda s: {"zeta_s": 1.0}),
    }
    for name, fn in fns.items():
        C.register_method(name, fn, label=labels[name], replace=True)


def tustin_check(seed: int) -> tuple[list[dict[str, Any]], str]:
    """LS fits mapped back to the continuous ``kv / (a s^3 + b s^2 + c s)`` on the rig.

    The exact Tustin structure ARX(3, 4, 0) and the paper's eq. 13, ARX(3, 3, 1), fitted by LS on
    the rig's estimation half without noise and with its default noise, then
    :func:`~hhra_phys.arx.tustin_inverse` with ``rtol = inf`` (the nearest continuous model; the
    deviations say how far the fit is from an exact Tustin image) and the continuous poles.
    """
    tf = HHRAModel().tf_coefficients()  # theta [rad] per I [mA]; the rig measures degrees
    truth_poles = np.roots([tf["a"], tf["b"], tf["c"], 0.0])
    rows: list[dict[str, Any]] = [
        {
            "case": "truth (linearised at rest)",
            "b": tf["b"],
            "c": tf["c"],
            "kv": float(np.degrees(tf["kv"])),
            "poles": truth_poles,
        }
    ]
    for noise in (0.0, DEFAULT_NOISE_DEG):
        est, val = simulate_rig(seed=seed, noise=noise).split(0.5)
        for na, nb, nk in ((3, 4, 0), (3, 3, 1)):
            model = arx.fit_ls(est.u, est.y, na, nb, nk, on_ill_conditioned="ignore").model
            b_full, a_full = model.filter_coefficients()
            inv = arx.tustin_inverse(b_full, a_full, est.dt, rtol=np.inf)
            rows.append(
                {
                    "case": f"noise {noise:g} deg, ARX({na},{nb},{nk})",
                    "val_mse": mse(val.y, model.simulate(val.u, y_init=est.y, u_init=est.u)),
                    "b": inv["b"],
                    "c": inv["c"],
                    "kv": inv["kv"],
                    "den_dev": inv["den_deviation"],
                    "num_dev": inv["num_deviation"],
                    "poles": model.continuous_poles(est.dt),
                }
            )
    lines = [
        "| case | val MSE [deg^2] | b/a [1/s] | c/a [1/s^2] | kv/a [deg/(mA s^3)] | "
        "continuous poles [1/s] | den. dev. | num. dev. |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        poles = ", ".join(
            f"{p.real:.4g}" + (f" ± {abs(p.imag):.4g}j" if p.imag else "")
            for p in sorted(r["poles"], key=lambda z: (z.real, z.imag))
            if p.imag >= 0
        )
        lines.append(
            f"| {r['case']} | {C._fmt(r.get('val_mse'))} | {r['b']:.4g} | {r['c']:.4g} | "
            f"{r['kv']:.4g} | {poles} | {C._fmt(r.get('den_dev'), 2)} | "
            f"{C._fmt(r.get('num_dev'), 2)} |"
        )
    for r in rows:
        r["poles"] = [[float(p.real), float(p.imag)] for p in r["poles"]]
    return rows, "\n".join(lines) + "\n"


def stable_fraction(
    box: tuple[float, float], na: int, draws: int = 200_000, seed: int = 0
) -> float:
    """Share of uniform draws of ``a_1..a_na`` in the box whose model is stable (radius <= 1)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(box[0], box[1], size=(draws, na))
    return float(np.mean(arx.pole_radius(a) <= 1.0))


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).resolve().parent,
        )
    except (OSError, subprocess.CalledProcessError):
        return None
    return out.stdout.strip() or None


def _check_free(paths: Sequence[Path], overwrite: bool) -> None:
    taken = [str(p) for p in paths if p.exists()]
    if taken and not overwrite:
        raise ParameterError(f"outputs exist: {', '.join(taken)} (use --overwrite)")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the experiment; returns the exit code (2 on bad input or an existing output)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/table3", help="output directory")
    parser.add_argument("--seeds", default="0,1,2,3,4", help="comma-separated seeds")
    parser.add_argument("--pop", type=int, default=100, help="population (paper: 100)")
    parser.add_argument("--iters", type=int, default=200, help="iterations (paper: 200)")
    parser.add_argument("--records", default="rig,public,tustin",
                        help=f"any of {', '.join(RECORDS)}")
    parser.add_argument(
        "--methods", help="comma-separated methods (default: every registered one); controls added"
    )
    parser.add_argument("--no-controls", action="store_true", help="only the registered methods")
    parser.add_argument("--figure-seed", type=int, default=0, help="seed of the output figures")
    parser.add_argument("--figures", metavar="DIR", help="also write figures for the docs here")
    parser.add_argument(
        "--plugin",
        action="append",
        default=[],
        metavar="MODULE",
        help="import MODULE first (registers more methods)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    args = parser.parse_args(argv)
    say = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
    start = time.perf_counter()
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
        records = [r.strip() for r in args.records.split(",") if r.strip()]
        if not seeds or not records or set(records) - set(RECORDS):
            raise ParameterError(f"--seeds needs integers; --records: {', '.join(RECORDS)}")
        if args.figure_seed not in seeds:
            raise ParameterError(f"--figure-seed {args.figure_seed} is not among --seeds")
        C.load_plugins(args.plugin)
        if not args.no_controls:
            register_controls()
        if args.methods:
            methods = [m.strip() for m in args.methods.split(",") if m.strip()]
        else:
            methods = [m for m in C.available_methods() if m not in CONTROLS]
        if not args.no_controls:
            methods += [m for m in CONTROLS if m not in methods]
        out = Path(args.out)
        fig_dir = Path(args.figures) if args.figures else None
        comparisons = [r for r in records if r != "tustin"]
        planned = [out / f"{r}_seed{s}.json" for r in comparisons for s in seeds]
        planned += [out / "summary.json", out / "tables.md"]
        for r in comparisons:
            planned += [out / f"{r}_{k}.png" for k in FIGURES]
            if fig_dir:
                planned += [fig_dir / f"identification_{r}_{k}.png" for k in FIGURES]
        _check_free(planned, args.overwrite)
        if fig_dir is not None and not fig_dir.is_dir():
            # Checked here: the figures are written after minutes of fits.
            raise ParameterError(f"--figures {fig_dir}: folder does not exist; create it first")
        out.mkdir(parents=True, exist_ok=True)

        summary: dict[str, Any] = {
            "command": "python experiments/table3.py " + " ".join(argv or sys.argv[1:]),
            "commit": _git_commit(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "seeds": seeds,
            "pop_size": args.pop,
            "max_iter": args.iters,
            "methods": methods,
            "stable_fraction_paper_box": stable_fraction(arx.PAPER_BOX, 3),
            "records": {},
        }
        tables = []
        if "tustin" in records:
            rows, table = tustin_check(args.figure_seed)
            summary["tustin"] = rows
            tables.append(
                f"## Tustin inverse map of LS fits (rig seed {args.figure_seed})\n\n{table}"
            )
        for record in comparisons:
            comps = []
            for seed in seeds:
                if record == "rig":
                    ds, split = simulate_rig(seed=seed), 0.5
                elif record == "rig_perturbed":
                    ds = simulate_rig(seed=seed, physical=perturbed_physical(seed))
                    split = 0.5
                else:
                    ds, split = load_public_actuator(), 512
                say(f"== {record}, seed {seed}")
                comp = C.run_comparison(
                    ds,
                    split,
                    methods,
                    seed=seed,
                    pop_size=args.pop,
                    max_iter=args.iters,
                    progress=say,
                )
                C.write_json(comp.to_dict(), out / f"{record}_seed{seed}.json", args.overwrite)
                comps.append(comp)
            reports = [c.to_dict() for c in comps]
            agg = C.aggregate(reports)
            summary["records"][record] = agg
            shown = next(c for c, s in zip(comps, seeds, strict=True) if s == args.figure_seed)
            paper_rows = [m for m in PAPER_ROWS if m in shown.results]
            extra_rows = [m for m in shown.results if m not in PAPER_ROWS and m not in CONTROLS]
            for target in [out] + ([fig_dir] if fig_dir else []):
                prefix = "" if target == out else "identification_"
                for kind in ("outputs", "errors"):
                    C.plot_outputs(
                        shown,
                        paper_rows + extra_rows,
                        target / f"{prefix}{record}_{kind}.png",
                        errors=kind == "errors",
                        overwrite=args.overwrite,
                    )
                C.plot_convergence(
                    comps,
                    target / f"{prefix}{record}_convergence.png",
                    methods=paper_rows + extra_rows,
                    overwrite=args.overwrite,
                )
            tables.append(
                f"## {record}: {reports[0]['dataset']}, {len(seeds)} seeds\n\n"
                f"Mean ± standard deviation over seeds {seeds}; range of the validation MSE.\n\n"
                + C.markdown_summary(agg)
                + f"\n### {record}, seed {args.figure_seed}\n\n"
                + C.markdown_table(shown.to_dict())
            )
        summary["seconds"] = time.perf_counter() - start
        C.write_json(summary, out / "summary.json", args.overwrite)
        text = (
            f"# Table 3 reproduction\n\nCommand: `{summary['command']}` (commit "
            f"{summary['commit']}), {summary['seconds']:.0f} s. Population {args.pop}, "
            f"{args.iters} iterations. Share of stable models among uniform draws of "
            f"(a1, a2, a3) in the paper's box [-5, 5]: {summary['stable_fraction_paper_box']:.4f}."
            "\n\n" + "\n".join(tables)
        )
        (out / "tables.md").write_text(text)
    except HHRAError as exc:
        print(f"table3: error: {exc}", file=sys.stderr)
        return 2
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
