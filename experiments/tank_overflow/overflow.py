"""The user's overflow effect for the overflow study (``--effects-from overflow.py``):
the upper tank spills above its rim and the spill is lost."""
from dataclasses import dataclass

import numpy as np

from hhra_phys import Effect, Parameter, register_effect

W = 0.2  # cm: width of the rim's smooth corner


def spill(h, h_max, k):
    """k*max(h - h_max, 0), its corner smoothed over W (a hyperbola: finite everywhere)."""
    z = (h - h_max) / W
    return k * W * (0.5 * (z + (z * z + 1.0) ** 0.5))


@register_effect
@dataclass(frozen=True)
class Overflow(Effect):
    """Above ``h_max`` the upper tank spills: ``dh1/dt -= k_over*(h1 - h_max)`` (smooth)."""

    name = "overflow"
    stage = "tanks"
    reads = ("h1",)
    writes = ("h1",)
    entry = "rate:h1"
    signature = "the levels stop rising when the upper tank is full"
    # A discovered hinge on h1 at h1's rate is this overflow in its discovered form.
    twin = ("hinge+(h1)",)

    @property
    def parameters(self):
        return (Parameter("h_max", "cm", 12.0, 2.0, 40.0, "linear", "rim of the upper tank"),
                Parameter("k_over", "1/s", 0.5, 0.01, 10.0, "log", "spill rate per cm"))

    def apply(self, ctx):
        ctx.add_rate("h1", -spill(ctx.x["h1"], ctx.p["h_max"], ctx.p["k_over"]))

    def first_order(self, sig):
        h = sig.states["h1"]
        return -np.asarray(spill(h, 12.0, 0.5), float).reshape(-1, 1)
