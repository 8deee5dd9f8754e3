"""The diagnosis loop's first home, kept so that code written for it runs unchanged.

The loop is :mod:`hhra_phys.diagnosis` (``hhra_phys.diagnose(...)``); ``augment`` is the same
function as :func:`hhra_phys.diagnosis.engine.diagnose`, ``LoopResult`` the same class as
:class:`~hhra_phys.diagnosis.result.DiagnosisResult`.
"""

from __future__ import annotations

from hhra_phys.diagnosis.candidates import refit_candidate
from hhra_phys.diagnosis.engine import augment, base_model_for
from hhra_phys.diagnosis.options import SHAPE_MODES, LoopOptions
from hhra_phys.diagnosis.result import LoopResult
from hhra_phys.diagnosis.stopping import noise_stop, selection_noise

#: Where these names live now (docs/make_api.py lists them there).
__moved_to__ = "hhra_phys.diagnosis"

__all__ = [
    "LoopOptions",
    "LoopResult",
    "augment",
    "base_model_for",
    "selection_noise",
    "noise_stop",
    "refit_candidate",
    "SHAPE_MODES",
]
