"""A full ``hhra-phys diagnose`` against one ``hhra-phys fit`` of the same record, side by side.

Target (issue 16): the diagnosis of a 20 s, 250 Hz record costs at most 6 times one fit
of it (moonshot 3 times). Both commands run as subprocesses of this script, one after
the other, in one run, on a reference-rig record (the independent implementation,
:func:`hhra_phys.reference.reference_record`) with one hidden effect. ``--cold`` points
both at an empty compiled-code cache (a first run on a machine: every model structure
compiles); without it the cache is warmed by a first unrecorded pair of runs.
Each command's CPU time (its own and that of every process it waited for: workers,
the C compiler) is printed beside its wall time: on a shared machine the load inflates
wall time, much less CPU time, so ``--cpu`` takes the ratio of CPU times.

    python benchmarks/bench_loop.py [--effect valve_deadzone] [--repeat 1] [--cold] [--cpu]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hhra_phys.data import save_csv
from hhra_phys.reference import reference_record

SIZES = {"valve_deadzone": {"i_dead": 0.1}, "input_delay": {"delay": 2.0},
         "gravity_load": {"g_grav_cos": 5.0, "g_grav_sin": -8.0},
         "clean": {}}  # no hidden effect (target: diagnose at most 2x the fit)


def _time(cmd: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU seconds of ``cmd`` (CPU: it and the processes it waited for)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effect", default="valve_deadzone", choices=sorted(SIZES))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--cold", action="store_true", help="empty compiled-code cache for each run")
    ap.add_argument("--extra", default="", help="extra diagnose options, e.g. '--workers 2'")
    ap.add_argument("--cpu", action="store_true",
                    help="the median ratio of CPU times instead of wall times")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp, "rec.csv")
        save_csv(reference_record(seed=args.seed, duration=20.0,
                                  effects={args.effect: SIZES[args.effect]}
                                  if SIZES[args.effect] else {}), rec)
        env = dict(os.environ)
        hhra = [sys.executable, "-m", "hhra_phys.cli"]
        fit_cmd = hhra + ["fit", str(rec), "--quiet"]
        diag_cmd = hhra + ["diagnose", str(rec)] + args.extra.split()
        if not args.cold:
            env["HHRA_PHYS_CACHE"] = str(Path(tmp, "cache"))
            _time(fit_cmd, env)
            _time(diag_cmd, env)
        rows = []
        for i in range(args.repeat):
            if args.cold:
                env["HHRA_PHYS_CACHE"] = str(Path(tmp, f"cache{i}"))
            (tf, cf), (td, cd) = _time(fit_cmd, env), _time(diag_cmd, env)
            rows.append((cf, cd) if args.cpu else (tf, td))
            print(f"run {i + 1}: fit {tf:.1f} s wall, {cf:.1f} s CPU; diagnose {td:.1f} s wall, "
                  f"{cd:.1f} s CPU; ratio {td / tf:.2f} wall, {cd / cf:.2f} CPU", flush=True)
    print(f"\n{args.effect}, 5000 samples, {'cold' if args.cold else 'warm'} cache, "
          f"load average {os.getloadavg()[0]:.1f}: median ratio "
          f"({'CPU' if args.cpu else 'wall'}) "
          f"{sorted(td / tf for tf, td in rows)[len(rows) // 2]:.2f}")


if __name__ == "__main__":
    main()
