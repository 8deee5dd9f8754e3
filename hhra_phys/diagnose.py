"""The diagnosis verb, and the residual analysis's first home.

Called, this module is the diagnosis: ``hhra_phys.diagnose(data, model=..., options=...)``
runs the loop (:func:`hhra_phys.diagnosis.engine.diagnose`) and returns a
:class:`~hhra_phys.diagnosis.result.DiagnosisResult`. Its names are the residual analysis's
(:mod:`hhra_phys.diagnosis.residual`, :mod:`~hhra_phys.diagnosis.first_order`,
:mod:`~hhra_phys.diagnosis.plots`), kept so that code written for them runs unchanged.
"""

from __future__ import annotations

from hhra_phys._verb import make_callable
from hhra_phys.diagnosis.first_order import linear_response, nuisance_basis
from hhra_phys.diagnosis.plots import plot_loop_residuals, plot_residuals
from hhra_phys.diagnosis.residual import (
    DETECTABLE,
    Diagnosis,
    EffectEvidence,
    analyse,
    combine_diagnoses,
    cross_correlation,
    diagnose_fit,
    generic_regressors,
    output_delay,
    regressor_table,
    whiteness,
)
from hhra_phys.noise import noise_level

#: Where these names live now (docs/make_api.py lists them there).
__moved_to__ = "hhra_phys.diagnosis"

__all__ = [
    "EffectEvidence",
    "Diagnosis",
    "noise_level",
    "whiteness",
    "cross_correlation",
    "output_delay",
    "generic_regressors",
    "regressor_table",
    "analyse",
    "combine_diagnoses",
    "linear_response",
    "nuisance_basis",
    "diagnose_fit",
    "plot_loop_residuals",
    "plot_residuals",
    "DETECTABLE",
]

make_callable(__name__, "hhra_phys.diagnosis.engine:diagnose")
