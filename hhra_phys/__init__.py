"""hhra-phys: fit physical models of actuators and processes to measured data.

The generic core (parts, model, simulator, problem, fit, diagnosis loop) knows no
particular system; the bundled models (:mod:`hhra_phys.models`) and a user's own
are packages of parts::

    from hhra_phys import Model, Part, State, Parameter, Effect, Simulator
    from hhra_phys import register_part, register_effect, HHRAModel

and the data path's verbs, a record's loader and the results::

    import hhra_phys
    data = hhra_phys.load("record.csv")
    fit = hhra_phys.fit(data, model=model)            # -> FitResult
    res = hhra_phys.diagnose(data, model=model)       # -> DiagnosisResult
    print(fit.summary()); print(res.summary())

``hhra_phys.fit`` and ``hhra_phys.diagnose`` are also the modules of those names (``from
hhra_phys.fit import FitOptions``): calling the module calls its verb
(:mod:`hhra_phys._verb`). They, ``FitResult`` and ``DiagnosisResult`` load on first use, so
``import hhra_phys`` stays light (no scipy).
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
    "Context", "Dataset", "DiagnosisResult", "Effect", "FitResult", "HHRAModel", "Model",
    "Parameter", "Part", "Signals", "Simulator", "State", "__version__", "diagnose", "fit",
    "load", "register_effect", "register_part",
]

if TYPE_CHECKING:
    from hhra_phys import diagnose, fit
    from hhra_phys.diagnosis.result import DiagnosisResult
    from hhra_phys.result import FitResult

#: Names loaded on first use -> (module, attribute; ``None``: the module itself). The verbs
#: import scipy and the fits; the results' dataclasses add about 5 ms each.
_LAZY = {
    "FitResult": ("hhra_phys.result", "FitResult"),
    "DiagnosisResult": ("hhra_phys.diagnosis.result", "DiagnosisResult"),
    "fit": ("hhra_phys.fit", None),
    "diagnose": ("hhra_phys.diagnose", None),
}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    module, attr = _LAZY[name]
    value = importlib.import_module(module)
    value = value if attr is None else getattr(value, attr)
    globals()[name] = value
    return value
