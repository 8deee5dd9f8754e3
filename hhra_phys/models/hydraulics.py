"""Building blocks shared by the bundled hydraulic models.

The valve laws in normalised pressure (the HHRA and the cylinder write the load
pressure over the supply pressure, ``p = P_L/p_s``) and the random perturbation of a
physical parameter set that recovery tests use to put the truth away from the nominal
values and the box centre, toward which a search can be drawn (``docs/benchmarks.md``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import replace
from typing import Any, TypeVar

import casadi as ca
import numpy as np

from hhra_phys.errors import ParameterError
from hhra_phys.parts import smooth_sign, smooth_signed_sqrt

__all__ = ["orifice_flow", "perturb_fields"]

T = TypeVar("T")


def orifice_flow(cmd: Any, p: Any, gain: Any, sign_eps: float, sqrt_delta: float) -> ca.SX:
    """Critical-centre orifice law ``gain * cmd * sqrt(1 - sign(cmd) * p)``, smoothed.

    Parameters
    ----------
    cmd : casadi.SX
        Valve command (input units, e.g. mA).
    p : casadi.SX
        Load pressure over supply pressure [-].
    gain : casadi.SX
        Flow gain (normalised pressure per second per input unit).
    sign_eps, sqrt_delta : float
        Widths of the smooth sign (input units) and of the smoothed signed square root
        (:func:`~hhra_phys.parts.smooth_signed_sqrt`): derivatives exist everywhere, and
        beyond the supply pressure the signed root reverses the flow as a real orifice does.
    """
    drop = 1 - smooth_sign(cmd, sign_eps) * p
    return gain * cmd * smooth_signed_sqrt(drop, sqrt_delta)


def perturb_fields(base: T, names: Iterable[str], seed: int | np.random.Generator | None,
                   spread: float, min_factor: float) -> T:
    """``base`` (a frozen dataclass) with fields ``names`` moved by random factors.

    Each field is multiplied by ``exp(+-m)`` with ``m`` log-uniform between
    ``log(min_factor)`` and ``log(spread)`` and the sign drawn at random, in the order
    of ``names`` from one generator (so a seed gives the same truth every time).
    """
    if not spread > min_factor >= 1:
        raise ParameterError(f"need spread > min_factor >= 1, got {spread}, {min_factor}")
    rng = np.random.default_rng(seed)  # a Generator passes through unchanged
    changes = {}
    for name in names:
        mag = rng.uniform(math.log(min_factor), math.log(spread))
        changes[name] = getattr(base, name) * math.exp(mag if rng.random() < 0.5 else -mag)
    return replace(base, **changes)  # type: ignore[type-var]
