"""Rig records with an integer input delay (issue 33): what `hhra-phys diagnose` chooses,
and its test RMSE against the true structure's refit.

For each record (:func:`hhra_phys.reference.reference_record`, 20 s at 250 Hz, 0.05 deg
noise, an input delay of ``--delays`` samples, seeds ``--seeds``) the CLI's
``diagnose`` runs with its defaults (estimation 50 %, selection 25 %, test 25 %) on the
record written as CSV; then the true structure (the HHRA with ``input_delay``,
``max_delay`` 12) is fitted on the same estimation part (``fit``'s defaults, the loop's
seed) and scored on the same test part, started as the loop starts it. Each row: the
chosen effects, the fitted delay of the ``input_delay`` step, the test RMSEs (loop's
final, true refit, their ratio) and the wall seconds of the diagnosis.

    PYTHONPATH=$PWD python experiments/delay_records.py [--delays 2,5,10] [--seeds 1,2]
        [--out experiments/results/delay_records.json] [--root OTHER_CHECKOUT --no-refit]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hhra_phys.data.formats import save_csv
from hhra_phys.diagnosis.selection import split_record
from hhra_phys.effects import make_effect
from hhra_phys.fit import FitOptions, fit
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.outputs import atomic_write_text, jsonable
from hhra_phys.problem import Problem
from hhra_phys.reference import reference_record

NOISE = 0.05
ROOT = Path(__file__).resolve().parent.parent


def _true_refit(rec, seed: int) -> dict:
    est, _, test = split_record(rec, 0.5, 0.25)
    model = HHRAModel(output="angle").with_parts(
        make_effect("input_delay", data=est, max_delay=12))
    res = fit(est, model, options=FitOptions(seed=seed))
    free = list(res.free)
    pr = Problem(model, [est], free=[n for n in free if not n.startswith("x0_")],
                 fixed={k: v for k, v in res.values.items() if k not in free},
                 initial_state="fit",
                 start={**res.values,
                        **{n: res.x0_param(n) for n in free if n.startswith("x0_")}},
                 allow_outside_box=True)
    v = np.array([res.values[n] if n in res.values else res.x0_param(n) for n in pr.free_names])
    y = pr.simulate_values(v, data=test)
    return {"true_delay_fit": float(res.values["delay"]),
            "true_test_rmse": float(np.sqrt(np.mean((test.y - y) ** 2)))}


def _diagnose(rec, seed: int, root: Path) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        csv, out = Path(tmp) / "rec.csv", Path(tmp) / "out.json"
        save_csv(rec, csv)
        env = dict(os.environ, PYTHONPATH=str(root))
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "hhra_phys.cli", "diagnose", str(csv),
                        "--seed", str(seed), "--json", str(out)],
                       cwd=tmp, env=env, check=True, stdout=subprocess.DEVNULL)
        seconds = time.perf_counter() - t0
        d = json.loads(out.read_text())
    steps = [s for s in d["steps"] if s.get("effect") == "input_delay"]
    delay_step = None
    if steps:
        s = steps[-1]
        delay_step = {"delay": (s.get("params") or {}).get("delay"),
                      "sel_rmse": (s.get("val") or {}).get("rmse"),
                      "accepted": s.get("accepted"), "round": s.get("round"),
                      "bic": s.get("criterion")}
    return {"chosen": d["chosen"], "test_rmse": d["test_scores"]["final"]["rmse"],
            "base_test_rmse": d["test_scores"]["base"]["rmse"],
            "input_delay_step": delay_step, "seconds": seconds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--delays", default="2,5,10")
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--out", default=None)
    ap.add_argument("--root", default=str(ROOT),
                    help="the package's checkout the diagnosis runs (e.g. another worktree, "
                         "for a before/after); the true refit runs this one's")
    ap.add_argument("--no-refit", action="store_true", help="the diagnosis only")
    args = ap.parse_args()
    rows = []
    print("| delay | seed | chosen | delay fitted | test RMSE loop / true refit (ratio) | s |")
    print("|---|---|---|---|---|---|")
    for d in (int(x) for x in args.delays.split(",")):
        for s in (int(x) for x in args.seeds.split(",")):
            rec = reference_record(seed=s, duration=20.0,
                                   effects={"input_delay": {"delay": float(d)}})
            row = {"delay": d, "seed": s, "root": args.root,
                   **_diagnose(rec, s, Path(args.root))}
            row.update({"true_delay_fit": None, "true_test_rmse": math.nan} if args.no_refit
                       else _true_refit(rec, s))
            row["ratio"] = row["test_rmse"] / row["true_test_rmse"]
            rows.append(row)
            step = row["input_delay_step"] or {}
            print(f"| {d} | {s} | {', '.join(row['chosen']) or '-'} | {step.get('delay')} | "
                  f"{row['test_rmse']:.4f} / {row['true_test_rmse']:.4f} "
                  f"({row['ratio']:.2f}) | {row['seconds']:.0f} |", flush=True)
            if args.out:
                atomic_write_text(args.out, json.dumps(jsonable(rows), indent=1))


if __name__ == "__main__":
    main()
