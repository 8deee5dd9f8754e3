"""The diagnosis loop on two records at once against each record alone.

Two reference-rig records (written without the package's model) with the same
hidden sharp Coulomb friction (30 rad/s^2, exact stick-slip) at different
excitations: 6 s of the paper's steps at full amplitude and 5 s at 0.6 of it,
250 Hz, 0.05 deg noise. :func:`hhra_phys.loop.augment` runs on both together
(library effects only, population 20 x 30 as ``tests/integration/test_loop_rates.py``);
the chosen model is then refitted on each record's estimation part alone (IPOPT
from the joint values) for the interval one record gives. Prints one row per
seed and the counts ``tests/integration/test_multi_diagnose.py`` asserts.

    PYTHONPATH=$PWD python experiments/multi_diagnose.py --seeds 1 2 3 4
"""

from __future__ import annotations

import argparse
import json
import warnings
from concurrent.futures import Executor

from hhra_phys.diagnosis.engine import augment
from hhra_phys.diagnosis.selection import split_record
from hhra_phys.fit import fit
from hhra_phys.reference import reference_record

TRUTH = 30.0
EFFECT = {"coulomb_friction": {"g_coulomb": TRUTH}}
LOOP_KW = {"max_effects": 2, "pop_size": 20, "max_iter": 30, "discover": False}


def records(seed: int):
    """The two records of one seed (different excitations and lengths)."""
    a = reference_record(seed=seed, duration=6.0, noise_deg=0.05, levels=4, effects=EFFECT,
                         smooth=False)
    b = reference_record(seed=100 + seed, duration=5.0, noise_deg=0.05, levels=4,
                         amplitude=0.6, effects=EFFECT, smooth=False)
    return a, b


def alone_width(res, ds) -> float:
    """Width of g_coulomb's 95 % CI: the chosen model refitted on one record's estimation part."""
    est = split_record(ds, 0.5, 0.25)[0]
    free = [n for n in res.final.free if not n.startswith("x0_")]
    one = fit(est, res.final.model, optimizer="none", free=free, start=res.final.values,
              widen_bounds=False)
    lo, hi = one.ci95["g_coulomb"]
    return hi - lo


def run(seed: int, executor: Executor | None = None) -> dict:
    """One seed: the joint loop's choice, estimate, interval and the records' own widths.

    ``executor`` runs the loop's candidate refits (same results as serial).
    """
    a, b = records(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = augment([a, b], seed=seed, executor=executor, **LOOP_KW)
        row = {"seed": seed, "chosen": res.chosen, "test_rmse": res.test["rmse"]}
        if "coulomb_friction" in res.chosen:
            lo, hi = res.final.ci95["g_coulomb"]
            row.update(value=res.final.values["g_coulomb"], ci=[lo, hi], width=hi - lo,
                       alone=[alone_width(res, ds) for ds in (a, b)])
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    args = ap.parse_args()
    rows = []
    for seed in args.seeds:
        row = run(seed)
        rows.append(row)
        print(json.dumps(row), flush=True)
    found = [r for r in rows if r["chosen"][:1] == ["coulomb_friction"]]
    covered = sum(r["ci"][0] <= TRUTH <= r["ci"][1] for r in found)
    narrower = sum(r["width"] < min(r["alone"]) for r in found)
    print(f"found first {len(found)}/{len(rows)}, truth in CI {covered}, narrower than "
          f"either record alone {narrower}")


if __name__ == "__main__":
    main()
