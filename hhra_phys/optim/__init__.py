"""Population optimisers with an ask/tell core: H-GWO (the reference paper), GWO, PSO and DE.

Every optimiser is registered by name in :mod:`hhra_phys.optim.registry` (:data:`METHODS`).
Use :func:`minimize` for a whole run (its settings: :class:`MinimizeOptions`), or an
optimiser class directly::

    opt = HGWO(bounds, pop_size=30, max_iter=100, seed=0)
    while not opt.done:
        X = opt.ask()            # (m, d) points, all inside the bounds
        opt.tell(cost(X))        # their m costs
    opt.x_best, opt.f_best, opt.history
"""

from __future__ import annotations

from hhra_phys.optim.bounds import Box
from hhra_phys.optim.core import Optimiser
from hhra_phys.optim.de import DE
from hhra_phys.optim.driver import IterationState, MinimizeOptions, make_optimiser, minimize
from hhra_phys.optim.gwo import GWO
from hhra_phys.optim.hgwo import HGWO
from hhra_phys.optim.history import NOI_RTOL, History, noi
from hhra_phys.optim.pso import PSO, PSOOptions
from hhra_phys.optim.registry import LABELS, METHODS, optimiser_class

__all__ = [
    "DE",
    "GWO",
    "HGWO",
    "LABELS",
    "METHODS",
    "NOI_RTOL",
    "PSO",
    "MinimizeOptions",
    "PSOOptions",
    "Box",
    "History",
    "IterationState",
    "Optimiser",
    "make_optimiser",
    "minimize",
    "noi",
    "optimiser_class",
]
