"""Settings objects: a frozen dataclass of a function's settings, overridden by keyword.

:class:`~hhra_phys.fit.FitOptions` and :class:`~hhra_phys.diagnosis.options.LoopOptions` are such
objects; each function takes one (``options=``) and keyword overrides of its fields, and
:func:`with_overrides` applies them the same way for both.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import fields, replace
from typing import Any, TypeVar

from hhra_phys.errors import ParameterError

__all__ = ["MAX_ITERATIONS", "MAX_POPULATION", "with_overrides"]

#: The largest population a global search takes (``pop_size``, ``--pop``): a hundred
#: times the paper's 100. Beyond it the searches' arrays stop fitting in memory (1e9
#: members of 6 parameters are 45 GiB; the leaders' distinctness check compares members
#: pairwise, 56 GiB at 1e5), and no study here needs more.
MAX_POPULATION = 10_000

#: The most iterations a global search takes (``max_iter``, ``--iters``): five thousand
#: times the paper's 200, about 14 h for a population of 4 on the rig's 5000 samples.
MAX_ITERATIONS = 1_000_000

T = TypeVar("T")


def with_overrides(options: T, overrides: dict[str, Any], what: str,
                   sequences: Iterable[str] = ()) -> T:
    """``options`` (a frozen dataclass) with ``overrides`` applied; not yet validated.

    Parameters
    ----------
    options : dataclass instance
        The settings to start from.
    overrides : dict
        ``{field: value}``; sequences named in ``sequences`` are stored as tuples (the
        object stays hashable and cannot change under its owner).
    what : str
        Whose settings they are, for the message (``"fit"``, ``"loop"``).
    sequences : iterable of str
        Fields that hold sequences.

    Raises
    ------
    ParameterError
        An override that is not a field, naming it and the fields there are.
    """
    names = {f.name for f in fields(options)}  # type: ignore[arg-type]
    bad = sorted(set(overrides) - names)
    if bad:
        raise ParameterError(f"unknown {what} setting(s) {', '.join(bad)}; settings: "
                             f"{', '.join(sorted(names))}")
    overrides = dict(overrides)
    for key in sequences:
        value = overrides.get(key)
        if value is not None and not isinstance(value, (str, tuple)):
            overrides[key] = tuple(value)
    return replace(options, **overrides)  # type: ignore[type-var]
