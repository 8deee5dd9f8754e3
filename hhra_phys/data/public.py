"""The public hydraulic-actuator record (Sjöberg et al. 1995): where it is and how to load it.

The record ships with the package (``hhra_phys/data/hydraulic_actuator.mat``, 17 kB,
declared as package data so that ``pip install .`` installs it; its source and checksum
are in ``docs/data.md``). ``HHRA_SHARED_DATA`` or a path given by the caller still comes
first, and a folder ``shared/data`` or ``../shared/data`` is looked in when the packaged
copy is missing.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from hhra_phys.data.checks import DataChecks
from hhra_phys.data.dataset import Dataset
from hhra_phys.data.errors import DataFileNotFoundError
from hhra_phys.data.formats import PathLike, load_mat

__all__ = ["PUBLIC_ACTUATOR_FILE", "PUBLIC_ACTUATOR_SHA256", "find_public_data",
           "load_public_actuator"]

#: File name of the public hydraulic-actuator record (described in ``docs/data.md``).
PUBLIC_ACTUATOR_FILE = "hydraulic_actuator.mat"

#: SHA-256 of the shipped record (``docs/data.md`` gives its source).
PUBLIC_ACTUATOR_SHA256 = "fbd54f88e40cba7ed5049f658888c6063ffadebeb1d7567d68ea79fc1a573eb3"


def _public_candidates(path: PathLike | None) -> Iterable[Path]:
    if path is not None:
        p = Path(path).expanduser()
        yield p / PUBLIC_ACTUATOR_FILE if p.is_dir() else p
        return
    env = os.environ.get("HHRA_SHARED_DATA")
    if env:
        p = Path(env).expanduser()
        yield p if p.suffix == ".mat" else p / PUBLIC_ACTUATOR_FILE
    yield Path(__file__).resolve().parent / PUBLIC_ACTUATOR_FILE  # the packaged copy
    seen = set()
    repo_root = Path(__file__).resolve().parents[2]  # hhra_phys/data/ -> repo (or site-packages)
    # The current directory and each folder above it (an installed copy, not editable,
    # lives in site-packages and cannot find the repository's neighbour), then the source
    # checkout this module is in, if it is one.
    bases = [Path.cwd(), *Path.cwd().parents]
    if (repo_root / "pyproject.toml").is_file():
        bases += [repo_root, *repo_root.parents]
    for base in bases:
        for cand in (base / ".." / "shared" / "data", base / "shared" / "data"):
            c = (cand / PUBLIC_ACTUATOR_FILE).resolve()
            if c not in seen:
                seen.add(c)
                yield c


def find_public_data(path: PathLike | None = None) -> Path:
    """Locate ``hydraulic_actuator.mat``.

    Search order: ``path`` (a file or its directory) when given, and nothing else; else the
    directory in the environment variable ``HHRA_SHARED_DATA``; else the copy shipped in
    the package (``hhra_phys/data/hydraulic_actuator.mat``); else ``../shared/data`` and
    ``shared/data`` relative to the current directory and each folder above it, and then
    to the source checkout (an editable install) and each folder above it.

    Raises
    ------
    DataFileNotFoundError
        Listing every place tried.
    """
    tried = []
    for candidate in _public_candidates(path):
        if candidate.is_file():
            return candidate
        tried.append(str(candidate))
    shown = tried if len(tried) <= 4 else [*tried[:3], f"... ({len(tried)} places)"]
    raise DataFileNotFoundError(
        f"public data file {PUBLIC_ACTUATOR_FILE} not found; tried: {'; '.join(shown)}. Set "
        "HHRA_SHARED_DATA to the folder that holds it (export HHRA_SHARED_DATA=/path/to/data), "
        "run from a folder below the one holding shared/data, or pass its path (Python: "
        "load_public_actuator(path))"
    )


def load_public_actuator(
    path: PathLike | None = None, *, checks: DataChecks | None = None
) -> Dataset:
    """Load the public hydraulic-actuator record (Sjöberg et al. 1995), 1024 samples.

    Input ``u`` = row 0 of ``X`` (valve opening, raw units); output ``y`` = ``y`` (oil
    pressure, ``output_name="pressure"``, ``output_unit="raw"``); extra channel ``"x1"`` =
    row 1 of ``X`` (undocumented; most likely the arm or piston position, with a one-sample
    glitch near sample 985). The sample period is not stored, so the record is in sample
    units (fs = 1, ``metadata["time_unit"] = "samples"``). The usual split is 512 + 512
    (``ds.split(0.5)``).

    Parameters
    ----------
    path : str or path-like, optional
        The file or its directory; see :func:`find_public_data` for the search otherwise.
    checks : DataChecks, optional
        Validation thresholds.
    """
    found = find_public_data(path)
    return load_mat(
        found,
        u="X[0]",
        y="y[0]",
        extra={"x1": "X[1]"},
        input_name="valve_opening",
        input_unit="raw",
        output_name="pressure",
        output_unit="raw",
        name="hydraulic_actuator",
        metadata={
            "description": "Hydraulic actuator of a robot arm: valve opening -> oil pressure",
            "reference": (
                "Sjoberg et al., Nonlinear black-box modeling in system identification: a "
                "unified overview, Automatica 31(12), 1995"
            ),
            "usual_split_index": 512,
            "notes": [
                "x1 = X row 1: undocumented third channel, likely arm/piston position",
                "x1 has a one-sample glitch near sample 985",
                "the output oscillates with a period of about 25 samples",
            ],
        },
        checks=checks,
    )
