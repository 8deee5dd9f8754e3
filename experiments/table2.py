"""Reproduce the reference paper's Table 2 and extend it (tracker issue 3).

Runs H-GWO, GWO, PSO and DE (and SciPy's differential_evolution as a reference) on the nine
benchmark functions with the paper's settings (population 30, 100 iterations, 30 seeded runs),
then at an equal evaluation budget, on shifted optima, and with H-GWO variants. Writes
``<out>.json``, ``<out>.md`` and convergence plots ``<out>.png`` / ``<out>_<table>.png``;
``out/`` is ignored by git. The numbers in ``docs/benchmarks.md`` come from::

    python experiments/table2.py --out out/table2

Existing outputs are never replaced unless ``--overwrite`` is given.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from hhra_phys.errors import HHRAError
from hhra_phys.paper.table2 import StudySettings, run_and_write


def main(argv: Sequence[str] | None = None) -> int:
    """Run the study; returns the exit code (2 on bad input or an existing output)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/table2", help="output prefix (default out/table2)")
    parser.add_argument("--runs", type=int, default=30, help="runs per cell (default 30)")
    parser.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        _, text = run_and_write(
            StudySettings(runs=args.runs, seed=args.seed),
            json_path=out.with_suffix(".json"),
            plot_path=out.with_suffix(".png"),
            markdown_path=out.with_suffix(".md"),
            overwrite=args.overwrite,
            jobs=args.jobs,
            progress=lambda line: print(line, file=sys.stderr),
        )
    except HHRAError as exc:
        print(f"table2: error: {exc}", file=sys.stderr)
        return 2
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
