"""``hhra-phys diagnose``: fit, find what the model lacks, add it, report before/after."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.cli._common import (
    _positive_float as positive_float,
)
from hhra_phys.cli._common import (
    add_data_arguments,
    add_model_arguments,
    check_outputs,
    fold_count,
    iterations,
    model_for,
    model_records,
    nonnegative_int,
    population,
    positive_int,
    report_error,
)
from hhra_phys.cli._guards import (
    STDOUT,
    all_or_nothing,
    check_arguments,
    check_search,
    output_path,
    seed,
    split_fraction,
    split_value,
    stdout_kept_for_json,
)
from hhra_phys.cluster import add_cluster_arguments, executor
from hhra_phys.errors import HHRAError, ParameterError
from hhra_phys.outputs import atomic_write_text

#: :data:`hhra_phys.diagnosis.options.SHAPE_MODES`, named here: the loop is imported only when
#: it runs.
_SHAPE_MODES = ("chosen", "contenders", "off")


def register(subparsers: Any) -> None:
    """Add the ``diagnose`` sub-command to the ``hhra-phys`` parser."""
    p = subparsers.add_parser(
        "diagnose",
        help="residual diagnosis and model augmentation with the effect library",
        description=(
            "Fit the physical model, analyse the residual, add effects of the library "
            "(friction, dead zone, delay, ...) one at a time, refit, and keep an effect only if "
            "the error on the selection part falls clearly, beyond what noise and structural "
            "mismatch allow, and BIC agrees; after each accepted effect, take out an earlier one "
            "the same rule would no longer accept (backward step); stop when the estimation and "
            "the selection residual are both at the noise level. The record splits into "
            "estimation (--split), selection and test (--test) "
            "parts; the test part chooses nothing and reports the error before and after. "
            "Writes a JSON summary and a Markdown report with residual plots before and after."
        ),
    )
    add_data_arguments(p, several=True)
    add_model_arguments(p, effects=True)
    p.add_argument("--validate", nargs="+", default=None, metavar="FILE",
                   help="whole records as the test part (same column options); then every "
                        "DATA record splits into estimation and selection only")
    p.add_argument("--json", type=output_path, metavar="OUT.json",
                   help="write the JSON summary here ('-': to stdout)")
    p.add_argument("--report", type=output_path, metavar="OUT.md",
                   help="write the Markdown report here (figures beside it)")
    p.add_argument("--max-effects", type=nonnegative_int, default=4,
                   help="most additions, library effects and discovered terms alike "
                        "(default 4; 0 adds nothing)")
    p.add_argument("--top", type=positive_int, default=None,
                   help="candidates refitted per round, best ranked first, at least 1 "
                        "(default: all)")
    p.add_argument("--effects", default=None,
                   help="comma-separated effects to consider (default: all registered, the "
                        "library's and those of --effects-from); 'none': no library effect, "
                        "so that discovery alone proposes")
    p.add_argument("--seed", type=seed, default=0, help="seed of the global searches")
    p.add_argument("--split", type=split_value, default=None,
                   help="estimation fraction of the record in (0, 1) (default 0.5), or the "
                        "sample index the estimation part ends before, as in fit and compare")
    p.add_argument("--test", type=float, default=0.25,
                   help="fraction held out at the end as the test part, which chooses nothing "
                        "(default 0.25; 0: the old two-way split, selection = validation)")
    p.add_argument("--pop", type=population, default=100,
                   help="base fit population (default 100, as hhra-phys fit)")
    p.add_argument("--iters", type=iterations, default=200,
                   help="base fit iterations (default 200, as hhra-phys fit)")
    p.add_argument("--margin", type=float, default=0.1,
                   help="required relative fall of the selection RMSE (default 0.1), unless "
                        "the candidate brings it to the noise level")
    p.add_argument("--noise-tol", type=float, default=None,
                   help="tolerance of the noise level (default: from the selection "
                        "part's length, hhra_phys.diagnosis.selection.noise_tolerance; see "
                        "docs/diagnosis.md)")
    p.add_argument("--no-discover", action="store_true",
                   help="do not propose terms and modes outside the library (discovery, "
                        "hhra_phys.diagnosis.discovery, proposes beside the library in every "
                        "round by default)")
    p.add_argument("--no-backward", action="store_true",
                   help="no backward step: keep every accepted effect (by default, after a round "
                        "accepts an effect, each earlier one is refitted out and removed if the "
                        "rule would no longer accept it)")
    p.add_argument("--shapes", choices=_SHAPE_MODES, default="chosen",
                   help="where to fit the switching width (and a friction's sign profile, "
                        "algebraic or tanh) of a library effect with a smooth edge (Coulomb "
                        "friction, a backlash's contact) where a sharper one fits better: "
                        "'chosen' (default) the round's accepted effect, 'contenders' every "
                        "contender before the round is decided, 'off' the library's default "
                        "widths (docs/diagnosis.md)")
    p.add_argument("--fit-shapes", action="store_true",
                   help="the same as --shapes contenders")
    p.add_argument("--no-rotate", action="store_true",
                   help="never rotate the parts: where the selection part and the criterion on "
                        "estimation disagree on a candidate whose regime one of them holds "
                        "thinly, the selection part decides alone (default: the candidate is "
                        "refitted on the selection part, scored on estimation, and the error "
                        "over both folds decides)")
    p.add_argument("--folds", type=fold_count, default=2, metavar="K",
                   help="contiguous folds where the parts rotate (default 2: the selection "
                        "part fitted and the estimation part scored); K > 2 cuts the "
                        "estimation part into K - 1 blocks, each held out in turn with the "
                        "model refitted on the rest of its record, and the error pooled over "
                        "the K folds decides (K - 1 refits of each model per rotation)")
    p.add_argument("--no-pairs", action="store_true",
                   help="never refit pairs: when a round accepts nothing, the refused effects "
                        "whose criterion was decisively lower while their selection error rose "
                        "are not refitted two at a time (default: they are, each pair one "
                        "candidate by the same rule; an effect that shows only beside another)")
    p.add_argument("--no-revisit", action="store_true",
                   help="do not revisit a round a discovered term won over an acceptable library "
                        "effect (by default, when the loop then ends above the noise level, the "
                        "path from that effect is followed too and the better final model by "
                        "the rule is kept)")
    p.add_argument("--keep-intersample", action="store_true",
                   help="never change the record's inter-sample behaviour (by default, when a "
                        "fit's residual shows the signature of a wrong one, the other "
                        "behaviours are candidates that change no physics, after the base fit "
                        "and in every round; docs/measuring.md)")
    p.add_argument("--discover-method", choices=("threshold", "l1"), default="threshold",
                   help="sparsity rule of the discovery (default threshold)")
    add_cluster_arguments(p, "the candidate refits", default="auto")
    p.add_argument("--budget", type=positive_float, default=None, metavar="SECONDS",
                   help="wall-clock seconds the loop may take: once spent it refits nothing "
                        "more and ends at the best model so far, saying so in the summary, "
                        "the report and the JSON (settings.budget, stopped_by_budget)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the loop and write the outputs; 0 on success, 2 on a usage error, 1 otherwise."""
    from hhra_phys.report import figure_paths

    figs = figure_paths(args.report, discover=not args.no_discover) if args.report else []
    try:
        check_arguments(args, {"--json": args.json, "--report": args.report,
                               **{f"--report's figure {Path(f).name}": f for f in figs}})
        check_outputs([None if args.json == STDOUT else args.json, args.report],
                      args.overwrite, figures=figs)
        if isinstance(args.split, float) and args.split >= 1:
            raise ParameterError("--split: the diagnosis needs selection data; give a "
                                 f"fraction below 1, got {args.split}")
        with stdout_kept_for_json(args.json):  # user code's prints: not in the JSON
            res = _diagnose(args)
        out = res.to_json()
        # With --json - the JSON alone goes to stdout; the summary to stderr.
        say = (lambda *a: print(*a, file=sys.stderr)) if args.json == STDOUT else print
        _print_summary(res, out, say)
        with all_or_nothing([args.json, args.report, *figs]):  # Ctrl-C: none of them stays
            if args.json == STDOUT:
                print(json.dumps(out, indent=2), flush=True)
            elif args.json:
                atomic_write_text(args.json, json.dumps(out, indent=2))
                print(f"wrote {args.json}")
            if args.report:
                say(f"wrote {res.report(args.report, overwrite=args.overwrite)}")
    except (HHRAError, OSError) as exc:
        return report_error("diagnose", exc)
    return 0


