"""Smoke versions of the experiment scripts: tiny settings, every output written.

The full experiments (minutes to an hour) produce the figures in ``docs/``; these
runs only check that each script still runs end to end and writes what it says.
The closed-loop studies have their CI version in ``tests/test_diagnose.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

# Each runs a script in a subprocess: the fits' scripts are slow (deselected by default),
# the optimiser table, the controller design and the long records' quick run by default
# (in the background, below).

REPO = Path(__file__).resolve().parents[2]
PUBLIC = REPO.parent / "shared" / "data"


def _call(script: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    # The scripts run outside the repository (cwd) and the package may be installed
    # elsewhere, so name the public data's directory explicitly.
    env = dict(os.environ, MPLBACKEND="Agg", HHRA_SHARED_DATA=str(PUBLIC))
    return subprocess.run([sys.executable, str(REPO / "experiments" / script), *args],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


def _run(script: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    proc = _call(script, *args, cwd=cwd)
    assert proc.returncode == 0, f"{script} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc


@pytest.mark.slow
def test_fit_rig_every_part(tmp_path):
    out = tmp_path / "fit_rig"
    _run("fit_rig.py", "--out", str(out), "--parts", "clean,noisy,speed,lam", "--seeds", "2",
         "--clean", "1", "--lam-seeds", "1", "--pop", "6", "--iters", "3", "--repeats", "1",
         "--scalar", "--profile", cwd=tmp_path)
    res = json.loads((out / "results.json").read_text())
    assert set(res) >= {"clean", "noisy", "speed", "lam"}
    assert len(res["noisy"]["rows"]) == 2 and "coverage_profile" in res["noisy"]
    assert res["speed"]["scalar_runs"][0]["nfev"] == res["speed"]["runs"][0]["nfev"]
    text = (out / "summary.md").read_text()
    assert "profile interval" in text and "scalar code" in text
    # Loose but meaningful: even this tiny search plus IPOPT recovers a noise-free rig to
    # 2 % (measured 0.5 %) and predicts noisy validation data to the noise (measured 1.01x).
    assert res["clean"]["worst"] < 0.02, res["clean"]["worst"]
    assert res["noisy"]["val_rmse_over_noise_max"] < 1.15
    assert res["noisy"]["val_vaf_min"] > 99.9
    assert res["speed"]["best_total"] > 0 and res["speed"]["runs"][0]["nfev"] > 0


@pytest.mark.slow
@pytest.mark.skipif(not PUBLIC.exists(), reason="public data not present next to the repository")
def test_table3_on_the_perturbed_rig_and_public_record(tmp_path):
    out = tmp_path / "t3"
    _run("table3.py", "--out", str(out), "--seeds", "0", "--records",
         "rig_perturbed,public,tustin", "--methods", "ls,ffrls,phys_hgwo_ipopt,phys_ipopt",
         "--no-controls", "--pop", "6", "--iters", "3", cwd=tmp_path)
    for name in ("rig_perturbed_seed0.json", "public_seed0.json", "summary.json", "tables.md",
                 "rig_perturbed_outputs.png", "public_convergence.png"):
        assert (out / name).exists(), name
    assert "physical IPOPT from nominal" in (out / "tables.md").read_text()
    # A missing figures folder is refused before the fits (it was found after them).
    proc = _call("table3.py", "--out", str(tmp_path / "t3b"), "--figures",
                 str(tmp_path / "missing"), "--records", "rig", cwd=tmp_path)
    assert proc.returncode == 2 and "folder does not exist" in proc.stderr
    assert not (tmp_path / "t3b").exists()


@pytest.mark.slow
@pytest.mark.skipif(not PUBLIC.exists(), reason="public data not present next to the repository")
def test_fit_public(tmp_path):
    out = tmp_path / "fp"
    _run("fit_public.py", "--out", str(out), "--seeds", "1", "--pop", "6", "--iters", "3",
         cwd=tmp_path)
    assert (out / "results.json").exists() and (out / "summary.md").exists()
    res = json.loads((out / "results.json").read_text())
    run = res["valves"]["orifice"]["runs"][0]
    # The physical model beats the best linear ARX (0.999) even after this tiny search
    # (measured 0.88); the validation output's st. dev. is 1.58.
    assert run["val"]["rmse"] < res["arx_baseline_val_rmse"]
    assert abs(res["val_std"] - 1.58) < 0.01


#: The default run's scripts start with the session, each in a process of its own
#: (tests/conftest.py, ``background``: the core pytest leaves idle); their tests read the
#: outcome. The same commands as before, in their own empty folders.
BACKGROUND = {
    "test_position_control": ["python", str(REPO / "experiments" / "position_control.py"),
                              "--out", "{out}/pc", "--pop", "6", "--iters", "3",
                              "--samples", "50"],
    "test_table2": ["python", str(REPO / "experiments" / "table2.py"), "--out", "{out}/t2",
                    "--runs", "1"],
    "test_long_records_quick": ["python", str(REPO / "experiments" / "long_records.py"),
                                "--out", "{out}/lr", "--quick", "--no-truth"],
    "test_cluster_equality_quick": ["python", str(REPO / "experiments" / "cluster_equality.py"),
                                    "--only", "4", "--duration", "4",
                                    "--out", "{out}/ce.json"],
}


def _result(background, name: str) -> Path:
    """The folder of a background script that must have succeeded."""
    run = background[name]
    code, text, err = run.result()
    assert code == 0, f"{name}: the script failed:\n{text[-2000:]}\n{err[-3000:]}"
    return run.out


def test_position_control(background):
    out = _result(background, "test_position_control") / "pc"
    for name in ("summary.json", "control_steps.png", "control_tracking.png",
                 "control_bode_family.png"):
        assert (out / name).exists(), name
    res = json.loads((out / "summary.json").read_text())
    # The fitted plant's hydraulic mode within 2 % of the rig's truth (measured 0.003 %),
    # and design A stable on the truth with margins a designer would accept.
    plant = res["plant"]
    assert abs(plant["wn"] / plant["wn_truth"] - 1) < 0.02
    margins = res["designs"]["A"]["margins"]["truth"]
    assert margins["stable"] == 1.0 and margins["gm"] > 6 and margins["pm"] > 30


def test_table2(background):
    folder = _result(background, "test_table2")
    prefix = folder / "t2"
    assert prefix.with_suffix(".json").exists() and prefix.with_suffix(".md").exists()
    res = json.loads(prefix.with_suffix(".json").read_text())["results"]
    # The paper's protocol spends about twice GWO's evaluations on H-GWO, and the six-hump
    # camel's minimum -1.0316 is found by H-GWO and GWO in one run.
    assert res["f1"]["hgwo"]["nfev"] == pytest.approx(2 * res["f1"]["gwo"]["nfev"], rel=0.05)
    for method in ("hgwo", "gwo"):
        assert res["f7"][method]["mean"] == pytest.approx(-1.0316285, abs=1e-3)
    again = _call("table2.py", "--out", str(prefix), "--runs", "1", cwd=folder)
    assert again.returncode == 2  # an existing output is never replaced


@pytest.mark.parametrize(("size", "says"), [
    ("drag=abc", "drag: the size must be a number, got 'abc'"),
    ("drg=5", "give family=value with a family of"),
    ("gravity=-3", "gravity: the size must be finite and positive"),
])
def test_one_loop_size_is_checked_before_any_loop(tmp_path, size, says):
    out = tmp_path / "rows.json"
    proc = _call("one_loop.py", "--families", "drag", "--seeds", "1", "--size", size,
                 "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 2 and "--size" in proc.stderr and says in proc.stderr
    assert not out.exists()  # refused before any loop ran or any row was written


def test_long_records_quick(background):
    # Both records, short, through the CLI from the user's model files; a tiny search,
    # one library candidate, no truth refit: the script runs end to end and writes its rows.
    out = _result(background, "test_long_records_quick") / "lr"
    rows = json.loads((out / "rows.json").read_text())["rows"]
    assert [r["record"] for r in rows] == ["drive_seed1", "duffing_seed1"]
    for r in rows:
        for key in ("fit", "diagnose"):
            assert r["commands"][key]["exit"] == 0, r["commands"][key]
            assert r["commands"][key]["wall_s"] > 0 and r["commands"][key]["cpu_s"] > 0
        assert r["diagnose"]["base"]["test"] is not None
        assert (out / f"{r['kind']}_model.py").exists() and (out / f"{r['kind']}_truth.py").exists()
    drive, duffing = rows
    assert drive["samples"] == 1500 and drive["test_samples"] == 1000
    assert duffing["samples"] == 1200 and duffing["metadata"]["intersample"] == "cubic"
    # The side-car says the input's inter-sample behaviour.
    side = json.loads((out / "duffing_seed1.json").read_text())
    assert "cubic" in json.dumps(side)


def test_long_records_generator_error(tmp_path):
    # The drive generator's own integration error against a finer replay: written per test
    # record, positive, finite, and far below the record's scale (4 cm moves). A generator
    # replayed at its own count against itself would give exactly zero.
    out = tmp_path / "ge"
    _run("long_records.py", "--generator-error", "--seeds", "2", "--drive-seconds", "1.2",
         "--out", str(out), cwd=tmp_path)
    (row,) = json.loads((out / "generator_error.json").read_text())["rows"]
    assert row["record"] == "drive test seed 1002" and row["fine"] > row["substeps"]
    assert 0.0 < row["rms_m"] <= row["max_m"] < 1e-4
    assert not (out / "rows.json").exists()  # nothing diagnosed


def test_cluster_equality_quick(background):
    # One short clean record, in one process and on a two-worker LocalCluster (loopback):
    # the script runs end to end, and the two runs wrote the same JSON.
    rows = json.loads((_result(background, "test_cluster_equality_quick") / "ce.json")
                      .read_text())
    assert [r["record"] for r in rows] == ["clean-5"]
    assert rows[0]["identical"], rows[0]["first_difference"]
    assert rows[0]["executor"] == "ClientExecutor"
