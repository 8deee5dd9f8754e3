"""Discovery of outside-library terms: families x sizes x seeds x sparsity rules.

Records come from the independent reference model with one term the effect
library has no part for (:mod:`hhra_phys.reference.outside`), and clean records
(false discoveries). Every record runs the loop with ``max_effects=0`` (library
rounds off, so the discovery step alone is scored) for each sparsity rule.
Reported per run: base and final validation RMSE, whether a term was accepted,
whether it uses the true term's variable, its expression against the truth, the
extrapolation flag and the wall time of the discovery step.

Usage::

    python experiments/discover.py [--seeds 3,5] [--duration 6] [--out results.json]
        [--families quadratic_drag:400,pressure_leak:100,cubic_spring:1000,none:0]
        [--methods threshold,l1]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

from hhra_phys.loop import augment
from hhra_phys.outputs import atomic_write_text, check_output_path, jsonable
from hhra_phys.reference.outside import OUTSIDE, outside_record

#: The variable each truth term depends on.
TRUE_SIGNAL = {"quadratic_drag": "omega", "cubic_spring": "theta", "pressure_leak": "p"}
TRUTH_TEXT = {"quadratic_drag": "d omega/dt += -{s:g}*omega*|omega|",
              "cubic_spring": "d omega/dt += -{s:g}*theta^3",
              "pressure_leak": "d p/dt += -{s:g}*p*|p|", "none": "nothing"}


def run(family: str, size: float, seed: int, method: str, duration: float,
        noise: float) -> dict:
    """One record, one sparsity rule: the row of the study."""
    ds = outside_record(family, size, seed=seed, duration=duration, noise_deg=noise)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = augment(ds, max_effects=0, pop_size=20, max_iter=30, seed=seed,
                      discover_kw={"method": method})
    found = [s.to_json() for s in res.steps if s.to_json().get("discovered")]
    acc = [s for s in found if s["accepted"]]
    return {
        "family": family, "size": size, "seed": seed, "method": method,
        "truth": TRUTH_TEXT[family].format(s=size),
        "val_before": res.base.metrics["val"]["rmse"],
        "val_after": res.final.metrics["val"]["rmse"],
        "accepted": acc[0]["expression"] if acc else None,
        "uses": acc[0]["uses"] if acc else [],
        "right_signal": bool(acc) and TRUE_SIGNAL.get(family, "") in acc[0]["uses"],
        "extrapolated": acc[0]["extrapolated"] if acc else [],
        "tried": [s["expression"] for s in found],
        "discovery_seconds": sum(s["seconds"] for s in found),
        "total_seconds": time.perf_counter() - t0,
        "noise": noise,
    }


def main(argv: list[str] | None = None) -> int:
    """Run the study and print a Markdown table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default="quadratic_drag:400,pressure_leak:100,"
                                            "cubic_spring:1000,none:0")
    ap.add_argument("--seeds", default="3,5")
    ap.add_argument("--methods", default="threshold,l1")
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--noise", type=float, default=0.05)
    ap.add_argument("--out", default=None, help="write the rows as JSON here")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    fams = []
    for item in args.families.split(","):
        name, _, size = item.partition(":")
        if name != "none" and name not in OUTSIDE:
            ap.error(f"--families: unknown family {name!r} (known: {', '.join(OUTSIDE)}, none)")
        fams.append((name, float(size or 0)))
    methods = args.methods.split(",")
    for m in methods:
        if m not in ("threshold", "l1"):
            ap.error(f"--methods: unknown method {m!r} (threshold, l1)")
    if args.out:
        check_output_path(args.out, overwrite=args.overwrite, what="study rows")
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = []
    print("| family | size | seed | method | val RMSE before -> after | accepted term | "
          "right signal | extrapolated | discovery [s] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for fam, size in fams:
        for seed in seeds:
            for m in methods:
                r = run(fam, size, seed, m, args.duration, args.noise)
                rows.append(r)
                print(f"| {fam} | {size:g} | {seed} | {m} | {r['val_before']:.3f} -> "
                      f"{r['val_after']:.3f} | `{r['accepted'] or '-'}` | "
                      f"{'yes' if r['right_signal'] else 'no'} | "
                      f"{', '.join(r['extrapolated']) or '-'} | "
                      f"{r['discovery_seconds']:.0f} |", flush=True)
    if args.out:
        atomic_write_text(args.out, json.dumps(jsonable(rows), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
