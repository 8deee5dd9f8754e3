"""Time the optimiser study (not a test).

Measures the paper's table alone (9 functions x 4 methods x 30 runs, population 30, 100
iterations, no SciPy reference), the performance target of tracker issue 3 (under 60 s on the
project's 2-core machine), and then the full study with every table::

    python benchmarks/bench_optim.py            # both
    python benchmarks/bench_optim.py --table-only
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from hhra_phys.paper.table2 import StudySettings, run_study


def main() -> None:
    """Print wall times of the study."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--table-only", action="store_true", help="skip the full study")
    parser.add_argument("--runs", type=int, default=30)
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args()
    print(f"python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}")

    t0 = time.perf_counter()
    run_study(
        StudySettings(runs=args.runs, tables=("results",), scipy_reference=False), jobs=args.jobs
    )
    t_table = time.perf_counter() - t0
    print(f"paper table, 9 x 4 x {args.runs} runs: {t_table:.1f} s (target < 60 s)")
    if args.table_only:
        return
    t0 = time.perf_counter()
    rep = run_study(StudySettings(runs=args.runs), jobs=args.jobs)
    print(f"full study (all tables, SciPy reference): {time.perf_counter() - t0:.1f} s")
    for key, secs in rep["timing"]["per_function"].items():
        print(f"  {key}: {secs:.1f} s")


if __name__ == "__main__":
    main()
