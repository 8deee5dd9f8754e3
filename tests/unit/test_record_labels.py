"""Units and names of a record for a model that is not the HHRA, and the CLI flags."""

import numpy as np
import pytest

from hhra_phys.cli import _common
from hhra_phys.data import Dataset
from hhra_phys.units import GENERIC_LABELS, label_record


def _ds(**labels):
    n = 50
    return Dataset(t=np.arange(n) * 0.01, u=np.sin(np.arange(n) / 5.0),
                   y=np.cos(np.arange(n) / 7.0), **labels)


class _Declares:
    input_unit = "V"
    output_unit = "mV"
    output_name = "capacitor voltage"


def test_unlabelled_record_is_never_ma_and_deg_for_a_user_model():
    data, notes = label_record(_ds())
    assert (data.input_unit, data.output_unit) == ("", "")
    assert (data.input_name, data.output_name) == (GENERIC_LABELS["input_name"],
                                                   GENERIC_LABELS["output_name"])
    assert notes and np.array_equal(data.y, _ds().y)


def test_model_declared_units_are_the_default_and_flags_win():
    data, _ = label_record(_ds(), model=_Declares())
    assert (data.input_unit, data.output_unit, data.output_name) == ("V", "mV",
                                                                     "capacitor voltage")
    assert data.input_name == "input"
    data, _ = label_record(_ds(), {"output_unit": "V", "input_name": "drive"}, _Declares())
    assert (data.output_unit, data.input_name, data.input_unit) == ("V", "drive", "V")


def test_labels_the_record_states_are_kept():
    ds = _ds(input_name="pump", input_unit="V", output_name="level", output_unit="cm")
    data, notes = label_record(ds, model=_Declares())
    assert (data.input_unit, data.output_unit, data.output_name) == ("V", "cm", "level")
    assert notes == []


@pytest.mark.parametrize("flag,key,value", [("--input-unit", "input_unit", "V"),
                                            ("--output-unit", "output_unit", "mV"),
                                            ("--input-name", "input_name", "drive"),
                                            ("--output-name", "output_name", "voltage")])
def test_record_commands_take_the_label_flags(flag, key, value, tmp_path):
    import argparse

    p = argparse.ArgumentParser()
    _common.add_data_arguments(p)
    path = tmp_path / "r.csv"
    path.write_text("t,u,y\n" + "".join(f"{k * 0.01},{k % 3},{k % 5}\n" for k in range(40)))
    args = p.parse_args([str(path), flag, value])
    assert getattr(_common.read_record(args), key) == value
    # A built-in record has its own labels: the flag would be ignored, so it is refused.
    with pytest.raises(Exception, match=flag):
        _common.load_data(p.parse_args(["rig", flag, value]))
