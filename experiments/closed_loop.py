"""Closed-loop study: hidden effects in rig records, does the loop find them?

For every effect asked for, several seeds and one or two effect sizes, a record
(4-level excitation, 0.05 deg noise) is generated with the effect hidden in the
plant; :func:`hhra_phys.loop.augment` then fits the base HHRA model, diagnoses and
augments it with the three-way split (estimation 50 %, selection 25 %, test 25 %).
Clean records (no effect) measure wrong effects, and records with two hidden
effects check that both are found.

The records come by default from the independent reference implementation
(:func:`hhra_phys.reference.reference_record`, ``--source reference``; ``--sharp``
for exact switching, e.g. stick-slip friction), so the library model never matches
the plant exactly; ``--source rig`` uses the package's own :func:`simulate_rig`.

Reported per effect: detection (the hidden effect chosen), wrong effects (effects
accepted that were not hidden), selection and test RMSE before/after (median), how
often the true parameter lies in the final 95 % CI, why the loop stopped and the
time per record. Writes a JSON file and prints Markdown tables (pasted into
docs/diagnosis.md).

    python experiments/closed_loop.py [--seeds 2 | --seeds 4,5] [--duration 8] [--out FILE.json]
        [--source reference|rig] [--sharp EFFECTS] [--sizes large|small|both] [--discover]
        [--pairs A+B,C+D] [--max-effects 2] [--top K]
        [--joint-search] [--no-backward]

With ``--sharp``, a record hiding one of those effects is generated with every
switch exact (``smooth=False`` for the whole reference plant: a dead zone beside a
sharp friction is exact too).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings

import numpy as np

from hhra_phys.diagnosis.engine import augment
from hhra_phys.effects import EFFECTS, make_effect
from hhra_phys.models.hhra.rig import simulate_rig
from hhra_phys.outputs import atomic_write_text, check_output_path, jsonable
from hhra_phys.reference import reference_record

NOISE = 0.05
#: Two sizes per effect: a small one and a large one.
SIZES: dict[str, list[dict[str, float]]] = {
    "coulomb_friction": [{"g_coulomb": 8.0}, {"g_coulomb": 30.0}],
    "valve_deadzone": [{"i_dead": 0.05}, {"i_dead": 0.2}],
    "valve_saturation": [{"i_sat": 0.85}, {"i_sat": 0.6}],
    "input_delay": [{"delay": 1.5}, {"delay": 4.0}],
    "valve_dynamics": [{"tau_spool": 0.006}, {"tau_spool": 0.025}],
    "gravity_load": [{"g_grav_cos": 3.0, "g_grav_sin": -4.0}, {"g_grav_cos": 10.0,
                                                               "g_grav_sin": -15.0}],
    "backlash": [{"play": 0.3}, {"play": 1.5}],
    "sensor_offset": [{"y_offset": 0.5}, {"y_offset": 3.0}],
    "asymmetric_valve": [{"asym": 0.03}, {"asym": 0.15}],
}
#: Pairs of hidden effects (large sizes), by name for ``--pairs``.
PAIRS = [("valve_deadzone", "input_delay"), ("coulomb_friction", "gravity_load"),
         ("valve_deadzone", "coulomb_friction")]


def make_record(effects: dict[str, dict[str, float]], seed: int, duration: float,
                source: str = "reference", sharp: bool = False):
    """The record with ``effects`` hidden: reference implementation or package rig."""
    if source == "reference":
        return reference_record(seed=seed, duration=duration, noise_deg=NOISE, levels=4,
                                effects=effects, smooth=not sharp)
    return simulate_rig(seed=seed, duration=duration, noise=NOISE, levels=4,
                        effects=[make_effect(n) for n in effects],
                        effect_params={k: v for p in effects.values() for k, v in p.items()})


def run_case(effects: dict[str, dict[str, float]], seed: int, duration: float,
             loop_kw: dict, source: str = "rig", sharp: bool = False) -> dict:
    t_rec = time.perf_counter()
    ds = make_record(effects, seed, duration, source, sharp)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = augment(ds, seed=seed, **loop_kw)
    in_ci = {}
    for p in effects.values():
        for k, v in p.items():
            ci = res.final.ci95.get(k)
            in_ci[k] = bool(ci is not None and ci[0] <= v <= ci[1])
    return {
        "hidden": list(effects), "truth": effects, "seed": seed, "chosen": res.chosen,
        "base_val": res.base.metrics["val"]["rmse"], "final_val": res.final.metrics["val"]["rmse"],
        "base_test": res.test_scores.get("base", {}).get("rmse"),
        "final_test": res.test_scores.get("final", {}).get("rmse"),
        "stop": res.settings.get("stop"),
        "base_est": res.base.metrics["est"]["rmse"], "final_est": res.final.metrics["est"]["rmse"],
        "params": {k: res.final.values.get(k) for p in effects.values() for k in p},
        "in_ci": in_ci,
        "flags": [n for s in res.steps for n in s.notes if s.effect in effects],
        "first_rank": res.diagnoses[0].ranked()[0].name if res.diagnoses else None,
        "not_identifiable": [e.name for e in res.diagnoses[0].evidence
                             if not e.identifiable and not e.note.startswith("skipped")]
        if res.diagnoses else [],
        "wrong": [n for n in res.chosen if n not in effects],
        "removed": res.settings.get("removed", []),
        "backward_steps": [{"round": s.round, "effect": s.effect, "action": s.action,
                            "reason": s.reason} for s in res.steps if s.action != "add"],
        # Every step's outcome and reason, so a changed figure can be traced to the rule.
        "steps": [{"round": s.round, "effect": s.effect, "action": s.action,
                   "accepted": s.accepted, "val_rmse": s.val.get("rmse"),
                   "val_rmse_before": s.val_rmse_before, "reason": s.reason}
                  for s in res.steps],
        "skipped": res.skipped,
        "rounds": len(res.diagnoses),
        "first_chosen": res.chosen[0] if res.chosen else None,
        "noise_levels": res.settings.get("noise_levels"),
        "sharp": sharp,
        "seconds": time.perf_counter() - t0,
        "record_seconds": t0 - t_rec,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="2",
                    help="N (seeds 1..N) or a comma-separated list of seeds")
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--effects", default=",".join(EFFECTS))
    ap.add_argument("--out", default="experiments/results/diagnosis_closed_loop.json")
    ap.add_argument("--cases", default="clean,single,pairs",
                    help="which cases to run: clean, single, pairs (comma-separated)")
    ap.add_argument("--top", type=int, default=None,
                    help="candidates refitted per round (default: all)")
    ap.add_argument("--source", choices=("reference", "rig"), default="reference",
                    help="records from the independent reference implementation (default) "
                         "or the package's own rig")
    ap.add_argument("--sharp", default="",
                    help="comma-separated effects whose reference records use exact "
                         "switching (smooth=False: sign, clip, stick-slip friction); "
                         "e.g. coulomb_friction")
    ap.add_argument("--sizes", choices=("small", "large", "both"), default="both",
                    help="which effect sizes of SIZES to run")
    ap.add_argument("--clean", type=int, default=None,
                    help="number of clean records (default: 2 per seed)")
    ap.add_argument("--pairs", default=None,
                    help="pairs to run with --cases pairs, e.g. valve_deadzone+input_delay "
                         "(comma-separated; default: all of PAIRS)")
    ap.add_argument("--max-effects", type=int, default=2, help="the loop's max_effects")
    ap.add_argument("--joint-search", action=argparse.BooleanOptionalAction, default=False,
                    help="search earlier effects' parameters again in a candidate's global "
                         "search (augment's joint_search; default: held)")
    ap.add_argument("--backward", action=argparse.BooleanOptionalAction, default=True,
                    help="the loop's backward step (augment's backward; --no-backward: "
                         "effects once accepted stay)")
    ap.add_argument("--discover", action="store_true",
                    help="let the loop look for a term outside the library (off: library "
                         "effects only)")
    args = ap.parse_args()
    sharp = {n for n in args.sharp.split(",") if n}
    if sharp and args.source != "reference":
        ap.error("--sharp needs --source reference")
    if sharp - set(SIZES):
        ap.error(f"--sharp: unknown effect(s) {', '.join(sorted(sharp - set(SIZES)))}")
    try:
        seeds = ([int(x) for x in args.seeds.split(",")] if "," in args.seeds
                 else list(range(1, int(args.seeds) + 1)))
    except ValueError:
        ap.error(f"--seeds: expected N or a comma-separated list of integers, got {args.seeds!r}")
    if not seeds:
        ap.error("--seeds: no seed")
    pairs = PAIRS
    if args.pairs:
        pairs = [tuple(p.split("+")) for p in args.pairs.split(",")]
        for p in pairs:
            if len(p) != 2 or set(p) - set(SIZES):
                ap.error(f"--pairs: expected EFFECT+EFFECT of {', '.join(SIZES)}, got "
                         f"{'+'.join(p)!r}")
    if args.max_effects < 1:
        ap.error("--max-effects must be >= 1")
    out = check_output_path(args.out, overwrite=True, what="--out", suffixes=(".json",))
    loop_kw = {"max_effects": args.max_effects, "top_k": args.top, "pop_size": 20,
               "max_iter": 30, "discover": args.discover,
               "joint_search": args.joint_search, "backward": args.backward}
    load_start = os.getloadavg()
    pick = {"small": [0], "large": [1], "both": [0, 1]}[args.sizes]
    kinds = set(args.cases.split(","))
    rows = []
    n_clean = 2 * len(seeds) if args.clean is None else args.clean
    cases: list[dict[str, dict[str, float]]] = [{}] * n_clean if "clean" in kinds else []
    if "single" in kinds:
        for name in args.effects.split(","):
            if name not in SIZES:
                ap.error(f"--effects: unknown effect {name!r}; known: {', '.join(SIZES)}")
            cases += [{name: SIZES[name][i]} for i in pick]
    if "pairs" in kinds:
        cases += [{a: SIZES[a][1], b: SIZES[b][1]} for a, b in pairs]
    for i, eff in enumerate(cases):
        for seed in seeds if eff else [seeds[i % len(seeds)] + 10 * (i // len(seeds))]:
            row = run_case(eff, seed, args.duration, loop_kw, args.source,
                           bool(sharp & set(eff)))
            rows.append(row)
            print(f"{'+'.join(row['hidden']) or 'clean':35s} seed {seed}: chosen "
                  f"{row['chosen']} selection {row['base_val']:.4g} -> {row['final_val']:.4g}, "
                  f"test {row['base_test'] or float('nan'):.4g} -> "
                  f"{row['final_test'] or float('nan'):.4g} stop {row['stop']} "
                  f"[{row['seconds']:.0f} s]", flush=True)
            # Written after every record, so an interrupted study keeps its rows.
            atomic_write_text(out, json.dumps(jsonable(
                {"noise": NOISE, "duration": args.duration, "loop": loop_kw,
                 "source": args.source, "sharp": sorted(sharp),
                 "loadavg_start": load_start, "loadavg_now": os.getloadavg(),
                 "command": "python " + " ".join(sys.argv), "rows": rows}), indent=1))
    print_tables(rows)


def _stop_kind(stop: str | None) -> str:
    """Short name of the loop's stop reason."""
    if stop and stop.startswith("selection residual at the noise level"):
        return "noise"
    return {"no candidate accepted": "none accepted", "max_effects": "max"}.get(stop or "",
                                                                              stop or "?")


