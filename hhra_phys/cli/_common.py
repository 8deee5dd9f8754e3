"""Helpers shared by the sub-commands: loading data and parsing parameter options."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from hhra_phys.cli._guards import (
    check_hopeless_range,
    check_model_builds,
    check_output_varies,
    check_sample_rate,
    seed,
)
from hhra_phys.data import INTERSAMPLE, Dataset, load, load_public_actuator
from hhra_phys.data._text import parse_delimiter
from hhra_phys.errors import ParameterError
from hhra_phys.outputs import FIGURE_SUFFIXES, OVERWRITE_HINT, check_output_path
from hhra_phys.units import TIME_UNITS, rescale_time


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (``--top``, ``--starts`` ...)."""
    return _int_at_least(text, 1)


def fold_count(text: str) -> int:
    """argparse type: folds of a rotation, an integer from 2 to
    :data:`~hhra_phys.diagnosis.folds.MAX_FOLDS` (``--folds``)."""
    from hhra_phys.diagnosis.folds import MAX_FOLDS

    return _int_at_least(text, 2, MAX_FOLDS, "each fold refits both models; more folds "
                                              "cut the estimation part too fine")


def population(text: str) -> int:
    """argparse type: a population size, an integer >= 4 (what every optimiser needs) and
    at most :data:`~hhra_phys.options.MAX_POPULATION`."""
    from hhra_phys.options import MAX_POPULATION

    return _int_at_least(text, 4, MAX_POPULATION)


def iterations(text: str) -> int:
    """argparse type: a number of iterations, an integer >= 1 and at most
    :data:`~hhra_phys.options.MAX_ITERATIONS`."""
    from hhra_phys.options import MAX_ITERATIONS

    return _int_at_least(text, 1, MAX_ITERATIONS)


def nonnegative_int(text: str) -> int:
    """argparse type: an integer >= 0 (``--max-effects``)."""
    return _int_at_least(text, 0)


_TOO_LARGE = "a larger search would not fit in memory or would run for days; see docs/data.md"


def _int_at_least(text: str, low: int, high: int | None = None, why: str = _TOO_LARGE) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {value}")
    if high is not None and value > high:
        raise argparse.ArgumentTypeError(
            f"expected an integer <= {high:,} ({why}), got {value:,}")
    return value


