"""Oracle for per-record parameters: records of plants that differ in one group, simulated by
the independent reference rig, fitted jointly with that group per record: each record's
reported value is its own plant's, and the stacked cost is the sum of the records' own."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys.fit import fit
from hhra_phys.models.cylinder import NOMINAL_GROUPS, LinearCylinderModel, simulate_cylinder
from hhra_phys.problem import Problem

FACTORS = (0.7, 1.4)  # moving mass of the two records' loads: c_force = A_p p_s / m


@pytest.fixture(scope="module")
def records():
    return [simulate_cylinder(seed=3 + k, duration=4.0, noise=0.02,
                              truth={"c_force": f * NOMINAL_GROUPS["c_force"]})
            for k, f in enumerate(FACTORS)]


def test_stacked_cost_is_the_sum_of_the_records_costs(records) -> None:
    model = LinearCylinderModel()
    free = ["c_force", "c_valve"]
    multi = Problem(model, records, cost="ssr", free=free, per_record=["c_force"])
    assert sorted(multi.free_names) == ["c_force_rec1", "c_force_rec2", "c_valve"]
    own = {"c_force_rec1": 0.8, "c_force_rec2": 1.3, "c_valve": 1.1}
    z = multi.to_z(np.array([own[n] * NOMINAL_GROUPS[n.split("_rec")[0]]
                             for n in multi.free_names]))
    total = 0.0
    for k, rec in enumerate(records, start=1):
        single = Problem(model, rec, cost="ssr", free=free)
        vals = np.array([own[f"c_force_rec{k}"] * NOMINAL_GROUPS["c_force"],
                         own["c_valve"] * NOMINAL_GROUPS["c_valve"]])
        total += float(single(single.to_z(vals)[None, :])[0])
    assert float(multi(z[None, :])[0]) == pytest.approx(total, rel=1e-9)


def test_each_record_reports_its_own_plant(records) -> None:
    res = fit(list(records), model=LinearCylinderModel(), optimizer="none", refine="ipopt",
              free=["c_force", "c_valve"], per_record=["c_force"], split=0.75,
              start={"c_force": NOMINAL_GROUPS["c_force"]}, widen_bounds=False)
    got = [rec["values"]["c_force"] for rec in res.records[:2]]
    want = [f * NOMINAL_GROUPS["c_force"] for f in FACTORS]
    np.testing.assert_allclose(got, want, rtol=0.05)
    assert res.values["c_valve"] == pytest.approx(NOMINAL_GROUPS["c_valve"], rel=0.05)
