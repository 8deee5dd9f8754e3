"""``hhra-phys demo`` timed cold (empty compiled-code cache) and warm, wall and CPU time.

Target (issue 25): at most 45 s cold and 25 s warm on an idle 2-core machine. The demo
runs as a subprocess of this script; its CPU time is that of the demo and of every
process it waited for (its candidate workers, the C compiler), from
``resource.getrusage(RUSAGE_CHILDREN)``, which a shared machine's load does not inflate
the way it inflates wall time. ``--cold`` gives each run an empty cache
(``HHRA_PHYS_CACHE``); without it a first unrecorded run fills a private cache.

    python benchmarks/bench_demo.py [--cold] [--repeat 1] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def timed(cmd: list[str], env: dict[str, str]) -> tuple[float, float, str]:
    """Wall and CPU seconds (self and waited-for children) of ``cmd``, and its stdout."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, check=True, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return wall, cpu, proc.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--cold", action="store_true", help="empty compiled-code cache for each run")
    ap.add_argument("--extra", default="", help="extra demo options, e.g. '--quick'")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ)
        demo = [sys.executable, "-m", "hhra_phys.cli", "demo", "--seed", str(args.seed),
                *args.extra.split()]
        if not args.cold:
            env["HHRA_PHYS_CACHE"] = str(Path(tmp, "cache"))
            timed(demo + ["--out", str(Path(tmp, "warmup"))], env)
        for i in range(args.repeat):
            if args.cold:
                env["HHRA_PHYS_CACHE"] = str(Path(tmp, f"cache{i}"))
            load0 = os.getloadavg()[0]
            wall, cpu, out = timed(demo + ["--out", str(Path(tmp, f"run{i}"))], env)
            found = re.search(r"effects added: (.*)", out)
            score = re.search(r"error on the held-out test part.*", out)
            print(f"run {i + 1} ({'cold' if args.cold else 'warm'}): wall {wall:.1f} s, "
                  f"CPU {cpu:.1f} s (load average {load0:.1f} -> {os.getloadavg()[0]:.1f}); "
                  f"{found.group(1) if found else '?'}; "
                  f"{score.group(0) if score else ''}", flush=True)


if __name__ == "__main__":
    main()
