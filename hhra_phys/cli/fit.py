"""``hhra-phys fit``: fit the physical model to a record."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from hhra_phys.cli._common import (
    add_data_arguments,
    add_model_arguments,
    check_outputs,
    iterations,
    model_for,
    model_records,
    parse_fixed,
    parse_names,
    population,
    positive_int,
    report_error,
)
from hhra_phys.cli._guards import (
    STDOUT,
    all_or_nothing,
    check_arguments,
    check_search,
    output_path,
    seed,
    split_fraction,
    split_value,
    stdout_kept_for_json,
)
from hhra_phys.cluster import add_cluster_arguments, executor
from hhra_phys.errors import HHRAError, ParameterError
from hhra_phys.fit import OPTIMIZERS, best_of, fit_many
from hhra_phys.fit_report import fit_figure_path


def register(subparsers: Any) -> None:
    """Add the ``fit`` sub-command."""
    p = subparsers.add_parser(
        "fit",
        help="fit a physical model (the HHRA by default) to a record",
        description=(
            "Global search (H-GWO by default, population 100, 200 iterations as in the paper) "
            "over the identifiable parameter groups, then local refinement with IPOPT or NLopt, "
            "95 % confidence intervals and free-run scores on estimation and validation data. "
            "A group that ends at the edge of its default box gets that side widened by a "
            "decade and the fit is repeated (--no-widen turns this off). "
            "Exit codes: 0 done, 1 data or runtime error (also a diverged fit, whose JSON is "
            "still written), 2 usage error, 130 interrupted (nothing written)."
        ),
    )
    add_data_arguments(p, several=True)
    add_model_arguments(p)
    p.add_argument("--optimizer", choices=OPTIMIZERS, default="hgwo", help="global search")
    p.add_argument("--refine", default="ipopt",
                   help="ipopt | nlopt | nlopt:ALGORITHM (e.g. nlopt:LN_BOBYQA) | none")
    p.add_argument("--free", default=None, metavar="NAMES",
                   help="comma-separated free parameters (default: all but those the model "
                        "holds, for the HHRA g_spring and g_load)")
    p.add_argument("--fix", action="extend", nargs="+", default=None, metavar="NAME=VALUE",
                   help="hold parameters at values: --fix g_leak=6.4 g_damping=4 (repeatable); "
                        "checked against the parameter's sign and box")
    p.add_argument("--allow-outside-box", action="store_true",
                   help="accept --fix values outside the parameter's box (not its sign)")
    p.add_argument("--no-widen", action="store_true",
                   help="do not widen a default box whose edge a group ends at")
    p.add_argument("--split", type=split_value, default=0.5,
                   help="estimation fraction of every record in (0, 1] (default 0.5; 1: no "
                        "validation part), or the sample index the estimation part ends "
                        "before, as in compare and diagnose")
    p.add_argument("--validate", nargs="+", default=None, metavar="FILE",
                   help="whole records for validation (same column options); then every DATA "
                        "record is used for estimation")
    p.add_argument("--seed", type=seed, default=0, help="seed of the global search")
    p.add_argument("--starts", type=positive_int, default=1, metavar="K",
                   help="multi-start: K fits with seeds SEED..SEED+K-1, the lowest estimation "
                        "error kept (default 1)")
    add_cluster_arguments(p, "the starts")
    p.add_argument("--pop", type=population, default=100, help="population size (default 100)")
    p.add_argument("--iters", type=iterations, default=200, help="iterations (default 200)")
    p.add_argument("--cost", choices=("itae", "mse", "rmse", "ssr"), default="itae",
                   help="global-search cost (default itae, the paper's)")
    p.add_argument("--lam", type=float, default=1.0,
                   help="H-GWO mutation factor lambda (paper 0.25; default 1, see docs)")
    p.add_argument("--valve", choices=("orifice", "linear"), default=None,
                   help="valve law of the HHRA (default orifice)")
    p.add_argument("--intervals", choices=("linear", "profile"), default="linear",
                   help="95 %% intervals: linearised at the optimum (default) or profile "
                        "likelihood (a few seconds more)")
    p.add_argument("--json", type=output_path, default=None, metavar="OUT.json",
                   help="write the result as JSON ('-': to stdout, the summary then goes to "
                        "stderr)")
    p.add_argument("--plot", type=output_path, default=None, metavar="OUT.png",
                   help="write a figure (.png, .svg or .pdf)")
    p.add_argument("--report", type=output_path, default=None, metavar="OUT.md",
                   help="write a Markdown report (parameters, intervals, errors, warnings) "
                        "with the fit's figure beside it (OUT_fit.png)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _automatic_box(args: argparse.Namespace, model: Any, auto_bounds: dict[str, Any],
                   free: list[str] | None, fixed: dict[str, float],
                   others: list[Any]) -> dict[str, tuple[float, float]]:
    """The automatic box of the free parameters, the widest over every record given."""
    from hhra_phys.fit import default_free

    chosen = set(free) if free is not None else set(default_free(model, fixed))
    bounds = {k: v for k, v in auto_bounds.items() if k in chosen}
    for other in others:  # the widest automatic box of all
        for k, (lo, hi) in model_for(args, other, args.valve)[1].items():
            if k in bounds:
                bounds[k] = (min(bounds[k][0], lo), max(bounds[k][1], hi))
    return bounds


def _say_fitting(args: argparse.Namespace, records: list[Any]) -> None:
    """The line on stderr that says what is fitted, and how."""
    data = records[0]
    what = (f"{len(records)} records ({sum(len(d) for d in records)} samples)"
            if len(records) > 1 else
            f"{data.name or data.source or 'record'} ({len(data)} samples)")
    print(f"fitting {what} with {args.optimizer} (pop {args.pop}, {args.iters} it.) + "
          f"{args.refine}" + (f", {args.starts} starts" if args.starts > 1 else ""),
          file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """Run the fit; returns the exit code (0, 1 data/runtime error or divergence, 2 usage)."""
    try:
        fig = fit_figure_path(args.report) if args.report else None
        check_arguments(args, {"--json": args.json, "--plot": args.plot,
                               "--report": args.report,
                               **({f"--report's figure {Path(fig).name}": fig} if fig else {})})
        check_outputs([None if args.json == STDOUT else args.json, args.report],
                      args.overwrite, figures=[args.plot, fig])
        fixed = parse_fixed(args.fix)
        free = parse_names(args.free, "--free")
        if args.model and args.valve is not None:  # before the model file is looked at
            raise ParameterError("--valve is an option of the built-in HHRA; it cannot be "
                                 "combined with --model")
        with stdout_kept_for_json(args.json):  # a model file's prints: not in the JSON
            res, records, validation = _fit(args, fixed, free)
        # With --json - the JSON alone goes to stdout; the summary to stderr.
        say = (lambda *a: print(*a, file=sys.stderr)) if args.json == STDOUT else print
        print_result(res, say)
        with all_or_nothing([args.json, args.plot, args.report, fig]):  # Ctrl-C: none stays
            return _write(args, res, records, validation, say)
    except (HHRAError, OSError) as exc:
        return report_error("fit", exc)


def _fit(args: argparse.Namespace, fixed: dict[str, float], free: list[str] | None
         ) -> tuple[Any, list[Any], list[Any] | None]:
    """Read the records, build the model, run the fits: (best result, records, validation)."""
    records, validation, data_warnings = model_records(args)
    from hhra_phys.multi import check_records

    check_records(records + (validation or []))  # a pressure record against an angle fit
    check_search(args.pop, args.iters, sum(len(d) for d in records), runs=args.starts)
    data = records[0]
    args.split = split_fraction(args.split, [len(d) for d in records])
    model, auto_bounds = model_for(args, data, args.valve)
    # Problem runs the same check in every fit; here it names --fix before any worker
    # starts. Notes about values accepted outside their box come with the result.
    model.params.check_values(fixed, allow_outside_box=args.allow_outside_box)
    bounds = _automatic_box(args, model, auto_bounds, free, fixed,
                            records[1:] + (validation or []))
    refine = [r for r in args.refine.split("+")] if args.refine else None
    _say_fitting(args, records)
    if len(records) == 1 and (validation is None or len(validation) == 1):
        target, val_arg = data, (validation[0] if validation else None)
    else:  # several records, or one record with several validation records
        target, val_arg = records, validation
    with executor(args.workers, args.dask) as ex:
        results = fit_many(
            [target], seeds=range(args.seed, args.seed + args.starts), executor=ex,
            model=model, optimizer=args.optimizer, refine=refine, free=free, fixed=fixed,
            default_bounds=bounds, split=args.split, validation=val_arg,
            pop_size=args.pop, max_iter=args.iters, cost=args.cost, lam=args.lam,
            progress=not args.quiet and args.starts == 1 and ex is None,
            intervals=args.intervals, widen_bounds=not args.no_widen,
            allow_outside_box=args.allow_outside_box)
    res = best_of(results)
    res.warnings.extend(data_warnings)
    return res, records, validation


def _write(args: argparse.Namespace, res: Any, records: list[Any],
           validation: list[Any] | None, say: Any) -> int:
    """Write the JSON (:meth:`~hhra_phys.result.FitResult.to_json`) and the figure; 1 for a
    diverged fit (its JSON is still written, no figure), else 0."""
    if args.json == STDOUT:
        print(json.dumps(res.to_json(), indent=1), flush=True)
    elif args.json:
        print(f"wrote {res.save(args.json, overwrite=args.overwrite)}")
    if res.status == "diverged":
        print("hhra-phys fit: error: the fit diverged (the model's simulation does not "
              "stay finite with the fitted values); "
              + ("the result marked diverged is in the JSON; " if args.json else "")
              + "check the units of the record and the --fix values", file=sys.stderr)
        return 1
    if args.plot:
        with stdout_kept_for_json(args.json):  # the model runs again for the figure
            plotted = (plot_records(res, records, validation, args.plot, args.split,
                                    args.overwrite)
                       if len(records) > 1 or validation else
                       plot_result(res, records[0], args.plot, args.split, args.overwrite))
        say(f"wrote {plotted}")
    if args.report:
        with stdout_kept_for_json(args.json):
            data = ([*records, *(validation or [])] if len(records) > 1 or validation
                    else records[0])
            say(f"wrote {res.report(args.report, data, overwrite=args.overwrite)}")
    return 0


def print_result(res: Any, say: Any) -> None:
    """The fit summary: parameters and derived quantities with their intervals
    (:meth:`~hhra_phys.result.FitResult.summary`), each record's errors, the stages."""
    say(res.summary())
    for rec in res.records if len(res.records) > 1 else []:  # one record: the summary
        parts = [f"{label} RMSE {_num(rec[key].get('rmse'), '.4g')}"
                 for key, label in (("est", "estimation"), ("val", "validation"))
                 if rec[key]]
        say(f"record {rec['name']}: {', '.join(parts)}")
    for st in res.stages:
        say(f"stage {st['name']:<16} cost {_num(st['cost_before'])} -> "
            f"{_num(st['cost'])}, {st['nfev']} evaluations, {st['seconds']:.2f} s")