def _diagnose(args: argparse.Namespace) -> Any:
    """Read the records, build the model and run :func:`hhra_phys.diagnose`
    (:func:`hhra_phys.diagnosis.engine.diagnose`)."""
    from hhra_phys.cli._common import parse_names
    from hhra_phys.diagnosis.engine import diagnose

    candidates = [] if args.effects == "none" else parse_names(args.effects, "--effects")
    added = user_effects(args.effects_from)
    if added:
        print(f"registered effects: {', '.join(added)}", file=sys.stderr)
    records, validation, data_warnings = _records(args)
    check_search(args.pop, args.iters, sum(len(d) for d in records))
    data = records[0]
    if args.split is not None:
        args.split = split_fraction(args.split, [len(d) for d in records])
    model, bounds = model_for(args, data)
    check_effects_build(model, data, added)
    for other in records[1:] + (validation or []):  # the widest automatic box of all
        for k, (lo, hi) in model_for(args, other)[1].items():
            if k in bounds:
                bounds[k] = (min(bounds[k][0], lo), max(bounds[k][1], hi))
    split = args.split if args.split is not None else 0.5
    several = len(records) > 1 or validation is not None
    what = (f"{len(records)} records ({sum(len(d) for d in records)} samples" if several
            else f"{data.name or data.source or 'record'} ({len(data)} samples")
    print(f"diagnosing {what}, split {split})", file=sys.stderr)
    with executor(args.workers, args.dask) as ex:
        res = diagnose(
            records if several else data, model, validation=validation, split=split,
            test=args.test,
            candidates=candidates,
            max_effects=args.max_effects, top_k=args.top, pop_size=args.pop,
            max_iter=args.iters, seed=args.seed, margin=args.margin,
            noise_tol=args.noise_tol, default_bounds=bounds, executor=ex,
            progress=lambda s: print(s, file=sys.stderr, flush=True),
            discover=not args.no_discover, discover_kw={"method": args.discover_method},
            backward=not args.no_backward, revisit=not args.no_revisit,
            rotate=not args.no_rotate, pairs=not args.no_pairs, folds=args.folds,
            intersample=not args.keep_intersample, budget=args.budget, progress_bar=True,
            fit_shapes="contenders" if args.fit_shapes else args.shapes,
        )
    res.warnings.extend(data_warnings)
    for name, why in res.skipped.items():  # a candidate that broke: said, not only in JSON
        if "failed" in str(why) or "does not assemble" in str(why):
            print(f"warning: candidate {name} was dropped: {why}", file=sys.stderr)
    return res


