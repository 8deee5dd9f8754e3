"""hhra-phys: fit physical models of hydraulic actuators to measured data."""

from __future__ import annotations

__version__ = "0.1.0"

from hhra_phys.model import HHRAModel, Model  # noqa: E402
from hhra_phys.simulate import Simulator  # noqa: E402

__all__ = ["HHRAModel", "Model", "Simulator", "__version__"]
