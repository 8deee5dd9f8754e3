"""Bad input through the CLI: a clear message, the right exit code, nothing lost or half-written.

Every case checks the exit code (2 usage, 1 data or runtime error, 130 interrupt), that no
traceback is printed and that the message names the file, the column or the flag. The
second round (issue 24: tracebacks, sizes, replaced or partial files, silent acceptance,
weak messages, newcomer items), case by case with its class, is in
``test_bad_inputs_classes.py``.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from hhra_phys.cli import build_parser, main
from hhra_phys.data import save
from hhra_phys.models.hhra.rig import simulate_rig

REPO = Path(__file__).resolve().parents[2]
QUICK = ["--pop", "8", "--iters", "2", "--quiet"]


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A short rig record and the same record in wrong units and with wrong labels."""
    d = tmp_path_factory.mktemp("records")
    ds = simulate_rig(seed=0, duration=4.0)
    out = {"rig": d / "rig.csv"}
    save(ds, out["rig"])

    def write(name: str, header: str, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
        cols = zip(t.tolist(), u.tolist(), y.tolist(), strict=True)
        rows = "\n".join(f"{a!r},{b!r},{c!r}" for a, b, c in cols)
        (d / name).write_text(f"{header}\n{rows}\n")
        out[name.split(".")[0]] = d / name

    write("ms.csv", "t,u,y", ds.t * 1000, ds.u, ds.y)
    write("rad.csv", "t,u,y", ds.t, ds.u, np.deg2rad(ds.y))
    write("labelled_rad.csv", "t,u [mA],y [rad]", ds.t, ds.u, np.deg2rad(ds.y))
    write("volts.csv", "t,u,y [V]", ds.t, ds.u, ds.y)
    return out


def run(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str]:
    """Exit code and stderr of ``hhra-phys ARGV`` run in this process."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own usage errors
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


@pytest.mark.parametrize(
    ("argv", "code", "words"),
    [
        (["fit", "{rig}", "--fix", "g_leak=-5"], 2, ["--fix g_leak", "positive"]),
        (["fit", "{rig}", "--fix", "g_leak=1e9"], 2, ["outside its box", "--allow-outside-box"]),
        (["fit", "{rig}", "--fix", "g_leak"], 2, ["--fix expects NAME=VALUE"]),
        (["fit", "{rig}", "--rig-seed", "3"], 2, ["--rig-seed", "rig.csv"]),
        (["fit", "--time-col", "t"], 2, ["--time-col", "DATA file"]),
        (["fit", "{rig}", "--fs", "250", "--time-unit", "ms"], 2, ["--fs", "--time-unit"]),
        (["fit", "{rig}", "--time-unit", "h"], 2, ["--time-unit"]),
        (["fit", "{rig}", "--pop", "2"], 2, ["--pop"]),
        (["fit", "{rig}", "--split", "0"], 2, ["--split"]),
        (["fit", "{rig}", "--plot", "{tmp}/fit.xyz"], 2, ["fit.xyz", ".png"]),
        (["fit", "{rig}", "--json", "{tmp}/no/such/dir/fit.json"], 2, ["does not exist"]),
        (["fit", "{tmp}/missing.csv"], 1, ["missing.csv"]),
        (["fit", "{rig}", "--input-col", "current"], 1, ["no column 'current'", "rig.csv"]),
        (["fit", "{ms}", *QUICK], 1, ["RK4 substeps", "--time-unit ms", "ms.csv"]),
        (["fit", "{volts}", *QUICK], 1, ["'V'", "'deg'", "volts.csv"]),
        (["diagnose", "{rig}", "--top", "0"], 2, ["--top"]),
        (["diagnose", "{rig}", "--max-effects", "-1"], 2, ["--max-effects"]),
        (["diagnose", "{rig}", "--split", "1"], 2, ["--split"]),
        (["diagnose", "{rig}", "--rig-seed", "1"], 2, ["--rig-seed"]),
        (["compare", "rig", "--u", "u"], 2, ["--input-col"]),
        (["compare", "{ms}", "--fs", "2", "--time-unit", "ms"], 2, ["--fs", "--time-unit"]),
        (["simulate", "--out", "{rig}"], 2, ["rig.csv", "exists; pass --overwrite"]),
    ],
)
def test_bad_input_is_a_clear_error(records: dict[str, Path], tmp_path: Path, capsys,
                                    argv: list[str], code: int, words: list[str]) -> None:
    argv = [a.format(tmp=tmp_path, **records) for a in argv]
    got, err = run(argv, capsys)
    assert got == code, err
    for w in words:
        assert w in err, (w, err)
    assert "overwrite=True" not in err  # CLI words, not Python's
    assert not list(tmp_path.iterdir())  # nothing written


def test_existing_output_is_refused_before_any_work(records, tmp_path, capsys) -> None:
    js = tmp_path / "fit.json"
    js.write_text("keep")
    code, err = run(["fit", str(records["rig"]), "--json", str(js), *QUICK], capsys)
    assert code == 2 and "exists; pass --overwrite" in err and "fitting" not in err
    assert js.read_text() == "keep"


def test_wrong_units_are_warned_or_converted(records, tmp_path, capsys) -> None:
    js = tmp_path / "rad.json"
    code, err = run(["fit", str(records["rad"]), "--refine", "none", "--json", str(js), *QUICK],
                    capsys)
    assert code == 0 and "radians" in err and "rad.csv" in err
    assert any("radians" in w for w in json.loads(js.read_text())["warnings"])
    code, err = run(["fit", str(records["labelled_rad"]), "--refine", "none", *QUICK], capsys)
    assert code == 0 and "converted from rad to deg" in err and "radians" not in err


def test_a_diverging_fit_writes_a_json_marked_diverged(records, tmp_path, capsys) -> None:
    js = tmp_path / "div.json"
    # g_spring 1e9: a spring no substep count serves (1e6 is now simulated accurately with
    # 16 RK4 substeps, chosen for those values).
    code, err = run(["fit", str(records["rig"]), "--fix", "g_spring=1e9", "--allow-outside-box",
                     "--json", str(js), "--plot", str(tmp_path / "div.png"), *QUICK], capsys)
    assert code == 1 and "diverged" in err and "JSON" in err
    d = json.loads(js.read_text())
    assert d["status"] == "diverged" and d["warnings"][0].startswith("DIVERGED")
    assert d["est"]["rmse"] is None  # not finite, written as null
    assert not (tmp_path / "div.png").exists()  # no figure of a failed fit


def test_a_singular_fit_has_undetermined_intervals(records, tmp_path, capsys) -> None:
    js = tmp_path / "leak.json"
    code, err = run(["fit", str(records["rig"]), "--fix", "g_leak=1e9", "--allow-outside-box",
                     "--json", str(js), *QUICK], capsys)
    assert code in (0, 1) and "LinAlgError" not in err
    d = json.loads(js.read_text())
    undetermined = d["intervals"].get("undetermined", [])
    assert undetermined, "a leakage of 1e9 1/s leaves parameters without effect"
    for name in undetermined:
        assert d["params"].get(name, {"ci95": [None, None]})["ci95"] == [None, None]


def test_compare_vocabulary_and_time_unit(records, capsys) -> None:
    def ls_row(argv: list[str]) -> tuple[str, str]:
        assert main(["compare", *argv, "--methods", "ls", "--quiet"]) == 0
        out, err = capsys.readouterr()
        row = next(line for line in out.splitlines() if line.startswith("| LS |"))
        return row.split("|")[2:9], err  # the scores (MSE ... ITAE), not the seconds

    scores_ms, err = ls_row([str(records["ms"])])
    assert "--time-unit ms" in err  # a warning: ITAE would be 1e6 times too large
    scores_rescaled, _ = ls_row([str(records["ms"]), "--time-unit", "ms", "--u", "u",
                                 "--output-col", "y"])
    scores_s, _ = ls_row([str(records["rig"])])
    assert scores_rescaled == scores_s
    assert float(scores_ms[-1]) > 1e5 * float(scores_s[-1])  # ITAE on a ms axis


def test_help_texts_read_well() -> None:
    parser = build_parser()
    sub = parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    for name, p in sub.items():
        text = p.format_help()
        assert "%%" not in text, name
    for name in ("fit", "diagnose", "compare"):
        text = sub[name].format_help()
        for flag in ("--time-col", "--input-col", "--output-col", "--fs", "--delimiter",
                     "--time-unit"):
            assert flag in text, (name, flag)


INTERRUPT = textwrap.dedent(
    """
    import os, signal, sys
    from hhra_phys import refine
    from hhra_phys.cli import main

    calls = {"n": 0}
    original = refine.CompiledLeastSquares.__call__

    def ctrl_c_in_the_solver(self, z):
        calls["n"] += 1
        if calls["n"] == 3:  # inside IPOPT's / NLopt's callbacks, as a user's Ctrl-C
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, z)

    refine.CompiledLeastSquares.__call__ = ctrl_c_in_the_solver
    sys.exit(main(sys.argv[1:]))
    """
)


@pytest.mark.parametrize("refiner", ["ipopt", "nlopt"])
def test_ctrl_c_inside_the_refiner_exits_130_and_writes_nothing(
    records, tmp_path: Path, refiner: str
) -> None:
    js, png = tmp_path / "fit.json", tmp_path / "fit.png"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run(
        [sys.executable, "-c", INTERRUPT, "fit", str(records["rig"]), "--refine", refiner,
         "--json", str(js), "--plot", str(png), *QUICK],
        capture_output=True, text=True, env=env, timeout=600,
    )
    assert proc.returncode == 130, proc.stderr[-2000:]
    assert "interrupted; nothing written" in proc.stderr and "Traceback" not in proc.stderr
    assert not list(tmp_path.iterdir())


def test_a_failed_write_leaves_no_file(records, tmp_path, capsys, monkeypatch) -> None:
    def disk_full(src: object, dst: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", disk_full)
    js = tmp_path / "fit.json"
    code, err = run(["fit", str(records["rig"]), "--refine", "none", "--json", str(js), *QUICK],
                    capsys)
    assert code == 1 and "No space left" in err
    assert not list(tmp_path.iterdir())  # neither the file nor its temporary


def _readme_python_block(folder: Path) -> tuple[list[str], dict[str, str]]:
    """The README's first Python block, run with this checkout first on the path."""
    text = (REPO / "README.md").read_text()
    code = text.split("```python\n", 1)[1].split("```", 1)[0]
    return ["python", "-c", code], {"PYTHONPATH": str(REPO)}


