"""map_stopping with a bounded number of jobs ahead of the caller."""

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from hhra_phys.interrupt import map_stopping


def _square(x: int) -> int:
    time.sleep(0.002 * (x % 3))  # uneven job lengths: results still in job order
    return x * x


@pytest.mark.parametrize("ahead", [None, 1, 2, 5, 50])
def test_results_are_those_of_map_in_order(ahead: int | None) -> None:
    with ThreadPoolExecutor(3) as ex:
        assert list(map_stopping(ex, _square, range(12), ahead=ahead)) == [
            x * x for x in range(12)]


@pytest.mark.parametrize("ahead", [1, 2, 3])
def test_closing_early_runs_at_most_ahead_more_jobs(ahead: int) -> None:
    started: list[int] = []
    lock = threading.Lock()

    def job(x: int) -> int:
        with lock:
            started.append(x)
        return x

    with ThreadPoolExecutor(4) as ex:
        it = map_stopping(ex, job, range(20), ahead=ahead)
        taken = [next(it) for _ in range(3)]
        it.close()  # the caller stops: the queued jobs are cancelled
    assert taken == [0, 1, 2]
    assert len(started) <= 3 + ahead - 1


def test_next_job_waits_for_the_caller() -> None:
    # One ahead: a job starts only when the caller asks for its result, so a caller that
    # stops after a result (a round settled by it) starts nothing more.
    started: list[int] = []

    def job(x: int) -> int:
        started.append(x)
        return x

    with ThreadPoolExecutor(2) as ex:
        it = map_stopping(ex, job, range(10), ahead=1)
        assert [next(it) for _ in range(3)] == [0, 1, 2]
        it.close()
    assert started == [0, 1, 2]
