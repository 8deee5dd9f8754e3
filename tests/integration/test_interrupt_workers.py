"""Ctrl-C with worker processes: the workers stop, the CLI exits 130 and writes nothing.

``hhra-phys diagnose --workers 2`` is interrupted while its candidate refits run in two
worker processes (SIGINT to the CLI process alone, as ``kill -INT``, and to its whole
process group, as a terminal's Ctrl-C); then no worker may be left running. In Python,
:func:`hhra_phys.fit.fit_many` with a user's ``ProcessPoolExecutor`` ends its workers
too instead of waiting for the running fits.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from hhra_phys.data import save
from hhra_phys.interrupt import stop_workers
from hhra_phys.reference import reference_record

REPO = Path(__file__).resolve().parents[2]


def _children(pid: int) -> set[int]:
    """Process ids whose parent is ``pid`` (Linux /proc)."""
    out = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.add(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has exited (its parent, the test, may not reap it)


# The CLI with slow candidate refits: each sleeps before refitting, so that the interrupt
# surely arrives while both workers hold a job (the workers are forked from this process,
# so they run the patched function, which pickles by its module and name as before).
SLOW_CANDIDATES = textwrap.dedent(
    """
    import functools, sys, time
    from hhra_phys.diagnosis import candidates, engine
    from hhra_phys.cli import main

    original = candidates.refit_candidate

    @functools.wraps(original)
    def slow(job):
        time.sleep(60)
        return original(job)

    # the loop's call and the workers' unpickling (by module and name) both see it
    engine.refit_candidate = candidates.refit_candidate = slow
    sys.exit(main(sys.argv[1:]))
    """
)


@pytest.fixture(scope="module")
def record(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "rig.csv"
    # A dead zone the base model lacks, so that the loop refits candidates.
    save(reference_record(seed=1, duration=8.0, effects={"valve_deadzone": {"i_dead": 0.1}}),
         path)
    return path


@pytest.mark.parametrize("group", [False, True], ids=["kill-INT", "terminal-Ctrl-C"])
def test_ctrl_c_during_candidate_refits_stops_the_workers(
    record: Path, tmp_path: Path, group: bool
) -> None:
    js = tmp_path / "out" / "diag.json"
    js.parent.mkdir()
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-c", SLOW_CANDIDATES, "diagnose", str(record), "--workers", "2",
         "--pop", "8", "--iters", "2", "--json", str(js), "--no-discover"],
        stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
    lines = []
    workers: set[int] = set()
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append(line)
            if line.startswith("round 1: ranking"):
                break
        deadline = time.monotonic() + 120
        while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
            workers |= _children(proc.pid)
            time.sleep(0.2)
        time.sleep(1.0)  # both workers now hold a (slow) candidate refit
        assert proc.poll() is None, "".join(lines)
        t_signal = time.monotonic()
        if group:
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGINT)
        rest = proc.stderr.read()  # until the CLI exits
        code = proc.wait(timeout=60)
        stopped_after = time.monotonic() - t_signal
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    err = "".join(lines) + rest
    assert workers, err
    assert code == 130, err[-2000:]
    assert stopped_after < 30, "the CLI waited for the running refits (60 s each)"
    assert "interrupted; nothing written" in err and "Traceback" not in err
    assert not list(js.parent.iterdir())
    time.sleep(0.5)
    assert not [w for w in workers if _alive(w)], "worker processes left running"


def _sleepy(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def test_stop_workers_ends_a_busy_process_pool_at_once() -> None:
    pool = ProcessPoolExecutor(max_workers=2)
    futures = [pool.submit(_sleepy, 60.0) for _ in range(4)]
    deadline = time.monotonic() + 30
    while not all(f.running() for f in futures[:2]) and time.monotonic() < deadline:
        time.sleep(0.05)
    procs = list(pool._processes.values())  # type: ignore[union-attr]
    t0 = time.monotonic()
    stop_workers(pool)
    assert time.monotonic() - t0 < 10  # not the 60 s of the running jobs
    # By /proc, not Process.is_alive(): the pool's manager thread may reap a worker
    # first, after which is_alive() cannot tell (waitpid fails) and says True.
    assert procs and not any(_alive(p.pid) for p in procs)
    deadline = time.monotonic() + 10
    while not all(f.done() for f in futures) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert all(f.done() for f in futures)  # cancelled, or failed with the broken pool


def test_the_executor_block_ends_work_nobody_waits_for() -> None:
    """``cluster.executor``: a job still running when the block ends (a candidate refit of a
    round another candidate settled) is ended, not waited for, and no worker is left."""
    from hhra_phys.cluster import executor

    t0 = time.monotonic()
    with executor(2) as pool:
        done = pool.submit(_sleepy, 0.0)
        abandoned = pool.submit(_sleepy, 60.0)
        assert done.result(timeout=30) == 0.0
        deadline = time.monotonic() + 30
        while not abandoned.running() and time.monotonic() < deadline:
            time.sleep(0.05)
        procs = list(pool._processes.values())  # type: ignore[union-attr]
    assert time.monotonic() - t0 < 40  # not the 60 s of the abandoned job
    assert procs and not any(_alive(p.pid) for p in procs)
