"""A lightly damped second-order resonator: a generic linear model of parts.

Physics (a mass on a spring and damper driven through a gain, or the electronic
resonator a filter makes)::

    dx/dt = v
    dv/dt = w_n^2 (gain u - x) - 2 zeta w_n v
    y     = x

with ``x`` the output (in the output's unit), ``v`` its rate, ``u`` the input,
``gain`` the static gain [output unit per input unit], ``w_n`` the natural
frequency [rad/s] and ``zeta`` the damping ratio [-]. Transfer function
``Y(s)/U(s) = gain w_n^2 / (s^2 + 2 zeta w_n s + w_n^2)``.

It knows no actuator: it is the model a user brings for a measured resonator
(``hhra-phys diagnose --model hhra_phys.models.resonator:make_model``), and the
base of the inter-sample study (``experiments/intersample.py``), whose records
come from the independent reference
(:func:`hhra_phys.reference.resonant.multisine_resonator_record`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from hhra_phys.model import Model
from hhra_phys.parameters import Parameter
from hhra_phys.parts import Context, Part, State, register_part

__all__ = ["ResonatorDrive", "ResonatorMotion", "ResonatorSensor", "make_model",
           "make_cubic_model"]


@register_part
@dataclass(frozen=True)
class ResonatorDrive(Part):
    """The input through the static gain: ``signals["drive"] = gain * u`` [output unit]."""

    name = "resonator_drive"
    stage = "drive"
    gain: float = 1.0
    unit: str = "V/V"

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (Parameter("gain", self.unit, self.gain, self.gain / 10, self.gain * 10, "log",
                          "static gain (output per input)"),)

    def apply(self, ctx: Context) -> None:
        ctx.signals["drive"] = ctx.p["gain"] * ctx.u


@register_part
@dataclass(frozen=True)
class ResonatorMotion(Part):
    """Mass, spring and damper: states ``x`` (output unit) and ``v`` (output unit per s)."""

    name = "resonator_motion"
    stage = "motion"
    w_n: float = 2 * 3.141592653589793 * 10.0
    zeta: float = 0.05
    scale: float = 1.0
    cubic: bool = False

    @property
    def parameters(self) -> Sequence[Parameter]:
        out = (Parameter("w_n", "rad/s", self.w_n, self.w_n / 10, self.w_n * 10, "log",
                         "natural frequency"),
               Parameter("zeta", "1", self.zeta, 1e-3, 2.0, "log", "damping ratio"))
        if self.cubic:  # a hardening (> 0) or softening (< 0) spring, relative to the linear one
            bound = 16.0 / self.scale ** 2  # 4x the linear spring at half the range
            out += (Parameter("k_cubic", "1/output^2", 0.0, -bound, bound, "linear",
                              "cubic stiffening of the spring"),)
        return out

    @property
    def states(self) -> Sequence[State]:
        return (State("x", "output", 0.0, "output (position)", scale=self.scale,
                      role="position"),
                State("v", "output/s", 0.0, "rate of the output", scale=self.scale * self.w_n,
                      role="velocity"))

    def apply(self, ctx: Context) -> None:
        w, z = ctx.p["w_n"], ctx.p["zeta"]
        x, v = ctx.x["x"], ctx.x["v"]
        ctx.add_rate("x", v)
        spring = x + ctx.p["k_cubic"] * x ** 3 if self.cubic else x
        ctx.add_rate("v", w * w * (ctx.signal("drive", self.name) - spring) - 2 * z * w * v)


@register_part
@dataclass(frozen=True)
class ResonatorSensor(Part):
    """The output is the position: ``y = x``."""

    name = "resonator_sensor"
    stage = "sensor"

    def apply(self, ctx: Context) -> None:
        ctx.signals["y"] = ctx.x["x"]


def make_model(data: Any = None, w_n: float | None = None, zeta: float = 0.05,
               gain: float = 1.0, cubic: bool = False) -> Model:
    """The resonator model, its nominal values from the record when one is given.

    Parameters
    ----------
    data : Dataset, optional
        A record: the nominal natural frequency is then the peak of the output's
        spectrum over the input's (a rough start the fit refines), unless ``w_n``
        is given.
    w_n : float, optional
        Nominal natural frequency [rad/s] (default: from ``data``, else 2 pi 10).
    zeta : float
        Nominal damping ratio [-].
    gain : float
        Nominal static gain [output unit per input unit].
    cubic : bool
        Add a cubic stiffening of the spring, ``w_n^2 (x + k_cubic x^3)`` (nominal 0,
        box ``+-16/scale^2`` with ``scale`` the output's range).

    Returns
    -------
    Model
    """
    if w_n is None:
        w_n = 2 * 3.141592653589793 * 10.0 if data is None else _peak_frequency(data)
    scale = 1.0
    if data is not None:
        import numpy as np

        scale = float(max(np.ptp(data.y), 1e-12))
    return Model([ResonatorDrive(gain=gain),
                  ResonatorMotion(w_n=w_n, zeta=zeta, scale=scale, cubic=cubic),
                  ResonatorSensor()], name="resonator")


def make_cubic_model(data: Any = None) -> Model:
    """:func:`make_model` with the cubic stiffening (a factory for ``--model``)."""
    return make_model(data, cubic=True)


def _peak_frequency(data: Any) -> float:
    """Angular frequency [rad/s] where the output's spectrum over the input's peaks."""
    import numpy as np
    from scipy import signal as sps

    n = min(1024, data.n)
    f, puy = sps.csd(data.u, data.y, fs=data.fs, nperseg=n)
    _, puu = sps.welch(data.u, fs=data.fs, nperseg=n)
    gain = np.abs(puy) / np.maximum(puu, 1e-300)
    ok = (f > 0) & (puu > 1e-3 * puu.max())
    return float(2 * np.pi * f[ok][np.argmax(gain[ok])])
