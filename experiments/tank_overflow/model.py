"""A user's model for the overflow study (experiments/overflow_records.py), written only
with the public API: two tanks in cascade, Torricelli outflows, no overflow.

A pump fills the upper tank, which drains into the lower one. Levels h1, h2 [cm]; input
the pump voltage u [V]; output the lower level [cm]. ``--model model.py:make_model``.
"""
from dataclasses import dataclass

from hhra_phys import Model, Parameter, Part, State, register_part


def outflow(h, a):
    """a*sqrt(h) for h >= 0, smooth through 0 so that derivatives exist."""
    return a * h / (h * h + 1e-4) ** 0.25


@register_part
@dataclass(frozen=True)
class Pump(Part):
    name = "pump"
    stage = "pump"

    @property
    def parameters(self):
        return (Parameter("k_pump", "cm/(s*V)", 0.5, 0.05, 5.0, "log", "pump gain"),)

    def apply(self, ctx):
        ctx.signals["inflow"] = ctx.p["k_pump"] * ctx.u


@register_part
@dataclass(frozen=True)
class UpperTank(Part):
    name = "upper_tank"
    stage = "tanks"

    @property
    def parameters(self):
        return (Parameter("a1", "cm^0.5/s", 0.3, 0.03, 3.0, "log", "upper outlet"),)

    @property
    def states(self):
        return (State("h1", "cm", 5.0, "upper level", scale=5.0),)

    def apply(self, ctx):
        q = outflow(ctx.x["h1"], ctx.p["a1"])
        ctx.signals["q12"] = q
        ctx.add_rate("h1", ctx.signal("inflow", self.name) - q)


@register_part
@dataclass(frozen=True)
class LowerTank(Part):
    name = "lower_tank"
    stage = "tanks"

    @property
    def parameters(self):
        return (Parameter("a2", "cm^0.5/s", 0.3, 0.03, 3.0, "log", "lower outlet"),)

    @property
    def states(self):
        return (State("h2", "cm", 5.0, "lower level", scale=5.0),)

    def apply(self, ctx):
        ctx.add_rate("h2", ctx.signal("q12", self.name) - outflow(ctx.x["h2"], ctx.p["a2"]))


@register_part
@dataclass(frozen=True)
class LevelSensor(Part):
    name = "level_sensor"
    stage = "sensor"

    def apply(self, ctx):
        ctx.signals["y"] = ctx.x["h2"]


def make_model():
    return Model([Pump(), UpperTank(), LowerTank(), LevelSensor()])
