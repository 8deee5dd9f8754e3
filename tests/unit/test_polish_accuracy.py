"""An accepted model's polish checks its integration at the values it starts from.

A candidate refitted at the base fit's substeps (given, so no error estimate) was polished
there: on a drive whose Coulomb friction switches within 1e-4 m/s the polish ran at RK4 x 2
(the base's count, where the sharp sign is barely resolved) and the next rounds took
stand-ins for the discretisation error. ``loop._accuracy_checked`` runs the step-doubling
estimate at the polish's start values, keeps those values, and leaves a problem whose
simulator carries the estimate (so the polish's own check at its fitted values runs too).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from hhra_phys.diagnosis.fits import _accuracy_checked
from hhra_phys.effects import make_effect
from hhra_phys.problem import Problem
from hhra_phys.simulate import Simulator, accuracy_tolerance

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration" / "user_models"))
import drive  # noqa: E402


def _problem(width: float, substeps: int) -> Problem:
    data = drive.simulate_record(seed=4, n=1500, coulomb=0.3, width=width, noise=0.0005)
    base = drive.make_model()
    fr = make_effect("coulomb_friction", model=base, width=width)
    model = base.with_parts(fr)
    start = {**drive.TRUTH, "g_coulomb": 0.3}
    sim = Simulator(model, fs=data.fs, substeps=substeps, method="rk4")
    return Problem(model, data, cost="ssr", free=["k_motor", "c_visc", "g_coulomb"],
                   initial_state="fit", simulator=sim, start=start)


def test_a_sharp_friction_polish_gets_the_substeps_its_values_need():
    pr = _problem(1e-4, 2)
    assert not pr.sim.accuracy  # given substeps: no estimate, as a candidate's
    checked = _accuracy_checked(pr)
    acc = checked.sim.accuracy
    assert checked.sim.substeps > 2
    assert acc["error_estimate"] is not None and acc["within"], acc
    np.testing.assert_allclose(checked.start_values(), pr.start_values(), rtol=1e-12)
    # the estimate is honest: the coarse count's own error is beyond the tolerance
    rec = pr.records[0]
    v = pr.start_values()
    coarse = pr.sim.accurate(rec.u, pr.full(v), 0.0, x0=pr.initial_states(v)[0],
                             finest=8)
    assert coarse.accuracy["error_estimate"] > accuracy_tolerance(rec.y)


def test_a_smooth_friction_keeps_its_substeps_with_the_estimate_recorded():
    pr = _problem(5e-2, 2)
    checked = _accuracy_checked(pr)
    assert checked.sim.substeps == 2
    assert checked.sim.accuracy["within"], checked.sim.accuracy
