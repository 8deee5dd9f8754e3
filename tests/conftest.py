"""Shared test set-up.

Layout: ``unit/`` checks one module against a reference it does not share code with
(closed forms, hand-computed steps, SciPy, python-control, CVODES); ``integration/``
runs whole paths (fit, diagnosis loop, CLI, guide, experiment scripts) and the
package's models against independent implementations (``hhra_phys.reference``).
The long studies (rates over several seeds, the experiment scripts) are marked ``slow``
and deselected by default (``addopts`` in ``pyproject.toml``); ``pytest -m slow`` runs
them (``docs/testing.md``). Each such behaviour keeps a fast version (one seed, a shorter
record) in the default run.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

#: The repository's root.
REPO = Path(__file__).resolve().parents[1]

# Figures are written to files, never shown.
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository's root directory."""
    return REPO


@pytest.fixture(scope="session")
def public_record():
    """The public hydraulic-actuator record, or a skip where ``shared/data`` is absent."""
    from hhra_phys.data import DataError, load_public_actuator

    try:
        return load_public_actuator()
    except DataError as exc:
        pytest.skip(f"public data not available: {exc}")


@pytest.fixture(scope="session")
def loop_workers():
    """Two worker processes for the candidate refits of the loop tests' rounds.

    The loop's own executor path (``augment(executor=...)``, ``hhra-phys diagnose
    --workers``), whose results equal the serial run's for the same seed
    (``tests/integration/test_loop_cluster.py``): the rate tests loop over seeds and
    candidates, and on the 2-core CI machine this halves their wall time.
    """
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=min(2, os.cpu_count() or 1)) as pool:
        yield pool


def _in_background(item) -> bool:
    """Whether ``item`` reads a command its module lists in ``BACKGROUND``."""
    table = getattr(getattr(item, "module", None), "BACKGROUND", None) or {}
    return getattr(item, "originalname", None) in table


def pytest_collection_modifyitems(items):
    """The tests that read a background command run last (in their order), so that their
    commands run beside the whole suite instead of making their tests wait."""
    items[:] = [i for i in items if not _in_background(i)] + [i for i in items
                                                                if _in_background(i)]


def _lower_priority() -> None:
    """In a background command's child before it starts: nice 10 (see ``_Background``)."""
    os.nice(10)


class _Background:
    """A command started at the session's start (see ``background``): ``python -m hhra_phys
    ARGV``, or, for an argument list that starts with ``"python"``, the interpreter under test
    with the rest (a script of the repository). It runs at ``nice`` 10: it takes the core
    that pytest leaves idle, never the one the tests in progress (and the loop's worker
    processes they wait for) run on."""

    def __init__(self, argv: list[str], out: Path, env: dict[str, str] | None = None):
        import subprocess
        import sys

        self.out = out
        # files, not pipes: a long run's output never fills a pipe nobody reads yet
        self._stdout = open(out / "stdout.txt", "w+")
        self._stderr = open(out / "stderr.txt", "w+")
        self._result: tuple[int, str, str] | None = None
        env = dict(os.environ, MPLBACKEND="Agg", **(env or {}))
        cmd = ([sys.executable, *argv[1:]] if argv[:1] == ["python"]
               else [sys.executable, "-m", "hhra_phys", *argv])
        self.proc = subprocess.Popen(cmd, cwd=out, stdout=self._stdout, stderr=self._stderr,
                                     env=env, preexec_fn=_lower_priority)

    def result(self, timeout: float = 900.0) -> tuple[int, str, str]:
        """Wait for the command: (exit code, stdout, stderr). Several tests may read one."""
        if self._result is None:
            code = self.proc.wait(timeout=timeout)
            texts = []
            for f in (self._stdout, self._stderr):
                f.seek(0)
                texts.append(f.read())
                f.close()
            self._result = (code, texts[0], texts[1])
        return self._result

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        for f in (self._stdout, self._stderr):
            if not f.closed:
                f.close()


@pytest.fixture(scope="session", autouse=True)
def background(request, tmp_path_factory):
    """Long CLI runs started when the session starts, in their own process.

    A test module may declare ``BACKGROUND = {"test name": [arguments of hhra-phys]}``
    (``{out}`` in an argument is the run's own empty folder; or a function of that folder
    that writes the command's inputs there and returns its arguments, or the arguments and
    extra environment variables; arguments that start with ``"python"`` run a script with
    the interpreter under test instead of ``hhra-phys``); when that test is
    selected, the command starts with the session and the test, moved to the end of the
    run (``pytest_collection_modifyitems``), reads ``background[name].result()``. pytest
    runs the tests on one core: on the 2-core CI machine such a run uses the other while
    the rest of the suite runs (the same command, the same assertions). What is still
    running when the session ends is killed.
    """
    jobs: dict[str, _Background] = {}
    for item in request.session.items:
        name = getattr(item, "originalname", None)
        if _in_background(item) and name not in jobs:
            out = tmp_path_factory.mktemp("background")
            spec = item.module.BACKGROUND[name]
            # a callable writes the command's inputs into its folder and gives its arguments
            argv = spec(out) if callable(spec) else [a.format(out=out) for a in spec]
            # a callable may also give the command's extra environment: (arguments, env)
            argv, env = argv if isinstance(argv, tuple) else (argv, None)
            jobs[name] = _Background(argv, out, env)
    yield jobs
    for job in jobs.values():
        job.stop()
