"""One exception hierarchy for hhra-phys.

Every error a user can provoke with bad input derives from :class:`HHRAError`,
so ``except HHRAError`` catches all of them, while each subclass also derives
from the closest built-in (``ValueError``, ``FileNotFoundError``, ``KeyError``)
so generic handlers keep working.
"""

from __future__ import annotations

__all__ = [
    "HHRAError",
    "DataError",
    "ParameterError",
    "ModelError",
    "SimulationError",
    "OutputPathError",
    "OutputExistsError",
]


class HHRAError(Exception):
    """Base class of all errors raised by hhra-phys for bad input or state."""


class DataError(HHRAError, ValueError):
    """A dataset, a data file or a signal is unusable; the message says where and why."""


class ParameterError(HHRAError, ValueError):
    """A parameter name, value, vector shape or bound is invalid."""


class ModelError(HHRAError, ValueError):
    """A model is inconsistent (unknown part, duplicated state, missing output ...)."""


class SimulationError(HHRAError, RuntimeError):
    """A simulation could not be set up (not raised for diverging population members)."""


class OutputPathError(ParameterError):
    """An output file cannot be written: bad folder, directory, suffix (see ``outputs``).

    A :class:`ParameterError` because the path is an argument the caller chose; raised
    before any work is done.
    """


class OutputExistsError(OutputPathError, FileExistsError):
    """An output file exists and replacing it was not allowed (pass ``overwrite=True``)."""
