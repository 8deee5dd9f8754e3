"""The default model: what :func:`hhra_phys.fit` and :func:`hhra_phys.diagnose` use when the
caller gives no model (or no record), registered by a model package.

The core (problem, fit, diagnosis) knows no particular model. A model package may offer
itself as the default by :func:`register_default`: a function giving the model and its
boxes for a record, optionally the conversion of a record to the model's units (with
warnings about implausible ranges) and an example record for a call without data. The
HHRA package (:mod:`hhra_phys.models.hhra`) registers the HHRA when it is imported, which
``import hhra_phys`` does, so ``hhra_phys.fit(record)`` fits the HHRA as it always has;
without a registered default, leaving out the model is an error that says to pass one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hhra_phys.data import Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.model import Model

__all__ = ["DefaultModel", "register_default", "default_for", "registered_default"]

#: ``(model, {name: (lower, upper)})`` for a record.
ModelFor = Callable[..., tuple[Model, dict[str, tuple[float, float]]]]
#: ``(record in the model's units, notes on the conversion, warnings on its ranges)``.
Prepare = Callable[[Dataset], tuple[Dataset, list[str], list[str]]]


@dataclass(frozen=True)
class DefaultModel:
    """A model package's offer to be the default model.

    Attributes
    ----------
    name : str
        What it is called in messages (``"HHRA"``).
    model_for : callable
        ``model_for(record, **options) -> (model, boxes)``: the model for a record and
        default boxes ``{name: (lower, upper)}`` that make sense for it (e.g. wider ones
        for a record in sample units); options are the package's own (the HHRA's
        ``valve``).
    prepare : callable, optional
        ``prepare(record) -> (record, notes, warnings)``: the record converted to the
        model's units where it declares others, with what was converted and warnings
        about implausible ranges. Applied only when the default model is used.
    example : callable, optional
        ``example() -> Dataset``: the record :func:`hhra_phys.fit` fits when called
        without data (the HHRA's simulated rig, seed 0).
    """

    name: str
    model_for: ModelFor
    prepare: Prepare | None = None
    example: Callable[[], Dataset] | None = None


_REGISTERED: list[DefaultModel] = []


def register_default(default: DefaultModel) -> DefaultModel:
    """Make ``default`` the default model (the last registered wins); returns it.

    Raises
    ------
    ParameterError
        ``default`` is not a :class:`DefaultModel`.
    """
    if not isinstance(default, DefaultModel):
        raise ParameterError(f"register_default needs a DefaultModel, got "
                             f"{type(default).__name__}")
    _REGISTERED.append(default)
    return default


def registered_default() -> DefaultModel:
    """The default model registered last.

    Raises
    ------
    ParameterError
        None is registered: the caller must give a model.
    """
    if not _REGISTERED:
        raise ParameterError("no model given and no default model is registered: pass "
                             "model=<a hhra_phys Model> (or import a model package that "
                             "registers one, hhra_phys.defaults.register_default)")
    return _REGISTERED[-1]


def default_for(data: Dataset, **options: Any) -> tuple[Model, dict[str, tuple[float, float]]]:
    """The default model and its boxes for ``data`` (:attr:`DefaultModel.model_for`)."""
    return registered_default().model_for(data, **options)
