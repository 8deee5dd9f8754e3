"""Oracle for the rule that claims a discovered resonance: a mode is claimed only when it is
a factor MODE_SEPARATION away from the model's own resonance on either side, and a load mode
only when the coupled model has one resonance more than the model without it. The own
resonance and the coupled model's modes are worked out here from the cylinder's physics
(eigenvalues of the linearised model, a two-mass system), not from the rule's code."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hhra_phys.diagnosis.discovery import _Fitted, _mode_rejected
from hhra_phys.models.cylinder import LinearCylinderModel, simulate_cylinder
from hhra_phys.problem import Problem
from hhra_phys.terms import MODE_SEPARATION, DiscoveredMode


@pytest.fixture(scope="module")
def setup():
    base = LinearCylinderModel()
    data = simulate_cylinder(seed=2, duration=2.0, noise=0.02)
    A = base.linearize(base.nominal())[0]
    lam = np.linalg.eigvals(A)
    w_own = float(np.abs(lam[lam.imag > 1e-6][0]))  # the hydraulic resonance [rad/s]
    return base, data, w_own


def _fitted(base, data, mode: DiscoveredMode, values: dict[str, float]) -> _Fitted:
    model = base.with_parts(mode)
    names = [p.name for p in mode.parameters]
    prob = Problem(model, data, free=names, allow_outside_box=True,
                   start={n: values[n] for n in names})
    ci = {n: (0.9 * values[n], 1.1 * values[n]) for n in names}  # clearly significant
    res = SimpleNamespace(values=dict(values), ci95=ci, x0_param=lambda n: 0.0)
    return _Fitted(mode, res, prob, names, 0.0, 0.0)


@pytest.mark.parametrize(("ratio", "claimed"),
                         [(0.55, True), (0.8, False), (1.25, False), (1.8, True)])
def test_output_mode_is_claimed_only_when_separated_on_either_side(setup, ratio, claimed):
    base, data, w_own = setup
    w = ratio * w_own
    mode = DiscoveredMode(target="output", index=1, w=w, zeta=0.1, mix=0.5, w_min=0.2 * w_own,
                          w_max=5 * w_own, unit="mm", time_unit="s")
    f = _fitted(base, data, mode, {"mode1_w": w, "mode1_z": 0.1, "mode1_k": 0.5})
    why = _mode_rejected(f, base, data, 1.0 / data.fs)
    assert (why == "") is claimed, (ratio, MODE_SEPARATION, why)


@pytest.mark.parametrize(("ratio", "k", "claimed"), [(3.0, 0.3, True), (1.08, 0.01, False)])
def test_load_mode_needs_one_more_resonance(setup, ratio, k, claimed):
    """A light load tuned near the own resonance (within the 20 % that count as one mode)
    leaves the coupled model with as many resolved resonances: not a second one."""
    base, data, w_own = setup
    w = ratio * w_own
    mode = DiscoveredMode(target="rate:v", index=1, w=w, zeta=0.1, mix=k, w_min=0.2 * w_own,
                          w_max=5 * w_own, unit="m/s", time_unit="s", twist_unit="m")
    f = _fitted(base, data, mode, {"mode1_w": w, "mode1_z": 0.1, "mode1_k": k})
    # the two-mass system: coupled eigenfrequencies from the linearised coupled model
    A = f.problem.model.linearize(f.problem.full(f.problem.start_values()))[0]
    lam = np.linalg.eigvals(A)
    ws = sorted(float(abs(x)) for x in lam[lam.imag > 1e-6])
    distinct = [ws[0]] + [x for a, x in zip(ws, ws[1:], strict=False) if x / a - 1 >= 0.2]
    assert (len(distinct) >= 2) is claimed  # the physics says whether there are two
    why = _mode_rejected(f, base, data, 1.0 / data.fs)
    assert (why == "") is claimed, why
