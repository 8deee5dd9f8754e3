"""The simulated rig: the paper's protocol, truth in the metadata, noise and quantisation."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys import HHRAModel
from hhra_phys.errors import ParameterError
from hhra_phys.models.hhra.physical import PhysicalParameters
from hhra_phys.models.hhra.rig import perturbed_physical, rig_model, simulate_rig


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_angle_stays_within_90_degrees_and_protocol_holds(seed):
    ds = simulate_rig(seed=seed)
    assert len(ds) == 5000 and ds.fs == pytest.approx(250.0)
    assert np.abs(ds.y).max() <= 90.0
    assert np.ptp(ds.y) > 20.0  # the shaft really moves
    levels = np.unique(np.round(np.abs(ds.u[ds.u != 0]), 9))
    assert levels.size >= 3  # several amplitude levels, not a binary signal
    assert abs(ds.u.mean()) < 1e-12  # inverse-repeat: zero mean


def test_truth_and_noise_in_metadata():
    clean = simulate_rig(seed=3, noise=0.0)
    noisy = simulate_rig(seed=3, noise=0.2)
    np.testing.assert_array_equal(clean.u, noisy.u)
    resid = noisy.y - clean.y
    assert resid.std() == pytest.approx(0.2, rel=0.05)
    truth = clean.metadata["true_params"]
    model = HHRAModel()
    for name in model.params.names:
        assert truth[name] == pytest.approx(PhysicalParameters().groups()[name])
    assert clean.metadata["noise_deg"] == 0.0 and clean.metadata["seed"] == 3
    assert np.radians(clean.y[0]) == pytest.approx(clean.metadata["x0"]["theta"])


def test_quantization_and_seeds():
    q = 360 / 2**13
    ds = simulate_rig(seed=1, duration=2.0, quantization=q)
    np.testing.assert_allclose(ds.y / q, np.round(ds.y / q), atol=1e-9)
    a, b = simulate_rig(seed=5, duration=2.0), simulate_rig(seed=5, duration=2.0)
    np.testing.assert_array_equal(a.y, b.y)
    assert not np.array_equal(a.y, simulate_rig(seed=6, duration=2.0).y)
    with pytest.raises(ParameterError, match="noise"):
        simulate_rig(noise=-1.0)


def test_perturbed_truth_lies_away_from_nominal():
    phys = perturbed_physical(3)
    model, truth = rig_model(phys)
    nominal = HHRAModel().nominal()
    moved = np.abs(np.log(truth[:5] / nominal[:5]))
    assert moved.max() > np.log(1.3)
    ds = simulate_rig(seed=0, duration=4.0, physical=phys)
    assert ds.metadata["physical"]["J"] == pytest.approx(phys.J)
