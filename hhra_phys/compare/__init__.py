"""The identification comparison of the paper's Table 3; the code is in :mod:`.runner`."""

from __future__ import annotations

from hhra_phys.compare.runner import *  # noqa: F403
from hhra_phys.compare.runner import MethodFn, __all__, _fmt  # noqa: F401
