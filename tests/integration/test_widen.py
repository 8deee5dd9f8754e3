"""A group outside its default box: the fit widens that side and refits (MEASURED_NOTES 12).

The rig of ``experiments/widen_box.py`` has ``g_damping`` 28 times nominal. Measured there
(5 seeds, 8 s, pop 30, 40 it.): without widening b/c is 13-20 % off in 5/5 seeds, with it
below 5 % in 5/5 (median 1.1 %). The test asks for 2 of 3 seeds.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from hhra_phys.fit import fit
from hhra_phys.models.hhra.model import HHRAModel
from hhra_phys.models.hhra.rig import simulate_rig

_SPEC = importlib.util.spec_from_file_location(
    "widen_box", Path(__file__).resolve().parents[2] / "experiments" / "widen_box.py")
widen_box = importlib.util.module_from_spec(_SPEC)  # type: ignore[arg-type]
_SPEC.loader.exec_module(widen_box)  # type: ignore[union-attr]


def _bc_error(res, truth) -> float:
    tf = HHRAModel().tf_coefficients_of(truth)
    return abs((res.tf["b"] / res.tf["c"]) / (tf["b"] / tf["c"]) - 1)


@pytest.mark.slow
def test_a_group_beyond_its_default_box_is_recovered_by_widening() -> None:
    good = 0
    for seed in range(3):
        data = simulate_rig(seed=seed, duration=8.0, physical=widen_box.heavy_damping())
        res = fit(data, pop_size=30, max_iter=40, seed=seed)
        sides = {(w["name"], w["side"]) for w in res.settings["widened"]}
        assert ("g_damping", "upper") in sides
        assert any("that side was widened by" in w for w in res.warnings)
        assert not any("ended at its" in w for w in res.warnings)
        truth = data.metadata["true_params"]["g_damping"]
        assert res.settings["bounds"]["g_damping"][1] > truth  # the box now holds the truth
        good += _bc_error(res, data.metadata["true_params"]) < 0.05
    assert good >= 2


def test_explicit_bounds_are_never_widened() -> None:
    data = simulate_rig(seed=0, duration=6.0, physical=widen_box.heavy_damping())
    nominal = HHRAModel().params["g_damping"]
    box = (nominal.lower, nominal.upper)
    res = fit(data, pop_size=20, max_iter=20, seed=0, bounds={"g_damping": box})
    assert res.settings["bounds"]["g_damping"] == list(box)
    assert all(w["name"] != "g_damping" for w in res.settings.get("widened", []))
    assert any(w.startswith("g_damping ended at its upper bound") for w in res.warnings)
