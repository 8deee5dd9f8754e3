"""The HHRA model and bounds a fit uses for a record when the user names no model."""

from __future__ import annotations

import numpy as np

from hhra_phys.data import Dataset
from hhra_phys.model import Model
from hhra_phys.models.hhra.model import HHRAModel

__all__ = ["NOMINAL_FS", "SAMPLE_UNIT_SPAN", "default_model"]

#: Sample rate whose time scale the nominal groups describe (the rig's) [Hz].
NOMINAL_FS = 250.0
#: Box of every positive group, as a factor around its nominal, for records in sample units.
SAMPLE_UNIT_SPAN = 100.0


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
