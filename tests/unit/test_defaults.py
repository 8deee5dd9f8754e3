"""The default model (``hhra_phys.defaults``): the HHRA registers itself; a fit or a
diagnosis without a model uses whatever is registered, and says what to do when nothing is."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import hhra_phys
from hhra_phys import defaults
from hhra_phys.defaults import DefaultModel, register_default, registered_default
from hhra_phys.errors import ParameterError
from hhra_phys.fit import default_model

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration" / "user_models"))
import drive  # noqa: E402


def test_the_hhra_is_the_default_once_hhra_phys_is_imported():
    assert registered_default().name == "HHRA"
    rec = drive.simulate_record(seed=1, n=400)
    model, _ = default_model(rec)
    assert isinstance(model, hhra_phys.HHRAModel)


def test_without_a_registered_default_a_fit_asks_for_a_model(monkeypatch):
    monkeypatch.setattr(defaults, "_REGISTERED", [])
    rec = drive.simulate_record(seed=1, n=400)
    with pytest.raises(ParameterError, match="pass model="):
        hhra_phys.fit(rec, max_iter=1, pop_size=4)
    with pytest.raises(ParameterError, match="pass model="):
        hhra_phys.diagnose(rec, max_effects=0, pop_size=4, max_iter=1)
    with pytest.raises(ParameterError, match="pass model="):
        hhra_phys.fit()  # nor is there a record to fit


def test_a_users_registered_default_is_fitted_without_naming_it(monkeypatch):
    monkeypatch.setattr(defaults, "_REGISTERED", list(defaults._REGISTERED))
    seen = []

    def model_for(data):
        seen.append(data.n)
        return drive.make_model(), {"k_motor": (0.5, 10.0)}

    register_default(DefaultModel("drive", model_for))
    rec = drive.simulate_record(seed=2, n=1200, noise=0.002)
    res = hhra_phys.fit(rec, pop_size=10, max_iter=10, seed=1)
    assert seen and set(res.values) >= {"k_motor", "c_visc"}
    assert res.values["k_motor"] == pytest.approx(drive.TRUTH["k_motor"], rel=0.02)
    assert np.isfinite(res.metrics["val"]["rmse"])
    with pytest.raises(ParameterError, match="no example record"):
        hhra_phys.fit()  # the drive offers no example record


def test_register_default_takes_only_a_default_model():
    with pytest.raises(ParameterError, match="DefaultModel"):
        register_default(lambda data: None)  # type: ignore[arg-type]