def print_tables(rows: list[dict]) -> None:
    print("\n| hidden effect | size | runs | detected (first) | wrong effects | "
          "selection RMSE before (median) | after (median) | test RMSE before (median) | "
          "after (median) | truth in 95 % CI | stopped | seconds (median) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        key = ("+".join(r["hidden"]) or "(clean)",
               ", ".join(f"{k}={v:g}" for p in r["truth"].values() for k, v in p.items()))
        groups.setdefault(key, []).append(r)
    for (name, size), rs in groups.items():
        hidden = set(rs[0]["hidden"])
        det = sum(hidden <= set(r["chosen"]) for r in rs) if hidden else 0
        first = sum(r["chosen"][:1] == rs[0]["hidden"][:1] for r in rs if r["chosen"])
        wrong = sorted({n for r in rs for n in set(r["chosen"]) - hidden})
        n_wrong = sum(bool(set(r["chosen"]) - hidden) for r in rs)
        ci = [all(r["in_ci"].values()) for r in rs if hidden <= set(r["chosen"]) and hidden]
        stops: dict[str, int] = {}
        for r in rs:
            stops[_stop_kind(r["stop"])] = stops.get(_stop_kind(r["stop"]), 0) + 1
        print(f"| {name}{' (sharp)' if rs[0].get('sharp') else ''} | {size or '-'} | {len(rs)} | "
              f"{f'{det} ({first})' if hidden else '-'} | "
              f"{n_wrong}{' (' + ', '.join(wrong) + ')' if wrong else ''} | "
              f"{np.median([r['base_val'] for r in rs]):.3g} | "
              f"{np.median([r['final_val'] for r in rs]):.3g} | "
              f"{np.median([r['base_test'] or np.nan for r in rs]):.3g} | "
              f"{np.median([r['final_test'] or np.nan for r in rs]):.3g} | "
              f"{f'{sum(ci)}/{len(ci)}' if ci else '-'} | "
              f"{', '.join(f'{k} {v}' for k, v in stops.items())} | "
              f"{np.median([r['seconds'] for r in rs]):.0f} |")
    n = len(rows)
    n_wrong = sum(bool(set(r["chosen"]) - set(r["hidden"])) for r in rows)
    print(f"\nWrong effects: {n_wrong} of {n} records accepted an effect that was not hidden; "
          f"time per loop median {np.median([r['seconds'] for r in rows]):.1f} s, "
          f"max {max(r['seconds'] for r in rows):.1f} s; record generation median "
          f"{np.median([r.get('record_seconds', 0) for r in rows]):.2f} s.")

if __name__ == "__main__":
    main()
