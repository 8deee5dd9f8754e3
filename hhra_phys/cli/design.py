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

from hhra_phys.cli._common import add_model_arguments, fraction, nonnegative_int, report_error
from hhra_phys.cli._guards import (
    all_or_nothing,
    check_arguments,
    check_size,
    output_path,
    seed,
)
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
            "switching-time and output limits. The design is made for the part of the record "
            "the fit of it will estimate from (--split, by default the fit's own, 0.5 for "
            "'hhra-phys fit'): that part is designed and the rest is a validation input. "
            "Writes t,u at the fit's sample rate and a JSON side-car (same name, .json) with "
            "the predicted 95 % interval widths for the designed input and for the fitted "
            "record's input (each for the part its fit estimates from), and prints the "
            "command that fits the record measured with the designed input."
        ),
    )
    p.add_argument("fit", metavar="FIT.json", help="a fit result written by 'hhra-phys fit --json'")
    p.add_argument("--duration", type=float, required=True, metavar="S",
                   help="length of the designed record [s]")
    p.add_argument("--out", type=output_path, default=None, metavar="FILE.csv",
                   help="the designed input (t,u); its side-car is FILE.json (default: "
                        "design.csv beside FIT.json)")
    p.add_argument("--split", type=fraction, default=None, metavar="F",
                   help="estimation fraction of the fit that will be made of the designed "
                        "record, as 'hhra-phys fit --split' (default: the fit's own split, 0.5 "
                        "for a default fit; 1 if it validated on other records): the first F "
                        "of the record is designed, the rest is a validation input; 1 designs "
                        "the whole record (fit it with --split 1 --validate OTHER.csv)")
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
    p.add_argument("--draws", type=nonnegative_int, default=4,
                   help="parameter draws from the fit's covariance averaged over (default 4)")
    p.add_argument("--data", default=None, metavar="FILE",
                   help="the fitted record (default: the fit's data source, or the simulated rig "
                        "it names)")
    add_model_arguments(p)
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


def fit_split(res: Any) -> float:
    """The estimation fraction the fit used (:func:`hhra_phys.design.estimation_split`)."""
    from hhra_phys.design import estimation_split

    return estimation_split(res)


def fit_command(split: float, validate: str | None) -> str:
    """The ``hhra-phys fit`` command of the record measured with a designed input."""
    cmd = f"hhra-phys fit RECORD.csv --split {split:g}"
    if split >= 1:
        cmd += f" --validate {validate or 'OTHER.csv'}"
    return cmd + " --json RECORD-fit.json"


#: Memory a designed sample costs (the input, the simulated output and its sensitivities
#: for every draw), measured: peak RSS grows by about 384 bytes per sample (docs/data.md).
DESIGN_BYTES_PER_SAMPLE = 512

#: Evaluations of the information a design makes (random candidates of every family,
#: then local steps; :func:`hhra_phys.design.design_input`'s defaults).
DESIGN_EVALUATIONS = 48 * 4 + 120


def load_fit(path: str, model: str | None) -> Any:
    """The fit result at ``path``; ``model`` (FILE.py:FACTORY) registers a user's parts first.

    Raises
    ------
    DataError
        The file is not a readable hhra-phys fit result (binary, not JSON, incomplete),
        or its model has parts no module registered (then the message says to give
        ``--model`` as the fit had it).
    """
    from hhra_phys.errors import DataError, ModelError
    from hhra_phys.result import FitResult

    if model:
        from hhra_phys.extensions import load_factory

        load_factory(model)  # importing the file registers its parts
    p = Path(path)
    if p.is_file():
        head = p.read_bytes()[:65536]
        try:
            head.decode("utf-8")
        except UnicodeDecodeError as exc:
            if len(head) < 65536 or exc.start < len(head) - 4:  # not a cut multi-byte char
                raise DataError(f"FIT.json {path}: not a text file (byte {exc.start} is "
                                f"{head[exc.start:exc.start + 1]!r}); give the JSON written by "
                                "'hhra-phys fit --json'") from None
    try:
        return FitResult.load(path)
    except ModelError as exc:
        if model or "unknown part type" not in str(exc):
            raise
        raise DataError(f"FIT.json {path}: {exc}. A fit made with --model FILE.py:FACTORY "
                        "needs the same --model here") from None
    except HHRAError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise DataError(f"FIT.json {path}: not a complete hhra-phys fit result "
                        f"({type(exc).__name__}: {exc}); give the JSON written by "
                        "'hhra-phys fit --json'") from None


