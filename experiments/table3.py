"""Reproduce the reference paper's identification comparison (Table 3, Figures 10-16).

Runs every registered comparison method (LS, RLS, FFRLS, PSO, GWO, H-GWO, FFRLS+H-GWO and any
plug-ins, e.g. the physical-model fits) plus a few controls on

* the simulated rig (:func:`hhra_phys.rig.simulate_rig`, the paper's 20 s at 250 Hz, 0.05 deg
  encoder noise), one record per seed, split in halves; and
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

Existing outputs are never replaced unless ``--overwrite`` is given.
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys import arx
from hhra_phys import compare as C
from hhra_phys.data import Dataset, load_public_actuator
from hhra_phys.errors import HHRAError, ParameterError
from hhra_phys.rig import simulate_rig

#: Rows of the paper's table plus plain H-GWO, in this order.
PAPER_ROWS = C.ARX_METHODS
#: Figures per record.
FIGURES = ("outputs", "errors", "convergence")
#: Control rows registered by this script.
CONTROLS = ("pso_2x", "gwo_2x", "ffrls_hgwo_ws", "ffrls_hgwo_z01", "ffrls_hgwo_z1")


def _double_budget(method: str) -> C.MethodFn:
    def run(est: Dataset, val: Dataset, s: C.CompareSettings) -> C.MethodOutcome:
        fit = arx.fit_metaheuristic(
            est.u,
            est.y,
            est.t,
            method=method,
            bounds=s.bounds,
            pop_size=s.pop_size,
            max_iter=2 * s.max_iter + 1,
            seed=s.seed,
            na=s.na,
            nb=s.nb,
            nk=s.nk,
        )
        return C.arx_outcome(fit, est, val)

    return run


def _hybrid(zeta_s: float | None = None, warm_start: bool = False) -> C.MethodFn:
    def run(est: Dataset, val: Dataset, s: C.CompareSettings) -> C.MethodOutcome:
        fit = arx.fit_ffrls_hgwo(
            est.u,
            est.y,
            est.t,
            zeta_s=s.zeta_s if zeta_s is None else zeta_s,
            warm_start=warm_start,
            pop_size=s.pop_size,
            max_iter=s.max_iter,
            seed=s.seed,
            na=s.na,
            nb=s.nb,
            nk=s.nk,
        )
        return C.arx_outcome(fit, est, val)

    return run


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
        "pso_2x": _double_budget("pso"),
        "gwo_2x": _double_budget("gwo"),
        "ffrls_hgwo_ws": _hybrid(warm_start=True),
        "ffrls_hgwo_z01": _hybrid(zeta_s=0.1),
        "ffrls_hgwo_z1": _hybrid(zeta_s=1.0),
    }
    for name, fn in fns.items():
        C.register_method(name, fn, label=labels[name], replace=True)


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
    parser.add_argument("--records", default="rig,public", help="rig, public or both")
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
        if not seeds or not records or set(records) - {"rig", "public"}:
            raise ParameterError("--seeds needs integers; --records is rig, public or both")
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
        planned = [out / f"{r}_seed{s}.json" for r in records for s in seeds]
        planned += [out / "summary.json", out / "tables.md"]
        for r in records:
            planned += [out / f"{r}_{k}.png" for k in FIGURES]
            if fig_dir:
                planned += [fig_dir / f"identification_{r}_{k}.png" for k in FIGURES]
        _check_free(planned, args.overwrite)
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
        for record in records:
            comps = []
            for seed in seeds:
                if record == "rig":
                    ds, split = simulate_rig(seed=seed), 0.5
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
