"""``hhra-phys compare``: the paper's identification comparison (Table 3) on one dataset."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from hhra_phys.cli._common import (
    FILE_OPTIONS,
    add_model_arguments,
    add_record_arguments,
    is_builtin,
    iterations,
    nonnegative_int,
    population,
    positive_int,
    read_record,
    report_error,
    with_intersample,
)
from hhra_phys.cli._guards import (
    STDOUT,
    all_or_nothing,
    check_arguments,
    check_search,
    check_size,
    output_path,
    seed,
    split_value,
    stdout_kept_for_json,
)
from hhra_phys.errors import HHRAError, ParameterError
from hhra_phys.outputs import FIGURE_SUFFIXES, atomic_write_text, check_output_path, jsonable

#: Words accepted as DATA for the built-in records.
PUBLIC_WORDS = ("public",)
RIG_WORDS = ("rig",)


def _methods(text: str) -> tuple[str, ...]:
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    if not names:
        raise argparse.ArgumentTypeError("give at least one method name")
    return names


def register(subparsers: Any) -> None:
    """Add the ``compare`` sub-command to the ``hhra-phys`` parser."""
    p = subparsers.add_parser(
        "compare",
        help="compare LS, RLS, FFRLS, PSO, GWO, H-GWO and FFRLS+H-GWO (and plug-ins) on data",
        description=(
            "Fit every method on the estimation part of a record, simulate each model in free "
            "run from the measured input on both parts, and score MSE, RMSE, VAF, ITAE, FIT "
            "(the reference paper's Table 3). DATA is a .csv/.tsv/.mat/.npz file, the word "
            "'public' (the public hydraulic-actuator record, split at sample 512 by default), "
            "or nothing / 'rig' (the simulated rig). Prints a Markdown table."
        ),
    )
    p.add_argument("data", nargs="*", default=None, metavar="DATA",
                   help="data file, 'public' or 'rig'; several files are compared on all "
                        "records at once (each split by --split; physical rows fitted jointly, "
                        "LS/RLS/FFRLS on the records' regression rows stacked, scores per "
                        "record and pooled)")
    p.add_argument("--public", action="store_true", help="use the public actuator record")
    # The one data vocabulary of every command; --u/--y are compare's older spellings.
    add_record_arguments(p, input_aliases=("--u",), output_aliases=("--y",))
    p.add_argument(
        "--split",
        type=split_value,
        default=None,
        help="estimation fraction in (0, 1) or the sample index the estimation part ends "
             "before, as in fit and diagnose (default 0.5; public: 512)",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the methods and the rig")
    p.add_argument(
        "--methods",
        type=_methods,
        default=None,
        help="comma-separated method names (default: every registered method)",
    )
    p.add_argument("--pop", type=population, default=100, help="population size (default 100)")
    p.add_argument("--iters", type=iterations, default=200, help="iterations (default 200)")
    p.add_argument("--na", type=nonnegative_int, default=3, help="ARX output order (default 3)")
    p.add_argument("--nb", type=positive_int, default=3, help="ARX input order (default 3)")
    p.add_argument("--nk", type=nonnegative_int, default=1, help="ARX input delay (default 1)")
    p.add_argument(
        "--box",
        type=float,
        nargs=2,
        default=(-5.0, 5.0),
        metavar=("LO", "HI"),
        help="search box of PSO, GWO and H-GWO for every coefficient (default -5 5)",
    )
    p.add_argument(
        "--zeta", type=float, default=0.5, help="expansion gain of the hybrid's box (default 0.5)"
    )
    p.add_argument(
        "--duration", type=float, default=20.0, help="rig record length in s (default 20)"
    )
    p.add_argument(
        "--plugin",
        action="append",
        default=[],
        metavar="MODULE",
        help="import MODULE first (it registers more methods); repeatable",
    )
    add_model_arguments(p)
    p.add_argument("--json", type=output_path, metavar="OUT",
                   help="write the JSON report ('-': to stdout, the table then goes to stderr)")
    p.add_argument(
        "--plot",
        type=output_path,
        metavar="OUT.png",
        help="figure of measured vs simulated output (.png, .svg or .pdf); convergence goes "
             "to OUT_convergence with the same suffix",
    )
    p.add_argument("--report", type=output_path, metavar="OUT.md",
                   help="write the Markdown table (.md)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.set_defaults(func=run)


def _load(args: argparse.Namespace) -> Any:
    """The record (or records, a list, for several DATA files) and its default split."""
    names = list(args.data or [])
    if len(names) > 1:
        return _load_several(args, names), 0.5
    args = argparse.Namespace(**{**vars(args), "data": names[0] if names else None})
    from hhra_phys.data import load_public_actuator
    from hhra_phys.models.hhra.defaults import PLAUSIBLE_FS
    from hhra_phys.units import range_warnings

    word = (args.data or "").lower()
    _check_builtin_choice(args, word)
    if args.public or word in PUBLIC_WORDS:
        # the usual split of that record (docs/data.md)
        return with_intersample(args, load_public_actuator()), 512
    if not args.data or word in RIG_WORDS:
        return _load_rig(args), 0.5
    data = read_record(args)
    for line in range_warnings(data, {}, PLAUSIBLE_FS):  # a time axis in ms inflates ITAE
        print(f"warning: {line}", file=sys.stderr)
    return data, 0.5


def _load_several(args: argparse.Namespace, names: list[str]) -> list[Any]:
    """Several DATA files, each read as one (files only), checked to belong together."""
    from hhra_phys.multi import check_records

    records = []
    for name in names:
        if is_builtin(name) or name.lower() in PUBLIC_WORDS:
            raise ParameterError(f"DATA {name!r}: several records must all be files")
        records.append(_load(argparse.Namespace(**{**vars(args), "data": [name]}))[0])
    check_records(records)
    return records


def _check_builtin_choice(args: argparse.Namespace, word: str) -> None:
    """Refuse DATA with --public, and a file's options with a built-in record."""
    if args.public and args.data and word not in PUBLIC_WORDS:
        raise ParameterError(f"give DATA ({args.data!r}) or --public, not both")
    if args.public or is_builtin(args.data):
        given = [flag for opt, flag in FILE_OPTIONS if getattr(args, opt, None) is not None]
        if given:
            raise ParameterError(f"{', '.join(given)}: options of a DATA file; the built-in "
                                 "records need none")


