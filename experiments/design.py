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
"""

from __future__ import annotations

import argparse
import json
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--pop", type=int, default=100)
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--draws", type=int, default=4)
    ap.add_argument("--out", default="experiments/out/design.json")
    ap.add_argument("--plot", default=None, help="figure of the first seed's inputs and widths")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args()
    out = check_output_path(args.out, overwrite=args.overwrite)
    rows = []
    t0 = time.perf_counter()
    for seed in range(args.seeds):
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
        "seeds": args.seeds, "pop": args.pop, "iters": args.iters, "draws": args.draws,
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
