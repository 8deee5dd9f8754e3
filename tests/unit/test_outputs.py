"""The output-path guard, atomic writes and the JSON sanitiser of hhra_phys.outputs."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hhra_phys.errors import HHRAError, OutputExistsError, OutputPathError, ParameterError
from hhra_phys.outputs import (
    FIGURE_SUFFIXES,
    atomic_path,
    atomic_write_bytes,
    atomic_write_text,
    check_output_path,
    jsonable,
)

# tmp_path is shared by the examples of one test; each example writes its own files.
_TMP = [HealthCheck.function_scoped_fixture]

# --------------------------------------------------------------------------- check_output_path


def test_guard_accepts_a_new_file_and_names_every_problem(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    assert check_output_path(target) == target
    target.write_text("x")
    with pytest.raises(OutputExistsError, match=r"result .*out\.json exists; pass overwrite"):
        check_output_path(target, what="result")
    assert check_output_path(target, overwrite=True) == target
    with pytest.raises(OutputPathError, match=r"nowhere.*does not exist"):
        check_output_path(tmp_path / "nowhere" / "f.json")
    with pytest.raises(OutputPathError, match="is a directory"):
        check_output_path(tmp_path, overwrite=True)
    with pytest.raises(OutputPathError, match=r"f\.txt: unsupported suffix '\.txt'; use \.png"):
        check_output_path(tmp_path / "f.txt", suffixes=FIGURE_SUFFIXES)
    assert check_output_path(tmp_path / "F.PNG", suffixes=FIGURE_SUFFIXES).name == "F.PNG"


def test_guard_errors_keep_the_old_exception_types(tmp_path: Path) -> None:
    (tmp_path / "a").write_text("")
    with pytest.raises(FileExistsError):  # what result.save and plots raised before
        check_output_path(tmp_path / "a")
    with pytest.raises(ParameterError):  # what compare and the CLI raised before
        check_output_path(tmp_path / "a")
    assert issubclass(OutputPathError, HHRAError)


@pytest.mark.skipif(os.geteuid() == 0 if hasattr(os, "geteuid") else True,
                    reason="root may write anywhere")
def test_guard_not_writable(tmp_path: Path) -> None:
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(OutputPathError, match="not writable"):
            check_output_path(locked / "f.json")
    finally:
        locked.chmod(0o700)


# --------------------------------------------------------------------------- atomic writes


def test_atomic_write_replaces_and_leaves_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "r.json"
    atomic_write_text(target, "one\n")
    atomic_write_bytes(target, b"two\r\n")
    assert target.read_bytes() == b"two\r\n"  # bytes as given, no newline translation
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_atomic_path_keeps_the_suffix_for_format_inference(tmp_path: Path) -> None:
    with atomic_path(tmp_path / "fig.png") as tmp:
        assert tmp.suffix == ".png" and tmp.parent == tmp_path
        tmp.write_bytes(b"png")
    assert (tmp_path / "fig.png").read_bytes() == b"png"


class Boom(Exception):
    pass


@settings(max_examples=40, deadline=None, suppress_health_check=_TMP)
@given(
    old=st.one_of(st.none(), st.binary(max_size=64)),
    partial=st.binary(max_size=256),
    name=st.sampled_from(["out.json", "fig.png", "data.npz", "noext"]),
)

def test_failure_inside_atomic_path_leaves_the_target_as_it_was(
    tmp_path: Path, old: bytes | None, partial: bytes, name: str
) -> None:
    folder = tmp_path / f"case{abs(hash((old, partial, name)))}"
    folder.mkdir()
    target = folder / name
    if old is not None:
        target.write_bytes(old)
    with pytest.raises(Boom), atomic_path(target) as tmp:
        tmp.write_bytes(partial)  # half-written output, then the writer fails
        raise Boom
    assert sorted(p.name for p in folder.iterdir()) == ([name] if old is not None else [])
    if old is not None:
        assert target.read_bytes() == old


def test_savefig_through_atomic_path(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    with atomic_path(tmp_path / "f.pdf") as tmp:
        fig.savefig(tmp)
    plt.close(fig)
    assert (tmp_path / "f.pdf").read_bytes().startswith(b"%PDF")


# --------------------------------------------------------------------------- jsonable


@dataclass
class _Point:
    x: float
    tags: tuple[str, ...]


def test_jsonable_types() -> None:
    obj = {
        "a": np.float64(1.5), "b": np.int32(3), "c": np.bool_(True), "d": np.array([[1, 2]]),
        "e": (1.0, math.nan, -math.inf), "f": _Point(0.25, ("x",)), "g": Path("/tmp/x"),
        "h": {2: np.float32(0.5)}, "i": 1 + 2j, "j": {"b", "a"}, "k": None,
    }
    out = jsonable(obj)
    assert out == {
        "a": 1.5, "b": 3, "c": True, "d": [[1, 2]], "e": [1.0, None, None],
        "f": {"x": 0.25, "tags": ["x"]}, "g": "/tmp/x", "h": {"2": 0.5}, "i": [1.0, 2.0],
        "j": ["a", "b"], "k": None,
    }
    json.dumps(out, allow_nan=False)  # strict JSON
    with pytest.raises(TypeError, match="object is not JSON"):
        jsonable(object())
    assert jsonable({"o": object}, default=lambda o: "obj") == {"o": "obj"}


@given(st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=5)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.tuples(inner, inner),
                            st.dictionaries(st.text(max_size=4), inner, max_size=4)),
    max_leaves=20,
))
def test_jsonable_is_strict_json_and_keeps_finite_values(obj: object) -> None:
    text = json.dumps(jsonable(obj), allow_nan=False)
    if "NaN" not in json.dumps(obj) and "Infinity" not in json.dumps(obj):
        # finite input: the same bytes as json.dumps of the original
        assert text == json.dumps(obj)
