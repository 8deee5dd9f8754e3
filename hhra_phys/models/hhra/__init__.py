"""The helical hydraulic rotary actuator (HHRA): parts, model, physical view, rig.

``HHRAModel`` (:mod:`.model`) builds the actuator from its parts; ``PhysicalParameters``
(:mod:`.physical`) maps the paper's physical symbols to the identifiable groups the
model is written in; ``simulate_rig`` (:mod:`.rig`) makes records of a simulated
rig with known truth.
"""

from hhra_phys.data import Dataset
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


def _example_record() -> Dataset:
    """The simulated rig, seed 0 (imported only when asked for)."""
    from hhra_phys.models.hhra.rig import simulate_rig

    return simulate_rig(seed=0)


def _register() -> None:
    """Offer the HHRA as the default model (:mod:`hhra_phys.defaults`): a fit or diagnosis
    without a model fits it, records converted to its units (mA, deg), the simulated rig
    when no record is given."""
    from hhra_phys.defaults import DefaultModel, register_default
    from hhra_phys.models.hhra.defaults import default_model, prepare_record

    register_default(DefaultModel("HHRA", default_model, prepare_record, _example_record))


_register()

__all__ = [
    "HHRAModel", "HHRA_STAGES", "NOMINAL_GROUPS", "RAD2DEG", "AngleOutput", "ChamberPressure",
    "CurrentCommand", "LinearValve", "OrificeValve", "PressureOutput", "RotaryMotion",
    "SpoolLag", "group_parameter", "PhysicalParameters",
]
