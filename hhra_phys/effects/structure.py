"""What the library reads from a model's symbolic form, whatever its parts are named.

The effects decide whether a model can take them from its assembled equations, not from
part names: :func:`output_slope` (is the output the angle in degrees? the backlash),
:func:`output_offsets` (does the output already have a free offset? the sensor offset),
the free constants at the velocity's rate (the constant force), and :func:`motion_scales`,
the typical acceleration and velocity of the model's motion that scale the motion effects'
bounds. Separate from the effects themselves because each family uses some of them and
:func:`~hhra_phys.effects.library.make_effect` the scales.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import casadi as ca

__all__ = ["motion_scales", "output_offsets", "output_slope"]


def output_slope(model: Any, state: str) -> float | None:
    """``dy/d state`` if the output is affine in ``state`` with a constant slope, else None.

    Read from the model's symbolic output, not from part names (so any model
    whose output is, say, the angle in degrees is recognised).
    """
    if state not in model.state_names:
        return None
    x, u, p = model.symbols()
    _, y = model.assemble(x, u, p, 0.004)
    d = ca.jacobian(y, x[model.state_names.index(state)])
    if not d.is_constant():
        return None
    return float(ca.DM(ca.evalf(d)))


def _rate_constants(model: Any) -> list[str]:
    """Free parameters that add a constant to the velocity's rate by themselves: a
    constant slope there, absent from every other rate and from the output."""
    v = model.motion.velocity
    if v is None:
        return []
    x, u, p = model.symbols()
    xdot, y = model.assemble(x, u, p, 0.004)
    iv = model.state_names.index(v)
    dx = ca.jacobian(xdot, p)
    dy = ca.jacobian(y, p)
    out = []
    for i, name in enumerate(model.params.names):
        if name in model.held:
            continue
        di = dx[iv, i]
        others = [dx[k, i] for k in range(model.nx) if k != iv]
        if (di.is_constant() and float(ca.evalf(di)) != 0.0 and dy[0, i].nnz() == 0
                and all(o.nnz() == 0 for o in others)):
            out.append(name)
    return out


def motion_scales(model: Any, values: Mapping[str, float] | None = None,
                  u_scale: float = 1.0) -> dict[str, Any]:
    """Scales of the model's motion for the library's motion effects.

    Parameters
    ----------
    model : Model
        A model with a velocity (:attr:`~hhra_phys.model.Model.motion`).
    values : mapping, optional
        Parameter values by name (a fit's); the nominal values elsewhere.
    u_scale : float
        Typical input magnitude (input units).

    Returns
    -------
    dict
        ``accel_scale``: typical acceleration [velocity unit/s], the change of the
        velocity's rate made by ``u_scale`` at the input and by every state with role
        ``"effort"`` at its :attr:`~hhra_phys.parts.State.scale` (the model linearised at
        rest; by the other states' scales if those give none); ``v_scale`` (the velocity
        state's scale) and ``v_unit`` (its unit). Empty for a model without a velocity.
    """
    v = model.motion.velocity
    if v is None:
        return {}
    st = model.states[model.state_names.index(v)]
    out: dict[str, Any] = {"v_scale": float(st.scale), "v_unit": st.unit or "1/s"}
    P = model.nominal()
    for i, name in enumerate(model.params.names):
        if values and name in values:
            P[i] = float(values[name])
    try:
        A, B, _, _ = model.linearize(p=P)
    except Exception:  # noqa: BLE001 - no scale rather than no effect
        return out
    iv = model.state_names.index(v)
    scales = [s.scale for s in model.states]
    effort = [k for k, s in enumerate(model.states) if s.role == "effort"]
    a = abs(float(B[iv, 0])) * u_scale + sum(abs(float(A[iv, k])) * scales[k] for k in effort)
    if not (math.isfinite(a) and a > 0):
        a = max((abs(float(A[iv, k])) * scales[k] for k in range(model.nx) if k != iv),
                default=0.0)
    if math.isfinite(a) and a > 0:
        out["accel_scale"] = a
    return out


def output_offsets(model: Any) -> list[str]:
    """Parameters that shift the output by themselves: ``dy/dq == 1`` and absent from ``f``."""
    x, u, p = model.symbols()
    xdot, y = model.assemble(x, u, p, 0.004)
    dy = ca.jacobian(y, p)
    dx = ca.jacobian(xdot, p)
    out = []
    for i, name in enumerate(model.params.names):
        di = dy[0, i]
        if di.is_constant() and float(ca.evalf(di)) == 1.0 and dx[:, i].nnz() == 0:
            out.append(name)
    return out
