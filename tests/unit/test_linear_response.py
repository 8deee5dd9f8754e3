"""The diagnosis's discrete linear response against scipy's ``dlsim``."""

import numpy as np
import pytest
import scipy.signal as sps

from hhra_phys.diagnose import _discrete_response


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("nx", [1, 3, 5])
def test_discrete_response_matches_dlsim(seed: int, nx: int) -> None:
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(nx, nx))
    A /= 1.02 * np.max(np.abs(np.linalg.eigvals(A)))  # stable, slowly decaying
    b, c, d = rng.normal(size=nx), rng.normal(size=nx), float(rng.normal())
    cols = rng.normal(size=(400, 4))
    got = _discrete_response(A, b, c, d, cols)
    for j in range(cols.shape[1]):
        _, y, _ = sps.dlsim((A, b[:, None], c[None, :], np.array([[d]]), 0.01), cols[:, j])
        np.testing.assert_allclose(got[:, j], y.ravel(), rtol=1e-12,
                                   atol=1e-12 * np.max(np.abs(y)))
