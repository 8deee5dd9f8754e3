"""Composable model parts.

A model in hhra-phys is an ordered list of :class:`Part` objects. Assembling the
model hands every part, in stage order, one symbolic :class:`Context`; each part
reads states, parameters, the input and named signals, and contributes

* time derivatives of states (``ctx.add_rate``),
* named signals for later parts (``ctx.signals``), such as the valve command or
  the flow, and
* the measured output (``ctx.signals["y"]``).

The stages run in the order of :data:`STAGES`::

    input   -> the valve command from the measured input (dead zone, saturation, delay, lag)
    valve   -> the flow into the chambers from the command and the load pressure
    flow    -> the pressure equation (piston displacement flow, leakage)
    motion  -> the angle/velocity equations (pressure torque, damping, friction, load)
    output  -> the measured output (angle in degrees, pressure, offsets, backlash)

Within a stage, parts run in the order they were added. This is what lets the
effect library (and users) add friction, dead zones, delays and so on to a model
without rewriting it: they are further parts.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import casadi as ca

from hhra_phys.errors import ModelError
from hhra_phys.parameters import Parameter

STAGES: tuple[str, ...] = ("input", "valve", "flow", "motion", "output")


@dataclass(frozen=True)
class State:
    """A continuous state of a model.

    Parameters
    ----------
    name : str
        Identifier (``theta``, ``omega``, ``p`` ...).
    unit : str
        Unit of the state.
    initial : float
        Default initial value at the start of a simulation.
    description : str
        What the state means.
    """

    name: str
    unit: str
    initial: float = 0.0
    description: str = ""


class Context:
    """Symbolic workspace shared by the parts while a model is assembled.

    Attributes
    ----------
    x : dict of str to casadi.SX
        State symbols by name.
    p : dict of str to casadi.SX
        Parameter symbols by name.
    u_lags : casadi.SX
        Input at the current sample and the previous ``n_lags`` samples
        (``u_lags[0]`` is the current input, zero-order hold over the sample).
    dt : float
        Sample period [s] (needed by discrete-time input parts such as a delay).
    signals : dict of str to casadi.SX
        Named intermediate expressions. The model convention is ``"command"``
        (valve command, input units), ``"flow"`` (flow term of the pressure
        equation) and ``"y"`` (measured output).
    """

    def __init__(
        self,
        x: dict[str, ca.SX],
        p: dict[str, ca.SX],
        u_lags: ca.SX,
        dt: float,
    ) -> None:
        self.x = x
        self.p = p
        self.u_lags = u_lags
        self.dt = dt
        self.signals: dict[str, ca.SX] = {}
        self.rates: dict[str, ca.SX] = {name: ca.SX(0) for name in x}

    @property
    def u(self) -> ca.SX:
        """The input at the current sample."""
        return self.u_lags[0]

    def add_rate(self, state: str, expr: ca.SX) -> None:
        """Add ``expr`` to the time derivative of ``state``."""
        if state not in self.rates:
            raise ModelError(
                f"a part adds to the derivative of unknown state {state!r}; "
                f"states are {', '.join(self.rates)}"
            )
        self.rates[state] = self.rates[state] + expr

    def signal(self, name: str, part: str = "") -> ca.SX:
        """Return signal ``name`` or raise a clear error naming the part that needs it."""
        if name not in self.signals:
            who = f"part {part!r} " if part else ""
            raise ModelError(
                f"{who}needs signal {name!r}, which no earlier part provides "
                f"(available: {', '.join(self.signals) or 'none'})"
            )
        return self.signals[name]


@dataclass(frozen=True)
class Part:
    """Base class of model parts.

    Subclasses set :attr:`stage`, may declare :attr:`parameters`, :attr:`states`
    and :attr:`n_lags` (how many past input samples they need), and implement
    :meth:`apply`.
    """

    #: Stage the part runs in (one of :data:`STAGES`).
    stage: ClassVar[str] = "motion"
    #: Short name used in reports; effects use their library name.
    name: ClassVar[str] = "part"

    @property
    def parameters(self) -> Sequence[Parameter]:
        """Parameters this part adds to the model."""
        return ()

    @property
    def states(self) -> Sequence[State]:
        """States this part adds to the model."""
        return ()

    @property
    def n_lags(self) -> int:
        """Number of past input samples the part needs (0: only the current one)."""
        return 0

    def apply(self, ctx: Context) -> None:  # pragma: no cover - abstract
        """Contribute rates and signals to ``ctx``."""
        raise NotImplementedError


# --- smooth helpers --------------------------------------------------------


def smooth_sign(v: ca.SX, eps: float) -> ca.SX:
    """Smooth sign ``v / sqrt(v^2 + eps^2)``: exact far from 0, differentiable at 0.

    ``eps`` has the unit of ``v``; the transition width is about ``2*eps``.
    """
    return v / ca.sqrt(v * v + eps * eps)


def smooth_signed_sqrt(z: ca.SX, delta: float) -> ca.SX:
    """Smooth ``sign(z)*sqrt(|z|)``, normalised to be exact at ``z = 1``.

    ``z / (z^2 + delta^2)^(1/4) * (1 + delta^2)^(1/4)``: the slope at 0 is
    finite (``(1+delta^2)^(1/4)/sqrt(delta)``), which bounds the stiffness of the
    orifice equation near the supply pressure, and the value at the rest
    operating point ``z = 1`` is exact, so the linearisation at rest equals the
    paper's linearised valve. Two square roots are used instead of ``pow``
    because they are several times cheaper in compiled code.
    """
    return z / ca.sqrt(ca.sqrt(z * z + delta * delta)) * math.sqrt(math.sqrt(1 + delta * delta))


def smooth_abs(v: ca.SX, eps: float) -> ca.SX:
    """Smooth ``|v|`` as ``sqrt(v^2 + eps^2) - eps`` (exact at 0, error below ``eps``)."""
    return ca.sqrt(v * v + eps * eps) - eps


def smooth_relu(v: ca.SX, eps: float) -> ca.SX:
    """Smooth ``max(v, 0)`` as ``(v + sqrt(v^2 + eps^2)) / 2``."""
    return 0.5 * (v + ca.sqrt(v * v + eps * eps))
