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
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

__all__ = ["check", "interruptible"]

_state = {"depth": 0, "hit": False}


def _handler(signum: int, frame: FrameType | None) -> None:
    _state["hit"] = True
    raise KeyboardInterrupt


def check() -> None:
    """Raise ``KeyboardInterrupt`` if Ctrl-C was pressed inside :func:`interruptible`.

    Call it after a foreign solver returns (its status cannot be trusted to say so).
    """
    if _state["hit"]:
        raise KeyboardInterrupt


@contextmanager
def interruptible() -> Iterator[None]:
    """A block in which Ctrl-C is recorded and re-raised when the block ends.

    Nested blocks share one flag; the outermost restores the previous SIGINT handler.
    Outside the main thread (where signal handlers cannot be set) it does nothing.

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
    if outer:
        _state["hit"] = False
        signal.signal(signal.SIGINT, _handler)
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
            _state["hit"] = False
