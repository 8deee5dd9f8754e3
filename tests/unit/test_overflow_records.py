"""experiments/overflow_records.py's records and user files (the study itself is not run in
CI: a diagnosis per seed; its rows are in experiments/results/)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from hhra_phys.parts import EFFECTS

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def study():
    spec = importlib.util.spec_from_file_location(
        "overflow_records", ROOT / "experiments" / "overflow_records.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["overflow_records"] = mod
    before = dict(EFFECTS)
    spec.loader.exec_module(mod)
    yield mod
    # The user's effect joined the registry on import: other tests loop over it.
    EFFECTS.clear()
    EFFECTS.update(before)


def test_early_records_overflow_in_the_estimation_half_only(study):
    for seed in (1, 2):
        _, h1 = study.record(seed, 0, "early")
        rim = study.TRUTH["h_max"]
        assert np.mean(h1[: study.N // 2] > rim) > 0.05
        assert np.mean(h1[study.N // 2:] > rim) == 0.0
        # the test record is drawn as in "parts": same for both families
        a, _ = study.record(seed, 1, "early")
        b, _ = study.record(seed, 1, "parts")
        assert np.array_equal(a.y, b.y)


def test_parts_records_are_seeded_and_overflow_somewhere(study):
    d1, h1 = study.record(3, 0)
    d2, _ = study.record(3, 0)
    assert np.array_equal(d1.y, d2.y) and d1.n == study.N
    assert np.mean(h1 > study.TRUTH["h_max"]) > 0.05


def test_the_users_overflow_binds_to_the_users_model(study):
    model = study.tank_model.make_model()
    eff = study.overflow.Overflow()
    assert eff.applicable(model) is None
    assert "h_max" in model.with_parts(eff).params.names
