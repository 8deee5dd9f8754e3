"""Ctrl-C that is never swallowed: :func:`interruptible`.

Python turns SIGINT into ``KeyboardInterrupt`` where Python code runs. Inside a solver
written in C that calls back into Python (IPOPT through CasADi, NLopt), the exception is
raised in the callback and the solver catches it: CasADi reports a failed evaluation and
IPOPT returns normally with an error status, so without care a fit would go on and write
an unfinished result as if it were final.

:func:`interruptible` records every SIGINT in a flag (and raises ``KeyboardInterrupt`` as
usual); when the block ends, or when :func:`check` is called in between, a recorded
interrupt is raised again, whatever a solver did with the first one (swallowed it, or
turned it into an error of its own).

Jobs in other processes (a ``ProcessPoolExecutor``, a Dask cluster) do not stop by
themselves when the parent is interrupted: ``Executor.map`` cancels the jobs not yet
started, but leaving a ``with ProcessPoolExecutor()`` block waits for the running ones.
:func:`stop_workers` (used by :func:`map_stopping`, :func:`stop_on_interrupt`,
:func:`hhra_phys.fit.fit_many` and the CLI's ``--workers``/``--dask``) cancels every
queued job and ends the worker processes at once; :func:`ignore_sigint` keeps a worker
that waits for a job from dying of the terminal's Ctrl-C (the parent decides).
"""

from __future__ import annotations

import signal
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from contextlib import contextmanager
from itertools import islice
from types import FrameType
from typing import Any, TypeVar

__all__ = [
    "check",
    "ignore_sigint",
    "interruptible",
    "last_signal",
    "map_stopping",
    "stop_on_interrupt",
    "stop_workers",
]

T = TypeVar("T")
R = TypeVar("R")

#: Seconds a terminated worker process gets to exit before it is killed.
TERMINATE_WAIT = 5.0

_state: dict[str, Any] = {"depth": 0, "hit": False, "signum": None}


def _handler(signum: int, frame: FrameType | None) -> None:
    _state["hit"] = True
    _state["signum"] = signum
    raise KeyboardInterrupt


def last_signal() -> int | None:
    """The signal that ended the last :func:`interruptible` block (``signal.SIGINT`` or,
    with ``terminate=True``, ``signal.SIGTERM``), or None; the CLI's exit code follows it
    (130 or 143)."""
    return _state["signum"]


def check() -> None:
    """Raise ``KeyboardInterrupt`` if Ctrl-C was pressed inside :func:`interruptible`.

    Call it after a foreign solver returns (its status cannot be trusted to say so).
    """
    if _state["hit"]:
        raise KeyboardInterrupt


