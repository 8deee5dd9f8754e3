"""Helpers shared by the sub-commands: loading data and parsing parameter options."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from hhra_phys.data import Dataset, load, load_public_actuator
from hhra_phys.data._text import parse_delimiter
from hhra_phys.errors import ParameterError
from hhra_phys.outputs import FIGURE_SUFFIXES, check_output_path


def add_data_arguments(p: argparse.ArgumentParser, several: bool = False) -> None:
    """``DATA`` (or ``DATA ...`` with ``several``) plus the column options of the loaders."""
    p.add_argument(
        "data", nargs="*" if several else "?", default=None, metavar="DATA",
        help="record to fit: a .csv/.mat/.npz file, 'public' for the public hydraulic-actuator "
             "record in ../shared/data, or nothing for the built-in simulated rig"
             + ("; several records are fitted jointly (shared parameters, an initial state "
                "per record)" if several else ""),
    )
    p.add_argument("--time-col", default=None, help="time column / variable (CSV default 't')")
    p.add_argument("--input-col", default=None, help="input column / variable (CSV default 'u')")
    p.add_argument("--output-col", default=None, help="output column / variable (CSV default 'y')")
    p.add_argument("--fs", type=float, default=None, help="sample rate in Hz if the file has none")
    add_delimiter_argument(p)
    p.add_argument("--rig-seed", type=int, default=0, help="seed of the simulated rig (no DATA)")


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


def load_data(args: argparse.Namespace) -> Dataset:
    """The dataset named on the command line (or the simulated rig)."""
    if args.data is None or args.data == "rig":
        from hhra_phys.models.hhra.rig import simulate_rig

        return simulate_rig(seed=args.rig_seed)
    if args.data == "public":
        return load_public_actuator()
    kw: dict[str, object] = {}
    suffix = Path(args.data).suffix.lower()
    for opt, key in (("time_col", "t"), ("input_col", "u"), ("output_col", "y")):
        value = getattr(args, opt)
        if value is not None:
            kw[key] = value
    if args.fs is not None:
        kw["fs"] = args.fs
    kw["delimiter"] = getattr(args, "delimiter", None)
    if suffix == ".mat" and "t" not in kw:
        kw["t"] = None
    return load(args.data, **kw)


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


def parse_fixed(items: list[str] | None) -> dict[str, float]:
    """``["NAME=VALUE", ...]`` -> ``{NAME: VALUE}`` with clear errors."""
    out: dict[str, float] = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError(f"--fix expects NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ParameterError(f"--fix {name}: {value!r} is not a number") from None
    return out


def parse_names(text: str | None) -> list[str] | None:
    """Comma-separated names, or None."""
    if text is None:
        return None
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise ParameterError("an empty list of names was given")
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
        return model_from_spec(args.model, data), {}
    from hhra_phys.fit import default_model

    return default_model(data, valve=valve or "orifice")
