"""An independent reference implementation of the HHRA, for tests and studies.

See :mod:`hhra_phys.reference.hhra`. Nothing here imports the package's model
code, so comparing the two checks the package's equations rather than
restating them.
"""

from hhra_phys.reference.hhra import (
    EFFECT_NAMES,
    REFERENCE_GROUPS,
    SOLVE_IVP_METHODS,
    RecordOptions,
    SolverOptions,
    reference_output,
    reference_record,
    reference_rhs,
    reference_state_names,
    simulate_reference,
    velocity_gain,
)

__all__ = [
    "EFFECT_NAMES",
    "REFERENCE_GROUPS",
    "SOLVE_IVP_METHODS",
    "RecordOptions",
    "SolverOptions",
    "reference_output",
    "reference_record",
    "reference_rhs",
    "reference_state_names",
    "simulate_reference",
    "velocity_gain",
]
