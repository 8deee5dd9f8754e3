"""``--model FILE.py:FACTORY`` and ``--effects-from``: a user's code, and clear errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from hhra_phys import Model
from hhra_phys.errors import ModelError
from hhra_phys.extensions import import_effects, model_from_spec

USER = Path(__file__).resolve().parents[1] / "integration" / "user_models" / "two_tank.py"


def test_a_file_factory_builds_the_users_model_and_registers_its_effects(tmp_path):
    copy = tmp_path / "my.models-v2" / "tanks.py"  # dots and dashes in the path
    copy.parent.mkdir()
    copy.write_text(USER.read_text())
    model = model_from_spec(f"{copy}:make_model")
    assert isinstance(model, Model) and model.stages == ("pump", "tanks", "sensor")
    assert import_effects([str(copy)]) == []  # already imported with the model: same module


@pytest.mark.parametrize(("spec", "words"), [
    ("no_colon.py", "expected FILE.py:FACTORY"),
    ("/nowhere/x.py:make", "no such Python file"),
    (f"{USER}:nothing_here", "has no 'nothing_here'"),
    (f"{USER}:SideInflow", "returned SideInflow, not a hhra_phys Model"),
    ("hhra_phys.extensions:load_factory", "calling it raised TypeError"),
    ("hhra_phys.models.hhra:HHRA_STAGES", "is not callable"),
    ("hhra_phys.models.hhra.rig:default_input", "not a hhra_phys Model"),
    ("no.such.module:f", "importing it raised ModuleNotFoundError"),
])
def test_bad_specs_name_what_is_wrong(spec, words):
    with pytest.raises(ModelError, match="--model") as info:
        model_from_spec(spec)
    assert words in str(info.value)


def test_a_file_that_fails_to_import_is_reported(tmp_path):
    bad = tmp_path / "broken.py"
    bad.write_text("raise RuntimeError('oops')\n")
    with pytest.raises(ModelError, match="importing it raised RuntimeError: oops"):
        import_effects([str(bad)])