def _load_rig(args: argparse.Namespace) -> Any:
    """The simulated rig's record of ``--duration`` s (checked before it is simulated)."""
    from hhra_phys.models.hhra.rig import simulate_rig

    if not (math.isfinite(args.duration) and args.duration > 0):
        raise ParameterError(f"--duration must be a finite number > 0, got {args.duration}")
    check_size(args.duration * 250.0, f"--duration {args.duration:g} s of the rig at 250 Hz")
    try:
        return with_intersample(args, simulate_rig(seed=args.seed, duration=args.duration))
    except ParameterError as exc:
        if "cannot hold" not in str(exc):  # the excitation's words for too few samples
            raise
        raise ParameterError(f"--duration {args.duration:g} s of the rig at 250 Hz is too "
                             f"short for its excitation ({exc}); lengthen --duration"
                             ) from None


def _outputs(args: argparse.Namespace) -> dict[str, Path | None]:
    plot = Path(args.plot) if args.plot else None
    paths = {
        "json": Path(args.json) if args.json else None,
        "plot": plot,
        "convergence": plot.with_name(f"{plot.stem}_convergence{plot.suffix or '.png'}")
        if plot
        else None,
        "report": Path(args.report) if args.report else None,
    }
    check_arguments(args, {"--json": args.json, "--plot": plot,
                           "--plot's convergence figure": paths["convergence"],
                           "--report": args.report})
    for key, p in paths.items():
        if p is not None and str(p) != STDOUT:
            suffixes = FIGURE_SUFFIXES if key in ("plot", "convergence") else None
            check_output_path(p, overwrite=args.overwrite, what=key, suffixes=suffixes)
    return paths


def _physical_model(args: argparse.Namespace, dataset: Any) -> dict[str, Any]:
    """The physical rows' model from ``--model`` (default: the HHRA for the record)."""
    if not args.model:
        return {}
    from hhra_phys.extensions import model_from_spec

    first = dataset[0] if isinstance(dataset, list) else dataset
    return {"extra": {"physical": {"model": model_from_spec(args.model, first)}}}


def run(args: argparse.Namespace) -> int:
    """Run the comparison described by ``args``; returns the exit code (2 on bad input)."""
    from hhra_phys import compare as C

    say = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    try:
        paths = _outputs(args)  # before any work, so a clash fails fast
        with stdout_kept_for_json(args.json):  # a plugin printing while imported
            _check_methods(C, args)
        dataset, default_split = _load(args)
        split = _split(args, dataset, default_split)
        records = dataset if isinstance(dataset, list) else [dataset]
        check_search(args.pop, args.iters, sum(len(d) for d in records))
        _check_orders(C, args, records, split)
        if say:
            what = (f"{len(dataset)} records" if isinstance(dataset, list) else repr(dataset))
            say(f"compare: {what}, split {split}")
        with stdout_kept_for_json(args.json):  # a plugin's or model's prints
            comp = C.run_comparison(
                dataset,
                split=split,
                methods=args.methods,
                seed=args.seed,
                pop_size=args.pop,
                max_iter=args.iters,
                progress=say or False,
                na=args.na,
                nb=args.nb,
                nk=args.nk,
                zeta_s=args.zeta,
                bounds=tuple(args.box),
                **_physical_model(args, dataset),
            )
        report = comp.to_dict()
        table = C.markdown_table(report)
        _write_outputs(C, comp, report, table, paths, args)
    except (HHRAError, OSError) as exc:
        return report_error("compare", exc)
    print(table, file=sys.stderr if args.json == STDOUT else sys.stdout)
    failed = [name for name, r in comp.results.items() if r.error]
    if failed and len(failed) == len(comp.results):
        print(f"hhra-phys compare: error: every method failed ({', '.join(failed)}); see the "
              "table's notes", file=sys.stderr)
        return 1
    return 0


