"""Designed inputs against the paper's inverse-M-sequence records, and two records against one.

On the reference rig (:func:`hhra_phys.reference.hhra.reference_record`, written
without the package's model) with truths away from the nominal values
(:func:`hhra_phys.models.hhra.rig.perturbed_physical`), for every seed:

1. a 20 s record with the paper's input (irregular multi-level steps built from
   the 4th-order inverse M-sequence, scaled so the angle stays within 80 deg) is
   fitted (``paper``);
2. an input of the same length and the same largest ``|u|`` is designed from that
   fit (:func:`hhra_phys.design.design_input`, D-optimal, default limits), run
   on the same truth with fresh noise and fitted (``designed``);
3. a second paper record (another input seed, fresh noise) is fitted jointly with
   the first (``joint``).

Every fit uses the whole record for estimation (``split=1``) with the default
search (H-GWO, population 100, 200 iterations, then IPOPT). Reported per seed and
as geometric means over seeds: the geometric mean over the free groups of the
relative 95 % interval width ``(hi - lo)/value``, and the largest relative error
of a group against the truth.

Run::

    PYTHONPATH=$PWD python experiments/design.py --seeds 5 --out experiments/out/design.json

Targets (issue 12): designed/paper width ratio <= 0.7 and the largest error at
least halved; joint/one width ratio <= 0.8.

``--workflow``: the default command-line workflow, as a user runs it (issue 23).
For every seed, each step a separate ``hhra-phys`` process with no extra flags:

1. ``hhra-phys simulate --generator reference --seed S --out a.csv`` (the
   reference rig, its own values, the paper's input);
2. ``hhra-phys fit a.csv --json fit.json`` (default split: estimation on the
   first half);
3. ``hhra-phys design fit.json --duration 20 --out design.csv`` (and its
   side-car ``design.json``);
4. the rig runs the designed input: the same reference truth, fresh noise
   (seed ``1000 + S``), written as ``designed.csv``;
5. ``hhra-phys fit designed.csv --json designed-fit.json``.

Reported per seed: the geometric mean over the free groups of the relative
95 % widths of both fits, their ratio (target <= 0.7), and the side-car's
predictions of both (target: within 30 % of the realised widths). Run::

    PYTHONPATH=$PWD nice -n 10 python experiments/design.py --workflow --seeds 1-5 \
        --out experiments/out/design_workflow.json
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hhra_phys.design import design_input
from hhra_phys.fit import fit
from hhra_phys.models.hhra.rig import perturbed_physical
from hhra_phys.outputs import atomic_write_text, check_output_path, jsonable
from hhra_phys.reference.hhra import reference_record

GROUPS = ("g_valve", "g_compress", "g_leak", "g_torque", "g_damping")


def summary(res: object, truth: dict[str, float]) -> dict[str, float]:
    """Geometric-mean relative 95 % width and largest relative error over the free groups."""
    widths = [(res.ci95[g][1] - res.ci95[g][0]) / res.values[g] for g in GROUPS]
    errors = {g: abs(res.values[g] / truth[g] - 1) for g in GROUPS}
    worst = max(errors, key=errors.get)
    return {"width": float(np.exp(np.mean(np.log(widths)))),
            "max_error": float(errors[worst]), "worst": worst,
            "widths": dict(zip(GROUPS, map(float, widths), strict=True)),
            "errors": errors}


def run_seed(seed: int, pop: int, iters: int, draws: int) -> dict[str, object]:
    truth = {k: v for k, v in perturbed_physical(100 + seed).groups().items() if k != "g_kp"}
    kw = {"split": 1.0, "pop_size": pop, "max_iter": iters, "seed": seed}
    paper = reference_record(seed=seed, params=truth)
    fit_paper = fit(paper, **kw)
    t0 = time.perf_counter()
    design = design_input(fit_paper, paper.duration, reference_input=paper.u, seed=seed,
                          draws=draws)
    seconds = time.perf_counter() - t0
    designed = reference_record(seed=1000 + seed, params=truth, u=design.u)
    fit_designed = fit(designed, **kw)
    second = reference_record(seed=500 + seed, params=truth)
    fit_joint = fit([paper, second], **kw)
    out = {"seed": seed, "truth": truth,
           "max_input": float(np.max(np.abs(paper.u))),
           "design": {"family": design.family, "peak_output": design.peak_output,
                      "evaluations": design.evaluations, "seconds": seconds,
                      "limits_broken": design.check(), "predicted": design.widths},
           "paper": summary(fit_paper, truth), "designed": summary(fit_designed, truth),
           "joint": summary(fit_joint, truth), "u_designed": design.u}
    return out


def _cli(*args: str, cwd: Path) -> str:
    """Run one ``hhra-phys`` command in its own process; its stdout (raises if it fails)."""
    cmd = [sys.executable, "-m", "hhra_phys.cli", *args]
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} exited {done.returncode}: {done.stderr[-2000:]}")
    return done.stdout


def _json_widths(path: Path) -> dict[str, float]:
    """Relative 95 % widths ``(hi - lo)/value`` of the free groups in a fit JSON."""
    params = json.loads(path.read_text())["params"]
    return {g: (p["ci95"][1] - p["ci95"][0]) / p["value"] for g, p in params.items()
            if p.get("free") and p.get("ci95") and g.startswith("g_")}


def _gm(widths: dict[str, float]) -> float:
    return float(np.exp(np.mean(np.log(list(widths.values())))))


def workflow_seed(seed: int, work: Path, duration: float) -> dict[str, object]:
    """The default CLI workflow on one seed (module docstring); the row of the table."""
    from hhra_phys.data import load, save

    d = work / f"seed{seed}"
    d.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    _cli("simulate", "--generator", "reference", "--seed", str(seed), "--out", "a.csv",
         "--overwrite", cwd=d)
    _cli("fit", "a.csv", "--json", "fit.json", "--quiet", "--overwrite", cwd=d)
    t1 = time.perf_counter()
    printed = _cli("design", "fit.json", "--duration", f"{duration:g}", "--out", "design.csv",
                   "--overwrite", cwd=d)
    t2 = time.perf_counter()
    plain = load(d / "a.csv")
    truth = plain.metadata["truth"]
    u = np.loadtxt(d / "design.csv", delimiter=",", skiprows=1)[:, 1]
    # The rig: the plain record's truth (the reference's own values), fresh noise.
    rec = reference_record(seed=1000 + seed, params=truth["params"], u=u,
                           valve=truth["valve"], fs=plain.fs)
    save(rec, d / "designed.csv", overwrite=True)
    _cli("fit", "designed.csv", "--json", "designed-fit.json", "--quiet", "--overwrite", cwd=d)
    side = json.loads((d / "design.json").read_text())
    plain_w, designed_w = _json_widths(d / "fit.json"), _json_widths(d / "designed-fit.json")
    row = {
        "seed": seed,
        "plain": {"widths": plain_w, "geomean": _gm(plain_w),
                  "predicted": side["fitted_record"]["geomean"]},
        "designed": {"widths": designed_w, "geomean": _gm(designed_w),
                     "predicted": side["designed"]["geomean"],
                     "predicted_widths": side["designed"]["widths"]},
        "ratio": _gm(designed_w) / _gm(plain_w),
        "ratio_predicted": side["designed"]["geomean"] / side["fitted_record"]["geomean"],
        "split": side["split"], "family": side["family"], "peak_output": side["peak_output"],
        "limits_broken": side["limits_broken"], "fit_command": side["fit_command"],
        "seconds": {"fit": t1 - t0, "design": t2 - t1, "total": time.perf_counter() - t0},
        "printed": printed,
    }
    for key in ("plain", "designed"):
        row[key]["predicted_over_realised"] = row[key]["predicted"] / row[key]["geomean"]
    return row


def parse_seeds(text: str) -> list[int]:
    """``"5"`` -> 0..4 (the paper study), ``"1-5"`` -> 1..5, ``"1,3"`` -> 1, 3."""
    if "-" in text:
        lo, hi = text.split("-")
        return list(range(int(lo), int(hi) + 1))
    if "," in text:
        return [int(x) for x in text.split(",")]
    return list(range(int(text)))


def main_workflow(args: argparse.Namespace) -> None:
    """``--workflow``: the default CLI workflow on every seed, and its table."""
    out = check_output_path(args.out, overwrite=args.overwrite)
    work = Path(tempfile.mkdtemp(prefix="hhra-design-workflow-"))
    rows = []
    t0 = time.perf_counter()
    for seed in parse_seeds(args.seeds):
        row = workflow_seed(seed, work, args.duration)
        rows.append(row)
        p, d = row["plain"], row["designed"]
        print(f"seed {seed}: plain {p['geomean']:.4g} (predicted {p['predicted']:.4g}), "
              f"designed {d['geomean']:.4g} (predicted {d['predicted']:.4g}); ratio "
              f"{row['ratio']:.3f} (predicted {row['ratio_predicted']:.3f}); "
              f"{row['family']}, peak {row['peak_output']:.1f} deg, "
              f"broken: {row['limits_broken'] or 'none'}; {row['seconds']['total']:.0f} s",
              flush=True)
        # Written after every seed: a run cut short still leaves its finished seeds.
        result = {
            "mode": "workflow", "seeds": [r["seed"] for r in rows], "duration": args.duration,
            "seconds": time.perf_counter() - t0,
            "ratio_geomean": float(np.exp(np.mean(np.log([r["ratio"] for r in rows])))),
            "ratio_worst": max(r["ratio"] for r in rows),
            "prediction_error_worst": max(abs(r[k]["predicted_over_realised"] - 1)
                                          for r in rows for k in ("plain", "designed")),
            "rows": rows,
        }
        atomic_write_text(out, json.dumps(jsonable(result), indent=1))
    print(json.dumps({k: v for k, v in result.items() if k != "rows"}, indent=1))
    if args.plot:
        first = work / f"seed{rows[0]['seed']}"
        print(f"wrote {plot_workflow(args.plot, first, rows[0], args.overwrite)}")
    print("| seed | plain: realised (predicted) | designed: realised (predicted) | ratio "
          "(predicted) | predicted/realised designed |")
    print("|---|---|---|---|---|")
    for r in rows:
        p, d = r["plain"], r["designed"]
        print(f"| {r['seed']} | {p['geomean']:.4f} ({p['predicted']:.4f}) | "
              f"{d['geomean']:.4f} ({d['predicted']:.4f}) | {r['ratio']:.3f} "
              f"({r['ratio_predicted']:.3f}) | {d['predicted_over_realised']:.3f} |")
    shutil.rmtree(work, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workflow", action="store_true",
                    help="the default CLI workflow (module docstring); --seeds as 1-5")
    ap.add_argument("--duration", type=float, default=20.0,
                    help="--workflow: the designed record's length [s] (default 20)")
    ap.add_argument("--seeds", default="5",
                    help="N (seeds 0..N-1), A-B or A,B,... (default 5)")
    ap.add_argument("--pop", type=int, default=100)
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--draws", type=int, default=4)
    ap.add_argument("--out", default="experiments/out/design.json")
    ap.add_argument("--plot", default=None, help="figure of the first seed's inputs and widths")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args()
    if args.workflow:
        main_workflow(args)
        return
    out = check_output_path(args.out, overwrite=args.overwrite)
    rows = []
    t0 = time.perf_counter()
    for seed in parse_seeds(args.seeds):
        row = run_seed(seed, args.pop, args.iters, args.draws)
        rows.append(row)
        p, d, j = row["paper"], row["designed"], row["joint"]
        print(f"seed {seed}: width paper {p['width']:.4g} designed {d['width']:.4g} "
              f"(x{d['width'] / p['width']:.3f}) joint {j['width']:.4g} "
              f"(x{j['width'] / p['width']:.3f}); largest error paper {p['max_error']:.4f} "
              f"({p['worst']}) designed {d['max_error']:.4f} ({d['worst']}) "
              f"joint {j['max_error']:.4f}; design {row['design']['seconds']:.1f} s, "
              f"limits broken: {row['design']['limits_broken'] or 'none'}", flush=True)
    gm = lambda xs: float(np.exp(np.mean(np.log(xs))))  # noqa: E731
    result = {
        "seeds": parse_seeds(args.seeds), "pop": args.pop, "iters": args.iters, "draws": args.draws,
        "seconds": time.perf_counter() - t0,
        "width_ratio_designed": gm([r["designed"]["width"] / r["paper"]["width"] for r in rows]),
        "width_ratio_joint": gm([r["joint"]["width"] / r["paper"]["width"] for r in rows]),
        "max_error_paper": max(r["paper"]["max_error"] for r in rows),
        "max_error_designed": max(r["designed"]["max_error"] for r in rows),
        "max_error_joint": max(r["joint"]["max_error"] for r in rows),
        "mean_max_error_paper": float(np.mean([r["paper"]["max_error"] for r in rows])),
        "mean_max_error_designed": float(np.mean([r["designed"]["max_error"] for r in rows])),
        "rows": [{k: v for k, v in r.items() if k != "u_designed"} for r in rows],
    }
    print(json.dumps({k: v for k, v in result.items() if k != "rows"}, indent=1))
    atomic_write_text(out, json.dumps(jsonable(result), indent=1))
    if args.plot:
        plot(args.plot, rows[0], args.overwrite)


def plot_workflow(path: str, d: Path, row: dict[str, object], overwrite: bool) -> Path:
    """The plain and the designed record of one workflow seed, and both fits' widths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hhra_phys.data import load

    p = check_output_path(path, overwrite=overwrite, what="figure")
    fig, ax = plt.subplots(3, 1, figsize=(9, 8.5))
    for a, name, label in ((ax[0], "a.csv", "plain record (the rig's own input)"),
                           (ax[1], "designed.csv", "designed record")):
        ds = load(d / name)
        a.plot(ds.t, ds.u, lw=0.7, label="valve current [mA]")
        b = a.twinx()
        b.plot(ds.t, ds.y, color="C1", lw=0.8)
        b.set_ylabel("angle [deg]", color="C1")
        a.axvline(ds.t[ds.n // 2], color="k", ls="--", lw=0.8)
        a.set_title(f"{label}, seed {row['seed']}: the fit estimates left of the dashed line")
        a.set_ylabel("current [mA]")
    ax[1].set_xlabel("time [s]")
    a = ax[2]
    groups = list(row["designed"]["widths"])
    x = np.arange(len(groups))
    bars = (("plain, realised", row["plain"]["widths"]),
            ("designed, predicted", row["designed"]["predicted_widths"]),
            ("designed, realised", row["designed"]["widths"]))
    for k, (label, w) in enumerate(bars):
        a.bar(x + (k - 1) * 0.27, [w[g] for g in groups], 0.27, label=label)
    a.set_xticks(x, groups)
    a.set_yscale("log")
    a.set_ylabel("relative 95 % width")
    a.legend()
    fig.tight_layout()
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


def plot(path: str, row: dict[str, object], overwrite: bool) -> Path:
    """Inputs of the first seed (paper, designed) and the fitted widths per group."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = check_output_path(path, overwrite=overwrite, what="figure")
    truth = row["truth"]
    paper = reference_record(seed=row["seed"], params=truth)
    designed = reference_record(seed=1000 + row["seed"], params=truth, u=row["u_designed"])
    fig, ax = plt.subplots(3, 1, figsize=(9, 8))
    for a, ds, label in ((ax[0], paper, "paper (inverse M-sequence)"),
                         (ax[1], designed, "designed (D-optimal)")):
        a.plot(ds.t, ds.u, lw=0.8, label="valve current [mA]")
        b = a.twinx()
        b.plot(ds.t, ds.y, color="C1", lw=0.8)
        b.set_ylabel("angle [deg]", color="C1")
        a.set_title(label)
        a.set_ylabel("current [mA]")
    a = ax[2]
    x = np.arange(len(GROUPS))
    for k, key in enumerate(("paper", "designed", "joint")):
        a.bar(x + (k - 1) * 0.27, [row[key]["widths"][g] for g in GROUPS], 0.27, label=key)
    a.set_xticks(x, GROUPS)
    a.set_yscale("log")
    a.set_ylabel("relative 95 % width")
    a.legend()
    ax[1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


if __name__ == "__main__":
    main()
