"""The comparison's method registry: built-in rows on import, third-party entry points."""

from __future__ import annotations

import sys
import warnings
from collections.abc import Iterator
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

from hhra_phys import compare as C
from hhra_phys.compare import registry

PLUGIN = '''
import numpy as np

from hhra_phys.compare import MethodOutcome, register_method

CALLS = []


def _zero(est, val, settings):
    return MethodOutcome(np.zeros(est.n), np.zeros(val.n))


def register():
    CALLS.append(1)
    register_method("tp_zero", _zero, label="third-party zero")
    register_method("ls", _zero, label="not LS", replace=True)  # a clash with a built-in
'''


@pytest.fixture
def plugins(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[list[EntryPoint]]:
    """Entry points of the group, as the test sets them; the registry restored afterwards."""
    (tmp_path / "tp_compare_rows.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    eps: list[EntryPoint] = []
    monkeypatch.setattr(registry, "entry_points", lambda group: list(eps))
    monkeypatch.setattr(registry, "_plugins_loaded", False)
    methods, labels = dict(C.METHODS), dict(C.METHOD_LABELS)
    yield eps
    C.METHODS.clear()
    C.METHODS.update(methods)
    C.METHOD_LABELS.clear()
    C.METHOD_LABELS.update(labels)
    sys.modules.pop("tp_compare_rows", None)


def test_built_in_rows_are_registered_on_import_without_entry_points(plugins):
    names = C.available_methods()
    assert names[: len(C.ARX_METHODS)] == C.ARX_METHODS
    assert names[len(C.ARX_METHODS) :] == tuple(C.PHYSICAL_ROWS)
    assert C.method_label("phys_ipopt") == "physical IPOPT from nominal"
    C.register_physical()  # idempotent: the same functions, nothing replaced
    assert C.available_methods() == names


def test_entry_point_into_the_package_is_skipped(plugins):
    # What the metadata of an older installation still declares: loading it would fail (the
    # module is gone) or register the physical rows a second time.
    old = EntryPoint("physical", "hhra_phys.compare_physical:register", C.ENTRY_POINT_GROUP)
    plugins.append(old)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        C.load_plugins()


def test_third_party_entry_point_adds_but_never_replaces(plugins):
    ls = C.METHODS["ls"]
    plugins.append(EntryPoint("tp", "tp_compare_rows:register", C.ENTRY_POINT_GROUP))
    with pytest.warns(UserWarning, match=r"plugin 'tp' registered \['ls'\].*kept"):
        names = C.load_plugins()
    assert names[-1] == "tp_zero" and names.count("tp_zero") == 1
    assert C.METHODS["ls"] is ls and C.method_label("ls") == "LS"
    assert C.method_label("tp_zero") == "third-party zero"
    C.load_plugins()  # entry points are loaded once
    assert sys.modules["tp_compare_rows"].CALLS == [1]
