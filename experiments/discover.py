"""Discovery of outside-library terms: families x sizes x seeds x sparsity rules.

Records come from the independent reference model with one term the effect
library has no part for (:mod:`hhra_phys.reference.outside`), or read through a
resonant sensor (``resonance:<period s>``, :mod:`hhra_phys.reference.resonant`, the
truth of the discovered mode), or with a load on a compliant coupling of the shaft
(``load:<period s>``, ratio ``--load-ratio``, damping ``--damping``: the truth of the
load mode at ``rate:omega``), or with one library effect at its large size of
``experiments/closed_loop.py`` (``<effect>:large``: a mode or term accepted there is
a stand-in), and clean records (false discoveries). Every record runs the loop
with no library effects (``candidates=[]``, one addition: discovery alone is
scored) for each sparsity rule.
Reported per run: base and final validation RMSE, whether a term was accepted,
whether it uses the true term's variable, its expression against the truth, the
extrapolation flag and the wall time of the discovery step.

Usage::

    python experiments/discover.py [--seeds 3,5] [--duration 6] [--out results.json]
        [--families quadratic_drag:400,pressure_leak:100,cubic_spring:1000,none:0]
        [--methods threshold,l1] [--damping 0.1] [--load-ratio 0.5]
        [--entries mode:output,mode:input,mode:rate:omega]

``--entries`` restricts the discovery to those entry points (``mode:output``,
``mode:input`` and ``mode:rate:omega`` alone score the resonant modes by themselves).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

from closed_loop import SIZES, make_record

from hhra_phys.diagnosis.engine import augment
from hhra_phys.outputs import atomic_write_text, check_output_path, jsonable
from hhra_phys.reference.outside import OUTSIDE, outside_record
from hhra_phys.reference.resonant import loaded_record, resonant_record

#: The variable each truth term depends on.
TRUE_SIGNAL = {"quadratic_drag": "omega", "cubic_spring": "theta", "pressure_leak": "p",
               "load": "omega"}
TRUTH_TEXT = {"quadratic_drag": "d omega/dt += -{s:g}*omega*|omega|",
              "cubic_spring": "d omega/dt += -{s:g}*theta^3",
              "pressure_leak": "d p/dt += -{s:g}*p*|p|", "none": "nothing",
              "resonance": "y_s = H y, period {s:g} s, z {z:g}",
              "load": "load of ratio {k:g} on the shaft, period {s:g} s, z {z:g}"}
#: Families whose truth is a mode (period in seconds as the size).
MODE_FAMILIES = ("resonance", "load")


def record(family: str, size: float, seed: int, duration: float, noise: float,
           damping: float, ratio: float = 0.5):
    """The study's record of ``family`` (module docstring)."""
    if family == "load":
        return loaded_record(size, ratio, damping, seed=seed, duration=duration,
                             noise_deg=noise)
    if family == "resonance":
        return resonant_record(size, damping, seed=seed, duration=duration, noise_deg=noise)
    if family in SIZES:
        return make_record({family: SIZES[family][1]}, seed, duration)
    return outside_record(family, size, seed=seed, duration=duration, noise_deg=noise)


