"""``hhra-phys simulate --generator reference``: records from the independent implementation."""

from __future__ import annotations

import json

import numpy as np

from hhra_phys.cli import main
from hhra_phys.data import load
from hhra_phys.reference import simulate_reference


def test_reference_generator_hides_an_effect_and_says_which(tmp_path, capsys):
    out = tmp_path / "rec.csv"
    rc = main(["simulate", "--out", str(out), "--generator", "reference", "--duration", "2",
               "--noise", "0", "--effect", "coulomb_friction:g_coulomb=8"])
    assert rc == 0
    meta = json.loads(out.with_suffix(".json").read_text())["metadata"]
    assert meta["generator"] == "reference"
    assert meta["truth"]["effects"]["coulomb_friction"]["g_coulomb"] == 8.0
    ds = load(str(out))
    # Noise-free: the record is the reference's own simulation of that input and truth.
    truth = meta["truth"]
    y = simulate_reference(ds.u, ds.fs, truth["params"], effects=truth["effects"],
                           x0=np.array(truth["x0"]))
    np.testing.assert_allclose(ds.y, y, atol=1e-6)


def test_effect_without_the_reference_generator_is_refused(tmp_path, capsys):
    rc = main(["simulate", "--out", str(tmp_path / "r.csv"), "--effect", "backlash"])
    assert rc == 2 and "--generator reference" in capsys.readouterr().err
    rc = main(["simulate", "--out", str(tmp_path / "r.csv"), "--generator", "reference",
               "--effect", "nothing:x=1"])
    assert rc == 2 and "unknown effect" in capsys.readouterr().err
    assert not (tmp_path / "r.csv").exists()
