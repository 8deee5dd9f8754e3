"""Hand-computed metric values where the shortcuts of ``tests/test_metrics.py`` hide a bug.

``tests/test_metrics.py`` uses a case with ``mse = 1``, where ``sqrt(mse) == mse``: an RMSE that
forgot the square root passed it (the ``metrics-rmse-no-root`` mutation of
``benchmarks/mutations.py``). Here the errors are chosen so every value is distinct from its
square.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hhra_phys import metrics as M

Y = np.array([0.0, 1.0, 2.0, 3.0, 4.0])


def test_rmse_is_the_root_of_the_mean_square() -> None:
    yhat = np.array([1.0, 1.0, 2.0, 3.0, 3.0])  # e = [-1, 0, 0, 0, 1]: mse = 2/5
    assert M.mse(Y, yhat) == pytest.approx(0.4)
    assert M.rmse(Y, yhat) == pytest.approx(math.sqrt(0.4))
    # a constant offset c gives rmse = |c| in output units, whatever c
    for c in (0.1, 3.0, -7.5):
        assert M.rmse(Y, Y + c) == pytest.approx(abs(c))


def test_rmse_batch_rows() -> None:
    batch = np.vstack([Y + 0.5, Y - 2.0, Y])
    np.testing.assert_allclose(M.rmse(Y, batch), [0.5, 2.0, 0.0])
