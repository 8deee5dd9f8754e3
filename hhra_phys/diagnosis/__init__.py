"""Diagnosis: find what a fitted model lacks, add it, and keep it only if it pays.

One verb, :func:`diagnose` (also ``hhra_phys.diagnose(...)``, ``hhra-phys diagnose``)::

    import hhra_phys
    res = hhra_phys.diagnose(data, model=model, options=LoopOptions(max_effects=2))
    print(res.summary())

returns a :class:`DiagnosisResult`. One concept a module, in the order of the data path:

- :mod:`.options`: the loop's settings (:class:`LoopOptions`);
- :mod:`.residual`: residual analysis of a fit and the library effects' first-order
  evidence (:func:`analyse`), on :mod:`.first_order`'s linearised response;
- :mod:`.screening` and :mod:`.discovery`: terms and modes the library does not have;
- :mod:`.selection`: the one rule that accepts, chooses, removes and stops;
- :mod:`.fits`, :mod:`.candidates`, :mod:`.backward`, :mod:`.stopping`: the refits;
- :mod:`.engine`: the loop itself, with its stages :mod:`.holds`, :mod:`.rotation`,
  :mod:`.shapes` and :mod:`.revisit`;
- :mod:`.result`: what it returns; :mod:`.plots`: its figures.

Names are loaded on first use, so that importing one module of the package (the selection
rule, say) does not import the loop.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__all__ = ["Diagnosis", "DiagnosisResult", "Discovery", "LoopOptions", "analyse", "diagnose"]

#: Public name -> the module of this package that defines it.
_HOME = {
    "diagnose": "engine", "augment": "engine", "DiagnosisResult": "result",
    "LoopResult": "result", "LoopOptions": "options", "analyse": "residual",
    "Diagnosis": "residual", "Discovery": "discovery",
}

if TYPE_CHECKING:
    from hhra_phys.diagnosis.discovery import Discovery
    from hhra_phys.diagnosis.engine import augment, diagnose  # noqa: F401
    from hhra_phys.diagnosis.options import LoopOptions
    from hhra_phys.diagnosis.residual import Diagnosis, analyse
    from hhra_phys.diagnosis.result import DiagnosisResult, LoopResult  # noqa: F401


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value
