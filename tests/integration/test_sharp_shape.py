"""A library effect is as sharp as the machine (``fit_shapes``, CLI ``--fit-shapes``): the
loop fits a friction's switching width, and its sign's profile, where the record resolves
them, and keeps the library's default where it does not (issue 32, item 3); by default in
the accepted effect, on request in every contender.

The user's drive (``user_models/drive.py``: ``q`` [m], ``v`` [m/s], declared by role) on
records of its independent NumPy plant with a Coulomb friction of 0.3 m/s^2 that switches
within ``width``. The library's default width on this model is 0.005 times the velocity's
scale (0.2 m/s): 1e-3 m/s.

- Switching within 5e-5 m/s (20 times sharper than the default): the accepted
  ``coulomb_friction`` carries a fitted ``v_switch`` below the default, and its selection
  error is below the same loop's with the width held at the default (the user's explicit
  ``fit_width=False``, which the loop leaves as given).
- Switching within 1e-3 m/s (the default itself): the friction at the default width leaves
  the record at the noise level, so no sharper width is searched and the default is kept.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from hhra_phys.diagnosis.engine import augment

sys.path.insert(0, str(Path(__file__).resolve().parent / "user_models"))
import drive  # noqa: E402

LOOP_KW = {"candidates": ["coulomb_friction"], "max_effects": 1, "discover": False,
           "pop_size": 20, "max_iter": 20, "fit_shapes": True}


def _friction_step(res):
    return next(s for s in res.steps if s.effect == "coulomb_friction")


def _width(res):
    part = next(p for p in res.final.model.parts if p.name == "coulomb_friction")
    return part.fit_width, res.final.values.get("v_switch")


@pytest.mark.parametrize("seed", [0, 1])
def test_a_sharp_friction_gets_its_fitted_width(seed):
    data = drive.simulate_record(seed=seed, coulomb=0.3, width=5e-5, noise=0.0005)
    res = augment(data, drive.make_model(), seed=seed, **LOOP_KW)
    assert res.chosen == ["coulomb_friction"], res.chosen
    fitted, v_switch = _width(res)
    assert fitted and v_switch < 5e-4, (fitted, v_switch)
    step = _friction_step(res)
    assert "v_switch" in step.params
    assert any("switching width fitted:" in n for n in step.notes), step.notes
    held = augment(data, drive.make_model(), seed=seed,
                   effect_kw={"coulomb_friction": {"fit_width": False}}, **LOOP_KW)
    assert _width(held) == (False, None)
    assert step.val["rmse"] < _friction_step(held).val["rmse"]
    # off: the library's default width, as the user's explicit fit_width=False
    off = augment(data, drive.make_model(), seed=seed, **{**LOOP_KW, "fit_shapes": "off"})
    assert _width(off) == (False, None)
    assert _friction_step(off).val == _friction_step(held).val
    # the default ("chosen"): the friction wins at its default width, then its width is
    # fitted in the accepted model; the final model is as sharp as the contenders' mode's
    chosen = augment(data, drive.make_model(), seed=seed,
                     **{**LOOP_KW, "fit_shapes": "chosen"})
    step = _friction_step(chosen)
    assert step.val == _friction_step(held).val  # judged at the default width
    fitted, v_switch = _width(chosen)
    assert fitted and v_switch < 5e-4, (fitted, v_switch)
    assert any(n.startswith("after acceptance: its switching width fitted:")
               for n in step.notes), step.notes
    assert chosen.final.metrics["val"]["rmse"] < off.final.metrics["val"]["rmse"]


def _profile(res):
    return next(p for p in res.final.model.parts if p.name == "coulomb_friction").profile


@pytest.mark.parametrize("seed", [4, 5])
def test_a_tanh_friction_gets_the_tanh_profile(seed):
    """A friction that reaches its level as ``tanh(v/width)`` does: the shape stage tries
    both profiles at a fitted width and keeps the tanh, whose selection error is below the
    same loop's with the profile held at the algebraic sign (the user's choice, left as
    given)."""
    data = drive.simulate_record(seed=seed, coulomb=0.3, width=5e-5, noise=0.0005,
                                 profile="tanh")
    res = augment(data, drive.make_model(), seed=seed, **LOOP_KW)
    assert res.chosen == ["coulomb_friction"], res.chosen
    assert _profile(res) == "tanh" and _width(res)[0], _friction_step(res).notes
    assert any("with the tanh sign" in n for n in _friction_step(res).notes)
    held = augment(data, drive.make_model(), seed=seed,
                   effect_kw={"coulomb_friction": {"profile": "algebraic"}}, **LOOP_KW)
    assert _profile(held) == "algebraic"
    assert _friction_step(res).val["rmse"] < _friction_step(held).val["rmse"]


def test_the_cli_fits_shapes_on_request(tmp_path):
    """``diagnose --fit-shapes`` on the user's drive model file: the JSON's final model
    holds the friction with ``fit_width`` and its fitted ``v_switch``."""
    import json

    from hhra_phys.cli import main
    from hhra_phys.data import save

    data = tmp_path / "drive.csv"
    save(drive.simulate_record(seed=0, coulomb=0.3, width=5e-5, noise=0.0005), data)
    model = Path(__file__).resolve().parent / "user_models" / "drive.py"
    out = tmp_path / "d.json"
    assert main(["diagnose", str(data), "--model", f"{model}:make_model", "--effects",
                 "coulomb_friction", "--max-effects", "1", "--no-discover", "--pop", "20",
                 "--iters", "20", "--workers", "0", "--fit-shapes", "--folds", "3",
                 "--json", str(out)]) == 0
    js = json.loads(out.read_text())
    assert js["chosen"] == ["coulomb_friction"]
    part = next(p for p in js["fits"]["final"]["model"]["parts"]
                if p["type"] == "CoulombFriction")
    assert part["args"]["fit_width"] is True
    assert js["fits"]["final"]["params"]["v_switch"]["value"] < 5e-4
    assert js["settings"]["fit_shapes"] == "contenders"
    assert js["settings"]["folds"] == 3 and js["settings"]["rotate"] is True


def test_shape_modes_are_checked_by_name():
    from hhra_phys.cli.diagnose import _SHAPE_MODES
    from hhra_phys.diagnosis.options import SHAPE_MODES, LoopOptions
    from hhra_phys.errors import ParameterError

    assert _SHAPE_MODES == SHAPE_MODES
    from hhra_phys.cli import build_parser

    parse = build_parser().parse_args
    assert parse(["diagnose", "d.csv"]).shapes == "chosen"
    assert parse(["diagnose", "--shapes", "off", "d.csv"]).shapes == "off"
    # the bare flag never swallows the record that follows it
    args = parse(["diagnose", "--fit-shapes", "d.csv"])
    assert args.fit_shapes is True and args.data == ["d.csv"]
    assert LoopOptions().shape_mode == "chosen"
    assert LoopOptions(fit_shapes=True).shape_mode == "contenders"
    assert LoopOptions(fit_shapes=False).shape_mode == "off"
    with pytest.raises(ParameterError, match="fit_shapes must be one of"):
        LoopOptions(fit_shapes="sharp").validate()


def test_a_friction_as_wide_as_the_default_keeps_the_default():
    data = drive.simulate_record(seed=2, coulomb=0.3, width=1e-3, noise=0.0005)
    res = augment(data, drive.make_model(), seed=2, **LOOP_KW)
    assert res.chosen == ["coulomb_friction"], res.chosen
    assert _width(res) == (False, None)
    # at the default width the friction already leaves the record at the noise level:
    # nothing sharper can beat it by more than the allowance, so it is not searched
    step = _friction_step(res)
    level = res.settings["noise_levels"][0]
    assert step.val["rmse"] <= 1.2 * level["noise"], (step.val, level)
    assert not any("switching width" in n for n in step.notes), step.notes


def test_a_discovered_friction_is_named_as_the_library_physics():
    """Without the library, discovery finds the friction at ``d v/dt`` with a sign of
    ``v``; the step names it as Coulomb friction in its discovered form (``same_as``),
    in the JSON too. The input entry, the same entry on this model (the motor force is
    linear in the command), is screened once, as ``rate:v``; a load mode whose first-order
    score cannot lower the criterion (below ``discover.score_floor``) is not refitted."""
    data = drive.simulate_record(seed=3, coulomb=0.3, width=5e-5, noise=0.0005)
    said: list[str] = []
    res = augment(data, drive.make_model(), seed=3, candidates=[], max_effects=1,
                  discover=True, discover_kw={"entries": ["input", "rate:v", "mode:rate:v"]},
                  pop_size=20, max_iter=20, progress=said.append)
    assert not [s.effect for s in res.steps
                if getattr(s, "entry", "") in ("input", "mode:rate:v")]
    assert any("screens the input entry once, as rate:v" in line for line in said), said
    assert any("does not refit mode:rate:v" in line for line in said), said
    found = [s for s in res.steps if getattr(s, "discovered", False)
             and s.entry == "rate:v" and "sgn(v)" in s.expression]
    assert found, [(s.effect, getattr(s, "expression", "")) for s in res.steps]
    assert all(s.same_as == ["coulomb_friction"] for s in found)
    rows = [d for d in res.to_json()["steps"] if d["effect"] == found[0].effect]
    assert rows and rows[0]["same_as"] == ["coulomb_friction"]
    # A discovered term has no first-order column: its regime is what its fit changes.
    regime = rows[0]["regime"]
    assert regime and "output change" in regime["basis"], regime
    assert regime["est"]["share"] + regime["sel"]["share"] == pytest.approx(1.0)
