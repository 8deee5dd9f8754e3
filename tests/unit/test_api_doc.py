"""docs/api.md is the generated, curated API map: current with the docstrings, not too long."""

from __future__ import annotations

import importlib.util
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _make_api():
    spec = importlib.util.spec_from_file_location("make_api", DOCS / "make_api.py")
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


def test_api_reference_is_current_and_curated():
    mod = _make_api()
    text = mod.render()
    assert len(text.splitlines()) <= mod.MAX_LINES
    assert (DOCS / "api.md").read_text() == text, "run: python docs/make_api.py"
    # every public module has a section, and the one-rule module is in it
    assert "## hhra_phys.selection" in text and "- `choose(" in text
