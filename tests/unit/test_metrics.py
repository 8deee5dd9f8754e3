"""Tests of hhra_phys.metrics against hand-computed values."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from hhra_phys import metrics as M
from hhra_phys.errors import DataError, ParameterError

# e = y - yhat = [0, 0, 1, 0, -2]; var(y) = 2; mean(e) = -0.2; var(e) = 0.96
Y = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
YHAT = np.array([0.0, 1.0, 1.0, 3.0, 6.0])


def test_hand_computed_values() -> None:
    assert M.mse(Y, YHAT) == pytest.approx(1.0)  # (1 + 4) / 5, squares (not the paper's -0.2)
    assert M.rmse(Y, YHAT) == pytest.approx(1.0)
    assert M.vaf(Y, YHAT) == pytest.approx(52.0)  # (1 - 0.96 / 2) * 100
    assert M.fit(Y, YHAT) == pytest.approx(100 * (1 - math.sqrt(5 / 10)))
    assert M.max_abs_error(Y, YHAT) == pytest.approx(2.0)


def test_itae_time_axis() -> None:
    # weights t_k - t_0 = 0, .1, .2, .3, .4; |e| = 0, 0, 1, 0, 2; dt = 0.1
    t = 10.0 + 0.1 * np.arange(5)  # a segment that does not start at 0
    assert M.itae(Y, YHAT, t) == pytest.approx((0.2 * 1 + 0.4 * 2) * 0.1)
    assert M.itae(Y, YHAT) == pytest.approx(2 * 1 + 4 * 2)  # sample units
    assert M.itae(Y, YHAT, dt=0.5) == pytest.approx((1.0 * 1 + 2.0 * 2) * 0.5)
    with pytest.raises(ParameterError):
        M.itae(Y, YHAT, t, dt=0.1)
    with pytest.raises(DataError, match="t has shape"):
        M.itae(Y, YHAT, np.arange(4.0))


def test_vaf_ignores_offset_fit_does_not() -> None:
    assert M.vaf(Y, Y + 3.0) == pytest.approx(100.0)
    assert M.fit(Y, Y + 3.0) < 0.0
    assert M.fit(Y, np.full(5, Y.mean())) == pytest.approx(0.0)
    assert M.vaf(Y, Y) == M.fit(Y, Y) == 100.0


def test_score_keys_and_values() -> None:
    t = 0.1 * np.arange(5)
    s = M.score(Y.tolist(), YHAT.tolist(), t)
    assert tuple(s) == M.KEYS == ("mse", "rmse", "vaf", "itae", "fit", "max_abs")
    assert s["itae"] == pytest.approx(0.1)
    assert s["vaf"] == pytest.approx(52.0)
    assert all(isinstance(v, float) for v in s.values())


def test_batch_rows_match_single_and_nonfinite_rows_are_worst() -> None:
    rng = np.random.default_rng(0)
    y = rng.normal(size=50)
    good = y + 0.1 * rng.normal(size=50)
    nan_row = good.copy()
    nan_row[7] = np.nan
    inf_row = good.copy()
    inf_row[0] = -np.inf
    huge = np.full(50, 1e308) * np.where(np.arange(50) % 2, 1, -1)  # overflows, finite input
    batch = np.vstack([good, nan_row, inf_row, huge])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning leaks out
        s = M.score(y, batch)
    single = M.score(y, good)
    for key in M.KEYS:
        assert s[key].shape == (4,)
        assert s[key][0] == pytest.approx(single[key])
        assert not np.isnan(s[key]).any()
    for key in ("mse", "rmse", "itae", "max_abs"):
        assert np.all(s[key][1:3] == np.inf)
    for key in ("vaf", "fit"):
        assert np.all(s[key][1:] == -np.inf)
    assert M.mse(y, nan_row) == np.inf and M.vaf(y, nan_row) == -np.inf


def test_shape_and_data_errors() -> None:
    with pytest.raises(DataError, match="shape mismatch"):
        M.mse(Y, YHAT[:4])
    with pytest.raises(DataError, match="shape mismatch"):
        M.score(Y, np.ones((5, 2)))
    with pytest.raises(DataError, match="1-D"):
        M.rmse(np.ones((2, 5)), np.ones((2, 5)))
    with pytest.raises(DataError, match="rows 2"):
        M.mse(np.array([1.0, 2.0, np.nan]), np.ones(3))
    with pytest.raises(DataError, match="constant"):
        M.vaf(np.ones(5), np.arange(5.0))
    with pytest.raises(DataError, match="constant"):
        M.fit(np.ones(5), np.arange(5.0))
