"""The helical hydraulic rotary actuator (HHRA): parts, model, physical view, rig.

``HHRAModel`` (:mod:`.model`) builds the actuator from its parts; ``PhysicalParameters``
(:mod:`.physical`) maps the paper's physical symbols to the identifiable groups the
model is written in; ``simulate_rig`` (:mod:`.rig`) makes records of a simulated
rig with known truth.
"""

from hhra_phys.models.hhra.model import (
    HHRA_STAGES,
    NOMINAL_GROUPS,
    RAD2DEG,
    AngleOutput,
    ChamberPressure,
    CurrentCommand,
    HHRAModel,
    LinearValve,
    OrificeValve,
    PressureOutput,
    RotaryMotion,
    SpoolLag,
    group_parameter,
)
from hhra_phys.models.hhra.physical import PhysicalParameters

__all__ = [
    "HHRAModel", "HHRA_STAGES", "NOMINAL_GROUPS", "RAD2DEG", "AngleOutput", "ChamberPressure",
    "CurrentCommand", "LinearValve", "OrificeValve", "PressureOutput", "RotaryMotion",
    "SpoolLag", "group_parameter", "PhysicalParameters",
]
