"""Units of records, held-value checks, singular information and the interrupt guard."""

from __future__ import annotations

import math
import os
import signal

import numpy as np
import pytest

from hhra_phys.data import Dataset
from hhra_phys.errors import DataError, ParameterError, SimulationError
from hhra_phys.interrupt import interruptible
from hhra_phys.models.hhra.defaults import prepare_record
from hhra_phys.models.hhra.model import HHRAModel
from hhra_phys.result import uncertainty
from hhra_phys.simulate import Simulator
from hhra_phys.units import conversion_factor, convert_record, rescale_time


def _record(u_scale: float = 1.0, y_scale: float = 1.0, fs: float = 250.0, **kw) -> Dataset:
    rng = np.random.default_rng(0)
    n = 500
    u = np.repeat(rng.uniform(-1, 1, n // 25), 25)
    y = np.cumsum(u) * 0.1 * y_scale  # spans about 10 deg, like a short rig record
    return Dataset.from_arrays(u * u_scale, y, fs=fs, source="rec.csv", **kw)


def test_conversion_factors() -> None:
    assert conversion_factor("rad", "deg") == pytest.approx(180 / math.pi)
    assert conversion_factor("A", "mA") == pytest.approx(1000.0)
    assert conversion_factor("ms", "s") == pytest.approx(1e-3)
    assert conversion_factor("deg", "deg") == 1.0
    assert conversion_factor("V", "deg") is None


def test_a_record_in_radians_and_amperes_is_converted() -> None:
    ds = _record(output_unit="rad", input_unit="A")
    out, notes = convert_record(ds, input_unit="mA", output_unit="deg")
    np.testing.assert_allclose(out.y, ds.y * 180 / math.pi)
    np.testing.assert_allclose(out.u, ds.u * 1000)
    assert (out.input_unit, out.output_unit) == ("mA", "deg")
    assert len(notes) == 2 and "from rad to deg" in notes[1]
    assert out.metadata["converted_units"]["output"][:2] == ["rad", "deg"]


def test_an_unconvertible_unit_is_an_error_naming_both() -> None:
    with pytest.raises(DataError, match=r"rec\.csv.*'V'.*'deg'"):
        convert_record(_record(output_unit="V"), output_unit="deg")
    same, notes = convert_record(_record(output_unit="raw"), output_unit="deg")
    assert same.output_unit == "raw" and not notes  # a scale-free unit is taken as it is


@pytest.mark.parametrize(
    ("kw", "words"),
    [
        ({"y_scale": math.pi / 180}, "radians"),       # an angle record in rad, labelled deg
        ({"y_scale": 1e5}, "scaled"),                  # output scaled by 1e5
        ({"u_scale": 1e-3}, "in A rather than mA"),    # input in A, labelled mA
        ({"fs": 0.25}, "--time-unit ms"),              # a time column in ms
    ],
)
def test_implausible_ranges_are_warned(kw: dict, words: str) -> None:
    _, _, warns = prepare_record(_record(**kw))
    assert len(warns) == 1 and words in warns[0] and "rec.csv" in warns[0]


def test_a_plausible_record_gets_no_warning() -> None:
    assert prepare_record(_record())[2] == []


def test_time_rescaling() -> None:
    ds = _record(fs=0.25)  # a 250 Hz record whose time column was in ms
    assert rescale_time(ds, "ms").fs == pytest.approx(250.0)
    with pytest.raises(ParameterError, match="one of"):
        rescale_time(ds, "hours")
    with pytest.raises(ParameterError, match="no time column"):
        rescale_time(Dataset.from_arrays(ds.u, ds.y), "ms")


def test_fixed_values_are_checked_against_sign_and_box() -> None:
    params = HHRAModel().params
    with pytest.raises(ParameterError, match="g_leak=-5.*positive"):
        params.check_values({"g_leak": -5})
    with pytest.raises(ParameterError, match="outside its box.*--allow-outside-box"):
        params.check_values({"g_leak": 1e9})
    notes = params.check_values({"g_leak": 1e9}, allow_outside_box=True)
    assert len(notes) == 1 and "accepted" in notes[0]
    with pytest.raises(ParameterError, match="g_leak=-5.*positive"):  # sign: never allowed
        params.check_values({"g_leak": -5}, allow_outside_box=True)
    with pytest.raises(ParameterError, match="unknown parameter"):
        params.check_values({"g_bogus": 1})
    assert params.check_values({"g_leak": 6.4, "g_spring": -3.0}) == []


def test_a_singular_information_matrix_gives_undetermined_intervals() -> None:
    rng = np.random.default_rng(1)
    J = np.zeros((100, 3))
    J[:, 0] = rng.normal(size=100)  # only the first parameter moves the output
    cov, corr, warns = uncertainty(J, rng.normal(size=100), ["a", "b", "c"])
    assert np.isfinite(cov[0, 0]) and np.isinf(cov[1, 1]) and np.isinf(cov[2, 2])
    assert any("b, c do not affect" in w for w in warns)
    cov, _, warns = uncertainty(np.zeros((50, 2)), np.ones(50), ["a", "b"])  # all dead
    assert np.isinf(np.diag(cov)).all()
    cov, _, warns = uncertainty(np.full((50, 2), np.nan), np.ones(50), ["a", "b"])  # diverged
    assert np.isinf(np.diag(cov)).all() and "diverges" in warns[0]


def test_a_time_axis_in_ms_is_refused_before_compiling() -> None:
    with pytest.raises(SimulationError, match=r"RK4 substeps.*--time-unit ms"):
        Simulator(HHRAModel(), fs=0.25)


def test_interruptible_raises_a_swallowed_ctrl_c() -> None:
    with pytest.raises(KeyboardInterrupt), interruptible():
        try:
            os.kill(os.getpid(), signal.SIGINT)
        except KeyboardInterrupt:
            pass  # what CasADi does with an exception raised in a callback
    before = signal.getsignal(signal.SIGINT)
    with interruptible():
        pass  # no interrupt: nothing raised, the handler restored
    assert signal.getsignal(signal.SIGINT) is before


def test_a_value_at_a_box_edge_after_a_coordinate_round_trip_is_inside() -> None:
    """A fit that ended at an edge returns it a little off (64.0000024 for 64): on the edge."""
    params = HHRAModel().params
    par = params["g_leak"]
    assert params.check_values({"g_leak": par.upper * (1 + 4e-8)}) == []
    assert params.check_values({"g_leak": par.lower * (1 - 4e-8)}) == []
    with pytest.raises(ParameterError, match="outside its box"):
        params.check_values({"g_leak": par.upper * 1.001})