#: The README's block (a fit and its files, several seconds) starts with the session in a
#: process of its own (tests/conftest.py, ``background``); its test reads the outcome.
BACKGROUND = {"test_the_readme_python_block_runs": _readme_python_block}


def test_the_readme_python_block_runs(background) -> None:
    run = background["test_the_readme_python_block_runs"]
    code, out, err = run.result()
    assert code == 0, err[-2000:]
    assert "(8, 5000)" in out and (run.out / "fit.json").exists()
    assert math.isfinite(json.loads((run.out / "fit.json").read_text())["val"]["rmse"])


def test_python_fit_converts_and_warns_with_the_default_model() -> None:
    from hhra_phys.fit import fit

    ds = simulate_rig(seed=0, duration=2.0)
    rad = type(ds)(t=ds.t, u=ds.u, y=np.deg2rad(ds.y), output_unit="rad", source="r.csv")
    res = fit(rad, optimizer="none", refine="none")
    assert any("converted from rad to deg" in w for w in res.warnings)
    assert res.metrics["est"]["rmse"] < 1.0  # fitted in degrees, as the model expects
    unlabelled = type(ds)(t=ds.t, u=ds.u, y=np.deg2rad(ds.y), source="r.csv")
    res = fit(unlabelled, optimizer="none", refine="none")
    assert any("radians" in w for w in res.warnings)


