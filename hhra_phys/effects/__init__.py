"""Library of effects a physical model may lack, as model parts.

Each effect is a :class:`~hhra_phys.parts.Part` with named parameters (units,
bounds, fitting scale), a smooth formulation wherever derivatives are taken,
and a declared *signature*: the way it shows up in the residual of a model that
lacks it. :mod:`hhra_phys.diagnosis.residual` ranks effects by that signature and
:mod:`hhra_phys.diagnosis` adds, refits and scores them.

Library names (stable, read by outside checks)::

    coulomb_friction  valve_deadzone  valve_saturation  input_delay  valve_dynamics
    gravity_load      backlash        sensor_offset     asymmetric_valve
    sensor_drift      input_offset    constant_force

Each effect declares what it needs: roles (:attr:`Effect.binds`) and names
(:attr:`Effect.reads`, :attr:`Effect.writes`), and :meth:`Effect.applicable` checks
exactly that, so the loop skips an effect a model cannot take and says why (for a
missing role, which one and how to declare it). Input-side effects
(``valve_deadzone``, ``valve_saturation``, ``input_delay``, ``valve_dynamics``,
``input_offset``) act on the model's input ``ctx.u`` and output-side ``sensor_offset``
and ``sensor_drift`` (a sensor's, not the physics') on the output ``y``: they attach to
any model. ``coulomb_friction``, ``constant_force`` and ``gravity_load`` bind by role:
they act on the rate of the model's velocity (:attr:`hhra_phys.model.Model.motion`, the
state with role ``"velocity"`` or ``"angular_velocity"``: ``omega`` on the HHRA, ``v`` on
the cylinder or a user's drive) and ``gravity_load`` reads its angle (role ``"angle"``);
``backlash`` binds the velocity and the position, rotary or linear, seen by an output affine
in the position (its play in the output's unit), ``asymmetric_valve`` the ``"flow"`` and
``"command"`` signals of a valve model such as the HHRA (by name). A user's effect is
registered with :func:`hhra_phys.parts.register_effect`.

Scaling. Bounds of input-stage effects are relative to ``u_scale`` (typical input
magnitude, default 1 mA), of motion effects to ``accel_scale`` (the model's
``g_torque``, default the rig's; on another model the velocity's rate made by the full
input and the efforts, :func:`motion_scales`), of velocity widths to ``v_scale`` (the
velocity state's scale), of time constants to ``dt`` (sample period);
:func:`make_effect` sets them from a record, a fit and the model so the same library
works on the rig (mA, deg, 250 Hz), on a linear drive (V, m, m/s) and on records in raw
units and sample time.

First-order signature. :meth:`Effect.first_order` returns, for a probe size of
the effect, the change it makes at its entry point (``"input"``: the model's input,
the valve command; ``"rate:@velocity"``: the rate of the model's velocity state, the
angular acceleration ``rate:omega`` on the HHRA; ``"output"``: the output) given the
signals of a simulation without it. Propagated through the linearised model this
is the direction in which the effect moves the output, which the diagnosis
compares with the residual.

Modules, one concept each: :mod:`.motion` (friction, gravity load, constant force: the
velocity's rate), :mod:`.inputs` (dead zone, saturation, offset, delay and lag of the input;
the asymmetric valve), :mod:`.sensors` (backlash before the encoder, sensor offset and drift),
:mod:`.structure` (what the effects read from a model's symbolic form, and its motion's
scales), :mod:`.common` (shared scales and shapes) and :mod:`.library` (registration in the
library's order, names, aliases, :func:`make_effect`). Import from ``hhra_phys.effects``:
every name stays here. Importing this package registers the library (``import hhra_phys``
does).
"""

from __future__ import annotations

from hhra_phys.effects.common import RAD2DEG as RAD2DEG
from hhra_phys.effects.common import RIG_ACCEL
from hhra_phys.effects.inputs import CORNER_WIDTH
from hhra_phys.effects.inputs import AsymmetricValve as AsymmetricValve
from hhra_phys.effects.inputs import InputDelay as InputDelay
from hhra_phys.effects.inputs import InputOffset as InputOffset
from hhra_phys.effects.inputs import ValveDeadzone as ValveDeadzone
from hhra_phys.effects.inputs import ValveDynamics as ValveDynamics
from hhra_phys.effects.inputs import ValveSaturation as ValveSaturation
from hhra_phys.effects.library import (
    EFFECT_ALIASES,
    LIBRARY,
    effect_name,
    library_twins,
    make_effect,
)
from hhra_phys.effects.library import REMOVED_SETTINGS as REMOVED_SETTINGS
from hhra_phys.effects.motion import FRICTION_WIDTH, SIGN_PROFILES
from hhra_phys.effects.motion import ConstantForce as ConstantForce
from hhra_phys.effects.motion import CoulombFriction as CoulombFriction
from hhra_phys.effects.motion import GravityLoad as GravityLoad
from hhra_phys.effects.sensors import BACKLASH_SPEED as BACKLASH_SPEED
from hhra_phys.effects.sensors import BACKLASH_WIDTH
from hhra_phys.effects.sensors import Backlash as Backlash
from hhra_phys.effects.sensors import SensorDrift as SensorDrift
from hhra_phys.effects.sensors import SensorOffset as SensorOffset
from hhra_phys.effects.structure import motion_scales, output_offsets, output_slope
from hhra_phys.parts import EFFECTS, Effect, Signals, corner_relu, register_effect

__all__ = ["EFFECTS", "EFFECT_ALIASES", "LIBRARY", "Effect", "Signals", "effect_name",
           "make_effect", "motion_scales", "register_effect", "RIG_ACCEL",
           "FRICTION_WIDTH", "BACKLASH_WIDTH", "CORNER_WIDTH", "corner_relu", "library_twins",
           "output_offsets", "output_slope", "SIGN_PROFILES"]
