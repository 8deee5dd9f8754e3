"""Console entry point of ``hhra-phys``.

A module outside the package on purpose: importing :mod:`hhra_phys` loads NumPy, CasADi
and the model library, which takes a second or two; a Ctrl-C in that time ends the
command quietly with exit 130, as it does once the command runs.
"""

from __future__ import annotations

import sys


def main() -> int:
    """Import the CLI (Ctrl-C: exit 130, nothing written) and run it."""
    try:
        from hhra_phys.cli import main as cli_main
    except KeyboardInterrupt:
        print("hhra-phys: interrupted while starting; nothing written", file=sys.stderr)
        return 130
    return cli_main()


if __name__ == "__main__":
    raise SystemExit(main())
