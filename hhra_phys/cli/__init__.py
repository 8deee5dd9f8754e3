"""Command-line interface ``hhra-phys``.

Each sub-command lives in its own module of this package and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to the
callable that runs it.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# Sub-command modules, in the order they are listed by ``--help``.
_COMMANDS = ("demo", "simulate", "fit", "compare", "diagnose", "design", "benchmark")


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level argument parser with every available sub-command."""
    parser = argparse.ArgumentParser(
        prog="hhra-phys",
        description="Fit physical models of hydraulic actuators to measured data.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMANDS:
        try:
            module = importlib.import_module(f"hhra_phys.cli.{name}")
        except ModuleNotFoundError as exc:  # a command not built yet
            if exc.name != f"hhra_phys.cli.{name}":
                raise
            continue
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hhra-phys`` console script.

    Exit codes, the same on every command: 0 done; 1 data or runtime error (unreadable
    record, diverged fit, simulation refused, a failed write); 2 usage error (bad option or
    value, output path that cannot be written, also argparse's own errors); 130 Ctrl-C
    and 143 SIGTERM,
    with nothing written (every writer is atomic and runs after the work). An error no
    check foresaw is one line and exit 1 as well; ``HHRA_PHYS_DEBUG=1`` shows its traceback.
    """
    try:  # the command modules import NumPy, CasADi ...: a Ctrl-C may come here
        from hhra_phys.cli._common import report_error
        from hhra_phys.errors import HHRAError
        from hhra_phys.interrupt import interruptible, last_signal

        parser = build_parser()
    except KeyboardInterrupt:
        print("hhra-phys: interrupted while starting; nothing written", file=sys.stderr)
        return 130
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        # A Ctrl-C that a solver swallowed is raised again here; SIGTERM is handled as
        # Ctrl-C, so every command's outputs are removed as a set when it is stopped.
        with interruptible(terminate=True):
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        import signal

        if last_signal() == signal.SIGTERM:
            print(f"hhra-phys {args.command}: terminated (SIGTERM); nothing written",
                  file=sys.stderr)
            return 128 + signal.SIGTERM
        print(f"hhra-phys {args.command}: interrupted; nothing written", file=sys.stderr)
        return 130
    except (HHRAError, OSError) as exc:  # a command that did not catch its own
        return report_error(args.command, exc)
    except Exception as exc:  # noqa: BLE001 - never a bare traceback for a user
        return unexpected_error(args.command, exc)


#: Set to 1 to see the traceback of an unexpected error.
DEBUG_ENV = "HHRA_PHYS_DEBUG"


def unexpected_error(command: str, exc: BaseException) -> int:
    """Report an error no check foresaw in one line (exit 1); the traceback on request."""
    import os
    import traceback

    if os.environ.get(DEBUG_ENV):
        traceback.print_exception(exc)
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    at = f" (in {where.name}, {where.filename}:{where.lineno})" if where else ""
    print(f"hhra-phys {command}: error: unexpected {type(exc).__name__}: {exc}{at}; "
          f"this is a bug (set {DEBUG_ENV}=1 for the traceback and report it)",
          file=sys.stderr)
    return 1