def test_problem_checks_fixed_values_as_the_cli_does() -> None:
    """Python's ``fixed`` gets the --fix check (sign, box), with the same opt-out."""
    from hhra_phys.errors import ParameterError
    from hhra_phys.fit import fit
    from hhra_phys.models.hhra.model import HHRAModel
    from hhra_phys.problem import Problem

    ds = simulate_rig(seed=0, duration=2.0)
    with pytest.raises(ParameterError, match=r"fixed g_leak=.* outside its box.*allow_outside"):
        Problem(HHRAModel(), ds, fixed={"g_leak": 1e9})
    with pytest.raises(ParameterError, match=r"fixed g_leak=-1.*positive quantity"):
        Problem(HHRAModel(), ds, fixed={"g_leak": -1.0}, allow_outside_box=True)
    with pytest.raises(ParameterError, match=r"fixed g_nope=.*g_nope"):
        Problem(HHRAModel(), ds, fixed={"g_nope": 1.0})
    problem = Problem(HHRAModel(), ds, fixed={"g_leak": 1e9}, allow_outside_box=True)
    assert problem.base[problem.model.params.index("g_leak")] == 1e9
    assert any("g_leak" in n and "allowed" in n for n in problem.notes)
    with pytest.raises(ParameterError, match="outside its box"):
        fit(ds, fixed={"g_leak": 1e9}, optimizer="none", refine="none")
    res = fit(ds, fixed={"g_leak": 1e9}, allow_outside_box=True, optimizer="none",
              refine="none")
    assert any("g_leak" in w and "allowed" in w for w in res.warnings)