def say_time_estimate(res: Any, duration: float, draws: int) -> None:
    """Time one information evaluation on a short input and print the design's estimate
    when it is over a minute (the design itself prints nothing until it is done)."""
    import time

    fs = float(res.settings.get("fs") or 0)
    if not fs:
        return
    n_short = max(50, min(int(duration * fs), 500))
    u = np.sign(np.sin(np.linspace(0.0, 6 * np.pi, n_short))) * 1e-3
    info = InformationModel(res, fs)
    start = time.perf_counter()
    try:
        info.widths(u)
    except HHRAError:
        return  # the design reports its own errors
    per_sample = (time.perf_counter() - start) / n_short
    seconds = per_sample * duration * fs * DESIGN_EVALUATIONS * max(draws, 1)
    if seconds > 60:
        print(f"design: about {DESIGN_EVALUATIONS * max(draws, 1)} evaluations of "
              f"{duration * fs:.3g} samples, estimated {_duration(seconds)} on this machine "
              "now (--duration and --draws set it; Ctrl-C stops it, writing nothing)",
              file=sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    return (f"{seconds / 60:.0f} min" if seconds < 5400 else f"{seconds / 3600:.3g} h")


def _geomean(widths: dict[str, float]) -> float:
    vals = [w for w in widths.values() if w > 0 and math.isfinite(w)]
    return float(np.exp(np.mean(np.log(vals)))) if vals else float("nan")


def check_same_model(spec: str, res: Any, record: Any, path: str) -> None:
    """Refuse ``--model`` when it builds another model than the one ``path`` was fitted
    with: the design uses the fit's model, values and covariance, so another model would
    be silently ignored.

    Raises
    ------
    ParameterError
        Naming both models' parts.
    """
    from hhra_phys.extensions import model_from_spec

    given = model_from_spec(spec, record).to_json()
    fitted = res.model_spec or {}

    def short(typ: Any) -> str:  # a user's part is registered under its module's name,
        return str(typ).rpartition(".")[2]  # which depends on how the file was imported

    def parts(m: Any) -> list[Any]:
        return [(short(p.get("type")), p.get("args")) for p in m.get("parts", [])]

    if parts(given) != parts(fitted):
        names = [short(p.get("type")) for p in given.get("parts", [])]
        had = [short(p.get("type")) for p in fitted.get("parts", [])]
        raise ParameterError(
            f"--model {spec} builds a model of parts {names}, but FIT.json {path} was fitted "
            f"with {had}: the design uses the fitted model (its values and covariance), so "
            "this --model would be ignored; give the --model the fit was made with, or "
            "leave it out")


def run(args: argparse.Namespace) -> int:
    """Design the input; returns the exit code."""
    from hhra_phys.design import design_input

    try:
        out, side = _output_paths(args)
        _check_limits(args)
        res = load_fit(args.fit, args.model)
        fs = float(res.settings.get("fs") or 0) or None
        if fs:  # the sensitivities of every sample and parameter are held at once
            check_size(args.duration * fs, f"--duration {args.duration:g} s at the fit's "
                       f"{fs:g} Hz", bytes_per_sample=DESIGN_BYTES_PER_SAMPLE,
                       what="the designed input")
        split = fit_split(res) if args.split is None else float(args.split)
        record = fitted_record(res, args.data)
        if args.model:
            check_same_model(args.model, res, record, args.fit)
        if record is None and args.max_input is None:
            raise ParameterError("the fitted record is not available (give --data FILE) and "
                                 "--max-input is not given: no input limit to design within")
        print(f"designing a {args.duration:g} s input ({args.criterion}-optimal, "
              f"{args.draws} draws) for {', '.join(InformationModel(res).free)}, "
              + ("the whole record for estimation" if split >= 1 else
                 f"the first {split:g} of it for estimation (--split {split:g})"),
              file=sys.stderr)
        say_time_estimate(res, args.duration, args.draws)
        design = design_input(res, args.duration, max_input=args.max_input,
                              output_limit=args.output_limit, min_hold=args.min_hold,
                              criterion=args.criterion, seed=args.seed, draws=args.draws,
                              reference_input=None if record is None else record.u,
                              split=split)
    except (HHRAError, OSError) as exc:
        return report_error("design", exc)
    broken = design.check()
    fitted = None if record is None else _fitted_widths(res, record, design)
    validate = None if record is None else (record.source or None)
    report = _side_car(args, design, broken, fitted, validate)
    _write_design(out, side, design, report)
    _say_widths(design, fitted, out, side, validate)
    if broken:
        print(f"hhra-phys design: error: the design breaks limits: {'; '.join(broken)}",
              file=sys.stderr)
        return 1
    return 0


def _output_paths(args: argparse.Namespace) -> tuple[Path, Path]:
    """The designed input's .csv (default: design.csv beside the fit) and its side-car,
    checked before any work."""
    if args.out is None:
        args.out = str(Path(args.fit).with_name("design.csv"))
    if not str(args.out).lower().endswith(".csv"):
        raise ParameterError(f"--out {args.out}: the designed input is written as .csv")
    check_arguments(args, {"--out": args.out,
                           "--out's side-car": str(sidecar_path(args.out))})
    out = check_output_path(args.out, overwrite=args.overwrite, what="designed input")
    side = check_output_path(sidecar_path(args.out), overwrite=args.overwrite,
                             what="design side-car")
    return out, side


def _check_limits(args: argparse.Namespace) -> None:
    """Refuse a duration or limit that is not a finite number > 0."""
    for flag, value in (("--duration", args.duration), ("--max-input", args.max_input),
                        ("--output-limit", args.output_limit), ("--min-hold", args.min_hold)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ParameterError(f"{flag} must be a finite number > 0, got {value}")


def _fitted_widths(res: Any, record: Any, design: Any) -> dict[str, Any]:
    """The predicted widths of the fitted record's own input, for comparison."""
    if abs(record.fs - design.fs) > 1e-9 * design.fs:
        print(f"note: the fitted record is sampled at {record.fs} Hz, the design at "
              f"{design.fs} Hz; its widths are predicted at its own rate", file=sys.stderr)
    # The part of the fitted record its fit estimated from (its split), as for the design.
    own = fit_split(res)
    n_own = record.n if own >= 1 else int(round(own * record.n))
    w = InformationModel(res, record.fs).widths(record.u[:n_own])
    return {"name": record.name or record.source, "duration": float(record.duration),
            "split": own, "n_est": n_own, "widths": w, "geomean": _geomean(w)}


def _side_car(args: argparse.Namespace, design: Any, broken: list[str],
              fitted: dict[str, Any] | None, validate: str | None) -> dict[str, Any]:
    """The JSON side-car of the design."""
    return {
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
        "split": design.split,
        "designed": {"duration": design.limits["duration"], "split": design.split,
                     "n_est": design.n_est, "widths": design.widths,
                     "geomean": _geomean(design.widths)},
        "designed_whole": ({"widths": design.widths_whole,
                            "geomean": _geomean(design.widths_whole)}
                           if design.widths_whole else None),
        "fit_command": fit_command(design.split, validate),
        "fitted_record": fitted,
        "width": "relative 95 % interval width (hi - lo) / value, predicted from the Fisher "
                 "information at the fitted values for a fit of the estimation part (the first "
                 "n_est samples; the fitted record's with its fit's split)",
    }


def _write_design(out: Path, side: Path, design: Any, report: dict[str, Any]) -> None:
    """Write the designed input (t,u) and its side-car, both or neither."""
    buf = io.StringIO()
    np.savetxt(buf, np.column_stack([design.t, design.u]), delimiter=",", header="t,u",
               comments="", fmt="%.10g")
    with all_or_nothing([out, side]):  # Ctrl-C between the two: neither stays
        atomic_write_text(out, buf.getvalue())
        atomic_write_text(side, json.dumps(jsonable(report), indent=1))


def _say_widths(design: Any, fitted: dict[str, Any] | None, out: Path, side: Path,
                validate: str | None) -> None:
    """The table of predicted widths, the files written and the command that fits the record."""
    print(f"{'parameter':<12} {'designed':>10} {'fitted rec.':>12}")
    for name, w in design.widths.items():
        other = f"{fitted['widths'][name]:12.4g}" if fitted else f"{'-':>12}"
        print(f"{name:<12} {w:10.4g} {other}")
    print(f"geometric mean of the relative 95 % widths: {_geomean(design.widths):.4g}"
          + (f" (fitted record's input: {fitted['geomean']:.4g})" if fitted else ""))
    print(f"wrote {out}\nwrote {side}")
    est = ("the whole record" if design.split >= 1 else
           f"its first {design.n_est / design.fs:g} s (the rest validates)")
    print(f"the widths are those of a fit that estimates from {est}; run {out.name} on the rig "
          f"and fit the record (RECORD.csv) with:\n  {fit_command(design.split, validate)}")
