"""Regime coverage: how much of a candidate's regime each part of the records contains.

A candidate acts in a regime of the signals (a saturation at the largest inputs, a
delay where the input changes, an overflow above a level, friction at reversals): its
first-order column (:meth:`hhra_phys.parts.Effect.first_order`, the change the effect makes
at its probe size on the model's signals) is large there and small elsewhere. A part that
barely reaches the regime says little about the candidate, whichever way its score goes
(issue 33, item 2). :func:`regime_coverage` measures it per part, the same way for every
candidate with a first-order column: a sample is *in the regime* where the column's size
exceeds :data:`REGIME_LEVEL` times its 99th percentile over the parts together (a
percentile, not the largest value: one spike must not set the scale; the 99th, not a
lower one: a delay's regime, the samples where the input changes, may be 4 % of them).

The loop writes the result into each library step (``steps[].regime`` of the JSON).
A candidate without a first-order column (a discovered term or mode, a user's effect
without one) is measured by what its fit changes: :func:`change_coverage` of the fitted
candidate's output against the current model's. Where the selection part and the
criterion on estimation disagree, a part that holds the regime thinly cannot refuse the
candidate alone and the parts rotate (:func:`hhra_phys.diagnosis.selection.needs_rotation`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.parts import Signals

__all__ = ["REGIME_LEVEL", "regime_coverage", "change_coverage"]

#: A sample is in a candidate's regime where its first-order column exceeds this fraction
#: of the column's 99th percentile (of its size over the parts).
REGIME_LEVEL = 0.1


def _signals(record: Any, values: np.ndarray, data: Dataset | None) -> Signals:
    """The model's simulated signals on a part (the record's own samples when ``data`` is
    None), started as the part's score starts it."""
    from hhra_phys.diagnosis.screening import variable_series  # here: discover imports much

    series, yhat = variable_series(record, values, data)
    d = record.data if data is None else data
    return Signals(u=np.asarray(d.u, dtype=float), dt=float(d.dt), output=d.output_unit or "",
                   states={n: series[n] for n in record.model.state_names}, y=yhat)


def _activity(effect: Any, sigs: Sequence[Signals]) -> list[np.ndarray] | None:
    """Size of the effect's first-order column(s) on each of ``sigs``, computed once on
    them end to end (an effect may scale its column by the signals' range: one scale for
    every part); None without a column."""
    names = list(sigs[0].states)
    whole = Signals(u=np.concatenate([s.u for s in sigs]), dt=sigs[0].dt,
                    output=sigs[0].output,
                    states={n: np.concatenate([s.states[n] for s in sigs]) for n in names},
                    y=np.concatenate([s.y for s in sigs]))
    cols = effect.first_order(whole)
    if cols is None:
        return None
    cols = np.asarray(cols, dtype=float).reshape(whole.u.size, -1)
    size = np.sqrt(np.sum(cols ** 2, axis=1))
    return np.split(size, np.cumsum([s.u.size for s in sigs])[:-1])


def regime_coverage(effect: Any, records: Sequence[tuple[Any, np.ndarray]],
                    parts: Mapping[str, Sequence[Dataset | None]]) -> dict[str, Any] | None:
    """How much of ``effect``'s regime each part holds.

    Parameters
    ----------
    effect : Effect
        The candidate (its :meth:`~hhra_phys.parts.Effect.first_order` column).
    records : sequence of (RecordProblem, ndarray)
        Each record's problem and free values (``Problem.per_record_values``): the model
        whose signals the column is computed on.
    parts : mapping of str to sequence
        Part name -> one part per record (``None``: that record's own estimation samples),
        e.g. ``{"est": [None], "sel": [selection part]}``.

    Returns
    -------
    dict or None
        ``None`` where the candidate has no first-order column or a part cannot be
        simulated. Otherwise ``level`` (the threshold, in the column's units),
        ``basis`` (what it is), and per part ``samples`` (its sample count),
        ``in_regime`` (the fraction of its samples in the regime) and ``share`` (its
        fraction of all regime samples of the parts).
    """
    try:
        keys = [(name, k) for name, dss in parts.items() for k in range(len(dss))]
        sizes = _activity(effect, [_signals(*records[k], parts[name][k]) for name, k in keys])
    except Exception:  # noqa: BLE001 - a report only: never let it end a candidate
        return None
    if sizes is None:
        return None
    act = {name: np.concatenate([a for (nm, _), a in zip(keys, sizes, strict=True)
                                 if nm == name]) for name in parts}
    return _coverage(act, "first-order column")


def change_coverage(changes: Mapping[str, np.ndarray]) -> dict[str, Any] | None:
    """How much of a fitted candidate's regime each part holds, by what it changes.

    Parameters
    ----------
    changes : mapping of str to ndarray
        Part name -> the candidate's simulated output less the current model's on that
        part (output units), e.g. ``{"est": ..., "sel": ...}``.

    Returns
    -------
    dict or None
        As :func:`regime_coverage` (``level``, ``basis``, and per part ``samples``,
        ``in_regime``, ``share``), a sample in the regime where the size of the change
        exceeds :data:`REGIME_LEVEL` times its 99th percentile over the parts; ``None``
        where the change is not finite or nowhere above zero.
    """
    act = {name: np.abs(np.asarray(c, dtype=float).ravel()) for name, c in changes.items()}
    return _coverage(act, "the fitted candidate's output change")


def _coverage(act: Mapping[str, np.ndarray], what: str) -> dict[str, Any] | None:
    """Each part's share of the samples where its activity ``act[part]`` (a size >= 0 per
    sample) exceeds :data:`REGIME_LEVEL` times its 99th percentile over the parts together
    (one scale for every part); ``None`` where it is not finite or nowhere above zero."""
    pooled = np.concatenate(list(act.values())) if act else np.zeros(0)
    if pooled.size == 0 or not np.isfinite(pooled).all():
        return None
    ref = float(np.percentile(pooled, 99))
    if ref <= 0:
        return None
    level = REGIME_LEVEL * ref
    total = int(np.sum(pooled > level))
    out: dict[str, Any] = {"level": level,
                           "basis": f"{what} above {REGIME_LEVEL:g} x its 99th percentile "
                                    "over the parts"}
    for name, a in act.items():
        n_in = int(np.sum(a > level))
        out[name] = {"samples": int(a.size),
                     "in_regime": n_in / a.size if a.size else 0.0,
                     "share": n_in / total if total else 0.0}
    return out