def run(family: str, size: float, seed: int, method: str, duration: float,
        noise: float, damping: float = 0.1, entries: list[str] | None = None,
        ratio: float = 0.5) -> dict:
    """One record, one sparsity rule: the row of the study."""
    ds = record(family, size, seed, duration, noise, damping, ratio)
    t0 = time.perf_counter()
    kw: dict = {"method": method}
    if entries:
        kw["entries"] = entries
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = augment(ds, candidates=[], max_effects=1, pop_size=20, max_iter=30, seed=seed,
                      discover_kw=kw)
    found = [s.to_json() for s in res.steps if s.to_json().get("discovered")]
    acc = [s for s in found if s["accepted"]]
    modes = [s for s in found if "period" in s["screening"]]
    mode = next((s for s in modes if s["accepted"]), modes[0] if modes else None)
    truth_w = ds.metadata.get("truth", {}).get("w") if family in MODE_FAMILIES else None
    w_ci = next((v for k, v in mode["ci95"].items() if k.endswith("_w")), None) if mode else None
    return {
        "family": family, "size": size, "seed": seed, "method": method,
        "truth": (f"{family} {SIZES[family][1]}" if family in SIZES
                  else TRUTH_TEXT[family].format(s=size, z=damping, k=ratio)),
        "mode_tried": mode["expression"] if mode else None,
        "mode_accepted": bool(mode and mode["accepted"]),
        "mode_val_rmse": mode["val"]["rmse"] if mode else None,
        "mode_reason": mode["reason"] if mode else None,
        "mode_params": mode["params"] if mode else None,
        "mode_ci95": mode["ci95"] if mode else None,
        "mode_period": mode["screening"]["period"] if mode else None,
        "mode_period_ci95": mode["screening"]["period_ci95"] if mode else None,
        "truth_w_in_ci": (bool(w_ci[0] <= truth_w <= w_ci[1])
                          if truth_w is not None and w_ci else None),
        "test_before": res.test_scores.get("base", {}).get("rmse"),
        "test_after": res.test_scores.get("final", {}).get("rmse"),
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
    ap.add_argument("--damping", type=float, default=0.1,
                    help="damping ratio of the resonance and load families")
    ap.add_argument("--load-ratio", type=float, default=0.5,
                    help="load inertia over the actuator's of the load family")
    ap.add_argument("--entries", default=None,
                    help="comma-separated entry points of the discovery (default: all)")
    args = ap.parse_args(argv)
    fams = []
    known = [*OUTSIDE, *MODE_FAMILIES, "none", *(f"{e}:large" for e in SIZES)]
    for item in args.families.split(","):
        name, _, size = item.partition(":")
        if name not in OUTSIDE and name not in ("none", *MODE_FAMILIES) and not (
                name in SIZES and size == "large"):
            ap.error(f"--families: unknown family {item!r} (known: {', '.join(known)})")
        try:
            fams.append((name, 0.0 if name in SIZES else float(size or 0)))
        except ValueError:
            ap.error(f"--families: size of {name!r} must be a number, got {size!r}")
        if name in MODE_FAMILIES and not fams[-1][1] > 0:
            ap.error(f"--families: {name} needs its period in seconds, e.g. {name}:0.25")
    if not args.damping > 0:
        ap.error(f"--damping must be > 0, got {args.damping}")
    if not args.load_ratio > 0:
        ap.error(f"--load-ratio must be > 0, got {args.load_ratio}")
    entries = args.entries.split(",") if args.entries else None
    methods = args.methods.split(",")
    for m in methods:
        if m not in ("threshold", "l1"):
            ap.error(f"--methods: unknown method {m!r} (threshold, l1)")
    if args.out:
        check_output_path(args.out, overwrite=args.overwrite, what="study rows")
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = []
    print("| family | size | seed | method | val RMSE before -> after | accepted term | "
          "right signal | extrapolated | mode period [95 % CI] (truth w in CI) | "
          "discovery [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for fam, size in fams:
        for seed in seeds:
            for m in methods:
                r = run(fam, size, seed, m, args.duration, args.noise, args.damping, entries,
                        args.load_ratio)
                rows.append(r)
                mode = "-"
                if r["mode_period"] is not None:
                    lo, hi = r["mode_period_ci95"]
                    inside = {None: "", True: " (yes)", False: " (no)"}[r["truth_w_in_ci"]]
                    mode = (f"{r['mode_period']:.4g} [{lo:.4g}, {hi:.4g}]"
                            f"{' accepted' if r['mode_accepted'] else ''}{inside}")
                print(f"| {fam} | {size:g} | {seed} | {m} | {r['val_before']:.3f} -> "
                      f"{r['val_after']:.3f} | `{r['accepted'] or '-'}` | "
                      f"{'yes' if r['right_signal'] else 'no'} | "
                      f"{', '.join(r['extrapolated']) or '-'} | {mode} | "
                      f"{r['discovery_seconds']:.0f} |", flush=True)
    if args.out:
        atomic_write_text(args.out, json.dumps(jsonable(rows), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
