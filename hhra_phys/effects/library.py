"""The library: its effects registered in order, their names and aliases, and their construction.

The effect classes live by physical role (:mod:`.motion`, :mod:`.inputs`, :mod:`.sensors`);
this module registers them as candidates of the diagnosis loop (:data:`EFFECTS`) in the
library's order, which is the loop's order where scores tie and must not change, and holds
what works on the registry: :data:`LIBRARY`, the generic names :data:`EFFECT_ALIASES`
(:func:`effect_name`), :func:`library_twins` (the library effect a discovered term is) and
:func:`make_effect`, which builds an effect scaled to a record, a fit and a model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hhra_phys.effects.inputs import (
    AsymmetricValve,
    InputDelay,
    InputOffset,
    ValveDeadzone,
    ValveDynamics,
    ValveSaturation,
)
from hhra_phys.effects.motion import FRICTION_WIDTH, ConstantForce, CoulombFriction, GravityLoad
from hhra_phys.effects.sensors import Backlash, SensorDrift, SensorOffset
from hhra_phys.effects.structure import motion_scales
from hhra_phys.errors import ModelError
from hhra_phys.parts import EFFECTS, Effect, register_effect

__all__ = ["EFFECT_ALIASES", "LIBRARY", "REMOVED_SETTINGS", "effect_name", "library_twins",
           "make_effect"]

# The library's order (each effect class is registered here, not where it is defined, so
# that the order is written in one place).
register_effect(CoulombFriction)
register_effect(GravityLoad)
register_effect(ValveDeadzone)
register_effect(ValveSaturation)
register_effect(InputDelay)
register_effect(ValveDynamics)
register_effect(AsymmetricValve)
register_effect(Backlash)
register_effect(SensorOffset)
register_effect(SensorDrift)
# The offsets, physics first, registered after the earlier library so that the order of
# the earlier candidates (the loop's order where scores tie) stays as it was.
register_effect(InputOffset)
register_effect(ConstantForce)

#: Names of the library's own effects (:data:`EFFECTS` also holds a user's registered ones).
LIBRARY: tuple[str, ...] = tuple(EFFECTS)

#: Generic names of the input effects, for any model's input (a pump voltage, a DAC
#: command), beside the valve names the HHRA keeps: the same parts, not new candidates.
EFFECT_ALIASES: dict[str, str] = {
    "input_deadzone": "valve_deadzone",
    "input_saturation": "valve_saturation",
    "input_lag": "valve_dynamics",
}


def effect_name(name: str) -> str:
    """The registered name of an effect given by its name or a generic alias
    (:data:`EFFECT_ALIASES`); a registered effect of the alias's name wins."""
    return name if name in EFFECTS else EFFECT_ALIASES.get(name, name)


def library_twins(entry: str, terms: Sequence[str], model: Any) -> list[str]:
    """Library effects whose own shape a discovered term holds at the same entry.

    A discovered term at ``entry`` whose pieces include an effect's :attr:`~hhra_phys.
    parts.Effect.twin` (``d v/dt += -0.3*sgn(v)`` at the velocity's rate: Coulomb
    friction; a constant at the input: an input offset) is that physics in its
    discovered form, whatever else it holds. The report and the diagnose JSON name it
    so (``steps[].same_as``): a reader sees the friction, not "a term outside the
    library". Roles resolve on ``model`` (:attr:`~hhra_phys.model.Model.motion`); an
    effect whose role the model lacks is no twin. Registered user effects that declare
    their own ``twin`` count as well (one inherited from a library class does not). It
    decides nothing.

    Parameters
    ----------
    entry : str
        The discovered term's entry (``"input"``, ``"output"``, ``"rate:<state>"``).
    terms : sequence of str
        Its pieces (:attr:`~hhra_phys.terms.DiscoveredTerm.terms`, e.g. ``"sign(v)"``).
    model : Model
        The model it was discovered on.

    Returns
    -------
    list of str
        Library effect names, in library order (empty: none).
    """
    motion = model.motion
    roles = {"@velocity": motion.velocity, "@position": motion.position,
             "@angle": motion.position if motion.rotary else None}
    have = set(terms)
    out = []
    for name, cls in EFFECTS.items():
        # Each effect's own declaration: a user's subclass of the friction is not named
        # the friction unless it says so.
        if not cls.__dict__.get("twin") or cls.entry_at(model) != entry:
            continue
        for piece in cls.twin:
            for role, state in roles.items():
                if role in piece:
                    piece = piece.replace(role, state or "\0")
            if piece in have:
                out.append(name)
                break
    return out


