"""The optimiser registry: every population optimiser of the package by name.

The one list the package reads its optimisers from: :func:`~hhra_phys.optim.minimize`
and :func:`~hhra_phys.optim.make_optimiser` (the method), the fit's ``optimizer``
(:data:`hhra_phys.fit.OPTIMIZERS`, these and ``"none"``) and the CLI's ``--optimizer``
choices, the benchmark study's methods and the ARX metaheuristic fits; their error
messages list the names from here.
"""

from __future__ import annotations

from hhra_phys.errors import ParameterError
from hhra_phys.optim.core import Optimiser
from hhra_phys.optim.de import DE
from hhra_phys.optim.gwo import GWO
from hhra_phys.optim.hgwo import HGWO
from hhra_phys.optim.pso import PSO

__all__ = [
    "LABELS",
    "METHODS",
    "optimiser_class",
]

#: Optimiser class per method name, in the order of the tables (the paper's H-GWO first).
METHODS: dict[str, type[Optimiser]] = {cls.method: cls for cls in (HGWO, GWO, PSO, DE)}

#: Display name per method name (``"hgwo"``: ``"H-GWO"``).
LABELS: dict[str, str] = {name: cls.label for name, cls in METHODS.items()}


def optimiser_class(method: str, what: str = "method") -> type[Optimiser]:
    """The optimiser class registered as ``method`` (case-insensitive).

    Parameters
    ----------
    method : str
        A key of :data:`METHODS`.
    what : str
        The setting's name, for the message (``"method"``, ``"optimizer"``).

    Raises
    ------
    ParameterError
        Naming ``what``, the registered methods and the value given.
    """
    key = method.lower() if isinstance(method, str) else None
    if key not in METHODS:
        raise ParameterError(f"{what}: expected one of {', '.join(METHODS)}, got {method!r}")
    return METHODS[key]
