"""Plain JSON types for the comparison's settings, results and report files.

Its own module because the method contract (:mod:`.registry`), the results (:mod:`.runner`)
and the report files (:mod:`.report`) all need it, and :mod:`.report` imports the registry.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np


def jsonable(obj: Any) -> Any:
    """Plain Python types; non-finite floats become None (JSON null)."""
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, bool | np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, complex | np.complexfloating):
        return [jsonable(obj.real), jsonable(obj.imag)]
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)
