"""``hhra-phys design``: the input that pins a fit's parameters down (:mod:`hhra_phys.design`)."""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.cli._common import report_error
from hhra_phys.cli._guards import seed
from hhra_phys.design import CRITERIA, MIN_HOLD_S, OUTPUT_LIMIT_DEG, InformationModel
from hhra_phys.errors import HHRAError, ParameterError
from hhra_phys.outputs import atomic_write_text, check_output_path, jsonable


def register(subparsers: Any) -> None:
    """Add the ``design`` sub-command."""
    p = subparsers.add_parser(
        "design",
        help="design the input that best determines a fit's free parameters",
        description=(
            "D-optimal (or A-/E-optimal) experiment design from a fit: the input that maximises "
            "the Fisher information of the free parameters, from the exact sensitivities, "
            "averaged over parameter draws from the fit's covariance, within the input, "
            "switching-time and output limits. Writes t,u at the fit's sample rate and a JSON "
            "side-car (same name, .json) with the predicted 95 % interval widths for the "
            "designed input and for the fitted record's input."
        ),
    )
    p.add_argument("fit", metavar="FIT.json", help="a fit result written by 'hhra-phys fit --json'")
    p.add_argument("--duration", type=float, required=True, metavar="S",
                   help="length of the designed record [s]")
    p.add_argument("--out", required=True, metavar="FILE.csv", help="the designed input (t,u)")
    p.add_argument("--max-input", type=float, default=None, metavar="I",
                   help="largest |u| (default: the largest |u| of the fitted record)")
    p.add_argument("--output-limit", type=float, default=OUTPUT_LIMIT_DEG, metavar="Y",
                   help=f"largest |y| simulated from rest at 0 (default {OUTPUT_LIMIT_DEG:g}: "
                        "the HHRA turns within +-90 deg, with a margin)")
    p.add_argument("--min-hold", type=float, default=MIN_HOLD_S, metavar="S",
                   help=f"shortest hold, the switching time [s] (default {MIN_HOLD_S:g})")
    p.add_argument("--criterion", choices=CRITERIA, default="d",
                   help="d: log det (default), a: trace, e: largest eigenvalue of the covariance")
    p.add_argument("--seed", type=seed, default=0, help="seed of the search and the draws")
    p.add_argument("--draws", type=int, default=4,
                   help="parameter draws from the fit's covariance averaged over (default 4)")
    p.add_argument("--data", default=None, metavar="FILE",
                   help="the fitted record (default: the fit's data source, or the simulated rig "
                        "it names)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.set_defaults(func=run)


def sidecar_path(out: str | Path) -> Path:
    """The JSON side-car of a designed input: the same name with ``.json``."""
    return Path(out).with_suffix(".json")


def fitted_record(res: Any, path: str | None) -> Any:
    """The record a fit was made on: ``path``, its data source, or the rig it names; or None."""
    from hhra_phys.data import load

    if path:
        return load(path)
    described = res.settings.get("data")
    first = described[0] if isinstance(described, list) and described else described or {}
    source, name = first.get("source"), first.get("name") or ""
    if source and Path(source).is_file():
        return load(source)
    if name.startswith("rig-seed") and name[len("rig-seed"):].isdigit():
        from hhra_phys.models.hhra.rig import simulate_rig

        return simulate_rig(seed=int(name[len("rig-seed"):]))
    return None


def _geomean(widths: dict[str, float]) -> float:
    vals = [w for w in widths.values() if w > 0 and math.isfinite(w)]
    return float(np.exp(np.mean(np.log(vals)))) if vals else float("nan")


def run(args: argparse.Namespace) -> int:
    """Design the input; returns the exit code."""
    from hhra_phys.design import design_input
    from hhra_phys.result import FitResult

    try:
        if not str(args.out).lower().endswith(".csv"):
            raise ParameterError(f"--out {args.out}: the designed input is written as .csv")
        out = check_output_path(args.out, overwrite=args.overwrite, what="designed input")
        side = check_output_path(sidecar_path(args.out), overwrite=args.overwrite,
                                 what="design side-car")
        for flag, value in (("--duration", args.duration), ("--max-input", args.max_input),
                            ("--output-limit", args.output_limit), ("--min-hold", args.min_hold)):
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ParameterError(f"{flag} must be a finite number > 0, got {value}")
        if args.draws < 0:
            raise ParameterError(f"--draws must be >= 0, got {args.draws}")
        res = FitResult.load(args.fit)
        record = fitted_record(res, args.data)
        if record is None and args.max_input is None:
            raise ParameterError("the fitted record is not available (give --data FILE) and "
                                 "--max-input is not given: no input limit to design within")
        print(f"designing a {args.duration:g} s input ({args.criterion}-optimal, "
              f"{args.draws} draws) for {', '.join(InformationModel(res).free)}", file=sys.stderr)
        design = design_input(res, args.duration, max_input=args.max_input,
                              output_limit=args.output_limit, min_hold=args.min_hold,
                              criterion=args.criterion, seed=args.seed, draws=args.draws,
                              reference_input=None if record is None else record.u)
    except (HHRAError, OSError) as exc:
        return report_error("design", exc)
    broken = design.check()
    fitted = None
    if record is not None:
        if abs(record.fs - design.fs) > 1e-9 * design.fs:
            print(f"note: the fitted record is sampled at {record.fs} Hz, the design at "
                  f"{design.fs} Hz; its widths are predicted at its own rate", file=sys.stderr)
        w = InformationModel(res, record.fs).widths(record.u)
        fitted = {"name": record.name or record.source, "duration": float(record.duration),
                  "widths": w, "geomean": _geomean(w)}
    buf = io.StringIO()
    np.savetxt(buf, np.column_stack([design.t, design.u]), delimiter=",", header="t,u",
               comments="", fmt="%.10g")
    atomic_write_text(out, buf.getvalue())
    report = {
        "format": "hhra-phys design",
        "fit": str(args.fit),
        "criterion": design.criterion,
        "value": design.value,
        "family": design.family,
        "seed": args.seed,
        "draws": args.draws,
        "fs": design.fs,
        "limits": design.limits,
        "peak_output": design.peak_output,
        "evaluations": design.evaluations,
        "limits_broken": broken,
        "designed": {"duration": design.limits["duration"], "widths": design.widths,
                     "geomean": _geomean(design.widths)},
        "fitted_record": fitted,
        "width": "relative 95 % interval width (hi - lo) / value, predicted from the Fisher "
                 "information at the fitted values",
    }
    atomic_write_text(side, json.dumps(jsonable(report), indent=1))
    print(f"{'parameter':<12} {'designed':>10} {'fitted rec.':>12}")
    for name, w in design.widths.items():
        other = f"{fitted['widths'][name]:12.4g}" if fitted else f"{'-':>12}"
        print(f"{name:<12} {w:10.4g} {other}")
    print(f"geometric mean of the relative 95 % widths: {_geomean(design.widths):.4g}"
          + (f" (fitted record's input: {fitted['geomean']:.4g})" if fitted else ""))
    print(f"wrote {out}\nwrote {side}")
    if broken:
        print(f"hhra-phys design: error: the design breaks limits: {'; '.join(broken)}",
              file=sys.stderr)
        return 1
    return 0
