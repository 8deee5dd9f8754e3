"""Several records of one plant: their scores pooled, their agreement checked, their parts.

Users record more than one run of a plant (different amplitudes, loads, days). The
fitting problem takes one record or several alike (:class:`~hhra_phys.problem.Problem`:
shared model parameters, per-record initial states and per-record parameters); this
module holds what the workflow needs around it for a set of records::

    res = fit([ds1, ds2])                  # shared groups, x0_theta_rec1, x0_theta_rec2
    res.records[0]["val"]["rmse"]          # metrics per record, pooled in res.metrics

* :func:`pooled_score`: the metrics of several records together;
* :func:`check_records`: records fitted together measure the same signals in the same units;
* :class:`RecordSet` and :func:`split_records`: the diagnosis loop's estimation, selection
  and test parts of several records.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.metrics import score
from hhra_phys.problem import record_label

__all__ = [
    "RecordSet",
    "check_records",
    "pooled_score",
    "split_records",
]

def pooled_score(records: Sequence[Dataset], outputs: Sequence[np.ndarray]) -> dict[str, float]:
    """Metrics of several records together.

    MSE, RMSE, VAF, fit and the largest error over all samples pooled; ITAE is
    the sum of the records' own ITAE (each on its own time axis).
    """
    y = np.concatenate([ds.y for ds in records])
    yhat = np.concatenate([np.asarray(o, dtype=float) for o in outputs])
    out = {k: float(v) for k, v in score(y, yhat).items()}
    out["itae"] = float(sum(score(ds.y, o, ds.t)["itae"]
                            for ds, o in zip(records, outputs, strict=True)))
    return out


def check_records(records: Sequence[Dataset], what: str = "record") -> None:
    """Several records of one plant must agree on their signals' names and units.

    Raises
    ------
    DataError
        A record whose input or output name or unit differs from the first
        record's (the message names both records, by file where they came from one).
    """
    from hhra_phys.errors import DataError

    records = list(records)
    if not records:
        return
    first = records[0]

    def where(ds: Dataset, k: int) -> str:  # the file, where the record came from one
        return str(ds.source or ds.name or f"{what} {k}")

    for k, ds in enumerate(records[1:], start=2):
        for attr, label in (("output_unit", "output unit"), ("output_name", "output"),
                            ("input_unit", "input unit"), ("input_name", "input")):
            a, b = getattr(first, attr), getattr(ds, attr)
            if a != b:
                raise DataError(
                    f"{where(ds, k)}: {label} {b!r}, but {where(first, 1)} has {a!r}: "
                    f"{what}s fitted together must measure the same signals in the same "
                    "units (convert the file, or fit them apart)")


class RecordSet(tuple):  # type: ignore[type-arg]
    """Several records (parts of records) that play the role of one in the loop.

    A tuple of :class:`~hhra_phys.data.Dataset` with the few attributes the
    diagnosis loop reads of a record: ``n`` (all samples), ``name``, the signals'
    names and units (the records agree on them, :func:`check_records`), and, for
    scaling an effect to the data (:func:`~hhra_phys.effects.make_effect`), ``u``
    and ``y`` (the records' samples one after another; never simulated as one
    record), ``dt`` (the largest sample period [s]: smoothing widths tied to it
    stay integrable at every record's rate) and ``fs`` (the first record's).
    """

    #: Whole validation records (scored with the first record's per-record values),
    #: not parts of the estimation records.
    whole = False

    @property
    def n(self) -> int:
        """Samples of all records."""
        return int(sum(ds.n for ds in self))

    @property
    def name(self) -> str:
        """The records' names joined by ``" + "``."""
        return " + ".join(record_label(ds, k) for k, ds in enumerate(self, start=1))

    @property
    def names(self) -> list[str]:
        """One label per record."""
        return [record_label(ds, k) for k, ds in enumerate(self, start=1)]

    @property
    def u(self) -> np.ndarray:
        """Inputs one after another, shape (n,)."""
        return np.concatenate([ds.u for ds in self])

    @property
    def y(self) -> np.ndarray:
        """Outputs one after another, shape (n,)."""
        return np.concatenate([ds.y for ds in self])

    @property
    def dt(self) -> float:
        """Largest sample period [s or samples]."""
        return float(max(ds.dt for ds in self))

    @property
    def fs(self) -> float:
        """Sample rate of the first record [Hz]."""
        return float(self[0].fs)

    def __getattr__(self, attr: str) -> Any:
        # Signal names, units and the time unit are common (check_records).
        if attr in ("output_unit", "output_name", "input_unit", "input_name", "time_unit"):
            return getattr(self[0], attr)
        raise AttributeError(attr)


def split_records(
    records: Sequence[Dataset], split: float, test: float,
    validation: Sequence[Dataset] | None = None,
) -> tuple[RecordSet, RecordSet, RecordSet | None]:
    """The diagnosis loop's estimation, selection and test parts of several records.

    Every record is split the loop's way (:func:`hhra_phys.diagnosis.selection.split_record`);
    with ``validation`` the records split into estimation and selection only
    (``test`` ignored) and the whole validation records are the test part.
    """
    from hhra_phys.diagnosis.selection import split_record

    records = list(records)
    check_records(records + list(validation or []))
    parts = [split_record(ds, split, 0.0 if validation else test) for ds in records]
    est = RecordSet(p[0] for p in parts)
    sel = RecordSet(p[1] for p in parts)
    if validation:
        held_whole = RecordSet(validation)
        held_whole.whole = True
        return est, sel, held_whole
    held = [p[2] for p in parts]
    return est, sel, (RecordSet(held) if held[0] is not None else None)