def _check_orders(C: Any, args: argparse.Namespace, records: list[Any],
                  split: float | int) -> None:
    """Refuse ARX orders that leave an estimation part too few regression rows (at least
    one per ARX parameter), before any method runs and nothing is written."""
    if args.methods is not None and not set(args.methods) & set(C.ARX_METHODS):
        return
    start = max(args.na, args.nk + args.nb - 1)  # the rows the first samples cannot fill
    for ds in records:
        n_est = split if isinstance(split, int) else int(round(split * len(ds)))
        if n_est - start < args.na + args.nb:
            raise ParameterError(
                f"--na {args.na} --nb {args.nb} --nk {args.nk}: the estimation part of "
                f"{ds.name or ds.source or 'the record'} has {n_est} samples, which leave "
                f"{max(n_est - start, 0)} regression rows for {args.na + args.nb} ARX "
                "parameters; lower the orders (the paper's are --na 3 --nb 3 --nk 1)")


def _check_methods(C: Any, args: argparse.Namespace) -> None:
    """Load the plugins and refuse an unknown ``--methods`` name."""
    registered = load_plugins(C, args.plugin)
    unknown = [m for m in args.methods or () if m not in registered]
    if unknown:  # checked before the data are loaded or simulated
        raise ParameterError(
            f"--methods: unknown {unknown}; registered: {', '.join(registered)}"
        )


def _split(args: argparse.Namespace, dataset: Any, default_split: float) -> float:
    """``--split`` (or the record's default), refusing what the comparison cannot score."""
    if isinstance(dataset, list) and args.plot:
        raise ParameterError("--plot draws one record; with several DATA records use "
                             "--json/--report (scores per record)")
    split = default_split if args.split is None else args.split
    if split == 1.0 and not isinstance(split, int):
        raise ParameterError("--split 1: the comparison scores every method on a "
                             "validation part; give a fraction below 1 or a sample index")
    return split


def _write_outputs(C: Any, comp: Any, report: dict[str, Any], table: str,
                   paths: dict[str, Path | None], args: argparse.Namespace) -> None:
    """Write the JSON, Markdown and figures asked for, all or none of them."""
    with all_or_nothing(paths.values()):  # Ctrl-C: none of them stays
        if paths["json"] and str(paths["json"]) == STDOUT:
            print(json.dumps(jsonable(report, default=str), indent=1), flush=True)
        elif paths["json"]:
            C.write_json(report, paths["json"], overwrite=args.overwrite)
        if paths["report"]:
            text = f"# Identification comparison: {report['dataset']}\n\n{table}"
            atomic_write_text(paths["report"], text)
        if paths["plot"]:
            C.plot_outputs(comp, path=paths["plot"], overwrite=args.overwrite)
            if any(r.outcome and r.outcome.history is not None for r in comp.results.values()):
                C.plot_convergence(comp, path=paths["convergence"], overwrite=args.overwrite)


def load_plugins(C: Any, modules: list[str]) -> list[str]:
    """Import each ``--plugin`` module; refuse one that registers no method.

    A module counts as registering when a method appears, or one registered is defined
    in it (imported earlier in the same process).
    """
    registered = C.load_plugins([])
    for mod in modules:
        before = dict(C.METHODS)
        try:
            registered = C.load_plugins([mod])
        except HHRAError:
            raise
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - a user's module
            what = (f"called sys.exit({exc.code!r})" if isinstance(exc, SystemExit)
                    else f"raised {type(exc).__name__}: {exc}")
            raise ParameterError(f"--plugin {mod}: importing it {what}") from None
        new = [n for n in C.METHODS if before.get(n) is not C.METHODS[n]]
        own = [n for n, fn in C.METHODS.items()
               if getattr(fn, "__module__", "") in (mod,) or
               getattr(fn, "__module__", "").startswith(mod + ".")]
        if not new and not own:
            raise ParameterError(f"--plugin {mod}: importing it registered no comparison "
                                 "method (call hhra_phys.compare.register_method in it)")
    return registered