def _print_summary(res: Any, out: dict[str, Any], say: Any) -> None:
    """Warnings (stderr), then the result's summary (:meth:`DiagnosisResult.summary
    <hhra_phys.diagnosis.result.DiagnosisResult.summary>`, from the JSON already built)."""
    from hhra_phys.diagnosis.result import summary_lines

    for w in out["warnings"]:  # the loop's and the final fit's, as in the JSON
        print(f"warning: {w}", file=sys.stderr)
    for line in summary_lines(res, out):
        say(line)


def user_effects(sources: list[str] | None) -> list[str]:
    """Import each ``--effects-from`` source; the names of the effects they registered.

    Raises
    ------
    ParameterError
        A source that registers no effect (a typo, or a file without
        ``@register_effect``), or one that registers an effect under a name already taken
        (the library's ``coulomb_friction`` would be silently replaced).
    """
    from hhra_phys.extensions import import_effects
    from hhra_phys.parts import EFFECTS

    added: list[str] = []
    for source in sources or []:
        before = dict(EFFECTS)
        new = import_effects([source])
        replaced = [n for n, cls in before.items() if EFFECTS.get(n) is not cls]
        if replaced:
            for n in replaced:  # put the library's back: the refusal changes nothing
                EFFECTS[n] = before[n]
            raise ParameterError(
                f"--effects-from {source}: registers {', '.join(map(repr, replaced))}, a name "
                "already registered (the library's effect would be replaced); give the "
                "effect a name of its own")
        if not new:
            raise ParameterError(
                f"--effects-from {source}: registered no effect (decorate Effect subclasses "
                "with @register_effect; see docs/guide.md)")
        added += new
    return added


