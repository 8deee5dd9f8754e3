"""Held-out parts that start right (issue 33, item 4): the true structure's selection and
test errors on rig records with an input delay, each part started two ways.

For each record (:func:`hhra_phys.reference.reference_record`, 20 s at 250 Hz, 0.05 deg
noise, an integer input delay of ``--delays`` samples) the true structure (the HHRA with
``input_delay``, ``max_delay`` 12) is fitted on the loop's estimation part (the first
50 %), then its selection part (the next 25 %) and test part (the last 25 %) are
simulated

``run-in``
    as the continuation of the estimation record's run (the rule since issue 33: the state
    the model reaches at the part's first sample, with the inputs before it);
``own start``
    as a separate record (the rule before: the first measured output and, under the
    ``"fit"`` rule, a state re-estimated on the part itself, the input before the part
    taken equal to its first sample). A copy of the part without its place in the record
    is scored this way.

``u steps`` is the largest input change within the delay's reach before the part starts
(mA): where it is large the part lacks that step for ``delay`` samples.

    python experiments/held_out_start.py [--delays 2,5,10] [--seeds 1-2,4] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.effects import make_effect
from hhra_phys.fit import FitOptions, fit
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.outputs import atomic_write_text, jsonable
from hhra_phys.problem import Problem
from hhra_phys.reference import reference_record
from hhra_phys.selection import split_record

NOISE = 0.05


def _alone(part: Dataset) -> Dataset:
    """The part as a separate record (no place in the one it was cut from)."""
    return Dataset(t=part.t, u=part.u, y=part.y, metadata=part.metadata, name=part.name)


def run(delay: int, seed: int) -> dict:
    rec = reference_record(seed=seed, duration=20.0,
                           effects={"input_delay": {"delay": float(delay)}})
    est, sel, test = split_record(rec, 0.5, 0.25)
    model = HHRAModel(output="angle").with_parts(
        make_effect("input_delay", data=est, max_delay=12))
    t0 = time.perf_counter()
    res = fit(est, model, options=FitOptions(seed=seed))
    free = list(res.free)
    pr = Problem(model, [est], free=[n for n in free if not n.startswith("x0_")],
                 fixed={k: v for k, v in res.values.items() if k not in free},
                 initial_state="fit",
                 start={**res.values,
                        **{n: res.x0_param(n) for n in free if n.startswith("x0_")}},
                 allow_outside_box=True)
    v = np.array([res.values[n] if n in res.values else res.x0_param(n) for n in pr.free_names])
    row = {"delay": delay, "seed": seed, "delay_fit": res.values["delay"],
           "est": float(np.sqrt(np.mean((est.y - pr.simulate_values(v)) ** 2))),
           "seconds": time.perf_counter() - t0}
    for name, part in (("sel", sel), ("test", test)):
        a = part.origin[1]
        row[f"{name}_u_step"] = float(np.ptp(rec.u[max(0, a - delay - 1):a + 1]))
        for how, ds in (("run_in", part), ("own_start", _alone(part))):
            y = pr.simulate_values(v, data=ds)
            row[f"{name}_{how}"] = float(np.sqrt(np.mean((part.y - y) ** 2)))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--delays", default="2,5,10")
    ap.add_argument("--seeds", default="1-2")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    seeds = []
    for item in args.seeds.split(","):
        lo, _, hi = item.partition("-")
        seeds += range(int(lo), int(hi or lo) + 1)
    rows = []
    print("| delay | seed | fitted delay | est RMSE | sel: run-in / own start (x noise) | "
          "test: run-in / own start (x noise) | u step before sel / test (mA) |")
    print("|---|---|---|---|---|---|---|")
    for d in (int(x) for x in args.delays.split(",")):
        for s in seeds:
            r = run(d, s)
            rows.append(r)
            print(f"| {d} | {s} | {r['delay_fit']:.2f} | {r['est']:.4f} | "
                  f"{r['sel_run_in']:.4f} / {r['sel_own_start']:.4f} "
                  f"({r['sel_run_in'] / NOISE:.2f} / {r['sel_own_start'] / NOISE:.2f}) | "
                  f"{r['test_run_in']:.4f} / {r['test_own_start']:.4f} "
                  f"({r['test_run_in'] / NOISE:.2f} / {r['test_own_start'] / NOISE:.2f}) | "
                  f"{r['sel_u_step']:.2f} / {r['test_u_step']:.2f} |", flush=True)
    if args.out:
        atomic_write_text(args.out, json.dumps(jsonable(rows), indent=1))


if __name__ == "__main__":
    main()
