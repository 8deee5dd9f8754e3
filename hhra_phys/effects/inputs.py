"""Effects on the input side: dead zone, saturation, offset, delay, lag, asymmetric valve.

They act on the model's input ``ctx.u`` (the valve command on the HHRA; a pump voltage or a
DAC command elsewhere), so they attach to any model: :class:`ValveDeadzone`,
:class:`ValveSaturation` (smooth corners of ``width*u_scale``), :class:`InputOffset`,
:class:`InputDelay` (fractional, in samples), :class:`ValveDynamics` (a first-order lag).
:class:`AsymmetricValve` runs in the ``valve`` stage on a valve model's ``"flow"`` signal but
enters, as they do, at the input. Bounds scale with the typical input ``u_scale`` and the
sample period ``dt``. They are registered as library effects by
:mod:`hhra_phys.effects.library`, in the library's order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from hhra_phys.errors import ParameterError
from hhra_phys.parameters import Parameter
from hhra_phys.parts import Context, Effect, Signals, State, corner_relu, smooth_sign

__all__ = ["CORNER_WIDTH", "AsymmetricValve", "InputDelay", "InputOffset", "ValveDeadzone",
           "ValveDynamics", "ValveSaturation"]


#: Default corner width of the dead zone and the saturation, relative to ``u_scale``.
CORNER_WIDTH = 0.01


class _InputCorner:
    """Corner width of an input-stage switch: ``width*u_scale``."""

    u_scale: float
    width: float

    def _check(self) -> None:
        for key in ("u_scale", "width"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"{self.name} {key} must be > 0, got {v!r}")  # type: ignore[attr-defined]

    def _relu(self, v: Any) -> Any:
        return corner_relu(v, self.width * self.u_scale)


@dataclass(frozen=True)
class ValveDeadzone(_InputCorner, Effect):
    """No flow for ``|command| < i_dead``: ``c -> relu(c - d) - relu(-c - d)``.

    ``relu`` is :func:`corner_relu`: exact beyond ``width*u_scale`` of the edges,
    a quadratic (C1) corner within.

    Parameters
    ----------
    u_scale : float
        Typical input magnitude (input units; 1 mA on the rig); sets the bounds.
    width : float
        Half width of the corners relative to ``u_scale`` (default
        :data:`CORNER_WIDTH`, 0.01).
    """

    u_scale: float = 1.0
    width: float = CORNER_WIDTH
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "valve_deadzone"
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "residual grows during small inputs (no motion where the model moves) and the "
        "apparent gain depends on the input level"
    )
    regressors: ClassVar[tuple[str, ...]] = ("small_input", "input_level")

    def __post_init__(self) -> None:
        self._check()

    @property
    def parameters(self) -> Sequence[Parameter]:
        s = self.u_scale
        return (Parameter("i_dead", "input", 0.05 * s, 1e-3 * s, 0.9 * s, "log",
                          "half width of the valve dead zone"),)

    def apply(self, ctx: Context) -> None:
        c = ctx.u
        d = ctx.p["i_dead"]
        ctx.u = self._relu(c - d) - self._relu(-c - d)

    def first_order(self, sig: Signals) -> np.ndarray:
        d = self.probe()["i_dead"]
        return -np.clip(sig.u, -d, d)[:, None]


@dataclass(frozen=True)
class ValveSaturation(_InputCorner, Effect):
    """Spool or current limit: ``c -> clip(c, -i_sat, i_sat)``.

    Written ``c - relu(c - s) + relu(-c - s)`` with :func:`corner_relu`: exact
    beyond ``width*u_scale`` of the limits. Parameters as :class:`ValveDeadzone`.
    """

    u_scale: float = 1.0
    width: float = CORNER_WIDTH
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "valve_saturation"
    twin: ClassVar[tuple[str, ...]] = ("sat(u)",)
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "the apparent gain falls at the largest inputs (the residual follows the input "
        "level at its extremes only)"
    )
    regressors: ClassVar[tuple[str, ...]] = ("input_level",)

    def __post_init__(self) -> None:
        self._check()

    @property
    def parameters(self) -> Sequence[Parameter]:
        s = self.u_scale
        return (Parameter("i_sat", "input", 0.8 * s, 0.05 * s, 3.0 * s, "log",
                          "largest effective valve command"),)

    def apply(self, ctx: Context) -> None:
        c = ctx.u
        s = ctx.p["i_sat"]
        ctx.u = c - self._relu(c - s) + self._relu(-c - s)

    def first_order(self, sig: Signals) -> np.ndarray:
        s = 0.8 * float(np.max(np.abs(sig.u)))
        return (np.clip(sig.u, -s, s) - sig.u)[:, None]


@dataclass(frozen=True)
class InputOffset(Effect):
    """A constant bias of the input: ``u -> u + u_offset`` (input units).

    A servo valve's null bias (the spool passes flow at zero current), a motor driver's
    command offset, a pump's zero. It acts on the model's input, so it attaches to any
    model; under an integrating output it leaves a trend in the output, which is physics
    before it is a sensor's drift.

    Parameters
    ----------
    u_scale : float
        Typical input magnitude (input units; 1 mA on the rig): the bounds are
        ``+-0.5*u_scale``, the probe ``0.05*u_scale``.
    """

    u_scale: float = 1.0
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "input_offset"
    twin: ClassVar[tuple[str, ...]] = ("one()",)
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "the model is driven by a constant input it does not see: a trend (integrating "
        "output) or an offset that follows the input's gain"
    )
    regressors: ClassVar[tuple[str, ...]] = ("time",)

    def __post_init__(self) -> None:
        if not (isinstance(self.u_scale, (int, float)) and math.isfinite(self.u_scale)
                and self.u_scale > 0):
            raise ParameterError(f"input_offset u_scale must be > 0, got {self.u_scale!r}")

    @property
    def parameters(self) -> Sequence[Parameter]:
        s = 0.5 * self.u_scale
        return (Parameter("u_offset", "input", 0.0, -s, s, "linear",
                          "constant bias of the input (valve null bias, command offset)"),)

    def apply(self, ctx: Context) -> None:
        ctx.u = ctx.u + ctx.p["u_offset"]

    def probe(self) -> dict[str, float]:
        return {"u_offset": 0.05 * self.u_scale}

    def first_order(self, sig: Signals) -> np.ndarray:
        return np.full((sig.u.size, 1), 0.05 * self.u_scale)


@dataclass(frozen=True)
class InputDelay(Effect):
    """Transport delay of the command, fractional, in samples.

    ``command(t) = u(t - delay*dt)`` with the held input samples interpolated
    linearly between neighbouring lags (``u_lags``): for ``delay = k + f`` the
    command is ``(1-f)*u[n-k] + f*u[n-k-1]``. The weights are the hat functions
    ``max(0, 1 - |delay - k|)``: continuous in ``delay``, with kinks at integers.

    Parameters
    ----------
    max_delay : int
        Upper bound of the delay's box [samples]. The part holds twice as many lags
        (``n_lags = 2*max_delay + 1``), so a box widened at its edge (the loop's, a
        fit's) can reach a delay up to ``2*max_delay + 1``; within the box the extra lags
        weigh exactly zero (issue 33: with ``n_lags = max_delay + 1`` a 10-sample delay
        ended at 9.00 and a stand-in made up the rest).
    """

    max_delay: int = 8
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "input_delay"
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "the measured response lags the simulated one: the cross-correlation of measured "
        "and simulated output changes peaks at a positive lag; residual follows the "
        "input's changes"
    )
    regressors: ClassVar[tuple[str, ...]] = ("input_change",)

    def __post_init__(self) -> None:
        if int(self.max_delay) != self.max_delay or self.max_delay < 1:
            raise ParameterError(f"max_delay must be a positive integer, got {self.max_delay}")

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (Parameter("delay", "samples", 1.0, 0.0, float(self.max_delay), "linear",
                          "transport delay of the valve command"),)

    @property
    def n_lags(self) -> int:
        return 2 * int(self.max_delay) + 1

    def apply(self, ctx: Context) -> None:
        d = ctx.p["delay"]
        out = ca.SX(0)
        for k in range(self.n_lags + 1):
            out = out + ca.fmax(0, 1 - ca.fabs(d - k)) * ctx.u_lags[k]
        # The delay acts on the measured input, wherever it sits among the input-side
        # effects: earlier ones (dead zone, saturation, lag) see the delayed input,
        # so substitute it for the current input in what they built.
        u0 = ctx.u_lags[0]
        ctx.u = ca.substitute(ctx.u, u0, out)
        for key, expr in ctx.signals.items():
            ctx.signals[key] = ca.substitute(expr, u0, out)
        for key, expr in ctx.rates.items():
            ctx.rates[key] = ca.substitute(expr, u0, out)

    def first_order(self, sig: Signals) -> np.ndarray:
        u = sig.u
        return (np.concatenate([u[:1], u[:-1]]) - u)[:, None]


@dataclass(frozen=True)
class ValveDynamics(Effect):
    """First-order lag of the valve spool: ``tau_spool * dx_spool/dt = command - x_spool``.

    Parameters
    ----------
    dt : float
        Sample period [s]; the bounds are ``0.3*dt .. 50*dt`` (faster lags are
        invisible at this sampling and too stiff for the integrator).
    """

    dt: float = 0.004
    stage: ClassVar[str] = "input"
    name: ClassVar[str] = "valve_dynamics"
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "the response to each input step starts late and rounded; high-frequency residual "
        "after input changes (an integrating output hides it)"
    )
    regressors: ClassVar[tuple[str, ...]] = ("input_change",)

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (Parameter("tau_spool", "s", 2.5 * self.dt, 0.3 * self.dt, 50 * self.dt, "log",
                          "valve spool time constant"),)

    @property
    def states(self) -> Sequence[State]:
        return (State("x_spool", "input", 0.0, "spool position in input units",
                      fit_initial=False),)

    def apply(self, ctx: Context) -> None:
        ctx.add_rate("x_spool", (ctx.u - ctx.x["x_spool"]) / ctx.p["tau_spool"])
        ctx.u = ctx.x["x_spool"]

    def first_order(self, sig: Signals) -> np.ndarray:
        tau = self.probe()["tau_spool"]
        a = math.exp(-sig.dt / tau)
        # The spool at sample k has seen the held inputs up to k-1 (zero-order hold),
        # starting at rest on u[0].
        b, den = [0.0, 1 - a], [1.0, -a]
        from scipy import signal as sps  # here, not at import: most of `import hhra_phys`

        lagged = sps.lfilter(b, den, sig.u, zi=sps.lfilter_zi(b, den) * sig.u[0])[0]
        return (lagged - sig.u)[:, None]


# --- valve stage --------------------------------------------------------------------


@dataclass(frozen=True)
class AsymmetricValve(Effect):
    """Different flow gains for the two directions: ``flow *= 1 + asym*sgn(command)``.

    ``asym`` [-] is half the relative difference of the gains (+0.1: 10 % more flow
    for a positive command, 10 % less for a negative one). Runs in the ``valve``
    stage after the valve part, on its ``"flow"`` signal.
    """

    u_scale: float = 1.0
    eps: float = 0.01
    stage: ClassVar[str] = "valve"
    name: ClassVar[str] = "asymmetric_valve"
    reads: ClassVar[tuple[str, ...]] = ("command", "flow")
    writes: ClassVar[tuple[str, ...]] = ("flow",)
    entry: ClassVar[str] = "input"
    signature: ClassVar[str] = (
        "residual drifts in proportion to the integral of |input| (time-growing drift "
        "whatever the direction)"
    )
    regressors: ClassVar[tuple[str, ...]] = ("time", "abs_input")

    @property
    def parameters(self) -> Sequence[Parameter]:
        return (Parameter("asym", "-", 0.0, -0.8, 0.8, "linear",
                          "relative flow-gain difference between directions (half)"),)

    def apply(self, ctx: Context) -> None:
        c = ctx.signal("command", self.name)
        flow = ctx.signal("flow", self.name)
        ctx.signals["flow"] = flow * (1 + ctx.p["asym"] * smooth_sign(c, self.eps * self.u_scale))

    def probe(self) -> dict[str, float]:
        return {"asym": 0.05}

    def first_order(self, sig: Signals) -> np.ndarray:
        return 0.05 * np.abs(sig.u)[:, None]