def fraction(text: str) -> float:
    """argparse type: a fraction in (0, 1] (``--split``)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction in (0, 1], got {text!r}") from None
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a fraction in (0, 1], got {text!r}")
    return value


def add_record_arguments(
    p: argparse.ArgumentParser,
    input_aliases: tuple[str, ...] = (),
    output_aliases: tuple[str, ...] = (),
) -> None:
    """The one data vocabulary of every command that reads a record.

    ``--time-col``, ``--input-col``, ``--output-col``, ``--fs``, ``--delimiter``,
    ``--time-unit`` and ``--intersample``; ``input_aliases``/``output_aliases`` keep a
    command's older spellings (``compare``'s ``--u``/``--y``) working.
    """
    p.add_argument("--time-col", default=None, metavar="COL",
                   help="time column / variable (CSV default 't')")
    p.add_argument("--input-col", *input_aliases, dest="input_col", default=None,
                   metavar="COL", help="input column / variable (CSV default 'u')")
    p.add_argument("--output-col", *output_aliases, dest="output_col", default=None,
                   metavar="COL", help="output column / variable (CSV default 'y')")
    p.add_argument("--fs", type=_positive_float, default=None, metavar="HZ",
                   help="sample rate in Hz if the file has no time column")
    add_delimiter_argument(p)
    p.add_argument("--time-unit", choices=tuple(TIME_UNITS), default=None,
                   help="unit of the file's time column (default s; ms divides it by 1000)")
    p.add_argument("--intersample", choices=INTERSAMPLE, default=None,
                   help="what the input did between samples: 'zoh' held (a DAC's output), "
                        "'foh' linear from one sample to the next (a continuous input that was "
                        "only sampled), 'cubic' the cubic convolution through four samples (a "
                        "smooth band-limited input); default: the record's side-car, else zoh")
    for side, example in (("input", "V"), ("output", "mV")):
        p.add_argument(f"--{side}-unit", default=None, metavar="UNIT",
                       help=f"unit of the {side} column (e.g. {example}; overrides the file's; "
                            "default: the file's, else the HHRA's for the HHRA, the --model's "
                            "declared unit, or none)")
        p.add_argument(f"--{side}-name", default=None, metavar="NAME",
                       help=f"name of the {side} channel in plots and reports")


def add_data_arguments(p: argparse.ArgumentParser, several: bool = False) -> None:
    """``DATA`` (or ``DATA ...`` with ``several``) plus the record vocabulary
    (:func:`add_record_arguments`) and ``--rig-seed``."""
    p.add_argument(
        "data", nargs="*" if several else "?", default=None, metavar="DATA",
        help="record to fit: a .csv/.mat/.npz file, 'public' for the public hydraulic-actuator "
             "record shipped with the package, or nothing (or 'rig') for the built-in simulated rig"
             + ("; several records are fitted jointly (shared parameters, an initial state "
                "per record)" if several else ""),
    )
    add_record_arguments(p)
    p.add_argument("--rig-seed", type=seed, default=None,
                   help="seed of the simulated rig (only without DATA; default 0)")


def _delimiter(text: str) -> str | None:
    try:
        return parse_delimiter(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_delimiter_argument(p: argparse.ArgumentParser) -> None:
    """``--delimiter`` of text records, for every command that reads one."""
    p.add_argument(
        "--delimiter", type=_delimiter, default=None, metavar="SEP",
        help="field separator of a .csv/.tsv record: ',', ';', 'tab', 'whitespace' or any one "
             "character (default: detected)",
    )


#: Options of :func:`add_record_arguments` that describe a file (not the rig or 'public').
FILE_OPTIONS = (("time_col", "--time-col"), ("input_col", "--input-col"),
                 ("output_col", "--output-col"), ("fs", "--fs"), ("delimiter", "--delimiter"),
                 ("time_unit", "--time-unit"))

#: The channel labels of :func:`add_record_arguments` (they describe a file too).
LABEL_FLAGS = (("input_unit", "--input-unit"), ("output_unit", "--output-unit"),
               ("input_name", "--input-name"), ("output_name", "--output-name"))
LABEL_OPTIONS = tuple(opt for opt, _ in LABEL_FLAGS)


def is_builtin(data: str | None) -> bool:
    """Whether DATA names a built-in record (nothing, 'rig' or 'public') rather than a file."""
    return data is None or data.lower() in ("rig", "public")


def read_record(args: argparse.Namespace) -> Dataset:
    """The record file ``args.data`` read with the vocabulary's options (time unit applied)."""
    if args.fs is not None and args.time_unit not in (None, "s"):
        raise ParameterError("--fs and --time-unit exclude each other: --fs builds the time "
                             "axis, --time-unit rescales the file's time column")
    kw: dict[str, object] = {}
    suffix = Path(args.data).suffix.lower()
    for opt, key in (("time_col", "t"), ("input_col", "u"), ("output_col", "y")):
        value = getattr(args, opt)
        if value is not None:
            kw[key] = value
    if args.fs is not None:
        kw["fs"] = args.fs
    for opt in LABEL_OPTIONS:  # the command line's labels win over the file's
        if getattr(args, opt, None) is not None:
            kw[opt] = getattr(args, opt)
    kw["delimiter"] = getattr(args, "delimiter", None)
    if suffix == ".mat" and "t" not in kw:
        kw["t"] = None
    data = load(args.data, **kw)
    if data.time_unit == "samples" and suffix == ".mat":
        print(f"note: {args.data} has no time variable (looked for {args.time_col or 't'!r}): "
              "its samples are counted as time steps; give --time-col NAME or --fs HZ for "
              "a time axis in seconds", file=sys.stderr)
    check_output_varies(data, args)
    return with_intersample(args, rescale_time(data, args.time_unit) if args.time_unit else data)


