"""Population optimisers with an ask/tell core: H-GWO (the reference paper), GWO, PSO and DE.

Use :func:`minimize` for a whole run, or an optimiser class directly::

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
from hhra_phys.optim.driver import METHODS, IterationState, make_optimiser, minimize
from hhra_phys.optim.gwo import GWO
from hhra_phys.optim.hgwo import HGWO
from hhra_phys.optim.history import NOI_RTOL, History, noi
from hhra_phys.optim.pso import PSO

__all__ = [
    "DE",
    "GWO",
    "HGWO",
    "METHODS",
    "NOI_RTOL",
    "PSO",
    "Box",
    "History",
    "IterationState",
    "Optimiser",
    "make_optimiser",
    "minimize",
    "noi",
]
