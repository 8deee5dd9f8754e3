"""Does a Dask cluster decide as one process does? (issue 31: "both cores, and a cluster").

The five records of ``benchmarks/bench_cost.py --set diagnose`` (the reference rig, 20 s at
250 Hz: dead zones of two sizes, sharp Coulomb friction, an input delay, clean) are each
diagnosed twice with ``hhra-phys diagnose`` as a subprocess: in one process
(``--workers 0``) and on a Dask ``LocalCluster`` of two single-threaded worker processes on
the loopback address (``--dask tcp://127.0.0.1:PORT``), same seed. The two JSON files are
compared whole, less what may differ by where the jobs ran (wall times, creation stamps,
the executor's name): the chosen effects, every step, every parameter and RMSE.

    python experiments/cluster_equality.py [--out FILE.json] [--only 0,2] [--duration 20]

Prints one line per record and writes the rows (record, chosen, test RMSE of each run,
identical or the first differing key) to ``--out`` (default: none).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_cost import SETS  # noqa: E402  (the records the cost issue is measured on)

from hhra_phys.data import save_csv  # noqa: E402
from hhra_phys.outputs import atomic_write_text  # noqa: E402
from hhra_phys.reference import reference_record  # noqa: E402


def _without_runtime(obj: Any) -> Any:
    """A diagnose JSON without the fields where the jobs ran may change."""
    if isinstance(obj, dict):
        return {k: _without_runtime(v) for k, v in obj.items()
                if k not in ("executor", "created", "argv", "workers", "dask")
                and not any(w in k for w in ("seconds", "time", "elapsed"))}
    if isinstance(obj, list):
        return [_without_runtime(v) for v in obj]
    return obj


def _first_difference(a: Any, b: Any, path: str = "") -> str:
    """The first key path where ``a`` and ``b`` differ (empty: equal)."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                return f"{path}/{k} (only in one)"
            d = _first_difference(a[k], b[k], f"{path}/{k}")
            if d:
                return d
        return ""
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path} (lengths {len(a)}, {len(b)})"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            d = _first_difference(x, y, f"{path}[{i}]")
            if d:
                return d
        return ""
    return "" if a == b or (a != a and b != b) else f"{path}: {a!r} vs {b!r}"


def _diagnose(csv: Path, out: Path, where: list[str]) -> tuple[dict[str, Any], float]:
    cmd = [sys.executable, "-m", "hhra_phys.cli", "diagnose", str(csv), "--seed", "1",
           "--json", str(out), "--overwrite", *where]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return json.loads(out.read_text()), time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="write the rows here (JSON)")
    ap.add_argument("--only", default="", help="comma-separated record indices (0-based)")
    ap.add_argument("--duration", type=float, default=20.0, help="record length [s]")
    args = ap.parse_args(argv)
    from distributed import LocalCluster

    recs = SETS["diagnose"]
    if args.only:
        recs = [recs[int(i)] for i in args.only.split(",")]
    rows = []
    with (tempfile.TemporaryDirectory() as tmp,
          LocalCluster(n_workers=2, threads_per_worker=1, host="127.0.0.1",
                       dashboard_address=None, processes=True) as cluster):
        for name, seed, eff in recs:
            csv = Path(tmp) / f"{name}-{seed}.csv"
            save_csv(reference_record(seed=seed, duration=args.duration,
                                      effects=eff or None), csv)
            one, t1 = _diagnose(csv, Path(tmp) / "one.json", ["--workers", "0"])
            dask, t2 = _diagnose(csv, Path(tmp) / "dask.json",
                                 ["--dask", cluster.scheduler_address])
            diff = _first_difference(_without_runtime(one), _without_runtime(dask))
            row = {"record": f"{name}-{seed}", "chosen": [one["chosen"], dask["chosen"]],
                   "test_rmse": [one["test"]["rmse"], dask["test"]["rmse"]],
                   "wall_s": [round(t1, 1), round(t2, 1)],
                   "identical": not diff, "first_difference": diff,
                   "executor": dask["settings"].get("executor")}
            rows.append(row)
            print(f"{row['record']:18s} one process {one['chosen']} test "
                  f"{one['test']['rmse']:.5g} ({t1:.1f} s); dask {dask['chosen']} test "
                  f"{dask['test']['rmse']:.5g} ({t2:.1f} s); "
                  + ("identical" if not diff else f"differ at {diff}"), flush=True)
    if args.out:
        atomic_write_text(Path(args.out), json.dumps(rows, indent=1) + "\n")
    return 0 if all(r["identical"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
