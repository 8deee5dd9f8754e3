"""The folds of the loop's blocked cross-validation: which samples each fold holds out.

Where the parts rotate (:mod:`hhra_phys.diagnosis.rotation`), the non-test samples of every
record are cut into ``k`` contiguous blocks: the selection part is one, the estimation part
is cut into ``k - 1`` of equal length. The loop's own fit (on estimation, scored on
selection) is the fold that holds out the selection block; every other fold holds out one
estimation block and is fitted on the rest of the record, the blocks before it and the
blocks after it (selection included) as up to two pieces, each with its own initial state.
With ``k = 2`` the one other fold is the selection part fitted and the estimation part
scored (the two-fold rotation); with the default split (0.5 estimation, 0.25 selection)
``k = 3`` gives three blocks of a quarter each. Blocks, not shuffled samples: a simulated
output carries its past, so a held-out block is scored by a free run from the state the
model reaches at its first sample (its leading window, :meth:`~hhra_phys.problem.
RecordProblem.lead_window`), as the selection part is.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from hhra_phys.data import Dataset
from hhra_phys.data.checks import DataChecks
from hhra_phys.errors import ParameterError
from hhra_phys.problem import Problem

__all__ = ["Fold", "fold_plan", "MAX_FOLDS", "LaterStartProblem"]

#: Most folds the loop accepts (``LoopOptions.folds``): each estimation block must keep
#: enough samples to be fitted and scored on its own.
MAX_FOLDS = 10


class LaterStartProblem(Problem):
    """A fold's problem: a piece that starts in the middle of its record has the initial
    value of every state fitted (:attr:`~hhra_phys.problem.Problem.fit_later_states`), not
    only the model's :attr:`~hhra_phys.model.Model.fitted_states`: a drive whose velocity
    starts at rest at the start of a record is moving where a later piece begins."""

    fit_later_states = True


@dataclass(frozen=True)
class Fold:
    """One fold beyond the loop's own: fitted on ``train``, scored on ``held``.

    Attributes
    ----------
    name : str
        ``"est"`` (k = 2: the whole estimation part held out) or ``"est j/m"`` (its block
        ``j`` of ``m``).
    train : list of Dataset
        The pieces the fold is fitted on (contiguous samples of the records, each piece
        with its own initial state), in record and time order.
    held : list of (Dataset or None)
        One entry per piece of ``train``: the block scored with that piece's per-record
        values (the first piece of each record), ``None`` for the others.
    n_held : int
        Samples held out (all records).
    """

    name: str
    train: list[Dataset]
    held: list[Dataset | None]
    n_held: int


def _span(parts: Sequence[Dataset]) -> list[Dataset]:
    """``parts`` as one piece where they are consecutive samples of one record (a part
    alone is itself); otherwise as they are."""
    if len(parts) == 1:
        return [parts[0]]
    origins = [ds.origin for ds in parts]
    if any(o is None or o[0] is not origins[0][0] for o in origins):
        return list(parts)
    if any(o[1] + ds.n != nxt[1] for o, ds, nxt in zip(origins[:-1], parts[:-1], origins[1:],
                                              strict=True)):
        return list(parts)
    root, start = origins[0]
    return [root.slice(start, origins[-1][1] + parts[-1].n)]


def _blocks(est: Dataset, m: int) -> list[Dataset]:
    """``est`` cut into ``m`` contiguous blocks of equal length (the last takes the rest)."""
    if m == 1:
        return [est]
    size = est.n // m
    return [est.slice(j * size, est.n if j == m - 1 else (j + 1) * size) for j in range(m)]


def fold_plan(est: Sequence[Dataset], sel: Sequence[Dataset], k: int) -> list[Fold]:
    """The ``k - 1`` folds that hold out an estimation block, for every record at once.

    Parameters
    ----------
    est, sel : sequence of Dataset
        Each record's estimation and selection parts (one each per record).
    k : int
        Folds in all, the loop's own (selection held out) included; at least 2.

    Returns
    -------
    list of Fold
        Fold ``j`` holds out estimation block ``j`` of every record. With ``k = 2`` its
        ``train`` is the selection parts themselves and its ``held`` the estimation parts.

    Raises
    ------
    ParameterError
        ``k`` out of range, or an estimation block shorter than a record may be
        (:attr:`~hhra_phys.data.checks.DataChecks.min_samples`).
    """
    if not (isinstance(k, int) and 2 <= k <= MAX_FOLDS):
        raise ParameterError(f"folds must be an integer from 2 to {MAX_FOLDS}, got {k!r}")
    m = k - 1
    if len(est) != len(sel):
        raise ParameterError(f"{len(est)} estimation parts for {len(sel)} selection parts")
    least = DataChecks().min_samples  # a block is a record of its own
    for ds in est:
        if ds.n // m < least:
            raise ParameterError(f"folds={k} cuts a {ds.n}-sample estimation part into "
                                 f"blocks of fewer than {least} samples; use fewer folds")
    blocks = [_blocks(ds, m) for ds in est]
    out: list[Fold] = []
    for j in range(m):
        train: list[Dataset] = []
        held: list[Dataset | None] = []
        for bl, s in zip(blocks, sel, strict=True):
            # The blocks before the held-out one, and those after it with the selection
            # part: one piece each where they are consecutive samples of the record (the
            # selection part itself when it is alone).
            pieces = (_span(bl[:j]) if j else []) + _span(bl[j + 1:] + [s])
            train += pieces
            held += [bl[j]] + [None] * (len(pieces) - 1)
        out.append(Fold(name="est" if m == 1 else f"est {j + 1}/{m}", train=train, held=held,
                        n_held=sum(bl[j].n for bl in blocks)))
    return out