def with_intersample(args: argparse.Namespace, data: Dataset) -> Dataset:
    """``data`` with the inter-sample behaviour ``--intersample`` gives (unchanged without)."""
    kind = getattr(args, "intersample", None)
    return data if kind is None or kind == data.intersample else data.with_intersample(kind)


def load_data(args: argparse.Namespace) -> Dataset:
    """The dataset named on the command line (or the simulated rig).

    Raises
    ------
    ParameterError
        File options (``--time-col`` ...) with a built-in record, or ``--rig-seed`` with a
        record that is not the rig: they would be silently ignored.
    """
    if is_builtin(args.data):
        given = [flag for opt, flag in FILE_OPTIONS + LABEL_FLAGS
                 if getattr(args, opt, None) is not None]
        if given:
            verb = "describes" if len(given) == 1 else "describe"
            raise ParameterError(f"{', '.join(given)} {verb} a DATA file; the "
                                 f"{'public record' if args.data == 'public' else 'simulated rig'}"
                                 " needs none")
    rig_seed = getattr(args, "rig_seed", None)
    if args.data is None or args.data.lower() == "rig":
        from hhra_phys.models.hhra.rig import simulate_rig

        return with_intersample(args, simulate_rig(seed=0 if rig_seed is None else rig_seed))
    if rig_seed is not None:
        raise ParameterError(f"--rig-seed seeds the simulated rig; it has no effect on DATA "
                             f"{args.data!r} (leave it out, or leave out DATA)")
    if args.data.lower() == "public":
        return with_intersample(args, load_public_actuator())
    return read_record(args)


def record_for_model(args: argparse.Namespace, data: Dataset) -> tuple[Dataset, list[str]]:
    """``data`` in the built-in HHRA's units, and warnings about implausible ranges.

    With ``--model`` (a user's model, whose units hhra-phys does not know) the values are
    unchanged; channels the record does not label take the model's declared names and
    units (attributes ``input_unit`` ... of the model), else generic ones, never the
    HHRA's mA and deg (:func:`~hhra_phys.units.label_record`). Conversions are printed on
    stderr; the warnings are printed and returned, so they can also go into the result.
    """
    if getattr(args, "model", None):
        from hhra_phys.extensions import model_from_spec
        from hhra_phys.units import label_record

        given = {k: getattr(args, k, None) for k in LABEL_OPTIONS}
        data, notes = label_record(data, given, model_from_spec(args.model, data))
        for line in notes:
            print(f"note: {line}", file=sys.stderr)
        return data, []
    from hhra_phys.models.hhra.defaults import prepare_record

    data, notes, warns = prepare_record(data)
    for line in notes:
        print(f"note: {line}", file=sys.stderr)
    check_hopeless_range(data)
    for line in warns:
        print(f"warning: {line}", file=sys.stderr)
    return data, warns


def exit_code(exc: BaseException) -> int:
    """The exit code of an error: 2 for usage (bad options, output paths), 1 for the rest.

    A :class:`~hhra_phys.errors.ParameterError` (which includes output-path errors) is a
    usage error; data, model, simulation and operating-system errors exit 1.
    """
    return 2 if isinstance(exc, ParameterError) else 1


def report_error(command: str, exc: BaseException) -> int:
    """Print ``hhra-phys COMMAND: error: ...`` on stderr and return :func:`exit_code`."""
    text = str(exc).replace(OVERWRITE_HINT, "pass --overwrite")  # the CLI's words
    print(f"hhra-phys {command}: error: {text}", file=sys.stderr)
    return exit_code(exc)