@contextmanager
def interruptible(terminate: bool = False) -> Iterator[None]:
    """A block in which Ctrl-C is recorded and re-raised when the block ends.

    Nested blocks share one flag; the outermost restores the previous SIGINT handler.
    Outside the main thread (where signal handlers cannot be set) it does nothing.

    Parameters
    ----------
    terminate : bool
        Treat SIGTERM (``kill PID``, a batch system's stop) as SIGINT too: it raises
        ``KeyboardInterrupt`` in the block, so every writer's clean-up runs and a
        command leaves none of its outputs (the CLI sets it; only the outermost block's
        value counts). :func:`last_signal` tells which signal it was.

    Raises
    ------
    KeyboardInterrupt
        When SIGINT arrived during the block, even if the code inside swallowed it.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    outer = _state["depth"] == 0
    previous = signal.getsignal(signal.SIGINT) if outer else None
    previous_term = signal.getsignal(signal.SIGTERM) if outer and terminate else None
    if outer:
        _state["hit"] = False
        _state["signum"] = None
        signal.signal(signal.SIGINT, _handler)
        if terminate:
            signal.signal(signal.SIGTERM, _handler)
    _state["depth"] += 1
    try:
        yield
        check()
    except BaseException:
        # A solver may also turn the interrupt into an error of its own (NLopt raises
        # its runtime_error): after a Ctrl-C, whatever comes out is the interrupt.
        if _state["hit"]:
            raise KeyboardInterrupt from None
        raise
    finally:
        _state["depth"] -= 1
        if outer:
            signal.signal(signal.SIGINT, previous)
            if terminate:
                signal.signal(signal.SIGTERM, previous_term)
            _state["hit"] = False


def ignore_sigint() -> None:
    """Worker-process initializer: SIGINT is ignored while a worker waits for a job.

    A terminal's Ctrl-C reaches every process of its group; an idle worker would die of
    it and break the pool before the parent decides. A job that runs :func:`fit
    <hhra_phys.fit.fit>` still stops at once (:func:`interruptible` sets its own handler
    for the job's duration), and the parent ends the workers (:func:`stop_workers`).

    SIGTERM gets its default action back: a forked worker inherits the CLI's handler,
    which raises ``KeyboardInterrupt`` and printed a traceback from every worker that
    :func:`stop_workers` ended, idle or busy. The parent decides, so a worker just ends.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def stop_workers(executor: Executor) -> None:
    """Cancel the queued jobs of ``executor`` and end its running ones (Ctrl-C, or a block done).

    A ``ProcessPoolExecutor``'s worker processes are terminated (killed if they do not
    exit within :data:`TERMINATE_WAIT` s), so none is left running; the pool cannot be
    used afterwards. Any other executor is shut down without waiting, which cancels its
    jobs (a Dask ``ClientExecutor`` cancels them on the cluster; thread pools finish the
    running ones in the background).

    Parameters
    ----------
    executor : concurrent.futures.Executor
    """
    procs = []
    if isinstance(executor, ProcessPoolExecutor):
        # No public handle on the workers before Python 3.14's terminate_workers().
        procs = list((getattr(executor, "_processes", None) or {}).values())
    try:
        executor.shutdown(wait=False, cancel_futures=True)
    except TypeError:  # executors whose shutdown has no cancel_futures (Dask's)
        executor.shutdown(wait=False)
    for proc in procs:
        if proc.is_alive():
            proc.terminate()
    for proc in procs:
        proc.join(TERMINATE_WAIT)
        if proc.is_alive():
            proc.kill()
            proc.join(TERMINATE_WAIT)
    if procs:
        # The pool's manager thread sees its workers gone and ends; waiting for it here
        # keeps Python's exit from waking it through a pipe it is closing (a traceback).
        executor.shutdown(wait=True)


@contextmanager
def stop_on_interrupt(executor: Executor | None) -> Iterator[None]:
    """A block after whose Ctrl-C the jobs of ``executor`` are stopped (:func:`stop_workers`).

    Parameters
    ----------
    executor : concurrent.futures.Executor or None
        ``None``: nothing to stop.

    Raises
    ------
    KeyboardInterrupt
        Again, after stopping the workers.
    """
    try:
        yield
    except KeyboardInterrupt:
        if executor is not None:
            stop_workers(executor)
        raise


def map_stopping(executor: Executor, fn: Callable[[T], R], jobs: Iterable[T],
                 ahead: int | None = None) -> Iterator[R]:
    """``executor.map(fn, jobs)`` whose results, on Ctrl-C while waiting, stop the workers.

    Parameters
    ----------
    executor : concurrent.futures.Executor
    fn : callable
        Picklable for process and Dask executors.
    jobs : iterable
    ahead : int, optional
        Most jobs submitted and not yet taken by the caller (``None``: all at once, as
        ``Executor.map``); the next job is submitted when the caller asks for the next
        result. A caller that may stop early (the loop's round, settled by a candidate at
        the noise level) then leaves at most ``ahead - 1`` jobs run for nothing:
        closing the iterator cancels the queued ones, but leaving a ``with
        ProcessPoolExecutor()`` block waits for the running ones. The results are those
        of ``Executor.map``; only when the jobs run changes.

    Yields
    ------
    The results in the order of ``jobs``.
    """
    if ahead is None:
        results: Iterator[Any] = executor.map(fn, jobs)
        with stop_on_interrupt(executor):
            yield from results
        return
    pending = iter(jobs)
    running: deque[Future[R]] = deque()
    try:
        with stop_on_interrupt(executor):
            for job in islice(pending, max(1, int(ahead))):
                running.append(executor.submit(fn, job))
            while running:
                yield running.popleft().result()
                # The next one is submitted only when the caller asks for more: a caller
                # that stops on this result (a settled round) starts nothing more, where
                # submitting before the yield ran one more refit for nothing (a backlash
                # refit of 2.5 CPU s after the friction that settled the round).
                for job in islice(pending, 1):
                    running.append(executor.submit(fn, job))
    finally:
        for fut in running:
            fut.cancel()