def check_effects_build(model: Any, data: Any, names: list[str]) -> None:
    """Build the model with each user effect once, so one whose ``apply`` raises is named
    now rather than dropped from the candidates with its reason in the JSON only."""
    from hhra_phys.cli._common import check_model_builds
    from hhra_phys.effects import make_effect
    from hhra_phys.errors import ModelError

    for name in names:
        try:
            eff = make_effect(name, data=data)
        except Exception as exc:  # noqa: BLE001 - a user's effect class
            raise ModelError(f"--effects-from: effect {name!r} cannot be made: "
                             f"{type(exc).__name__}: {exc}") from None
        why = eff.applicable(model)
        if why is None:
            check_model_builds(model.with_parts(eff), data, f"--effects-from effect {name!r}")
            check_effect_finite(model, eff, data, name)
        elif "does not assemble" in why:  # Effect.applicable's words for a failing apply
            raise ModelError(f"--effects-from effect {name!r}: {why}")
        # other reasons: not a candidate for this model, and the loop says so


#: Samples of the record a user's effect is simulated on before the loop (a quick check).
EFFECT_CHECK_SAMPLES = 500


def check_effect_finite(model: Any, eff: Any, data: Any, name: str) -> None:
    """Simulate the model with a user's effect at its nominal values on the start of the
    record (CasADi's virtual machine, nothing compiled): an output that is not finite
    where the model without it is finite is the effect's, and is named now (the loop
    would reject the candidate as 'RMSE -> inf' without saying why)."""
    from hhra_phys.errors import ModelError
    from hhra_phys.simulate import Simulator

    u = np.asarray(data.u[:EFFECT_CHECK_SAMPLES], dtype=float)

    def finite(m: Any) -> bool:
        sim = Simulator(m, fs=float(data.fs), backend="casadi", intersample=data.intersample)
        with np.errstate(all="ignore"):
            return bool(np.all(np.isfinite(sim.simulate(u, m.nominal()))))

    try:
        if finite(model) and not finite(model.with_parts(eff)):
            raise ModelError(
                f"--effects-from effect {name!r}: the model with it at its nominal values "
                f"({', '.join(f'{p.name}={p.nominal:g}' for p in eff.parameters)}) "
                f"simulates to NaN or inf on the first {u.size} samples of "
                f"{data.name or data.source or 'the record'}; check its apply()")
    except ModelError:
        raise
    except Exception:  # noqa: BLE001 - a check; the loop reports other failures itself
        return


def _records(args: argparse.Namespace) -> tuple[list[Any], list[Any] | None, list[str]]:
    """DATA records and --validate records in the model's units, and their warnings.

    Records of different signals or units are refused, naming the files
    (:func:`~hhra_phys.multi.check_records`).
    """
    from hhra_phys.multi import check_records

    records, validation, warnings = model_records(args)
    check_records(records + (validation or []))
    return records, validation, warnings