def load_records(args: argparse.Namespace, names: list[str] | None = None) -> list[Dataset]:
    """Every record named (``args.data`` as a list, or ``names``), with the same column options.

    No name gives the one record :func:`load_data` gives for none (the simulated rig).
    """
    items = names if names is not None else args.data
    if isinstance(items, str) or items is None:
        items = [items]
    if not items:
        items = [None]
    return [load_data(argparse.Namespace(**{**vars(args), "data": item})) for item in items]


def model_records(args: argparse.Namespace) -> tuple[list[Dataset], list[Dataset] | None,
                                                   list[str]]:
    """DATA records and ``--validate`` records in the model's units, and their warnings.

    Each record is loaded by :func:`load_records` and converted by
    :func:`record_for_model`; ``None`` for the validation records when
    ``--validate`` was not given.
    """
    warnings: list[str] = []

    def converted(names: list[str] | None) -> list[Dataset]:
        out = []
        for ds in load_records(args, names):
            ds, warns = record_for_model(args, ds)
            out.append(ds)
            warnings.extend(warns)
        return out

    records = converted(None)
    validation = converted(args.validate) if getattr(args, "validate", None) else None
    return records, validation, warnings


def parse_fixed(items: list[str] | None) -> dict[str, float]:
    """``["NAME=VALUE", ...]`` -> ``{NAME: VALUE}`` with clear errors."""
    out: dict[str, float] = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError(f"--fix expects NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        if not name.strip():
            raise ParameterError(f"--fix expects NAME=VALUE, got {item!r} (no name)")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ParameterError(f"--fix {name}: {value!r} is not a number") from None
    return out


def parse_names(text: str | None, flag: str = "a list of names") -> list[str] | None:
    """Comma-separated names, or None; ``flag`` is named when the list is empty."""
    if text is None:
        return None
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise ParameterError(f"{flag} {text!r}: an empty list of names; give comma-separated "
                             "names (or leave the flag out for the default)")
    return names


def check_outputs(
    paths: list[str | None], overwrite: bool, *, figures: list[str | None] | None = None
) -> None:
    """Check every output file before a long run starts (see ``check_output_path``).

    ``figures`` are checked as ``paths`` and must also have a suffix matplotlib writes.
    """
    for p in paths:
        if p:
            check_output_path(p, overwrite=overwrite)
    for p in figures or []:
        if p:
            check_output_path(p, overwrite=overwrite, what="figure", suffixes=FIGURE_SUFFIXES)


def add_model_arguments(p: argparse.ArgumentParser, effects: bool = False) -> None:
    """``--model FILE.py:FACTORY`` (and ``--effects-from`` for the diagnosis)."""
    p.add_argument("--model", default=None, metavar="FILE.py:FACTORY",
                   help="your own model: FILE.py:FACTORY or package.module:FACTORY, a callable "
                        "returning a hhra_phys Model (default: the HHRA)")
    if effects:
        p.add_argument("--effects-from", action="append", default=None,
                       metavar="FILE.py|MODULE",
                       help="import this file or module first, so the effects it registers "
                            "with @register_effect become candidates (repeatable)")


def model_for(args: argparse.Namespace, data: Dataset,
              valve: str | None = None) -> tuple[Any, dict[str, tuple[float, float]]]:
    """The model to fit (``--model`` or the HHRA for the record) and its automatic bounds."""
    if getattr(args, "model", None):
        from hhra_phys.extensions import model_from_spec

        if valve is not None:
            raise ParameterError("--valve is an option of the built-in HHRA; it cannot be "
                                 "combined with --model")
        model = model_from_spec(args.model, data)
        check_model_builds(model, data, f"--model {args.model}")
        check_sample_rate(args, data, model)
        return model, {}
    from hhra_phys.fit import default_model

    model, bounds = default_model(data, valve=valve or "orifice")
    check_sample_rate(args, data, model)
    return model, bounds
