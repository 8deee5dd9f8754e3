"""Shared test set-up.

Layout: ``unit/`` checks one module against a reference it does not share code with
(closed forms, hand-computed steps, SciPy, python-control, CVODES); ``integration/``
runs whole paths (fit, diagnosis loop, CLI, guide, experiment scripts) and the
package's models against independent implementations (``hhra_phys.reference``).
The long studies (rates over several seeds, the experiment scripts) are marked ``slow``
and deselected by default (``addopts`` in ``pyproject.toml``); ``pytest -m slow`` runs
them (``docs/testing.md``). Each such behaviour keeps a fast version (one seed, a shorter
record) in the default run.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

#: The repository's root.
REPO = Path(__file__).resolve().parents[1]

# Figures are written to files, never shown.
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository's root directory."""
    return REPO


@pytest.fixture(scope="session")
def public_record():
    """The public hydraulic-actuator record, or a skip where ``shared/data`` is absent."""
    from hhra_phys.data import DataError, load_public_actuator

    try:
        return load_public_actuator()
    except DataError as exc:
        pytest.skip(f"public data not available: {exc}")


@pytest.fixture(scope="session")
def loop_workers():
    """Two worker processes for the candidate refits of the loop tests' rounds.

    The loop's own executor path (``augment(executor=...)``, ``hhra-phys diagnose
    --workers``), whose results equal the serial run's for the same seed
    (``tests/integration/test_loop_cluster.py``): the rate tests loop over seeds and
    candidates, and on the 2-core CI machine this halves their wall time.
    """
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=min(2, os.cpu_count() or 1)) as pool:
        yield pool
