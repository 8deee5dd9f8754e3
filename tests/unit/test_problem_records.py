"""One Problem for any number of records: a record is a set of one."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys.errors import ParameterError
from hhra_phys.models.cylinder import LinearCylinderModel, simulate_cylinder
from hhra_phys.problem import Problem, RecordProblem, as_records


@pytest.fixture(scope="module")
def records():
    return [simulate_cylinder(seed=k, duration=d, noise=0.02)
            for k, d in ((5, 3.0), (6, 2.0))]


def test_a_record_and_a_list_of_one_are_the_same_problem(records) -> None:
    model = LinearCylinderModel()
    one = Problem(model, records[0], cost="ssr", initial_state="fit")
    listed = Problem(model, [records[0]], cost="ssr", initial_state="fit")
    assert one.free_names == listed.free_names
    assert not any("_rec" in n for n in one.free_names)
    z = one.to_z(one.start_values())
    Z = np.stack([z, z + 0.01])
    np.testing.assert_array_equal(one(Z), listed(Z))
    # the record's own part is the problem's block, at the same coordinates
    (rec, idx), = one.blocks()
    assert isinstance(rec, RecordProblem)
    np.testing.assert_array_equal(idx, np.arange(one.n_free))
    np.testing.assert_array_equal(one(Z), rec(Z))


@pytest.mark.parametrize("seed_shift", [0, 1])
def test_several_records_share_the_model_and_own_their_initial_states(records,
                                                                     seed_shift) -> None:
    model = LinearCylinderModel()
    recs = records[seed_shift:] + records[:seed_shift]
    pr = Problem(model, recs, cost="ssr", initial_state="fit")
    own = [n for n in pr.free_names if n.startswith("x0_")]
    assert own and all(n.endswith(("_rec1", "_rec2")) for n in own)
    shared = [n for n in pr.free_names if not n.startswith("x0_")]
    assert shared == [n for n in Problem(model, recs[0]).free_names if not n.startswith("x0_")]
    v = pr.start_values()
    parts = pr.simulate_parts(v)
    assert [p.size for p in parts] == [len(ds) for ds in recs]
    np.testing.assert_array_equal(pr.simulate_values(v), np.concatenate(parts))
    # the cost is the sum of the records' own
    z = pr.to_z(v)[None, :]
    total = sum(float(rec(z[:, idx])[0]) for rec, idx in pr.blocks())
    assert float(pr(z)[0]) == pytest.approx(total, rel=1e-12)


def test_records_are_checked_by_kind(records) -> None:
    with pytest.raises(ParameterError, match="at least one record"):
        as_records([])
    with pytest.raises(ParameterError, match="Dataset"):
        as_records([records[0], np.zeros(3)])  # type: ignore[list-item]
    with pytest.raises(ParameterError, match="only 2 records"):
        Problem(LinearCylinderModel(), records, start={"x0_x_rec3": 0.0})


@pytest.mark.parametrize("n_records", [1, 2])
def test_a_problem_with_finer_substeps_starts_where_it_started(records, n_records) -> None:
    # with_simulator rebuilds the problem (with_boxes): the free parameters' start values,
    # fitted initial states and per-record ones included, must survive, or a polish at
    # finer substeps restarts from the model's nominal values.
    model = LinearCylinderModel()
    recs = records[:n_records]
    base = Problem(model, recs, cost="ssr", initial_state="fit")
    start = {n: v * 1.3 + 0.01 for n, v in zip(base.free_names, base.start_values(),
                                               strict=True)}
    pr = Problem(model, recs, cost="ssr", initial_state="fit", start=start)
    want = pr.start_values()
    assert not np.allclose(want, base.start_values())
    finer = pr.with_simulator(pr.sim.with_substeps(pr.sim.substeps * 2))
    assert finer.sim.substeps == pr.sim.substeps * 2
    assert finer.free_names == pr.free_names
    np.testing.assert_allclose(finer.start_values(), want, rtol=1e-12)
    widened = pr.with_boxes({})
    np.testing.assert_allclose(widened.start_values(), want, rtol=1e-12)
