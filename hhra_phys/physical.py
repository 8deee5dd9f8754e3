"""The HHRA's physical parameters: moved to :mod:`hhra_phys.models.hhra.physical`.

This module keeps ``from hhra_phys.physical import PhysicalParameters`` working.
"""

from hhra_phys.models.hhra.physical import *  # noqa: F403
