"""hhra-phys: fit physical models of actuators and processes to measured data.

The generic core (parts, model, simulator, problem, fit, diagnosis loop) knows no
particular system; the bundled models (:mod:`hhra_phys.models`) and a user's own
are packages of parts::

    from hhra_phys import Model, Part, State, Parameter, Effect, Simulator
    from hhra_phys import register_part, register_effect, HHRAModel

and a record, its loader and a fit's result::

    from hhra_phys import Dataset, load, FitResult
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

from hhra_phys import terms as _terms  # noqa: E402, F401, I001  (registers discovered parts)
from hhra_phys import effects as _effects  # noqa: E402, F401  (registers the library)
from hhra_phys.data import Dataset, load  # noqa: E402, I001  (after parts: the core first)
from hhra_phys.model import Model  # noqa: E402
from hhra_phys.models.hhra import HHRAModel  # noqa: E402
from hhra_phys.parameters import Parameter  # noqa: E402
from hhra_phys.parts import (  # noqa: E402
    Context,
    Effect,
    Part,
    Signals,
    State,
    register_effect,
    register_part,
)
from hhra_phys.simulate import Simulator  # noqa: E402

__all__ = [
    "Context", "Dataset", "Effect", "FitResult", "HHRAModel", "Model", "Parameter", "Part",
    "Signals", "Simulator", "State", "__version__", "load", "register_effect", "register_part",
]

if TYPE_CHECKING:
    from hhra_phys.result import FitResult


def __getattr__(name: str) -> Any:
    """``FitResult`` on first use: its module's dataclasses would add about 5 ms to the import."""
    if name == "FitResult":
        from hhra_phys.result import FitResult

        globals()[name] = FitResult
        return FitResult
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
