"""Case study: the closed loop on the public measured hydraulic-actuator record.

Valve opening -> oil pressure, 1024 samples in sample time (fs = 1): estimation
1-512, selection 513-768 (chooses among candidates), test 769-1024 (chooses
nothing). Base model: ``HHRAModel(output="pressure")`` with the groups rescaled to
the record's resonance (:func:`hhra_phys.loop.base_model_for`). The loop then tries
every applicable library effect (backlash and sensor_offset do not apply to a
pressure output with its own offset), then the discovery (terms and resonant
modes, :mod:`hhra_phys.discover`).

    HHRA_SHARED_DATA=/work/shared/data python experiments/public_case.py
        [--pop 60] [--iters 100] [--seed 0] [--max-effects 3]

Writes docs/figures/diagnosis_public.json and the residual figures
docs/figures/diagnosis_public_before.png / _after.png (and _discovery.png: residuals
just before and after each discovered term), and prints the summary.
"""

from __future__ import annotations

import argparse
import json
import warnings

from hhra_phys.data import load_public_actuator
from hhra_phys.diagnose import plot_loop_residuals
from hhra_phys.loop import augment, base_model_for
from hhra_phys.outputs import atomic_write_text, jsonable


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pop", type=int, default=60)
    ap.add_argument("--iters", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-effects", type=int, default=3,
                    help="most library effects accepted before discovery (default 3)")
    ap.add_argument("--prefix", default="docs/figures/diagnosis_public")
    args = ap.parse_args()
    if args.max_effects < 0:
        ap.error(f"--max-effects must be >= 0, got {args.max_effects}")
    data = load_public_actuator()
    model, bounds = base_model_for(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = augment(data, model, split=512 / 1024, bounds=bounds,
                      max_effects=args.max_effects, top_k=4,
                      pop_size=args.pop, max_iter=args.iters, cand_pop=20, cand_iter=30,
                      seed=args.seed, progress=print)
    out = res.to_json()
    atomic_write_text(f"{args.prefix}.json", json.dumps(jsonable(out), indent=1))
    plot_loop_residuals(res, data, f"{args.prefix}_before.png", f"{args.prefix}_after.png",
                        overwrite=True, label="public record")
    found = [s for s in res.steps if getattr(s, "residuals", None)]
    if found:  # residuals just before and after each term of the discovery step
        from hhra_phys.discover import plot_discovery

        plot_discovery(found, f"{args.prefix}_discovery.png", overwrite=True)
    print("chosen:", res.chosen)
    for part in ("est", "val"):
        print(part, "base", out["base"][part], "final", out["final"][part])
    print("base values:", res.base.values)
    print("warnings:", res.warnings + res.final.warnings)


if __name__ == "__main__":
    main()
