"""Writing results: one output-path guard, atomic writes and one JSON sanitiser.

Every writer of the package (fit results, reports, figures, data files) and every CLI
command goes through :func:`check_output_path` before doing any work, so a long run never
ends in "file exists" or "no such directory", and writes through :func:`atomic_path` (or
:func:`atomic_write_text` / :func:`atomic_write_bytes`), so an interrupted or failing write
never leaves a truncated file where a good one was. :func:`jsonable` turns results into
strict JSON (NaN and infinities become ``null``); :func:`format_metric` writes a number into a
summary or report (a missing or non-finite one as ``"-"``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.errors import OutputExistsError, OutputPathError

__all__ = [
    "FIGURE_SUFFIXES",
    "OVERWRITE_HINT",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output_path",
    "format_metric",
    "jsonable",
]

PathLike = str | os.PathLike

#: How every "exists" refusal says what to do; the CLI replaces it with its own words.
OVERWRITE_HINT = "pass overwrite=True (CLI: --overwrite)"

#: Suffixes matplotlib writes. Figures must have one: without it ``savefig`` would append
#: ".png" (a file other than the one checked) and could not write through a temporary name.
FIGURE_SUFFIXES = (
    ".png", ".pdf", ".svg", ".svgz", ".jpg", ".jpeg", ".eps", ".ps", ".tif", ".tiff", ".webp",
)


def check_output_path(
    path: PathLike,
    *,
    overwrite: bool = False,
    what: str = "output",
    suffixes: Iterable[str] | None = None,
) -> Path:
    """Check that ``path`` can be written, before any work is done.

    Parameters
    ----------
    path : str or path-like
        The file to be written (``~`` is expanded).
    overwrite : bool
        Accept an existing file (it is replaced).
    what : str
        What the file is ("JSON result", "--plot"), used in messages.
    suffixes : iterable of str, optional
        Accepted suffixes, compared case-insensitively (``(".png", ".pdf")``); ``None``
        accepts any.

    Returns
    -------
    pathlib.Path
        The expanded path.

    Raises
    ------
    OutputExistsError
        The file exists and ``overwrite`` is False (also a ``FileExistsError``).
    OutputPathError
        The path is a directory, its folder does not exist or is not writable, or its
        suffix is not in ``suffixes``. The message names the path and the problem.
    """
    p = Path(path).expanduser()
    label = f"{what} {p}"
    if suffixes is not None:
        allowed = [s.lower() for s in suffixes]
        if p.suffix.lower() not in allowed:
            raise OutputPathError(
                f"{label}: unsupported suffix {p.suffix or '(none)'!r}; use "
                + " or ".join(allowed)
            )
    if p.is_dir():
        raise OutputPathError(f"{label} is a directory; give a file name")
    if p.exists() and not overwrite:
        raise OutputExistsError(
            f"{label} exists; {OVERWRITE_HINT} to replace it"
        )
    parent = p.parent
    if not parent.is_dir():
        # Not created silently: a typo in a folder name should not scatter results.
        raise OutputPathError(f"{label}: folder {parent} does not exist; create it first")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputPathError(f"{label}: folder {parent} is not writable")
    # Permissions do not tell everything (root, /proc, a read-only or full file system):
    # create a file where the result's temporary will be, as the writer will.
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".check", dir=parent)
    except OSError as exc:
        raise OutputPathError(
            f"{label}: cannot create a file in folder {parent}: {exc.strerror or exc}"
        ) from None
    os.close(fd)
    os.unlink(probe)
    return p


@contextmanager
def atomic_path(path: PathLike) -> Iterator[Path]:
    """A temporary path next to ``path``, renamed over it when the block succeeds.

    For writers that want a file name (``matplotlib`` ``savefig``, ``np.savez``): the
    temporary file keeps the suffix of ``path`` (so format inference works) and lives in
    the same folder (so the final rename is atomic). If the block raises, the temporary
    file is removed and ``path`` is left as it was.

    Parameters
    ----------
    path : str or path-like
        The target file; its folder must exist (see :func:`check_output_path`).

    Yields
    ------
    pathlib.Path
        Where to write.
    """
    p = Path(path).expanduser()
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{p.stem}.", suffix=f".tmp{p.suffix}",
                                        dir=p.parent)
    except OSError as exc:  # the user's path, not the temporary's, in the message
        raise OSError(exc.errno, f"cannot write {p}: {exc.strerror or exc}") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # mkstemp creates the file 0600; give the result the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, p)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if exc.filename is None and str(p) in str(exc):
            raise
        # A writer's error names the temporary file; the user gave ``path``.
        raise OSError(exc.errno, f"cannot write {p}: {exc.strerror or exc}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`); returns the path."""
    p = Path(path).expanduser()
    with atomic_path(p) as tmp:
        tmp.write_bytes(data)
    return p


def atomic_write_text(path: PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_path`); returns the path.

    Newlines are written as given (no platform translation), so files are byte-identical
    across systems.
    """
    return atomic_write_bytes(path, text.encode(encoding))


def format_metric(value: Any, spec: str = ".4g") -> str:
    """A number for a summary or report (``spec``, default four significant digits); a
    diverged fit's missing or non-finite one as ``"-"``."""
    return format(value, spec) if value is not None and np.isfinite(value) else "-"


def jsonable(obj: Any, *, default: Callable[[Any], Any] | None = None) -> Any:
    """``obj`` as plain JSON types, recursively; the one sanitiser of the package.

    Mappings become dicts with string keys, lists/tuples/sets become lists (sets sorted),
    NumPy arrays and scalars become lists and Python numbers, dataclass instances become
    dicts, complex numbers ``[real, imag]``, paths strings, and NaN/inf become ``None``
    (strict JSON has no such numbers). Finite floats are returned unchanged, so
    ``json.dumps`` writes them exactly as before.

    Parameters
    ----------
    obj : Any
    default : callable, optional
        Applied to any other object (e.g. ``str``); without it such objects raise.

    Raises
    ------
    TypeError
        For an object of another type when ``default`` is not given.
    """
    if obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, _SCALARS):
        return _scalar(obj)
    if isinstance(obj, Mapping):
        return {_key(k): jsonable(v, default=default) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        obj = obj.tolist()
    elif isinstance(obj, set | frozenset):
        obj = sorted(obj)
    if isinstance(obj, list | tuple):
        return [jsonable(v, default=default) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return jsonable(dataclasses.asdict(obj), default=default)
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if default is not None:
        return jsonable(default(obj))
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


_SCALARS = (bool, np.bool_, int, np.integer, float, np.floating, complex, np.complexfloating)


def _scalar(obj: Any) -> Any:
    """A number as a plain JSON number (``None`` for NaN and infinities)."""
    if isinstance(obj, bool | np.bool_):  # before int: bool is an int
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    return [_scalar(float(obj.real)), _scalar(float(obj.imag))]


def _key(key: Any) -> str:
    # json.dumps would reject NumPy keys; str() keeps the text that int/float keys had before.
    return key if isinstance(key, str) else str(jsonable(key, default=str))
