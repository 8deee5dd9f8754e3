"""A module that is also its verb: ``hhra_phys.fit(...)`` and ``hhra_phys.fit.FitOptions``.

``hhra_phys.fit`` and ``hhra_phys.diagnose`` were modules before they were the package's
top-level verbs; code imports from them (``from hhra_phys.fit import fit``). Making the module
callable keeps every import working and gives the short call. :class:`VerbModule` is set as
the module's class by the module itself (:func:`make_callable`), which Python supports for
exactly this (a module's ``__class__`` may be a subclass of :class:`types.ModuleType`).
"""

from __future__ import annotations

import importlib
import inspect
import sys
import types
from typing import Any

__all__: list[str] = []


class VerbModule(types.ModuleType):
    """A module whose call is one function of the package (named by ``__verb__``,
    ``"module:function"``, imported on the first call)."""

    def _target(self) -> Any:
        path, _, name = self.__verb__.partition(":")
        return getattr(importlib.import_module(path), name)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self._target()(*args, **kwargs)

    @property
    def __signature__(self) -> inspect.Signature:  # help() and IDEs show the verb's
        return inspect.signature(self._target())


def make_callable(module_name: str, verb: str) -> None:
    """Make the module ``module_name`` callable as ``verb`` (``"package.module:function"``)."""
    module = sys.modules[module_name]
    module.__verb__ = verb
    module.__class__ = VerbModule
