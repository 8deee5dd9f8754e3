"""Where independent jobs run: here, local processes, or a Dask cluster.

Candidate refits of the diagnosis loop (:func:`hhra_phys.diagnosis.engine.augment`),
multi-start fits (:func:`hhra_phys.fit.fit_many`) and the optimiser study
(:func:`hhra_phys.paper.table2.run_study`) take any :class:`concurrent.futures.Executor`.
The CLI builds one from ``--workers N`` (a local ``ProcessPoolExecutor``) or
``--dask ADDRESS`` (the executor of a Dask ``distributed.Client`` connected to a
running scheduler, e.g. ``tcp://10.0.0.5:8786``; install ``hhra-phys[dask]``).

Every job carries its own seed, so the results do not depend on where, or in
which order, the jobs ran.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from contextlib import contextmanager
from typing import Any

from hhra_phys.errors import ParameterError
from hhra_phys.interrupt import ignore_sigint, stop_on_interrupt, stop_workers

#: BLAS threads per process while local worker processes run: one. The cores are shared
#: by the processes; OpenBLAS's own threads spin while they wait for work and took the
#: cores from the workers' compiled simulations (the 25 s drive record's diagnosis: 235 s
#: CPU for 122 s wall with two workers, 119 s CPU for 96 s wall with one BLAS thread each,
#: the same decisions; benchmarks/notes/performance.md).
BLAS_THREADS_WITH_WORKERS = 1

__all__ = [
    "executor",
    "one_blas_thread",
    "auto_workers",
    "add_cluster_arguments",
    "check_scheduler_answers",
    "dask_client",
]


def dask_client(address: str) -> Any:
    """A ``distributed.Client`` connected to the Dask scheduler at ``address``.

    Raises
    ------
    ParameterError
        If Dask's distributed package is not installed (``pip install
        "hhra-phys[dask]"``) or the scheduler cannot be reached.
    """
    try:
        from distributed import Client
    except ImportError:
        raise ParameterError(
            "--dask needs Dask's distributed scheduler client: pip install \"hhra-phys[dask]\" "
            "(or dask[distributed])") from None
    check_scheduler_answers(address)
    try:
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise ParameterError(f"--dask {address}: cannot reach the Dask scheduler: {exc}") from None
    except (ValueError, TypeError) as exc:  # distributed's words for a malformed address
        raise ParameterError(f"--dask {address}: not a scheduler address: {exc}") from None
    try:  # jobs sent to a scheduler without workers would wait for ever
        client.wait_for_workers(1, timeout=WORKER_TIMEOUT)
    except (OSError, TimeoutError):
        client.close()
        raise ParameterError(
            f"--dask {address}: the scheduler has no worker (none joined within "
            f"{WORKER_TIMEOUT:g} s); start one with: dask worker {address}") from None
    return client


#: Seconds to wait for a connection and for a scheduler's first bytes.
PROBE_TIMEOUT = 5.0

#: Seconds to wait for the scheduler's first worker.
WORKER_TIMEOUT = 20.0

#: The largest first message a Dask scheduler sends (its handshake, a few hundred bytes).
MAX_HANDSHAKE_BYTES = 2**20


def check_scheduler_answers(address: str, timeout: float | None = None) -> None:
    """Check that a Dask scheduler, not another server, listens at a ``tcp://`` address.

    A scheduler sends its handshake as soon as a client connects, led by its length as
    8 bytes. Dask's client reads whatever answers as such a length: an HTTP server's
    ``HTTP/1.1`` became a 3 EiB allocation. Here the first bytes are read with a timeout
    and their length checked before Dask connects. Other protocols (tls://, ws://) and
    scheduler files are left to Dask.

    Raises
    ------
    ParameterError
        Nothing listens, nothing answers within ``timeout`` s (default
        :data:`PROBE_TIMEOUT`), or the answer is not a scheduler's handshake.
    """
    import socket
    import struct

    timeout = PROBE_TIMEOUT if timeout is None else timeout
    text = address.strip()
    if "://" in text and not text.startswith("tcp://"):
        return
    if text.endswith(".json"):
        return
    host, _, port = text.removeprefix("tcp://").rpartition(":")
    host = host.strip("[]")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout) as sock:
            sock.settimeout(timeout)
            head = b""
            while len(head) < 8:
                chunk = sock.recv(8 - len(head))
                if not chunk:
                    break
                head += chunk
    except TimeoutError:
        raise ParameterError(
            f"--dask {address}: something listens there but did not answer as a Dask "
            f"scheduler does within {timeout:g} s; is the address the scheduler's "
            "(usually port 8786, not the dashboard's 8787)?") from None
    except (OSError, ValueError) as exc:
        raise ParameterError(f"--dask {address}: cannot reach the Dask scheduler: {exc}") from None
    if len(head) < 8 or struct.unpack("<Q", head)[0] > MAX_HANDSHAKE_BYTES:
        raise ParameterError(
            f"--dask {address}: the server there is not a Dask scheduler (it answered "
            f"{head!r}); give the scheduler's address (usually port 8786)")


def one_blas_thread() -> Any:
    """Limit every BLAS library this process has loaded to
    :data:`BLAS_THREADS_WITH_WORKERS` thread(s).

    ``scipy.linalg`` is loaded first so that its own copy of OpenBLAS is limited too
    (NumPy and SciPy each bundle one). Worker processes of :func:`executor` also get
    ``OPENBLAS_NUM_THREADS`` for a library loaded later.

    Returns
    -------
    threadpoolctl.threadpool_limits
        The limit; its ``restore_original_limits()`` gives the libraries their thread
        counts back.
    """
    import scipy.linalg  # noqa: F401 - its BLAS, loaded before the limit is set
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=BLAS_THREADS_WITH_WORKERS, user_api="blas")


def _start_worker() -> None:
    """Worker-process initializer: SIGINT ignored (:func:`ignore_sigint`) and one BLAS
    thread (:func:`one_blas_thread`), environment included for libraries loaded later."""
    ignore_sigint()
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = str(BLAS_THREADS_WITH_WORKERS)
    one_blas_thread()


def auto_workers() -> int | None:
    """``--workers auto``: one worker process per usable core, none on a single core."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        cores = os.cpu_count() or 1
    return cores if cores > 1 else None


def _workers_arg(text: str) -> int | str:
    """``--workers`` value: ``auto`` or a non-negative integer."""
    if text == "auto":
        return text
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected 'auto' or a non-negative integer, got {text!r}") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"expected 'auto' or a non-negative integer, got {n}")
    return n


@contextmanager
def executor(workers: int | str | None = None,
             dask: str | None = None) -> Iterator[Executor | None]:
    """The executor asked for, shut down (or disconnected) on exit.

    On Ctrl-C inside the block its jobs are cancelled and the local worker processes
    ended at once (:func:`hhra_phys.interrupt.stop_workers`): no worker is left running
    and nothing waits for the jobs that were running. So too when the block ends: a local
    job still running then is one whose result the block did not wait for.

    Parameters
    ----------
    workers : int or "auto", optional
        Local worker processes (``>= 1``); ``None`` or ``0``: no executor (run here);
        ``"auto"``: one per usable core (:func:`auto_workers`), none on a single core
        or when ``dask`` is given.
    dask : str, optional
        Address of a running Dask scheduler; excludes ``workers``.

    Yields
    ------
    concurrent.futures.Executor or None
    """
    if workers == "auto":
        workers = None if dask else auto_workers()
    if workers is not None and (not isinstance(workers, int) or workers < 0):
        raise ParameterError(f"--workers must be a non-negative integer, got {workers!r}")
    if dask and workers:
        raise ParameterError("give either --workers or --dask, not both")
    if dask:
        client = dask_client(dask)
        try:
            ex = client.get_executor()
            with stop_on_interrupt(ex):
                yield ex
        finally:
            client.close()
    elif workers:
        # One BLAS thread here too while the workers run: this process judges and screens
        # beside them, and its idle BLAS threads would spin on their cores.
        limits = one_blas_thread()
        try:
            with (ProcessPoolExecutor(max_workers=workers, initializer=_start_worker) as pool,
                  stop_on_interrupt(pool)):
                yield pool
                # What still runs once the block is done is work nobody will read (a
                # candidate refit of a round another candidate settled while it ran): end
                # it rather than wait for it. Measured: a dead-zone record's diagnosis
                # waited 3 s at its end for a friction refit the settled round had
                # abandoned (7.6 s without that wait).
                stop_workers(pool)
        finally:
            limits.restore_original_limits()
    else:
        yield None


def add_cluster_arguments(p: argparse.ArgumentParser, what: str,
                          default: int | str | None = None) -> None:
    """``--workers N`` and ``--dask ADDRESS`` for a sub-command; ``what`` names the jobs.

    ``default`` of ``--workers``: ``None`` (run here) or ``"auto"`` (one process per
    core where there is more than one).
    """
    auto = (" (default: auto, one per core where there is more than one; 0 runs them here)"
            if default == "auto" else "; auto: one per core")
    p.add_argument("--workers", type=_workers_arg, default=default, metavar="N",
                   help=f"run {what} in N local worker processes (results as without){auto}")
    p.add_argument("--dask", default=None, metavar="ADDRESS",
                   help=f"run {what} on a running Dask scheduler, e.g. tcp://host:8786 "
                        "(needs pip install \"hhra-phys[dask]\")")
