"""hhra-phys: fit physical models of hydraulic actuators to measured data."""

from __future__ import annotations

__version__ = "0.1.0"
