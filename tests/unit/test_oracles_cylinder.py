"""Oracles for the cylinder model from the physics written out here, chamber by chamber.

Each chamber at mid-stroke holds half the swept volume plus its line's dead volume; the two
oil columns are springs ``beta A^2 / V_i`` in parallel on the piston. The model's resonance,
its steady velocity per mA and its transfer function must follow from that, not from the
model's own derived quantities.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from hhra_phys.models.cylinder import CylinderPhysical, LinearCylinderModel

# The nominal cylinder and two others (a short stroke with long lines, a large bore).
CASES = [
    CylinderPhysical(),
    replace(CylinderPhysical(), stroke=0.2, V_dead=1.5e-3, m=300.0, beta_e=1.4e9),
    replace(CylinderPhysical(), bore=0.125, rod=0.07, stroke=0.8, m=2500.0, B_p=4.0e4),
]


def _by_hand(c: CylinderPhysical) -> dict[str, float]:
    area = math.pi / 4 * c.bore**2 - math.pi / 4 * c.rod**2  # annulus of each side
    chamber = area * c.stroke / 2 + c.V_dead  # each side at mid-stroke
    stiffness = 2 * c.beta_e * area**2 / chamber  # two oil columns in parallel
    return {"area": area, "chamber": chamber, "w_h": math.sqrt(stiffness / c.m),
            # no-load flow of the critical-centre valve over the piston area
            "v_per_mA": c.C_d * c.w * c.k_x * math.sqrt(c.p_s / c.rho) / area}


def test_nominal_cylinder_is_the_documented_one() -> None:
    c = CylinderPhysical()
    h = _by_hand(c)
    assert h["area"] == pytest.approx(34.4e-4, rel=2e-3)  # 34.4 cm^2
    assert 2 * h["chamber"] == pytest.approx(2.72e-3, rel=2e-3)  # 2.72 L in all
    assert h["w_h"] == pytest.approx(147.0, rel=1e-2)  # 23 Hz
    assert c.natural_frequency() == pytest.approx(h["w_h"], rel=1e-9)
    assert c.velocity_gain() == pytest.approx(h["v_per_mA"], rel=1e-9)


@pytest.mark.parametrize("case", range(len(CASES)))
def test_model_resonance_and_gain_follow_from_the_chambers(case: int) -> None:
    c = CASES[case]
    h = _by_hand(c)
    model = LinearCylinderModel(nominal={k: v for k, v in c.groups().items() if k != "c_kp"})
    A, B, C, _ = model.linearize(model.nominal())
    lam = np.linalg.eigvals(A)
    osc = lam[np.abs(lam.imag) > 1e-6]
    # the hydraulic resonance: |lambda|^2 = w_h^2 + c_damping * c_leak
    g = c.groups()
    assert np.abs(osc[0]) == pytest.approx(math.sqrt(h["w_h"]**2 + g["c_damping"] * g["c_leak"]),
                                           rel=1e-6)
    # steady velocity per mA at rest [m/s]: the integrator's gain of x/I
    tf = model.tf_coefficients()
    assert tf["kv"] / tf["c"] == pytest.approx(
        h["v_per_mA"] * h["w_h"]**2 / (h["w_h"]**2 + g["c_damping"] * g["c_leak"]), rel=1e-6)
    # the transfer function is the linearisation's (characteristic polynomial and gain)
    np.testing.assert_allclose(np.poly(A), [1.0, tf["b"], tf["c"], tf["d"]], rtol=1e-9,
                               atol=1e-9 * tf["c"])
    s = 2j * h["w_h"]
    lin = complex((C @ np.linalg.solve(s * np.eye(3) - A, B))[0, 0])
    assert lin == pytest.approx(1000.0 * tf["kv"] / (s**3 + tf["b"] * s**2 + tf["c"] * s
                                                     + tf["d"]), rel=1e-9)


@pytest.mark.parametrize("case", range(len(CASES)))
def test_physical_symbols_from_groups_written_by_hand(case: int) -> None:
    c = CASES[case]
    h = _by_hand(c)
    v_t = 2 * h["chamber"]
    groups = {"c_force": h["area"] * c.p_s / c.m, "c_damping": c.B_p / c.m,
              "c_compress": 4 * c.beta_e * h["area"] / (v_t * c.p_s),
              "c_leak": 4 * c.beta_e * c.C_tp / v_t,
              "c_valve": 4 * c.beta_e * c.C_d * c.w * c.k_x / math.sqrt(c.rho) / (
                  v_t * math.sqrt(c.p_s))}
    for name, value in groups.items():
        assert c.groups()[name] == pytest.approx(value, rel=1e-9), name
    # solve the symbols back from groups of a changed plant (mass and bulk modulus x1.3)
    other = replace(c, m=1.3 * c.m, beta_e=1.3 * c.beta_e)
    back = c.from_groups(other.groups())
    assert back.m == pytest.approx(other.m, rel=1e-9)
    assert back.beta_e == pytest.approx(other.beta_e, rel=1e-9)
    assert back.C_tp == pytest.approx(c.C_tp, rel=1e-9)
