"""Scales, units and shapes the library's effect families share.

The motion, input and sensor effects (:mod:`.motion`, :mod:`.inputs`, :mod:`.sensors`) each
import these from here rather than from one another, so that every family stands on its
own: the rig's acceleration scale (the default of the motion effects' bounds), degrees per
radian (the backlash's angle output), the unit of a velocity's rate and the NumPy smooth
sign the first-order signatures use.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["RAD2DEG", "RIG_ACCEL"]

RAD2DEG = 180.0 / math.pi

#: The rig's g_torque [rad/s^2]: default scale of accelerations of motion effects.
RIG_ACCEL = 175.58


def _smooth_np(v: np.ndarray, eps: float) -> np.ndarray:
    return v / np.sqrt(v * v + eps * eps)


def _rate_unit(v_unit: str) -> str:
    """Unit of a velocity's rate: ``"rad/s"`` -> ``"rad/s^2"``, ``"m"`` -> ``"m/s"``."""
    return f"{v_unit}^2" if v_unit.endswith("/s") else f"{v_unit}/s"
