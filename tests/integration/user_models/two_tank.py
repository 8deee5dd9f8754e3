"""A user's own model, written only with the public API: two tanks in cascade.

A pump fills the upper tank, which drains into the lower one.

Levels h1, h2 [cm]; input pump voltage u [V]; output the lower level [cm].
Torricelli outflows a*sqrt(h) (smoothed at h = 0 so derivatives exist).
"""
from dataclasses import dataclass

import numpy as np

from hhra_phys import (
    Effect,
    Model,
    Parameter,
    Part,
    Simulator,
    State,
    register_effect,
    register_part,
)
from hhra_phys.data import Dataset


def outflow(h, a):
    # a*sqrt(h) for h >= 0, smooth through 0 (levels never go much below 0)
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


@register_effect
@dataclass(frozen=True)
class SideInflow(Effect):
    """A constant extra inflow into the lower tank (a second feed nobody declared)."""

    name = "side_inflow"
    stage = "tanks"
    reads = ("h2",)
    writes = ("h2",)
    entry = "rate:h2"
    signature = "the lower level settles higher than the model predicts"

    @property
    def parameters(self):
        return (Parameter("q_side", "cm/s", 0.05, 1e-3, 2.0, "log", "side inflow"),)

    def apply(self, ctx):
        ctx.add_rate("h2", ctx.p["q_side"])

    def first_order(self, sig):
        return np.full((sig.u.size, 1), 0.05)


def make_model():
    return Model([Pump(), UpperTank(), LowerTank(), LevelSensor()])


def simulate_record(seed: int = 0, n: int = 1600, fs: float = 2.0, q_side: float = 0.1,
                    noise: float = 0.05) -> Dataset:
    """A record of the two tanks (with ``q_side`` of undeclared side inflow), seeded."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(1.0, 4.0, n // 60 + 1), 60)[:n]
    truth = make_model() if q_side <= 0 else make_model().with_parts(SideInflow())
    values = {"k_pump": 0.4, "q_side": q_side}
    p = np.array([values.get(par.name, par.nominal) for par in truth.params])
    x0 = np.array([rng.uniform(2.0, 6.0), rng.uniform(4.0, 8.0)])
    y = Simulator(truth, fs=fs).simulate(u, p, x0=x0) + noise * rng.standard_normal(n)
    return Dataset(t=np.arange(n) / fs, u=u, y=y, name=f"two tanks seed {seed}",
                   input_name="pump", input_unit="V", output_name="level", output_unit="cm",
                   metadata={"truth": dict(zip(truth.params.names, p.tolist(), strict=True))})
