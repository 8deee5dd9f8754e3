"""Would a stop on a flat objective save the judged refits' time without changing them?

Records the objective of every IPOPT iteration of every refine of one ``hhra-phys
diagnose`` run (``--workers 0``: the refines run in this process), then replays stop rules
offline: stop a judged refit (one with the stall check, ``stall_iter > 0``) at iteration
``k`` once its best objective fell by less than ``tau`` BIC units over the last ``w``
iterations, ``N ln(f[k-w] / f[k]) < tau``. Prints, per rule, the refits it stops, the
iterations and seconds (pro rata) it saves and the BIC units it leaves against where IPOPT
ended them. Results: benchmarks/notes/performance.md ("A flat-objective stop ...").

    python benchmarks/replay_flat_stop.py --json hist.json -- RECORD.csv --model M.py:F \\
        --validate TEST.csv --seed 1 --workers 0 --overwrite
    python benchmarks/replay_flat_stop.py --json hist.json --replay-only
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

RULES = ((8, 0.5), (10, 0.5), (10, 1.0), (15, 1.0), (20, 1.0))


def record(cli_args: list[str]) -> list[dict]:
    """Run ``hhra-phys diagnose`` with IPOPT's iterations recorded; one row per refine."""
    import hhra_phys.fit as fit_mod
    import hhra_phys.refine as refine_mod
    from hhra_phys.cli import main

    rows: list[dict] = []
    current: list[float] = []
    plain_eval = refine_mod._Stall.eval

    def eval_recording(self, arg):  # the stall check sees every iteration's objective
        current.append(float(np.asarray(arg[1]).ravel()[0]))
        return plain_eval(self, arg)

    plain_refine = fit_mod.refine_ipopt

    def refine_recording(problem, z0, *a, **k):
        current.clear()
        t0 = time.perf_counter()
        stage = plain_refine(problem, z0, *a, **k)
        rows.append({"n_obs": int(sum(pr.y.size for pr in problem.records)),
                     "judged": int(k.get("stall_iter", 0)) > 0, "f": list(current),
                     "seconds": time.perf_counter() - t0})
        return stage

    refine_mod._Stall.eval = eval_recording
    fit_mod.refine_ipopt = refine_recording
    try:
        rc = main(["diagnose", *cli_args])
    finally:
        refine_mod._Stall.eval, fit_mod.refine_ipopt = plain_eval, plain_refine
    if rc:
        raise SystemExit(f"hhra-phys diagnose failed (exit {rc}): nothing recorded")
    return rows


def replay(rows: list[dict], w: int, tau: float) -> dict:
    """One rule over the recorded refines (judged ones with a history only)."""
    stopped, saved, seconds, losses = 0, 0, 0.0, []
    for row in rows:
        f = row["f"]
        if not row["judged"] or len(f) <= w:
            continue
        best = np.minimum.accumulate(np.asarray(f, dtype=float))
        n = row["n_obs"]
        for k in range(w, best.size):
            if best[k] > 0 and n * math.log(best[k - w] / best[k]) < tau:
                rest = best.size - 1 - k
                stopped, saved = stopped + 1, saved + rest
                seconds += row["seconds"] * rest / best.size
                losses.append(n * math.log(best[k] / best[-1]))
                break
    return {"w": w, "tau": tau, "stopped": stopped, "iterations_saved": saved,
            "seconds_saved": seconds, "largest_loss": max(losses, default=0.0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", required=True, help="where the recorded histories go (or are)")
    ap.add_argument("--replay-only", action="store_true", help="replay a recorded file")
    ap.add_argument("diagnose_args", nargs=argparse.REMAINDER,
                    help="after --: the arguments of hhra-phys diagnose")
    args = ap.parse_args()
    if args.replay_only:
        with open(args.json) as fh:
            rows = json.load(fh)
    else:
        rows = record([a for a in args.diagnose_args if a != "--"])
        with open(args.json, "w") as fh:
            json.dump(rows, fh)
    judged = [r for r in rows if r["judged"]]
    print(f"{len(rows)} refines, {sum(len(r['f']) for r in rows)} iterations; "
          f"{len(judged)} judged, {sum(r['seconds'] for r in judged):.1f} s")
    for w, tau in RULES:
        r = replay(rows, w, tau)
        print(f"w {w:2d} tau {tau:3.1f}: stops {r['stopped']:3d}, saves "
              f"{r['iterations_saved']:5d} iterations {r['seconds_saved']:5.1f} s, largest "
              f"loss {r['largest_loss']:.1f} BIC units")


if __name__ == "__main__":
    main()
