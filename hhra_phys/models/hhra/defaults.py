"""The HHRA model and bounds a fit uses for a record when the user names no model."""

from __future__ import annotations

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.model import Model
from hhra_phys.models.hhra.model import HHRAModel
from hhra_phys.units import ChannelRange, convert_record, range_warnings

__all__ = ["NOMINAL_FS", "PLAUSIBLE", "PLAUSIBLE_FS", "SAMPLE_UNIT_SPAN", "default_model",
           "prepare_record"]

#: Sample rate whose time scale the nominal groups describe (the rig's) [Hz].
NOMINAL_FS = 250.0
#: Box of every positive group, as a factor around its nominal, for records in sample units.
SAMPLE_UNIT_SPAN = 100.0

#: Plausible ranges of an HHRA record in the model's units. Wide on purpose (warnings, not
#: errors): the simulated rig's current peaks at 1 mA and its angle spans about 55 deg, so a
#: record in A or in radians lands 50x below these limits, one scaled by 1e5 far above;
#: servo-valve rated currents are 10 to 200 mA.
PLAUSIBLE: dict[str, ChannelRange] = {
    "input": ChannelRange("mA", 0.02, 300.0, "peak",
                          too_low="is the valve current in A rather than mA?",
                          too_high="is the valve current in uA, or scaled?"),
    "output": ChannelRange("deg", 2 * 3.141592653589793, 36000.0, "span",
                           too_low="is the angle in radians rather than degrees?",
                           too_high="is the angle scaled (counts, or a gain of 1e3 or more)?"),
}
#: Plausible sample rates of an HHRA record [Hz] (the rig's is 250 Hz).
PLAUSIBLE_FS = (5.0, 1e6)


def default_model(
    data: Dataset, valve: str = "orifice"
) -> tuple[Model, dict[str, tuple[float, float]]]:
    """The HHRA model (and bounds) for a record.

    Angle output in degrees, or a pressure output when the record's output is
    called ``pressure``. A record in sample units (unknown sample time, such as
    the public hydraulic-actuator data) is fitted per sample: the nominal groups
    are rescaled from seconds to 4 ms samples (the rig's 250 Hz) and every
    positive group may range over a factor of 100 either way, because nothing
    is known of that actuator; a pressure output's gain and offset get boxes of
    10 and 1 times the largest measured value.
    """
    output = "pressure" if data.output_name == "pressure" else "angle"
    model: Model = HHRAModel(valve=valve, output=output)  # type: ignore[arg-type]
    bounds: dict[str, tuple[float, float]] = {}
    if data.metadata.get("time_unit") == "samples":
        model = model.time_scaled(1.0 / NOMINAL_FS, time_unit="sample")
        for par in model.params:
            if par.scale == "log":
                bounds[par.name] = (par.nominal / SAMPLE_UNIT_SPAN, par.nominal * SAMPLE_UNIT_SPAN)
    if output == "pressure":
        peak = float(np.max(np.abs(data.y)))
        bounds["p_gain"] = (-10 * peak, 10 * peak)
        bounds["p_offset"] = (-peak, peak)
    return model, bounds


def prepare_record(data: Dataset) -> tuple[Dataset, list[str], list[str]]:
    """A record in the HHRA's units, with what was converted and what looks implausible.

    The input is converted to mA and an angle output to degrees when the record declares
    another known unit (``rad``, ``A`` ...); a pressure output keeps its unit (its gain is
    fitted). See :mod:`hhra_phys.units`.

    Parameters
    ----------
    data : Dataset

    Returns
    -------
    Dataset
        The record in the model's units (``data`` itself if nothing changed).
    notes : list of str
        One line per converted channel.
    warnings : list of str
        Ranges that do not fit the units (:data:`PLAUSIBLE`, :data:`PLAUSIBLE_FS`).

    Raises
    ------
    DataError
        A unit the model cannot convert (the message names both units).
    """
    angle = data.output_name != "pressure"
    data, notes = convert_record(data, input_unit="mA", output_unit="deg" if angle else None)
    ranges = dict(PLAUSIBLE) if angle else {"input": PLAUSIBLE["input"]}
    return data, notes, range_warnings(data, ranges, PLAUSIBLE_FS)
