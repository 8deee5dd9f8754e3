"""The reference implementation's settings objects: a SolverOptions or RecordOptions and
the keywords they hold give the same simulation; bad settings are named."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys.reference import RecordOptions, SolverOptions, reference_record, simulate_reference
from hhra_phys.reference.hhra import REFERENCE_GROUPS

EFFECTS = {"coulomb_friction": {"g_coulomb": 12.0}}


@pytest.mark.parametrize("smooth", [True, False])
def test_solver_options_and_keywords_agree(smooth: bool) -> None:
    u = np.repeat([0.4, -0.3, 0.0, 0.5], 40)
    groups = {k: v for k, v in REFERENCE_GROUPS.items() if k != "g_kp"}
    kw = {"method": "Radau", "rtol": 1e-8, "atol": 1e-10, "stick_band": 1e-5}
    a = simulate_reference(u, 250.0, groups, effects=EFFECTS, smooth=smooth, **kw)
    b = simulate_reference(u, 250.0, groups, effects=EFFECTS, smooth=smooth,
                           solver=SolverOptions(**kw))
    c = simulate_reference(u, 250.0, groups, effects=EFFECTS, smooth=smooth,
                           solver=SolverOptions(**{**kw, "rtol": 1e-3}), rtol=1e-8)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)  # the keyword overrides the object


@pytest.mark.parametrize("seed", [0, 3])
def test_record_options_and_keywords_agree(seed: int) -> None:
    kw = {"amplitude": 0.6, "levels": 3, "noise_ar": 0.4, "drift_deg": 0.2,
          "quantization": 0.01, "rtol": 1e-8, "atol": 1e-10}
    a = reference_record(seed, 1.0, effects=EFFECTS, **kw)
    opts = RecordOptions(amplitude=0.6, levels=3, noise_ar=0.4, drift_deg=0.2,
                         quantization=0.01, solver=SolverOptions(rtol=1e-8, atol=1e-10))
    b = reference_record(seed, 1.0, effects=EFFECTS, options=opts)
    np.testing.assert_array_equal(a.u, b.u)
    np.testing.assert_array_equal(a.y, b.y)
    assert a.metadata["truth"]["integrator"] == {"method": "LSODA", "rtol": 1e-8,
                                                 "atol": 1e-10, "stick_band": 1e-6}
    # the record's truth reproduces its noise-free output with the same solver
    truth = a.metadata["truth"]
    y = simulate_reference(a.u, a.fs, truth["params"], effects=truth["effects"],
                           x0=truth["x0"], **truth["integrator"])
    assert np.max(np.abs(y - a.y)) < 5 * 0.05 + 0.2 + 0.01


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"method": "Euler"}, "method must be one of RK45"),
    ({"rtol": 0.0}, "rtol must be a finite number > 0"),
    ({"stick_band": -1.0}, "stick_band must be a finite number >= 0"),
    ({"noise_ar": 1.0}, r"noise_ar must be a finite number in \(-1, 1\)"),
    ({"levels": 0}, "levels must be an integer >= 1"),
    ({"amplitude": float("inf")}, "amplitude must be a finite number > 0"),
    ({"rtl": 1e-6}, "unknown reference record setting.*rtl"),
])
def test_bad_record_settings_are_named(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        reference_record(0, 1.0, **kwargs)
