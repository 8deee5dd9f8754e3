"""A user's own, non-hydraulic model through the generic core: Python and the CLI.

The model (``user_models/two_tank.py``) is written only with the public contract
(``Model, Part, State, Parameter, Effect, register_part, register_effect``), has
stage names of its own, fits both tanks' initial levels by default, and brings an
effect of its own (``side_inflow``, outside the library) that the loop must find
on records that contain it and leave out on records that do not.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from hhra_phys import Model
from hhra_phys.diagnosis.engine import augment
from hhra_phys.effects import EFFECTS, make_effect
from hhra_phys.fit import fit
from hhra_phys.models.cylinder import LinearCylinderModel
from hhra_phys.models.hhra import HHRAModel

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "user_models"))
import two_tank  # noqa: E402

NOISE = 0.05
CANDIDATES = ["side_inflow", "sensor_offset", "valve_deadzone", "coulomb_friction"]


def test_model_uses_its_own_stages_and_fits_initial_levels():
    model = two_tank.make_model()
    assert model.stages == ("pump", "tanks", "sensor")
    assert model.fitted_states == ["h1", "h2"]
    data = two_tank.simulate_record(seed=3, q_side=0.0)
    res = fit(data, model, pop_size=30, max_iter=40, seed=0)
    # Both initial levels are parameters of the fit, within a few noise levels of the truth.
    assert {"x0_h1", "x0_h2"} <= set(res.free)
    assert res.metrics["val"]["rmse"] < 1.3 * NOISE, res.metrics["val"]
    truth = data.metadata["truth"]
    for name in ("k_pump", "a1", "a2"):
        lo, hi = res.ci95[name]
        assert lo <= truth[name] <= hi, (name, truth[name], res.ci95[name])


@pytest.mark.parametrize("model", [HHRAModel(), HHRAModel(output="pressure"),
                                   LinearCylinderModel(), two_tank.make_model()],
                         ids=["hhra", "hhra_pressure", "cylinder", "two_tank"])
def test_every_effect_applies_or_is_skipped_with_a_reason(model: Model):
    for name in EFFECTS:
        eff = make_effect(name)
        why = eff.applicable(model)
        if why is None:
            augmented = model.with_parts(eff)
            f = augmented.functions(0.004)["f"]
            x = augmented.x0()
            u = np.zeros(augmented.n_lags + 1)
            assert np.all(np.isfinite(np.array(f(x, u, augmented.nominal()))))
        else:
            assert isinstance(why, str) and len(why) > 10, (name, why)
    # The input- and output-side effects attach to any model.
    for name in ("valve_deadzone", "valve_saturation", "input_delay", "valve_dynamics"):
        assert make_effect(name).applicable(model) is None, name


def test_offset_is_a_candidate_where_the_output_does_not_integrate():
    tank = two_tank.make_model()
    assert make_effect("sensor_offset").applicable(tank) is None
    # The pressure output has an offset parameter already: structurally recognised.
    why = make_effect("sensor_offset").applicable(HHRAModel(output="pressure"))
    assert why is not None and "p_offset" in why


@pytest.mark.slow
def test_loop_finds_the_users_effect_and_nothing_on_clean_records():
    """Records with the side inflow: found first on each of 3 seeds; clean: nothing added.

    Measured on seeds 0-2 (0.1 cm/s side inflow, 0.05 cm noise): side_inflow accepted
    first on 3 of 3, validation RMSE 0.33 -> 0.053 cm (seed 1); sensor_offset (the
    library's nearest stand-in) gains less and is not added after it.
    """
    found = 0
    for seed in range(3):
        data = two_tank.simulate_record(seed=seed)
        res = augment(data, two_tank.make_model(), candidates=CANDIDATES, max_effects=2,
                      seed=seed)
        assert "coulomb_friction" in res.skipped and "velocity" in res.skipped["coulomb_friction"]
        if res.chosen[:1] == ["side_inflow"]:
            found += 1
            step = next(s for s in res.steps if s.accepted)
            lo, hi = step.ci95["q_side"]
            assert lo <= 0.1 <= hi, step.ci95
            assert res.final.metrics["val"]["rmse"] < 1.5 * NOISE
    assert found == 3
    clean = two_tank.simulate_record(seed=5, q_side=0.0)
    res = augment(clean, two_tank.make_model(), candidates=CANDIDATES, max_effects=1, seed=0)
    assert res.chosen == [], [s.reason for s in res.steps]


def _users_record(folder: Path) -> tuple[str, str]:
    """The record of seed 1 as a CSV in ``folder``: (its path, the model's ``FILE:FACTORY``)."""
    data = two_tank.simulate_record(seed=1)
    csv = folder / "tanks.csv"
    np.savetxt(csv, np.column_stack([data.t, data.u, data.y]), delimiter=",",
               header="t,u,y", comments="")
    return str(csv), f"{HERE / 'user_models' / 'two_tank.py'}:make_model"


def _cli_fit(folder: Path) -> list[str]:
    csv, spec = _users_record(folder)
    return ["fit", csv, "--model", spec, "--pop", "20", "--iters", "20", "--quiet", "--json",
            str(folder / "fit.json")]


def _cli_diagnose(folder: Path) -> list[str]:
    # The loop's base search at 20 x 30 (not the CLI's 100 x 200): side_inflow chosen and
    # coulomb_friction skipped on records of seeds 0-4 at this size (2026-11-26).
    csv, spec = _users_record(folder)
    return ["diagnose", csv, "--model", spec, "--effects-from",
            str(HERE / "user_models" / "two_tank.py"), "--effects", ",".join(CANDIDATES),
            "--max-effects", "1", "--pop", "20", "--iters", "30", "--json",
            str(folder / "diag.json")]


def _cli_compare(folder: Path) -> list[str]:
    csv, spec = _users_record(folder)
    return ["compare", csv, "--model", spec, "--methods", "ls,phys_ipopt", "--quiet", "--json",
            str(folder / "compare.json")]


#: The three commands on the user's model start with the session, each in a process of its
#: own (tests/conftest.py, ``background``: the core pytest leaves idle); the tests read the
#: outcome. The same commands as one test ran one after the other before.
BACKGROUND = {"test_cli_fits_the_users_model": _cli_fit,
              "test_cli_diagnoses_the_users_model": _cli_diagnose,
              "test_cli_compares_the_users_model": _cli_compare}


def _cli_json(background, name: str, out: str) -> dict:
    run = background[name]
    code, _, err = run.result()
    assert code == 0, err[-2000:]
    return json.loads((run.out / out).read_text())


def test_cli_fits_the_users_model(background):
    out = _cli_json(background, "test_cli_fits_the_users_model", "fit.json")
    assert {"k_pump", "a1", "a2", "x0_h1", "x0_h2"} <= set(out["free"])


def test_cli_diagnoses_the_users_model(background):
    out = _cli_json(background, "test_cli_diagnoses_the_users_model", "diag.json")
    assert out["chosen"] == ["side_inflow"]
    assert "coulomb_friction" in out["skipped"]
    assert {"base", "final", "steps", "chosen"} <= set(out)
    assert math.isfinite(out["final"]["val"]["rmse"])


def test_cli_compares_the_users_model(background):
    rows = _cli_json(background, "test_cli_compares_the_users_model", "compare.json")["methods"]
    # The physical row fits the user's model: far better than a linear ARX on this record.
    assert rows["phys_ipopt"]["val"]["rmse"] < 0.5 * rows["ls"]["val"]["rmse"]
