"""Run every shell and Python block of docs/guide.md, in order, in an empty directory.

A block preceded by ``<!-- guide-test: repo -->`` runs in the repository's root instead.
The installation block (``<!-- guide-test: install -->``) is not re-run (it would modify
the environment and needs the network); the test checks instead that the package it
installs is this checkout, installed editable, with the ``test`` extra declared. The blocks
run in a process of their own started with the session (``BACKGROUND``; ``python
tests/integration/test_guide.py FOLDER`` runs them alone), and each block's test reads its
exit code.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
GUIDE = REPO / "docs" / "guide.md"
BLOCK = re.compile(
    r"(?:<!-- guide-test: (?P<mode>[\w-]+) -->\n)?```(?P<lang>bash|python)\n(?P<code>.*?)```",
    re.S,
)
TIMEOUT = 300


def guide_blocks() -> list[tuple[int, str, str, str]]:
    """(line, language, mode, code) of every bash/python block of the guide."""
    text = GUIDE.read_text()
    out = []
    for m in BLOCK.finditer(text):
        line = text.count("\n", 0, m.start("code")) + 1
        out.append((line, m["lang"], m["mode"] or "tmp", m["code"]))
    return out


BLOCKS = guide_blocks()


def test_guide_has_the_sections_and_blocks():
    text = GUIDE.read_text()
    for heading in ("Installation", "Quick start", "Preparing your own data", "Fitting",
                    "Reading the result and its uncertainty", "Comparing methods",
                    "The diagnosis loop", "Controller design", "A model of another actuator",
                    "Your own system",
                    "Running on several machines", "API reference"):
        assert f"## {heading}\n" in text, heading
    assert sum(lang == "bash" for _, lang, _, _ in BLOCKS) >= 5
    assert sum(lang == "python" for _, lang, _, _ in BLOCKS) >= 8
    # Every fenced block is one the test runs (or an explicit text block).
    fences = re.findall(r"^```(\w*)$", text, re.M)
    langs = [f for f in fences if f]
    assert set(langs) <= {"bash", "python", "text"}, set(langs)
    assert len([f for f in langs if f in ("bash", "python")]) == len(BLOCKS)


@pytest.fixture(scope="module")
def shims(tmp_path_factory) -> Path:
    """A folder whose ``hhra-phys`` and ``python`` are the interpreter under test."""
    return _make_shims(tmp_path_factory.mktemp("bin"))


def _make_shims(d: Path) -> Path:
    """Write into ``d`` an ``hhra-phys``, ``python`` and ``python3`` that run the interpreter
    under test.

    The guide's shell blocks call ``hhra-phys`` and ``python``; run as
    ``venv/bin/python -m pytest`` without activating the venv, PATH would find another
    installation's (or none). Put first on PATH, these run ``sys.executable -m hhra_phys``.
    """
    d.mkdir(parents=True, exist_ok=True)
    for name, target in (("hhra-phys", f'"{sys.executable}" -m hhra_phys'),
                         ("python", f'"{sys.executable}"'), ("python3", f'"{sys.executable}"')):
        f = d / name
        f.write_text(f'#!/bin/sh\nexec {target} "$@"\n')
        f.chmod(0o755)
    return d


def _env(shims: Path | None = None) -> dict[str, str]:
    env = dict(os.environ)
    if shims is not None:
        env["PATH"] = f"{shims}{os.pathsep}{env.get('PATH', '')}"
    env["MPLBACKEND"] = "Agg"
    # The examples' fits show no progress bars; keep the child's output small anyway.
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def _run_block(line: int, lang: str, mode: str, code: str, workdir: Path,
               shims: Path) -> tuple[int, str, str]:
    """Run one block as a user would: (exit code, stdout, stderr)."""
    cwd = REPO if mode == "repo" else workdir
    if lang == "bash":
        cmd = ["bash", "-euo", "pipefail", "-c", code]
    else:
        script = workdir / f"guide_line{line}.py"
        script.write_text(code)
        cmd = [sys.executable, str(script)]
    try:
        proc = subprocess.run(cmd, cwd=cwd, env=_env(shims), capture_output=True, text=True,
                              timeout=TIMEOUT)
    except subprocess.TimeoutExpired as exc:
        return -1, str(exc.stdout or ""), f"timed out after {TIMEOUT} s"
    return proc.returncode, proc.stdout, proc.stderr


def run_guide(folder: Path) -> None:
    """Every block but the installation's, in order, in ``folder/guide`` (one working
    directory, as a reader's): ``folder/results.json`` maps each block's line to its
    (exit code, stdout, stderr)."""
    workdir = folder / "guide"
    workdir.mkdir(parents=True, exist_ok=True)
    shims = _make_shims(folder / "bin")
    results = {line: _run_block(line, lang, mode, code, workdir, shims)
               for line, lang, mode, code in BLOCKS if mode != "install"}
    (folder / "results.json").write_text(json.dumps(results))


#: The blocks run one after the other in a process of their own that starts with the
#: session (tests/conftest.py, ``background``): about a minute and a half of fits and CLI
#: runs on the core pytest leaves idle; each block's test reads its outcome.
BACKGROUND = {"test_guide_block": lambda folder: ["python", __file__, str(folder)]}


@pytest.fixture(scope="module")
def guide_results(background) -> dict[int, tuple[int, str, str]]:
    run = background["test_guide_block"]
    code, _, err = run.result()
    assert code == 0, f"the guide's runner failed:\n{err[-3000:]}"
    return {int(k): v for k, v in json.loads((run.out / "results.json").read_text()).items()}


# In the default run: the guide is what a user follows first (about a minute on an idle
# machine, its loop example the longest block).
@pytest.mark.parametrize(("line", "lang", "mode", "code"), BLOCKS,
                         ids=[f"line{b[0]}-{b[1]}" for b in BLOCKS])
def test_guide_block(line, lang, mode, code, request):
    if mode == "install":
        _check_install(code)
        return
    returncode, stdout, stderr = request.getfixturevalue("guide_results")[line]
    assert returncode == 0, (
        f"docs/guide.md block at line {line} ({lang}) failed with exit {returncode}\n"
        f"--- stdout ---\n{stdout[-3000:]}\n--- stderr ---\n{stderr[-3000:]}"
    )


def _check_install(code: str) -> None:
    assert 'pip install -e ".[test]"' in code
    import hhra_phys

    # The installed package is this checkout (editable install).
    assert Path(hhra_phys.__file__).resolve().is_relative_to(REPO)
    pyproject = (REPO / "pyproject.toml").read_text()
    assert re.search(r"^test\s*=", pyproject, re.M), "pyproject.toml has no 'test' extra"
    # Through the interpreter under test, not whatever 'hhra-phys' PATH finds first.
    proc = subprocess.run([sys.executable, "-m", "hhra_phys", "--help"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0 and "fit" in proc.stdout


def test_the_cli_runs_through_this_interpreter(shims):
    """``python -m hhra_phys`` is the command, and the guide's PATH finds it first."""
    proc = subprocess.run(["sh", "-c", "command -v hhra-phys && hhra-phys --help"],
                          env=_env(shims), capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(str(shims)) and "design" in proc.stdout


if __name__ == "__main__":
    run_guide(Path(sys.argv[1]))
