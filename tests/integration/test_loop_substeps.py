"""The loop's candidates are simulated as finely as the base fit ended.

A fit refines its substeps at the fitted values when the accuracy rule asks for more
(``fit._accurate_at_fit``); the loop scores its base there, so its candidates must start
from the same integration. On a two-tank record whose upper tank spills (a user's model
without the spill), the base fit ends at RK4 x 8 from a start of x 2; at x 2 the base's
own values cost 30 % more, and every candidate refit began from that worse point.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hhra_phys import Parameter, Part, Simulator, register_part
from hhra_phys.data import Dataset
from hhra_phys.diagnosis import engine

sys.path.insert(0, str(Path(__file__).parent / "user_models"))
import two_tank  # noqa: E402


@register_part
@dataclass(frozen=True)
class _Spill(Part):
    """Truth only: the upper tank spills above 15 cm (a smooth corner of 0.2 cm)."""

    name = "spill_truth"
    stage = "tanks"

    @property
    def parameters(self):
        return (Parameter("k_spill", "1/s", 2.0, 0.0, 10.0, "linear", "spill rate"),)

    def apply(self, ctx):
        z = (ctx.x["h1"] - 15.0) / 0.2
        ctx.add_rate("h1", -ctx.p["k_spill"] * 0.2 * 0.5 * (z + (z * z + 1.0) ** 0.5))


def _record(seed: int, n: int = 1024, fs: float = 0.25) -> Dataset:
    rng = np.random.default_rng(seed)
    levels = rng.uniform(0.5, 3.2, n // 40 + 1)
    levels[rng.choice(levels.size, 3, replace=False)] = rng.uniform(4.0, 4.5, 3)
    u = np.repeat(levels, 40)[:n]
    truth = two_tank.make_model().with_parts(_Spill())
    values = {"k_pump": 0.4, "a1": 0.35, "a2": 0.3}
    p = np.array([values.get(q.name, q.nominal) for q in truth.params])
    x0 = rng.uniform(2.0, 8.0, 2)
    y = Simulator(truth, fs=fs, substeps=8).simulate(u, p, x0=x0)
    return Dataset(t=np.arange(n) / fs, u=u, y=y + 0.05 * rng.standard_normal(n),
                   name="spilling tanks", input_unit="V", output_unit="cm")


def test_candidates_keep_the_substeps_the_base_fit_ended_with(monkeypatch):
    seen = []
    refit = engine.refit_candidate

    def spy(job):
        seen.append(job.cfg.substeps)
        return refit(job)

    monkeypatch.setattr(engine, "refit_candidate", spy)
    res = engine.diagnose(_record(2), model=two_tank.make_model(), candidates=["sensor_offset"],
                       discover=False, max_effects=1, seed=2, intersample=False,
                       background=False, pop_size=40, max_iter=60)
    integ = res.base.settings["integration"]
    # The case this guards: the accuracy rule refined the base fit's substeps.
    assert integ["substeps"] > integ["start_substeps"]
    assert seen == [((0.25, integ["substeps"]),)]
