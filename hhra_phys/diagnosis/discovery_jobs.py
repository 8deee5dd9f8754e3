"""Discovery's refits on the loop's executor: the round's discovered forms side by side.

A round's library refits run in the executor's worker processes; its discovery ran after
them in this process, one entry after another, while the workers waited: in round 2 of a
25 s drive record, 29 of the round's 40 seconds on one core of two. Each entry's refit
(its sparse forms, or a mode's starts) needs nothing from the others, so all are submitted
at once (:func:`submit_refits`) and taken in the loop's order (:func:`take_refit`),
judged there as before. A refit is the same computation wherever it runs (every fit
carries its own seed, :mod:`hhra_phys.cluster`): the steps, lines and choices are those
of the serial loop. A refit the round no longer needs (settled by another candidate) is
cancelled if it has not started.

The :class:`~hhra_phys.diagnosis.discovery.Discovery` goes to the worker without its live
problems (``Discovery.__getstate__``); the fitted candidate comes back without its
problem, which is rebuilt here from the arguments that built it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Executor, Future
from dataclasses import replace
from typing import Any

from hhra_phys.diagnosis.discovery import Discovery, Proposal

__all__ = ["submit_refits", "take_refit", "cancel_refits", "refit_elsewhere"]

#: What a worker sends back: ``((step, fitted, veto) or None, lines said)``.
Outcome = tuple[Any, list[str]]


def refit_elsewhere(job: tuple[Discovery, Proposal]) -> Outcome:
    """One proposal's :meth:`Discovery.refit` in a worker, with the lines it said; the
    fitted candidate without its problem (compiled code stays in the worker)."""
    disc, proposal = job
    lines: list[str] = []
    disc.say = lines.append
    got = disc.refit(proposal)
    if got is None:
        return None, lines
    step, fitted, veto = got
    return (step, replace(fitted, problem=None), veto), lines


def submit_refits(executor: Executor, disc: Discovery, proposals: Sequence[Proposal]
                  ) -> dict[int, Future[Outcome]]:
    """Every proposal's refit submitted now, keyed by ``id(proposal)``."""
    # What Discovery.__getstate__ computes, computed here: a process pool pickles the jobs
    # in its own thread.
    disc.prepare_to_travel()
    return {id(p): executor.submit(refit_elsewhere, (disc, p)) for p in proposals}


def take_refit(futures: dict[int, Future[Outcome]], disc: Discovery, proposal: Proposal,
               say: Callable[[str], None]) -> Any:
    """The refit of ``proposal`` as :meth:`Discovery.refit` gives it here: its lines said
    now, in the loop's order, and its fitted problem rebuilt (the worker built it from
    these arguments with the same settings)."""
    try:
        got, lines = futures.pop(id(proposal)).result()
    except Exception:  # noqa: BLE001 - it could not run there (a part that does not pickle)
        return disc.refit(proposal)  # here, as without workers; its own errors are its own
    for line in lines:
        say(line)
    if got is None:
        return None
    step, fitted, veto = got
    return step, replace(fitted, problem=disc.fitter.problem(*fitted.built)), veto


def cancel_refits(futures: dict[int, Future[Outcome]]) -> None:
    """Cancel the refits not taken (those not started do not run)."""
    for fut in futures.values():
        fut.cancel()
    futures.clear()
