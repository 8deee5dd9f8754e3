"""Linear-cylinder records with Coulomb friction of the seals (issue 32): does `hhra-phys
diagnose` name the friction on the cylinder model, with no stand-in, and how close does it
end to the true structure's refit?

For each seed a record of the valve-controlled cylinder comes from the independent
reference implementation (:func:`hhra_phys.models.cylinder.simulate_cylinder`: SciPy,
exact zero-order hold, physical SI variables) with a Coulomb friction force
``--force`` [N] switching over ``--width`` [m/s] (``F_c*tanh(v/v_c)``, which
:class:`~hhra_phys.models.cylinder.LinearCylinderModel` lacks), 20 s at 250 Hz, 0.05 mm
of position noise, the plant's groups drawn away from the model's nominal values
(:func:`~hhra_phys.models.cylinder.perturbed_physical`, the same seed). The CLI's
``diagnose`` runs as a user would run it on the cylinder (``--model
hhra_phys.models.cylinder:LinearCylinderModel``, estimation 50 %, selection 25 %, test
25 %); then the true structure (the cylinder model with the library's
``coulomb_friction``, bound to the piston velocity by role) is fitted on the same
estimation part (``fit``'s defaults, the loop's seed) and scored on the same test part,
started as the loop starts it. Each row: the chosen effects (and what a discovered term
is the discovered form of), the test RMSEs (loop's final, true refit, their ratio), wall
and CPU seconds of the diagnosis.

    PYTHONPATH=$PWD python experiments/cylinder_friction.py [--seeds 1-5] [--force 800]
        [--width 1e-3] [--out experiments/results/cylinder_friction.json]
        [--root OTHER_CHECKOUT] [--no-refit]
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
from hhra_phys.models.cylinder import (
    LinearCylinderModel,
    perturbed_physical,
    simulate_cylinder,
)
from hhra_phys.outputs import atomic_write_text, jsonable
from hhra_phys.problem import Problem

ROOT = Path(__file__).resolve().parent.parent
MODEL = "hhra_phys.models.cylinder:LinearCylinderModel"


def _record(seed: int, force: float, width: float):
    return simulate_cylinder(seed=seed, duration=20.0, truth=perturbed_physical(seed),
                             coulomb=force, coulomb_width=width)


def _true_refit(rec, seed: int) -> dict:
    est, _, test = split_record(rec, 0.5, 0.25)
    base = LinearCylinderModel()
    model = base.with_parts(make_effect("coulomb_friction", data=est, model=base))
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
    return {"true_test_rmse": float(np.sqrt(np.mean((test.y - y) ** 2))),
            "true_g_coulomb": float(res.values["g_coulomb"])}


def _diagnose(rec, seed: int, root: Path) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        csv, out = Path(tmp) / "rec.csv", Path(tmp) / "out.json"
        save_csv(rec, csv)
        env = dict(os.environ, PYTHONPATH=str(root))
        t0, ru0 = time.perf_counter(), os.times()
        subprocess.run([sys.executable, "-m", "hhra_phys.cli", "diagnose", str(csv),
                        "--model", MODEL, "--seed", str(seed), "--json", str(out)],
                       cwd=tmp, env=env, check=True, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)
        ru1 = os.times()
        seconds = time.perf_counter() - t0
        d = json.loads(out.read_text())
    chosen = set(d["chosen"])
    named = {s["effect"]: s.get("same_as") or [] for s in d["steps"]
             if s.get("discovered") and s["effect"] in chosen}
    expr = {s["effect"]: s.get("expression") for s in d["steps"]
            if s.get("discovered") and s["effect"] in chosen}
    fric = [s for s in d["steps"] if s["effect"] == "coulomb_friction" and s.get("accepted")]
    return {"chosen": d["chosen"], "same_as": named, "expressions": expr,
            "g_coulomb": (fric[-1].get("params") or {}).get("g_coulomb") if fric else None,
            "test_rmse": d["test_scores"]["final"]["rmse"],
            "base_test_rmse": d["test_scores"]["base"]["rmse"], "seconds": seconds,
            "cpu_seconds": (ru1.children_user + ru1.children_system
                            - ru0.children_user - ru0.children_system)}


def _seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(x) for x in text.split(",")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1-5")
    ap.add_argument("--force", type=float, default=800.0, help="Coulomb force [N]")
    ap.add_argument("--width", type=float, default=1e-3, help="switching velocity [m/s]")
    ap.add_argument("--out", default=None)
    ap.add_argument("--root", default=str(ROOT),
                    help="the package's checkout the diagnosis runs (e.g. another worktree, "
                         "for a before/after); records and the true refit run this one's")
    ap.add_argument("--no-refit", action="store_true", help="the diagnosis only")
    args = ap.parse_args()
    rows = []
    print("| seed | chosen | test RMSE loop / true refit (ratio) | s |")
    print("|---|---|---|---|")
    for s in _seeds(args.seeds):
        rec = _record(s, args.force, args.width)
        row = {"seed": s, "force_N": args.force, "width": args.width, "root": args.root,
               "accel": rec.metadata["coulomb"]["accel_m_per_s2"],
               **_diagnose(rec, s, Path(args.root))}
        row.update({"true_test_rmse": math.nan} if args.no_refit else _true_refit(rec, s))
        row["ratio"] = row["test_rmse"] / row["true_test_rmse"]
        rows.append(row)
        names = [c + (f" (= {', '.join(row['same_as'][c])})" if row["same_as"].get(c) else "")
                 for c in row["chosen"]]
        print(f"| {s} | {', '.join(names) or '-'} | {row['test_rmse']:.4f} / "
              f"{row['true_test_rmse']:.4f} ({row['ratio']:.2f}) | {row['seconds']:.0f} |",
              flush=True)
        if args.out:
            atomic_write_text(args.out, json.dumps(jsonable(rows), indent=1))


if __name__ == "__main__":
    main()
