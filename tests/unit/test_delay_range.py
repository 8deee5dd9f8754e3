"""input_delay reaches beyond its box when the box is widened (issue 33): the part holds
``2*max_delay + 1`` lags, and within the box the extra lags weigh nothing."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys.effects import make_effect
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.reference.hhra import REFERENCE_GROUPS
from hhra_phys.simulate import Simulator

FS = 250.0


def _run(max_delay: int, delay: float, seed: int) -> np.ndarray:
    model = HHRAModel(output="angle").with_parts(make_effect("input_delay",
                                                             max_delay=max_delay))
    vals = {n: REFERENCE_GROUPS[n] for n in model.params.names if n in REFERENCE_GROUPS}
    vals["delay"] = delay
    p = np.array([vals[n] for n in model.params.names])
    u = np.repeat(np.random.default_rng(seed).uniform(-1, 1, 40), 25)
    return Simulator(model, fs=FS).simulate(u, p)


def test_the_default_part_holds_17_lags() -> None:
    eff = make_effect("input_delay")
    assert eff.max_delay == 8 and eff.n_lags == 17
    assert eff.parameters[0].upper == 8.0  # the box itself is unchanged


@pytest.mark.parametrize(("delay", "seed"), [(10.0, 0), (12.5, 1), (17.0, 2), (3.3, 3)])
def test_a_delay_beyond_the_box_is_the_delay(delay, seed) -> None:
    """The default part (box up to 8) at a delay of up to 17 samples simulates what a part
    built for it does; a shorter delay's output does not depend on the extra lags."""
    np.testing.assert_allclose(_run(8, delay, seed), _run(20, delay, seed), atol=1e-9)
    # and the delay does act: 10 samples is not 9
    if delay > 9:
        assert np.max(np.abs(_run(8, delay, seed) - _run(8, 9.0, seed))) > 1e-3
