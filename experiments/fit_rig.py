"""Physical fitting on the simulated rig: accuracy, uncertainty coverage, speed, H-GWO's lambda.

Parts (each can be run alone with ``--parts``):

``clean``     noise-free records of rigs whose truth lies away from the nominal values
              (``hhra_phys.models.hhra.rig.perturbed_physical``): relative error of every group.
``noisy``     records with the rig's default noise (0.05 deg), one perturbed truth per
              seed: validation VAF and RMSE (against the noise level), and how often the
              95 % confidence interval of each group contains the truth (coverage;
              with ``--profile`` also for profile-likelihood intervals).
``speed``     the paper's search (H-GWO, population 100, 200 iterations) on all 5000
              samples of the 20 s record, then IPOPT: wall time of each stage (with
              ``--scalar``, each run is repeated in scalar code for a side-by-side ratio).
``lam``       H-GWO with the paper's lambda = 0.25 against lambda = 1 on perturbed truths:
              cost after the global search and after IPOPT.

Run::

    python experiments/fit_rig.py --out out/fit_rig [--parts clean,noisy,speed,lam]
        [--seeds 20] [--pop 100] [--iters 200] [--repeats 2] [--scalar] [--profile]

Writes ``results.json`` and ``summary.md`` into ``--out`` (a new directory, or use
``--overwrite``) and prints the summary.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.fit import fit
from hhra_phys.models.hhra.rig import DEFAULT_NOISE_DEG, perturbed_physical, simulate_rig

GROUPS = ["g_valve", "g_compress", "g_leak", "g_torque", "g_damping"]


def _truth(data: Any) -> dict[str, float]:
    return {n: data.metadata["true_params"][n] for n in GROUPS}


def part_clean(n: int, pop: int, iters: int) -> dict[str, Any]:
    rows = []
    for k in range(n):
        data = simulate_rig(seed=100 + k, noise=0.0, physical=perturbed_physical(100 + k))
        t0 = time.perf_counter()
        res = fit(data, pop_size=pop, max_iter=iters, seed=k)
        truth = _truth(data)
        err = {g: res.values[g] / truth[g] - 1 for g in GROUPS}
        rows.append({"seed": 100 + k, "rel_err": err,
                     "max_abs_rel_err": max(map(abs, err.values())),
                     "val_rmse": res.metrics["val"]["rmse"], "seconds": time.perf_counter() - t0})
        print(f"clean {k}: max |rel err| {rows[-1]['max_abs_rel_err']:.2e}", file=sys.stderr)
    return {"rows": rows, "worst": max(r["max_abs_rel_err"] for r in rows),
            "within_0.5%": sum(r["max_abs_rel_err"] <= 0.005 for r in rows)}


def part_noisy(n: int, pop: int, iters: int, profile: bool = False) -> dict[str, Any]:
    rows = []
    for k in range(n):
        data = simulate_rig(seed=200 + k, physical=perturbed_physical(200 + k))
        res = fit(data, pop_size=pop, max_iter=iters, seed=k,
                  intervals="profile" if profile else "linear")
        truth = _truth(data)
        linear = res.intervals.get("linear", res.ci95)
        inside = {g: bool(linear[g][0] <= truth[g] <= linear[g][1]) for g in GROUPS}
        extra: dict[str, Any] = {}
        if profile:
            extra = {
                "inside_profile": {g: bool(res.ci95[g][0] <= truth[g] <= res.ci95[g][1])
                                   for g in GROUPS},
                "profile_seconds": res.intervals["seconds"],
                "open_ends": res.intervals["open_ends"],
            }
        rows.append({**extra,
            "seed": 200 + k,
            "val_vaf": res.metrics["val"]["vaf"],
            "val_rmse": res.metrics["val"]["rmse"],
            "est_rmse": res.metrics["est"]["rmse"],
            "inside": inside,
            "rel_err": {g: res.values[g] / truth[g] - 1 for g in GROUPS},
            "warnings": res.warnings,
        })
        print(f"noisy {k}: val RMSE {rows[-1]['val_rmse']:.4f}, in CI {sum(inside.values())}/5",
              file=sys.stderr)
    coverage = {g: float(np.mean([r["inside"][g] for r in rows])) for g in GROUPS}
    all_in = float(np.mean([all(r["inside"].values()) for r in rows]))
    out: dict[str, Any] = {}
    if profile:
        out["coverage_profile"] = {g: float(np.mean([r["inside_profile"][g] for r in rows]))
                                   for g in GROUPS}
        out["coverage_all_groups_profile"] = float(
            np.mean([all(r["inside_profile"].values()) for r in rows]))
        out["profile_seconds_median"] = float(np.median([r["profile_seconds"] for r in rows]))
    return {**out,
        "rows": rows,
        "noise": DEFAULT_NOISE_DEG,
        "val_vaf_min": min(r["val_vaf"] for r in rows),
        "val_rmse_mean": float(np.mean([r["val_rmse"] for r in rows])),
        "val_rmse_max": max(r["val_rmse"] for r in rows),
        "val_rmse_over_noise_max": max(r["val_rmse"] for r in rows) / DEFAULT_NOISE_DEG,
        "coverage": coverage,
        "coverage_all_groups": all_in,
    }


def _timed_fit(data: Any, pop: int, iters: int, seed: int, simd: bool) -> dict[str, Any]:
    previous = os.environ.get("HHRA_PHYS_SIMD")
    # Read when the fit builds its simulator.
    os.environ["HHRA_PHYS_SIMD"] = "auto" if simd else "off"
    try:
        t0 = time.perf_counter()
        res = fit(data, split=1.0, pop_size=pop, max_iter=iters, seed=seed)
        total = time.perf_counter() - t0
    finally:
        if previous is None:
            os.environ.pop("HHRA_PHYS_SIMD")
        else:
            os.environ["HHRA_PHYS_SIMD"] = previous
    stages = {s["name"]: s["seconds"] for s in res.stages}
    return {"total": total, **stages, "nfev": sum(s["nfev"] for s in res.stages),
            "ipopt_iterations": res.stages[-1]["info"].get("iterations"),
            "est_rmse": res.metrics["est"]["rmse"]}


def part_speed(pop: int, iters: int, repeats: int, scalar: bool) -> dict[str, Any]:
    """Timed fits; with ``scalar`` each run is followed by the same fit in scalar code."""
    data = simulate_rig(seed=0)
    runs, scalar_runs = [], []
    for r in range(repeats):
        runs.append(_timed_fit(data, pop, iters, r, simd=True))
        print(f"speed {r}: {runs[-1]}", file=sys.stderr)
        if scalar:
            scalar_runs.append(_timed_fit(data, pop, iters, r, simd=False))
            print(f"speed {r}, scalar code: {scalar_runs[-1]}", file=sys.stderr)
    out = {"samples": len(data), "pop": pop, "iters": iters, "runs": runs,
           "best_total": min(r["total"] for r in runs),
           "best_ipopt": min(r["ipopt"] for r in runs)}
    if scalar_runs:
        out["scalar_runs"] = scalar_runs
        out["best_total_scalar"] = min(r["total"] for r in scalar_runs)
    return out


def part_lam(n: int, pop: int, iters: int) -> dict[str, Any]:
    rows = []
    for k in range(n):
        data = simulate_rig(seed=300 + k, physical=perturbed_physical(300 + k))
        row: dict[str, Any] = {"seed": 300 + k}
        for lam in (0.25, 1.0):
            res = fit(data, pop_size=pop, max_iter=iters, seed=k, lam=lam)
            row[str(lam)] = {"global_cost": res.stages[0]["cost"],
                             "final_val_rmse": res.metrics["val"]["rmse"],
                             "max_abs_rel_err": max(abs(res.values[g] / _truth(data)[g] - 1)
                                                    for g in GROUPS)}
        rows.append(row)
        print(f"lam {k}: {row}", file=sys.stderr)
    summary = {}
    for lam in ("0.25", "1.0"):
        summary[lam] = {
            "median_global_cost": float(np.median([r[lam]["global_cost"] for r in rows])),
            "median_final_val_rmse": float(np.median([r[lam]["final_val_rmse"] for r in rows])),
            "worst_rel_err": max(r[lam]["max_abs_rel_err"] for r in rows),
        }
    return {"rows": rows, "summary": summary}


def summary_markdown(results: dict[str, Any]) -> str:
    lines = []
    if "clean" in results:
        c = results["clean"]
        lines += ["### Noise-free recovery", "",
                  f"{len(c['rows'])} rigs with truths away from the nominal values; worst relative "
                  f"error over all groups and rigs: **{c['worst']:.2e}**; rigs with every group "
                  f"within 0.5 %: **{c['within_0.5%']}/{len(c['rows'])}**.", ""]
    if "noisy" in results:
        m = results["noisy"]
        lines += ["### Default noise (0.05 deg)", "",
                  f"{len(m['rows'])} seeded records, each with its own perturbed truth.", "",
                  "| quantity | value | target |", "|---|---|---|",
                  f"| smallest validation VAF | {m['val_vaf_min']:.4f} % | >= 99.5 % |",
                  f"| mean validation RMSE | {m['val_rmse_mean']:.4f} deg | <= 0.055 deg |",
                  f"| largest validation RMSE / noise | {m['val_rmse_over_noise_max']:.3f} "
                  "| <= 1.10 |",
                  f"| records with every group inside its 95 % CI | "
                  f"{100 * m['coverage_all_groups']:.0f} % | - |"]
        for g, cov in m["coverage"].items():
            lines.append(f"| coverage of {g} | {100 * cov:.0f} % | >= 90 % |")
        if "coverage_profile" in m:
            lines.append(f"| records with every group inside its profile 95 % CI | "
                         f"{100 * m['coverage_all_groups_profile']:.0f} % | - |")
            for g, cov in m["coverage_profile"].items():
                lines.append(f"| coverage of {g}, profile interval | {100 * cov:.0f} % "
                             "| >= 90 % |")
            lines.append(f"| median seconds for the profile intervals | "
                         f"{m['profile_seconds_median']:.1f} | - |")
        lines.append("")
    if "speed" in results:
        s = results["speed"]
        lines += ["### Speed", "",
                  f"H-GWO (population {s['pop']}, {s['iters']} iterations) on {s['samples']} "
                  f"samples, then IPOPT; best of {len(s['runs'])} runs: total "
                  f"**{s['best_total']:.1f} s** (target 12 s), IPOPT **{s['best_ipopt']:.2f} s** "
                  "(target 1 s).", ""]
        lines += ["| run | H-GWO s | IPOPT s | total s | evaluations | IPOPT iterations |",
                  "|---|---|---|---|---|---|"]
        for i, r in enumerate(s["runs"]):
            lines.append(f"| {i} | {r.get('hgwo', 0):.1f} | {r.get('ipopt', 0):.2f} | "
                         f"{r['total']:.1f} | {r['nfev']} | {r['ipopt_iterations']} |")
        for i, r in enumerate(s.get("scalar_runs", [])):
            lines.append(f"| {i}, scalar code | {r.get('hgwo', 0):.1f} | "
                         f"{r.get('ipopt', 0):.2f} | {r['total']:.1f} | {r['nfev']} | "
                         f"{r['ipopt_iterations']} |")
        if "best_total_scalar" in s:
            lines += ["", f"Same fits in scalar code (`HHRA_PHYS_SIMD=off`), each run right "
                      f"after its vector-code twin: best **{s['best_total_scalar']:.1f} s**, "
                      f"ratio scalar / vector **{s['best_total_scalar'] / s['best_total']:.2f}**."]
        lines.append("")
    if "lam" in results:
        lam = results["lam"]["summary"]
        lines += ["### H-GWO lambda: paper's 0.25 against 1", "",
                  "| lambda | median global ITAE | median final validation RMSE "
                  "| worst group error |",
                  "|---|---|---|---|"]
        for k, v in lam.items():
            lines.append(f"| {k} | {v['median_global_cost']:.4g} | "
                         f"{v['median_final_val_rmse']:.4f} | {v['worst_rel_err']:.3g} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--parts", default="clean,noisy,speed,lam")
    ap.add_argument("--seeds", type=int, default=20, help="records of the noisy part")
    ap.add_argument("--clean", type=int, default=5, help="records of the clean part")
    ap.add_argument("--lam-seeds", type=int, default=5)
    ap.add_argument("--pop", type=int, default=100)
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=2, help="runs of the speed part")
    ap.add_argument("--profile", action="store_true",
                    help="noisy part: also profile-likelihood intervals (coverage of both)")
    ap.add_argument("--scalar", action="store_true",
                    help="speed part: also time each fit in scalar code (HHRA_PHYS_SIMD=off)")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    if args.out.exists() and any(args.out.iterdir()) and not args.overwrite:
        sys.exit(f"{args.out} is not empty; pass --overwrite")
    args.out.mkdir(parents=True, exist_ok=True)
    parts = [p.strip() for p in args.parts.split(",") if p.strip()]
    results: dict[str, Any] = {"settings": vars(args) | {"out": str(args.out)},
                               "machine": platform.platform(), "date": time.strftime("%Y-%m-%d")}
    t0 = time.perf_counter()
    if "clean" in parts:
        results["clean"] = part_clean(args.clean, args.pop, args.iters)
    if "noisy" in parts:
        results["noisy"] = part_noisy(args.seeds, args.pop, args.iters, args.profile)
    if "speed" in parts:
        results["speed"] = part_speed(args.pop, args.iters, args.repeats, args.scalar)
    if "lam" in parts:
        results["lam"] = part_lam(args.lam_seeds, args.pop, args.iters)
    results["seconds"] = time.perf_counter() - t0
    (args.out / "results.json").write_text(json.dumps(results, indent=1, default=float))
    text = summary_markdown(results)
    (args.out / "summary.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
