"""A user's own prismatic drive, written only with the public API and declared by roles.

A motor pushes a carriage: position ``q`` [m] (role ``"position"``), velocity ``v``
[m/s] (role ``"velocity"``), input the motor command ``u`` [V], output the encoder's
position in mm. Mass and viscous friction only::

    dq/dt = v
    dv/dt = k_motor*u - c_visc*v          (force over mass, m/s^2)

The names are the user's (no ``omega``, no ``theta``): library effects that act on a
velocity (``coulomb_friction``, ``constant_force``) bind to ``v`` by its role.

:func:`simulate_record` is an independent plant (NumPy RK4 on a fine step, sharp
friction), not the package's simulator: a known Coulomb friction, a constant force and
an input offset can be put in.
"""
from dataclasses import dataclass

import numpy as np

from hhra_phys import Model, Parameter, Part, State, register_part
from hhra_phys.data import Dataset

MM_PER_M = 1000.0


@register_part
@dataclass(frozen=True)
class Motor(Part):
    name = "motor"
    stage = "motor"

    @property
    def parameters(self):
        return (Parameter("k_motor", "m/(s^2*V)", 2.0, 0.2, 20.0, "log",
                          "motor force over mass per volt"),)

    def apply(self, ctx):
        ctx.signals["force"] = ctx.p["k_motor"] * ctx.u


@register_part
@dataclass(frozen=True)
class Carriage(Part):
    name = "carriage"
    stage = "carriage"

    @property
    def parameters(self):
        return (Parameter("c_visc", "1/s", 5.0, 0.5, 50.0, "log",
                          "viscous friction over mass"),)

    @property
    def states(self):
        return (State("q", "m", 0.0, "carriage position", scale=0.05, role="position"),
                State("v", "m/s", 0.0, "carriage velocity", scale=0.2, fit_initial=False,
                      role="velocity"))

    def apply(self, ctx):
        ctx.add_rate("q", ctx.x["v"])
        ctx.add_rate("v", ctx.signal("force", self.name) - ctx.p["c_visc"] * ctx.x["v"])


@register_part
@dataclass(frozen=True)
class Encoder(Part):
    name = "encoder"
    stage = "sensor"

    def apply(self, ctx):
        ctx.signals["y"] = MM_PER_M * ctx.x["q"]


def make_model():
    return Model([Motor(), Carriage(), Encoder()], name="drive")


#: The plant's own values (the model's nominal ones are a guess around them).
TRUTH = {"k_motor": 2.5, "c_visc": 6.0}


def simulate_record(seed: int = 0, n: int = 3000, fs: float = 1000.0, coulomb: float = 0.0,
                    const: float = 0.0, u_offset: float = 0.0, noise: float = 0.002,
                    width: float = 1e-4, substeps: int = 4, kp: float = 20.0,
                    profile: str = "algebraic") -> Dataset:
    """A closed-loop record of the drive (set points and sines on the command), seeded.

    Parameters
    ----------
    coulomb : float
        Coulomb friction over mass [m/s^2] (smooth sign of width ``width`` [m/s]).
    profile : {"algebraic", "tanh"}
        Shape of that sign: ``v/sqrt(v^2 + width^2)`` or ``tanh(v/width)``.
    const : float
        Constant force over mass [m/s^2] at the velocity's rate.
    u_offset : float
        Bias of the motor command [V].
    noise : float
        Encoder noise [mm].
    kp : float
        Gain of the position controller [V/m] (the loop closes at about 7 rad/s).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    # Closed-loop excitation: a position controller (kp) tracks random set points, with
    # sines on the command that the velocity lags (its sign is not the command's).
    ref = np.zeros(n)
    k = 0
    while k < n:
        hold = int(rng.uniform(0.3, 0.6) * fs)
        ref[k:k + hold] = rng.uniform(-0.03, 0.03)
        k += hold
    dither = sum(a * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
                 for a, f in ((0.3, 0.9), (0.2, 2.3), (0.15, 4.7)))
    km, cv = TRUTH["k_motor"], TRUTH["c_visc"]

    def sign(v):
        return np.tanh(v / width) if profile == "tanh" else v / np.sqrt(v * v + width * width)

    def rate(x, uk):
        q, v = x
        return np.array([v, km * (uk + u_offset) - cv * v - coulomb * sign(v) + const])

    h = 1.0 / (fs * substeps)
    x = np.zeros(2)
    qs = np.empty(n)
    u = np.empty(n)
    for i in range(n):
        qs[i] = x[0]
        u[i] = np.clip(kp * (ref[i] - x[0]) + dither[i], -2.0, 2.0)
        for _ in range(substeps):
            k1 = rate(x, u[i])
            k2 = rate(x + 0.5 * h * k1, u[i])
            k3 = rate(x + 0.5 * h * k2, u[i])
            k4 = rate(x + h * k3, u[i])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    y = MM_PER_M * qs + noise * rng.standard_normal(n)
    return Dataset(t=np.arange(n) / fs, u=u, y=y, name=f"drive seed {seed}",
                   input_name="command", input_unit="V", output_name="position",
                   output_unit="mm",
                   metadata={"truth": {**TRUTH, "g_coulomb": coulomb, "g_const": const,
                                       "u_offset": u_offset}})
