"""Regime coverage (issue 33, item 2): how much of a candidate's regime each part holds."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hhra_phys.data import Dataset
from hhra_phys.diagnosis.selection import Step, split_record
from hhra_phys.effects import make_effect
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.problem import Problem
from hhra_phys.reference.hhra import REFERENCE_GROUPS
from hhra_phys.regime import regime_coverage

FS, N = 250.0, 2000


def _setup(seed: int, big_first: bool):
    """A record whose input reaches +-1 mA in one half and +-0.3 in the other (steps of
    25 samples), its parts and the base model's problem on the estimation part."""
    rng = np.random.default_rng(seed)
    amp = np.where((np.arange(N) < N // 2) == big_first, 1.0, 0.3)
    u = np.repeat(rng.uniform(-1, 1, N // 25), 25) * amp
    ds = Dataset(t=np.arange(N) / FS, u=u, y=0.01 * rng.standard_normal(N), name="r")
    est, sel, _ = split_record(ds, 0.5, 0.25)
    model = HHRAModel(output="angle")
    vals = {n: REFERENCE_GROUPS[n] for n in model.params.names if n in REFERENCE_GROUPS}
    pr = Problem(model, [est], free=["g_valve"], fixed={k: v for k, v in vals.items()
                                                       if k != "g_valve"},
                 start={"g_valve": vals["g_valve"]})
    return pr, est, sel


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_saturation_regime_in_one_part_only(seed) -> None:
    for big_first in (True, False):
        pr, est, sel = _setup(seed, big_first)
        eff = make_effect("valve_saturation", data=est if big_first else sel)
        cov = regime_coverage(eff, pr.per_record_values(pr.start_values()),
                              {"est": [None], "sel": [sel]})
        rich, poor = ("est", "sel") if big_first else ("sel", "est")
        assert cov[rich]["in_regime"] > 0.05 and cov[poor]["in_regime"] == 0.0
        assert cov[rich]["share"] == 1.0 and cov[poor]["share"] == 0.0
        assert cov["est"]["samples"] == est.n and cov["sel"]["samples"] == sel.n


@pytest.mark.parametrize("seed", [0, 3])
def test_a_delay_regime_is_in_both_parts(seed) -> None:
    pr, est, sel = _setup(seed, True)
    cov = regime_coverage(make_effect("input_delay"), pr.per_record_values(pr.start_values()),
                          {"est": [None], "sel": [sel]})
    # the input changes every 25 samples in both parts
    for part in ("est", "sel"):
        assert 0.02 < cov[part]["in_regime"] < 0.2
    assert cov["est"]["share"] + cov["sel"]["share"] == pytest.approx(1.0)


def test_without_a_column_nothing_is_claimed() -> None:
    pr, _, sel = _setup(0, True)

    class NoColumn:
        def first_order(self, sig):
            return None

    assert regime_coverage(NoColumn(), pr.per_record_values(pr.start_values()),
                           {"est": [None], "sel": [sel]}) is None


def test_the_step_carries_it_into_the_json() -> None:
    step = Step(1, "valve_saturation", {}, {}, {}, {}, {}, 0.0, 0.0, 0.0,
                regime={"est": {"samples": 10, "in_regime": 0.1, "share": 1.0}})
    d = json.loads(json.dumps(step.to_json()))
    assert d["regime"]["est"]["share"] == 1.0
    assert Step(1, "x", {}, {}, {}, {}, {}, 0.0, 0.0, 0.0).to_json()["regime"] is None
