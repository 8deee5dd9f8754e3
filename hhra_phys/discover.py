"""Discovery's first home, kept so that code written for it runs unchanged: the module is
:mod:`hhra_phys.diagnosis.discovery` (the method) with :mod:`hhra_phys.diagnosis.screening`
(its first-order stage).
"""

from __future__ import annotations

from hhra_phys.diagnosis.discovery import (
    SPARSITY_METHODS,
    DiscoveredStep,
    Discovery,
    Proposal,
    next_index,
)
from hhra_phys.diagnosis.plots import plot_discovery
from hhra_phys.diagnosis.screening import (
    Candidate,
    EntryScreen,
    ModeScreen,
    entry_points,
    input_followers,
    input_twin,
    lasso_path,
    load_column,
    mode_column,
    score_floor,
    screen,
    screen_mode,
    term_library,
    variable_forms,
    variable_series,
)

# The discovered parts (registered in hhra_phys.terms) were importable from here too.
from hhra_phys.terms import DiscoveredMode, DiscoveredTerm  # noqa: F401

#: Where these names live now (docs/make_api.py lists them there).
__moved_to__ = "hhra_phys.diagnosis"

__all__ = [
    "DiscoveredStep",
    "Candidate",
    "EntryScreen",
    "entry_points",
    "input_followers",
    "input_twin",
    "score_floor",
    "next_index",
    "term_library",
    "screen",
    "variable_forms",
    "variable_series",
    "lasso_path",
    "Discovery",
    "Proposal",
    "plot_discovery",
    "SPARSITY_METHODS",
    "ModeScreen",
    "load_column",
    "mode_column",
    "screen_mode",
]
