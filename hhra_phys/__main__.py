"""``python -m hhra_phys``: the ``hhra-phys`` command, run by this interpreter."""

from hhra_phys.cli import main

raise SystemExit(main())