def _num(x: float | None, spec: str = ".6g") -> str:
    return "-" if x is None else format(x, spec)


def plot_result(res: Any, data: Any, path: str, split: float, overwrite: bool) -> Any:
    """Figure of a fit on its estimation and validation parts."""
    from hhra_phys.plots import plot_fit

    est, val = data.split(split) if split < 1 else (data, None)
    parts = [("estimation", est, res.predict(est))]
    if val is not None:
        parts.append(("validation", val, res.predict(val)))
    return plot_fit(path, parts, res.history, title=f"hhra-phys fit of {data.name or 'record'}",
                    overwrite=overwrite, stages=res.stages)


def plot_records(res: Any, records: list[Any], validation: list[Any] | None, path: str,
                 split: float, overwrite: bool) -> Any:
    """Figure of a fit of several records: each record's parts, then the validation records."""
    from hhra_phys.plots import plot_fit

    parts = []
    for ds in records:
        pieces = ([("", ds)] if validation or split >= 1 else
                  list(zip(("estimation", "validation"), ds.split(split), strict=True)))
        for label, piece in pieces:
            name = f"{ds.name or ds.source or 'record'} {label}".strip()
            parts.append((name, piece, res.predict(piece)))
    for ds in validation or []:
        parts.append((f"{ds.name or ds.source or 'record'} validation", ds, res.predict(ds)))
    return plot_fit(path, parts, res.history, title="hhra-phys fit", overwrite=overwrite,
                    stages=res.stages)
