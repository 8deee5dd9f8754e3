"""The HHRA's simulated rig: moved to :mod:`hhra_phys.models.hhra.rig`.

This module keeps ``from hhra_phys.rig import simulate_rig`` (and the other names)
working.
"""

from hhra_phys.models.hhra.rig import *  # noqa: F403
