"""What the data cannot tell: undetermined directions get no interval, a discovered
term that only reparametrises the model is refused, the final fit's warnings reach
the diagnose JSON."""

import sys
from pathlib import Path

import numpy as np
import pytest

from hhra_phys import Simulator
from hhra_phys.data import Dataset
from hhra_phys.diagnosis.result import LoopResult
from hhra_phys.fit import fit
from hhra_phys.result import redundant, uncertainty, weak_directions
from hhra_phys.terms import DiscoveredTerm

sys.path.insert(0, str(Path(__file__).parent / "user_models"))
import two_tank  # noqa: E402


def _record(seed: int) -> Dataset:
    rng = np.random.default_rng(seed)
    n, fs = 900, 2.0
    u = np.repeat(rng.uniform(1.0, 4.0, n // 60 + 1), 60)[:n]
    m = two_tank.make_model()
    p = np.array([{"k_pump": 0.4}.get(q.name, q.nominal) for q in m.params])
    y = Simulator(m, fs=fs, substeps=8).simulate(u, p, x0=np.array([3.0, 5.0]))
    return Dataset(t=np.arange(n) / fs, u=u, y=y + 0.02 * rng.standard_normal(n),
                   name="tanks", input_name="pump", input_unit="V", output_name="level",
                   output_unit="cm")


def _term(spec: str, variable: str) -> DiscoveredTerm:
    return DiscoveredTerm(target="rate:h1", index=1, terms=(spec,), variables=(variable,),
                          scales=(1.0,), start=(0.0,), bound=(5.0,), knots=(0.0,),
                          knot_max=(0.0,), unit="cm/s", var_units=("V",))


@pytest.mark.parametrize("seed", [0, 1])
def test_a_term_duplicating_a_parameter_is_refused(seed):
    """``d h1/dt += a*u`` beside the pump gain ``k_pump*u``: one direction the data
    cannot see; both lose their interval (not a tight one), the term is refused."""
    term = _term("lin(u)", "u")
    res = fit(_record(seed), two_tank.make_model().with_parts(term), pop_size=10,
              max_iter=10, seed=seed)
    new = [p.name for p in term.parameters]
    reason = redundant(res, new)
    assert reason is not None and "k_pump" in reason and new[0] in reason
    for name in ("k_pump", new[0]):
        assert all(np.isnan(res.ci95[name]))
        assert name in res.intervals["reasons"]
    assert any("not identifiable" in w for w in res.warnings)
    # The well-determined parameters keep finite intervals.
    assert np.all(np.isfinite(res.ci95["a1"]))
    # The final fit's warnings reach the diagnose JSON.
    loop = LoopResult(base=res, final=res, steps=[], chosen=[], diagnoses=[],
                      final_diagnosis=None, settings={})
    out = loop.to_json()
    assert set(res.warnings) <= set(out["warnings"])
    assert out["fits"]["final"]["intervals"]["weak_directions"]
    assert "params" not in out["final"]  # each fit once: its parameters are in fits


def test_parameters_the_data_can_tell_are_not_redundant():
    """The two tanks alone: the pump gain and the lower outlet are correlated near 1
    on this record, but the data still determine them: no weak direction, nothing
    called redundant, finite intervals."""
    res = fit(_record(3), two_tank.make_model(), pop_size=10, max_iter=10, seed=3)
    assert not res.intervals.get("weak_directions")
    assert redundant(res, ["a2"]) is None
    assert all(np.all(np.isfinite(res.ci95[n])) for n in ("k_pump", "a1", "a2"))


@pytest.mark.slow
def test_a_term_the_data_can_tell_is_not_refused():
    """``d h1/dt += a*u^2`` is not a reparametrisation of the pump gain (50 s loaded:
    a model of its own to compile)."""
    term = _term("sq(u)", "u")
    res = fit(_record(2), two_tank.make_model().with_parts(term), pop_size=10, max_iter=10,
              seed=2)
    assert redundant(res, [p.name for p in term.parameters]) is None
    assert not res.intervals.get("weak_directions")


def test_weak_directions_of_a_singular_jacobian():
    rng = np.random.default_rng(0)
    a = rng.standard_normal(200)
    J = np.column_stack([a, 2 * a, rng.standard_normal(200)])
    weak = weak_directions(J, ["p", "q", "s"])
    assert len(weak) == 1 and set(weak[0]["params"]) == {"p", "q"}
    cov, corr, warns = uncertainty(J, 0.1 * rng.standard_normal(200), ["p", "q", "s"])
    assert np.isinf(cov[0, 0]) and np.isinf(cov[1, 1]) and np.isfinite(cov[2, 2])
    assert corr[0, 1] == pytest.approx(-1.0, abs=1e-6) or corr[0, 1] == pytest.approx(
        1.0, abs=1e-6)
    assert weak_directions(np.column_stack([a, rng.standard_normal(200)]), ["p", "q"]) == []