#: Smoothing settings of earlier versions, removed, with what replaces them.
REMOVED_SETTINGS: dict[str, str] = {
    "eps": "the smoothing tied to the sample period; set the physical 'width' instead "
           "(or fit_width=True where the effect offers it)",
    "eps_omega": "the soft backlash contact; set the contact 'width' [deg] instead "
                 "(or fit_width=True)",
}


# --- construction -------------------------------------------------------------------


def _model_scales(model: Any, values: Mapping[str, float] | None,
                  u_scale: float) -> dict[str, Any]:
    """:func:`make_effect`'s settings from the model: its motion's scales and units."""
    if "g_torque" in model.params.names:
        return {}  # the HHRA: g_torque (or the rig's) and the rig's units, as before roles
    out = motion_scales(model, values, u_scale)
    if "v_scale" in out:  # the friction's switching width (CoulombFriction.scaled_fields)
        out["friction_width"] = FRICTION_WIDTH * out["v_scale"]
    return out


def make_effect(
    name: str,
    *,
    data: Any | None = None,
    values: Mapping[str, float] | None = None,
    model: Any | None = None,
    **kw: Any,
) -> Effect:
    """Build library effect ``name``, scaled to a record and a fit.

    Parameters
    ----------
    name : str
        Library name (see :data:`EFFECTS`).
    data : Dataset, optional
        Record the effect will be fitted to: sets ``u_scale`` (largest
        ``|input|``), ``dt`` (sample period) and ``y_scale`` (output st. dev.).
    values : dict, optional
        Fitted values of the model it is added to: ``g_torque`` sets ``accel_scale``.
    model : Model, optional
        The model it is added to: where ``values`` has no ``g_torque`` (any model but
        the HHRA), :func:`motion_scales` sets ``accel_scale``, and the velocity state
        sets ``v_scale``, ``v_unit`` and the friction's ``width``
        (:data:`FRICTION_WIDTH` times ``v_scale``), so that the motion effects work in
        the model's own units (a linear drive in m, m/s); each class takes what it needs
        (:meth:`~hhra_phys.parts.Effect.scaled_fields`).
    **kw
        Fields of the effect class (explicit ones win).

    Raises
    ------
    ModelError
        Unknown name or field.
    """
    cls = EFFECTS.get(effect_name(name))
    if cls is None:
        raise ModelError(f"unknown effect {name!r}; library: {', '.join(sorted(EFFECTS))} "
                         f"(generic names: {', '.join(EFFECT_ALIASES)})")
    fields = set(cls.__dataclass_fields__)
    auto: dict[str, Any] = {}
    if data is not None:
        auto["u_scale"] = float(np.max(np.abs(data.u))) or 1.0
        auto["dt"] = float(data.dt)
        auto["y_scale"] = float(np.std(data.y)) or 1.0
        if getattr(data, "output_unit", ""):
            auto["y_unit"] = data.output_unit
    if model is not None:
        auto.update(_model_scales(model, values, auto.get("u_scale", 1.0)))
    if values and values.get("g_torque", 0) > 0:
        auto["accel_scale"] = float(values["g_torque"])
    args = cls.scaled_fields(auto, model)
    removed = sorted(set(kw) & set(REMOVED_SETTINGS) - fields)
    if removed:
        raise ModelError(f"effect {name!r}: " + "; ".join(
            f"{k} was removed ({REMOVED_SETTINGS[k]})" for k in removed))
    unknown = set(kw) - fields
    if unknown:
        raise ModelError(
            f"effect {name!r} has no field(s) {sorted(unknown)}; fields: {sorted(fields)}"
        )
    args.update(kw)
    return cls(**args)
