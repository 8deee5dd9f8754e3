"""``hhra-phys benchmark``: the optimiser study of the reference paper's Table 2, and more."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from hhra_phys.cli._common import iterations, population, positive_int, report_error
from hhra_phys.cli._guards import STDOUT, check_arguments, output_path, seed
from hhra_phys.cluster import add_cluster_arguments, executor
from hhra_phys.errors import HHRAError, ParameterError
from hhra_phys.optim.registry import METHODS
from hhra_phys.outputs import jsonable
from hhra_phys.paper.benchmarks import BENCHMARK_KEYS
from hhra_phys.paper.table2 import PAPER_METHODS, TABLES, StudySettings, run_and_write


def _names(text: str) -> tuple[str, ...]:
    return tuple(t.strip() for t in text.split(",") if t.strip())


def register(subparsers: Any) -> None:
    """Add the ``benchmark`` sub-command to the ``hhra-phys`` parser."""
    p = subparsers.add_parser(
        "benchmark",
        help="run H-GWO, GWO, PSO and DE on the paper's nine benchmark functions",
        description=(
            "Reproduce the reference paper's Table 2 (population 30, 100 iterations, 30 seeded "
            "runs) and extend it: equal evaluation budgets, shifted optima, H-GWO variants, and "
            "SciPy's differential_evolution as an external reference. Prints markdown tables."
        ),
    )
    p.add_argument("--runs", type=positive_int, default=30,
                   help="seeded runs per cell (default 30)")
    p.add_argument("--pop", type=population, default=30, help="population size (default 30)")
    p.add_argument("--iters", type=iterations, default=100, help="iterations (default 100)")
    p.add_argument("--seed", type=seed, default=0, help="base seed (default 0)")
    p.add_argument(
        "--functions",
        type=_names,
        default=BENCHMARK_KEYS,
        help="comma-separated subset of f1..f9 (default all)",
    )
    p.add_argument(
        "--methods",
        type=_names,
        default=PAPER_METHODS,
        help=f"comma-separated subset of {','.join(METHODS)} (default {','.join(PAPER_METHODS)})",
    )
    p.add_argument(
        "--tables",
        type=_names,
        default=TABLES,
        help=f"comma-separated subset of {','.join(TABLES)} (default all)",
    )
    p.add_argument("--no-scipy", action="store_true", help="leave out SciPy's DE reference")
    p.add_argument("--jobs", type=positive_int, default=1, help="worker processes (default 1)")
    add_cluster_arguments(p, "the benchmark functions (one job each)")
    p.add_argument("--json", type=output_path, metavar="FILE",
                   help="write the report as JSON ('-': to stdout, the tables then go to stderr)")
    p.add_argument(
        "--plot",
        type=output_path,
        metavar="FILE",
        help="convergence plot of the first table; others go to FILE_<table>.<ext>",
    )
    p.add_argument("--markdown", type=output_path, metavar="FILE.md",
                   help="also write the tables to a Markdown file")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the study described by ``args``; returns the exit code (2 on bad input)."""
    progress = None if args.quiet else (lambda line: print(line, file=sys.stderr))
    try:
        check_arguments(args, {"--json": args.json, "--markdown": args.markdown,
                               "--plot": args.plot})
        if args.pop < 5 and not args.no_scipy:
            raise ParameterError(f"--pop {args.pop}: the SciPy reference "
                                 "(differential_evolution) needs a population of at least 5; "
                                 "raise --pop or pass --no-scipy")
        settings = StudySettings(
            runs=args.runs,
            pop_size=args.pop,
            max_iter=args.iters,
            seed=args.seed,
            functions=args.functions,
            methods=args.methods,
            tables=args.tables,
            scipy_reference=not args.no_scipy,
        )
        from hhra_phys.cli._guards import all_or_nothing
        from hhra_phys.paper.table2 import plot_paths

        figures = list(plot_paths(args.plot, settings.tables).values()) if args.plot else []
        # Stopped (Ctrl-C, SIGTERM) or failed between its writes: none of them stays.
        with executor(args.workers, args.dask) as ex, all_or_nothing(
                [args.json, args.markdown, *figures]):
            report, text = run_and_write(
                settings,
                json_path=None if args.json == STDOUT else args.json,
                plot_path=args.plot,
                markdown_path=args.markdown,
                overwrite=args.overwrite,
                jobs=args.jobs,
                progress=progress,
                executor=ex,
            )
    except (HHRAError, OSError) as exc:
        return report_error("benchmark", exc)
    if args.json == STDOUT:
        print(text, file=sys.stderr)
        print(json.dumps(jsonable(report, default=str), indent=1))
    else:
        print(text)
    return 0
