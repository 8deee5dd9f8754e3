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

    ``sign(z) * (sqrt(|z| + delta) - sqrt(delta)) / (sqrt(1 + delta) - sqrt(delta))``.
    It is continuously differentiable, with the finite slope
    ``1/(2 sqrt(delta))`` (over the normaliser) at ``z = 0``, which bounds the
    stiffness of the orifice equation at the supply pressure; its value at the
    rest operating point ``z = 1`` is exact, so the linearisation at rest equals
    the paper's linearised valve. For ``delta = 1e-6`` it is within 0.1 % of
    ``sqrt(z)`` for ``z >= 0.25`` and within 1 % for ``z >= 0.01``. One square
    root and no division: the valve law dominates the cost of a simulation and
    square roots and divisions are its slow operations.
    """
    norm = 1.0 / (math.sqrt(1.0 + delta) - math.sqrt(delta))
    mag = (ca.sqrt(ca.fabs(z) + delta) - math.sqrt(delta)) * norm
    return ca.sign(z) * mag


def smooth_abs(v: ca.SX, eps: float) -> ca.SX:
    """Smooth ``|v|`` as ``sqrt(v^2 + eps^2) - eps`` (exact at 0, error below ``eps``)."""
    return ca.sqrt(v * v + eps * eps) - eps


def smooth_relu(v: ca.SX, eps: float) -> ca.SX:
    """Smooth ``max(v, 0)`` as ``(v + sqrt(v^2 + eps^2)) / 2``."""
    return 0.5 * (v + ca.sqrt(v * v + eps * eps))
