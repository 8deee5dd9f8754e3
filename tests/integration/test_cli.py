"""The command-line interface, run in-process with small settings (the demo in a process
of its own, started with the session: ``BACKGROUND``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hhra_phys.cli import main
from hhra_phys.data import load_csv


def test_simulate_writes_csv_and_sidecar_and_never_overwrites(tmp_path, capsys):
    out = tmp_path / "rig.csv"
    assert main(["simulate", "--out", str(out), "--seed", "3", "--duration", "4",
                 "--noise", "0.1"]) == 0
    ds = load_csv(out)
    assert len(ds) == 1000 and ds.fs == pytest.approx(250.0)
    assert np.abs(ds.y).max() <= 90.0
    assert ds.metadata["noise_deg"] == 0.1 and "true_params" in ds.metadata
    assert (tmp_path / "rig.json").exists()
    assert main(["simulate", "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err


def test_fit_on_a_csv_writes_json_and_plot(tmp_path, capsys):
    data = tmp_path / "rig.csv"
    main(["simulate", "--out", str(data), "--duration", "4"])
    js, png = tmp_path / "fit.json", tmp_path / "fit.png"
    rc = main(["fit", str(data), "--pop", "8", "--iters", "3", "--seed", "1", "--json", str(js),
               "--plot", str(png), "--quiet", "--fix", "g_leak=6.4"])
    assert rc == 0
    d = json.loads(js.read_text())
    assert d["params"]["g_leak"]["value"] == 6.4 and d["params"]["g_leak"]["ci95"] is None
    assert d["params"]["g_valve"]["ci95"][0] < d["params"]["g_valve"]["value"]
    for key in ("rmse", "vaf", "mse", "itae"):
        assert key in d["est"] and key in d["val"]
    assert [s["name"] for s in d["stages"]] == ["hgwo", "ipopt"] and d["seed"] == 1
    assert png.stat().st_size > 1000
    out = capsys.readouterr().out
    assert "95 % CI" in out
    js2 = tmp_path / "profile.json"
    assert main(["fit", str(data), "--pop", "8", "--iters", "3", "--seed", "1", "--json",
                 str(js2), "--quiet", "--intervals", "profile"]) == 0
    d2 = json.loads(js2.read_text())
    assert d2["intervals"]["method"] == "profile"
    lo, hi = d2["params"]["g_torque"]["ci95"]
    assert lo < d2["params"]["g_torque"]["value"] < hi
    assert "95 % CI (profile)" in capsys.readouterr().out
    assert main(["fit", str(data), "--fix", "nonsense"]) == 2
    assert main(["fit", str(data), "--free", "g_valve,bogus", "--json", str(tmp_path / "x.json"),
                 "--quiet", "--pop", "4", "--iters", "1"]) == 2
    assert "unknown parameter 'bogus'" in capsys.readouterr().err


#: The demo (the longest of these runs) starts with the session in its own process
#: (tests/conftest.py, ``background``); its test reads the outcome.
BACKGROUND = {"test_demo_quick_runs_end_to_end": ["demo", "--quick", "--out", "{out}/demo"]}


def test_demo_quick_runs_end_to_end(background):
    run = background["test_demo_quick_runs_end_to_end"]
    code, text, err = run.result()
    assert code == 0, err[-3000:]
    out = run.out / "demo"
    assert "physical H-GWO+IPOPT" in text and "in CI" in text
    from hhra_phys.cli.demo import hidden_effect

    hidden, _ = hidden_effect(0)
    assert f"hides {hidden}" in text and "error on the held-out test part" in text
    loop = json.loads((out / "demo_loop.json").read_text())
    assert loop["test"]["rmse"] < loop["base"]["test"]["rmse"]
    # The README's count: two records with their side-cars, the fit's and the loop's JSON
    # and figure.
    assert len(list(out.iterdir())) == 8 and "writes eight files" in (
        Path(__file__).resolve().parents[2] / "README.md").read_text()
    for name in ("demo_fit.png", "demo_fit.json", "demo_rig.csv", "demo_loop.png",
                 "demo_loop.json", "demo_loop_rig.csv"):
        assert (out / name).exists()
    assert main(["demo", "--quick", "--out", str(out)]) == 2  # never overwrites
