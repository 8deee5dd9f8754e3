"""Oracles for time and unit conversion: records written to CSV with a known sample rate and
time unit, read back the way the CLI reads them, must give that rate; angles in known units
must give the known number of degrees."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hhra_phys.data import Dataset, load_csv
from hhra_phys.units import convert_record, rescale_time


def _write(path: Path, t: np.ndarray | None, u: np.ndarray, y: np.ndarray, unit: str = "deg"
           ) -> Path:
    cols = ([] if t is None else [t]) + [u, y]
    head = ("" if t is None else "t,") + f"u [mA],y [{unit}]"
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=head, comments="",
               fmt="%.12g")
    return path


@pytest.mark.parametrize(("fs", "unit", "factor"),
                         [(250.0, "ms", 1e3), (1000.0, "us", 1e6), (50.0, "s", 1.0)])
def test_time_column_in_a_unit_gives_the_true_rate(tmp_path, fs, unit, factor) -> None:
    n = 400
    rng = np.random.default_rng(int(fs))
    t_true = 3.0 + np.arange(n) / fs  # a record that does not start at 0
    path = _write(tmp_path / "r.csv", t_true * factor, rng.standard_normal(n),
                  rng.standard_normal(n))
    ds = rescale_time(load_csv(path), unit)
    assert ds.fs == pytest.approx(fs, rel=1e-9)
    assert ds.dt == pytest.approx(1.0 / fs, rel=1e-9)
    assert ds.duration == pytest.approx(n / fs, rel=1e-9)
    np.testing.assert_allclose(ds.t, t_true, rtol=1e-9)


@pytest.mark.parametrize("fs", [100.0, 2000.0])
def test_rate_without_time_column_starts_at_zero(tmp_path, fs) -> None:
    n = 100
    path = _write(tmp_path / "r.csv", None, np.linspace(-1, 1, n), np.sin(np.arange(n)))
    ds = load_csv(path, fs=fs)
    assert ds.t[0] == 0.0
    assert ds.t[-1] == pytest.approx((n - 1) / fs)
    assert ds.fs == pytest.approx(fs)
    built = Dataset.from_arrays(np.sin(np.arange(n)), np.arange(n, dtype=float), fs=fs)
    np.testing.assert_allclose(built.t, np.arange(n) / fs)


@pytest.mark.parametrize(("unit", "deg_per_unit"),
                         [("rad", 180 / math.pi), ("mrad", 0.18 / math.pi), ("rev", 360.0),
                          ("deg", 1.0)])
def test_angle_units_convert_to_degrees(unit, deg_per_unit) -> None:
    y = np.linspace(-2.0, 10.0, 30)
    ds = Dataset.from_arrays(np.sin(np.arange(30.0)), y, fs=10.0, output_unit=unit,
                             input_unit="mA")
    out, _ = convert_record(ds, input_unit="mA", output_unit="deg")
    # independent: a full turn is 2 pi rad = 360 deg = 1 rev, 1 mrad = 1e-3 rad
    np.testing.assert_allclose(out.y, y * deg_per_unit, rtol=1e-12)
    assert out.output_unit == "deg"
