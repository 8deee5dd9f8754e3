"""A user's own models and effects, named on the command line or in a script.

``--model FILE.py:FACTORY`` or ``--model package.module:FACTORY`` names a callable
that returns a :class:`~hhra_phys.model.Model`; ``--effects-from FILE.py`` (or a
module) is imported so that the effects it registers with
:func:`~hhra_phys.parts.register_effect` become candidates of the diagnosis loop.

A file is imported under a module name derived from its path, once per process,
so that part classes it defines keep one identity (saved fits reload them by
class name once the same file is imported again).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import re
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

from hhra_phys.errors import ModelError
from hhra_phys.model import Model
from hhra_phys.parts import EFFECTS

__all__ = ["import_source", "load_factory", "model_from_spec", "import_effects"]


def import_source(source: str, what: str = "--model") -> ModuleType:
    """Import a Python file (``path/to/file.py``) or a module (``package.module``).

    Raises
    ------
    ModelError
        The file does not exist or fails to import (the message names it and the
        error it raised).
    """
    if source.endswith(".py") or "/" in source or "\\" in source:
        path = Path(source).expanduser().resolve()
        if not path.is_file():
            raise ModelError(f"{what} {source}: no such Python file")
        # A module name of identifier characters only: a dot would make it a package path.
        name = "hhra_user_" + re.sub(r"\W", "_", "_".join(path.with_suffix("").parts[-3:]))
        if name in sys.modules:
            return sys.modules[name]
        spec = importlib.util.spec_from_file_location(name, path)
        if spec is None or spec.loader is None:
            raise ModelError(f"{what} {source}: cannot be imported as Python")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - any error in user code
            del sys.modules[name]
            raise ModelError(
                f"{what} {source}: importing it {_raised(exc)}") from exc
        return module
    try:
        return importlib.import_module(source)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - sys.exit() too
        raise ModelError(
            f"{what} {source}: importing it {_raised(exc)}") from exc


def load_factory(spec: str, what: str = "--model") -> Callable[..., Any]:
    """The callable named by ``FILE.py:NAME`` or ``package.module:NAME``."""
    source, sep, attr = spec.rpartition(":")
    if not sep or not source or not attr:
        raise ModelError(
            f"{what} {spec!r}: expected FILE.py:FACTORY or package.module:FACTORY "
            "(a callable returning a Model)")
    module = import_source(source, what)
    obj = getattr(module, attr, None)
    if obj is None:
        public = [n for n in dir(module) if not n.startswith("_")]
        raise ModelError(f"{what} {spec}: {source} has no {attr!r} "
                         f"(it defines {', '.join(public) or 'nothing public'})")
    if not callable(obj):
        raise ModelError(f"{what} {spec}: {attr!r} is not callable")
    return obj


def model_from_spec(spec: str, data: Any = None, what: str = "--model") -> Model:
    """Build the model named by ``spec`` (:func:`load_factory`).

    The factory is called with no argument, or with the record as ``data=``
    when its signature has a parameter of that name (so it can scale its
    nominal values or bounds to the record).

    Raises
    ------
    ModelError
        The factory fails or does not return a :class:`Model`.
    """
    factory = load_factory(spec, what)
    if isinstance(factory, type) and issubclass(factory, Model):
        kwargs: dict[str, Any] = {}
    else:
        try:
            params = inspect.signature(factory).parameters
        except (TypeError, ValueError):
            params = {}  # type: ignore[assignment]
        kwargs = {"data": data} if "data" in params else {}
    try:
        model = factory(**kwargs)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - sys.exit() too
        raise ModelError(
            f"{what} {spec}: calling it {_raised(exc)}") from exc
    if not isinstance(model, Model):
        raise ModelError(f"{what} {spec}: returned {type(model).__name__}, not a hhra_phys Model")
    return model


def import_effects(sources: list[str] | None) -> list[str]:
    """Import each source (file or module) and return the effect names it registered."""
    added: list[str] = []
    for source in sources or []:
        before = set(EFFECTS)
        import_source(source, "--effects-from")
        added += [n for n in EFFECTS if n not in before]
    return added


def _raised(exc: BaseException) -> str:
    """What user code did, in words: 'called sys.exit(3)' or 'raised KeyError: ...'."""
    if isinstance(exc, SystemExit):
        return f"called sys.exit({exc.code!r}) (a model or effect file must not exit)"
    return f"raised {type(exc).__name__}: {exc}"
