"""Bad input, third round (issue 35): nothing lost, nothing silent, no traceback.

Each case runs through ``hhra_phys.cli.main`` in this process (every one fails before any
long work) or through the Python API, and checks the exit code, the words that name the
file, flag, key or parameter at fault, and that nothing was written or replaced. The
signal cases run in a subprocess (a real SIGTERM).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from hhra_phys.cli import main
from hhra_phys.data import save
from hhra_phys.models.hhra.rig import simulate_rig

REPO = Path(__file__).resolve().parents[2]
QUICK = ["--pop", "4", "--iters", "2", "--refine", "none", "--quiet"]


def run(argv: list[object], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    """Exit code, stdout and stderr of ``hhra-phys ARGV`` run in this process."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own usage errors
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "this is a bug" not in err, err
    return code, out, err


def files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` with its bytes (to see what a case wrote or replaced)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


@pytest.fixture(scope="module")
def fitjs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A fit result of a 2 s rig record, as the JSON dict ``fit --json`` writes."""
    from hhra_phys.fit import fit

    res = fit(simulate_rig(seed=0, duration=2.0), optimizer="none", refine="none")
    return json.loads(json.dumps(res.to_json()))


@pytest.fixture
def rec(tmp_path: Path) -> Path:
    """A 2 s rig record ``good.csv`` with its side-car ``good.json``, in a fresh folder."""
    p = tmp_path / "good.csv"
    save(simulate_rig(seed=0, duration=2.0), p)
    return p


def refused(argv: list[object], code: int, words: list[str], folder: Path,
            capsys: pytest.CaptureFixture) -> str:
    """Run a case that must be refused: its exit code and words, nothing written or replaced."""
    before = files(folder)
    got, _, err = run(argv, capsys)
    assert got == code, err
    for w in words:
        assert w in err, (w, err)
    assert len(err.strip().splitlines()[-1]) > 0
    assert files(folder) == before, "a refused run wrote or replaced a file"
    return err


# -- lost: an output is never an input of the run ---------------------------------------------


def test_the_records_own_side_car_is_never_replaced(rec, capsys) -> None:
    side = rec.with_suffix(".json")
    refused(["fit", rec, *QUICK, "--json", side, "--overwrite"], 2,
            ["--json", "good.json", "DATA's side-car", "--overwrite never applies"],
            rec.parent, capsys)


def test_a_validation_records_side_car_is_never_replaced(rec, tmp_path, capsys) -> None:
    other = tmp_path / "val.csv"
    save(simulate_rig(seed=1, duration=2.0), other)
    refused(["fit", rec, "--validate", other, *QUICK, "--json", other.with_suffix(".json"),
             "--overwrite"], 2, ["--validate's side-car", "val.json"], tmp_path, capsys)
    refused(["diagnose", rec, "--pop", "4", "--iters", "1", "--json",
             rec.with_suffix(".json"), "--overwrite"], 2, ["DATA's side-car"], tmp_path, capsys)


# -- silent: side-cars that say something impossible -----------------------------------------


@pytest.mark.parametrize(("edit", "words"), [
    (lambda s: {**s, "intersample": "bogus"}, ["'intersample'", "'bogus'"]),
    (lambda s: {**s, "metadata": {**s["metadata"], "intersample": "bogus"}},
     ["'metadata.intersample'", "'bogus'"]),
    (lambda s: {**s, "fs": -250}, ["'fs'", "-250"]),
    (lambda s: {**s, "fs": 0}, ["'fs'"]),
    (lambda s: [], ["must be a JSON object", "list"]),
    (lambda s: 42, ["must be a JSON object", "int"]),
])
def test_a_side_car_that_says_the_impossible_is_named(edit, words, rec, capsys) -> None:
    side = rec.with_suffix(".json")
    side.write_text(json.dumps(edit(json.loads(side.read_text()))))
    refused(["fit", rec, *QUICK], 1, ["good.json", *words], rec.parent, capsys)


def test_a_valid_top_level_intersample_is_honoured(rec) -> None:
    from hhra_phys.data import load

    side = rec.with_suffix(".json")
    side.write_text(json.dumps({**json.loads(side.read_text()), "intersample": "foh"}))
    assert load(rec).intersample == "foh"


# -- partial: SIGTERM leaves nothing, as SIGINT does -------------------------------------------


TERM_IN_SECOND_WRITE = textwrap.dedent(
    """
    import os, signal, sys
    from hhra_phys import loop
    from hhra_phys.cli import main

    real = loop.LoopResult.report
    sig = getattr(signal, sys.argv.pop(1))

    def terminated_while_writing(self, *a, **k):  # the JSON is written by now
        assert os.path.exists(sys.argv[sys.argv.index("--json") + 1])
        os.kill(os.getpid(), sig)
        return real(self, *a, **k)

    loop.LoopResult.report = terminated_while_writing
    sys.exit(main(sys.argv[1:]))
    """
)


@pytest.mark.parametrize(("sig", "code", "words"), [
    ("SIGTERM", 143, "terminated (SIGTERM); nothing written"),
    ("SIGINT", 130, "interrupted; nothing written"),
])
def test_a_signal_while_writing_leaves_nothing(sig, code, words, rec, tmp_path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run(
        [sys.executable, "-c", TERM_IN_SECOND_WRITE, sig, "diagnose", str(rec), "--pop", "4",
         "--iters", "1", "--max-effects", "0", "--no-discover", "--json",
         str(out / "d.json"), "--report", str(out / "r.md")],
        capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == code, proc.stderr[-2000:]
    assert words in proc.stderr and "Traceback" not in proc.stderr
    assert not list(out.iterdir())


def test_sigterm_is_handled_as_sigint_only_inside_the_cli() -> None:
    from hhra_phys.interrupt import interruptible, last_signal

    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), interruptible(terminate=True):
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(10**6):  # the handler runs between bytecodes
            pass
    assert last_signal() == signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is before  # restored
    with interruptible():
        assert signal.getsignal(signal.SIGTERM) is before  # the library's default: untouched


def test_simulate_stopped_between_the_csv_and_its_side_car_leaves_neither(
        tmp_path, capsys, monkeypatch) -> None:
    import hhra_phys.data.csv_format as csv_format  # save_csv writes through its own name

    real, calls = csv_format.atomic_write_text, []

    def second(path, text):
        calls.append(path)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(path, text)

    monkeypatch.setattr(csv_format, "atomic_write_text", second)
    code, _, err = run(["simulate", "--out", tmp_path / "s.csv", "--duration", "2"], capsys)
    assert code == 130 and len(calls) == 2
    assert not list(tmp_path.iterdir())


# -- hang and allocation: sizes refused before the work ---------------------------------------


@pytest.mark.parametrize(("argv", "words"), [
    (["fit", "{rec}", "--iters", "1000000000"], ["--iters", "<= 1,000,000"]),
    (["fit", "{rec}", "--pop", "1000000000"], ["--pop", "<= 10,000"]),
    (["diagnose", "{rec}", "--pop", "1000000000"], ["--pop", "<= 10,000"]),
    (["compare", "{rec}", "--iters", "1000000000"], ["--iters"]),
    (["benchmark", "--pop", "1000000000"], ["--pop"]),
    (["benchmark", "--pop", "4", "--runs", "1"], ["--pop 4", "SciPy reference", "--no-scipy"]),
    (["fit", "{rec}", "--pop", "10000", "--iters", "1000000"],
     ["--pop/--iters", "h allowed", "lower --pop or --iters"]),
    (["fit", "{rec}", "--pop", "4", "--iters", "1000000", "--starts", "10000"],
     ["10000 starts", "h allowed"]),
    (["compare", "{rec}", "--na", "100000", "--methods", "ls", "--json", "{out}/c.json"],
     ["--na 100000", "250 samples", "regression rows", "lower the orders"]),
    (["compare", "{rec}", "--nb", "300", "--nk", "300", "--methods", "ls"], ["--nb 300"]),
])
def test_sizes_are_refused_before_the_work(argv, words, rec, tmp_path, capsys) -> None:
    argv = [a.format(rec=rec, out=tmp_path) for a in argv]
    err = refused(argv, 2, words, tmp_path, capsys)
    assert "fitting" not in err and "[1/" not in err


def test_the_search_budget_counts_memory_and_time(monkeypatch, capsys) -> None:
    from hhra_phys.cli import _guards
    from hhra_phys.errors import ParameterError

    monkeypatch.setattr(_guards, "available_memory", lambda: 4 * 2**20)  # 1 MiB allowed
    with pytest.raises(ParameterError, match=r"--pop 1000: .* memory"):
        _guards.check_search(1000, 1, 5000)
    _guards.check_search(4, 1, 5000)
    monkeypatch.setattr(_guards, "available_memory", lambda: None)
    _guards.check_search(100, 200, 5000)  # the paper's search: no word
    assert capsys.readouterr().err == ""
    _guards.check_search(100, 50000, 5000)  # about 17 min: announced
    assert "about 17 min" in capsys.readouterr().err


def test_python_fit_refuses_sizes_naming_the_setting() -> None:
    from hhra_phys.errors import ParameterError
    from hhra_phys.fit import fit

    ds = simulate_rig(seed=0, duration=2.0)
    with pytest.raises(ParameterError, match=r"pop_size must be at most 10,000"):
        fit(ds, pop_size=10**9)
    with pytest.raises(ParameterError, match=r"max_iter must be at most 1,000,000"):
        fit(ds, max_iter=10**9)
    with pytest.raises(ParameterError, match=r"pop_size must be an integer"):
        fit(ds, pop_size=True)


# -- the Python API: wrong types named, no AttributeError -------------------------------------


@pytest.mark.parametrize(("call", "words"), [
    (lambda ds: __import__("hhra_phys.fit").fit.fit(ds, model="HHRA"),
     ["model must be a hhra_phys Model", "'HHRA'"]),
    (lambda ds: __import__("hhra_phys.fit").fit.fit(ds, model=__import__(
        "hhra_phys").HHRAModel), ["model must be", "pass an instance"]),
    (lambda ds: __import__("hhra_phys.fit").fit.fit(42), ["data must be a Dataset", "42"]),
    (lambda ds: __import__("hhra_phys.fit").fit.fit("rec.csv"),
     ["data must be a Dataset", "hhra_phys.data.load"]),
    (lambda ds: __import__("hhra_phys.fit").fit.fit(ds, fixed={"g_leak": "abc"}),
     ["fixed g_leak='abc'", "must be a number"]),
    (lambda ds: __import__("hhra_phys.fit").fit.fit(ds, start={"g_leak": "abc"}),
     ["start g_leak='abc'", "must be a number"]),
    (lambda ds: __import__("hhra_phys.fit").fit.fit(ds, start={"g_leak": -1.0}),
     ["start g_leak=-1.0", "positive"]),
    (lambda ds: __import__("hhra_phys.fit").fit.fit(ds, start={"g_nope": 1.0}),
     ["start g_nope", "unknown parameter"]),
    (lambda ds: __import__("hhra_phys.fit").fit.fit(ds, start={"g_leak": float("nan")}),
     ["start g_leak", "finite"]),
    (lambda ds: __import__("hhra_phys.fit").fit.fit(ds, start=[1.0, 2.0]),
     ["start", "mapping"]),
    (lambda ds: __import__("hhra_phys").Parameter(3, "1", 1.0, 0.1, 10.0),
     ["Parameter name must be a str", "3"]),
    (lambda ds: __import__("hhra_phys").Parameter("k", "1", "1", 0.1, 10.0),
     ["parameter 'k'", "nominal must be a number"]),
    (lambda ds: __import__("hhra_phys").Parameter("k", 1, 1.0, 0.1, 10.0),
     ["parameter 'k'", "unit must be a str"]),
])
def test_the_python_api_names_the_argument(call, words) -> None:
    from hhra_phys.errors import HHRAError

    ds = simulate_rig(seed=0, duration=2.0)
    with pytest.raises(HHRAError) as info:
        call(ds)
    for w in words:
        assert w in str(info.value), (w, str(info.value))


# -- fit JSON edited by hand: the key named ------------------------------------------------------


def _edit(d: dict, path: str, value: object) -> dict:
    out = json.loads(json.dumps(d))
    *keys, last = path.split(".")
    target = out
    for k in keys:
        target = target[int(k)] if isinstance(target, list) else target[k]
    target[last] = value
    return out


@pytest.mark.parametrize(("path", "value", "words"), [
    ("params.g_valve.value", -31.7, ["'params.g_valve.value'", "positive quantity"]),
    ("params.g_leak.value", "abc", ["'params.g_leak.value'", "must be a number"]),
    ("model.class", "Bogus", ["'model.class'", "'Bogus'", "not a known model"]),
    ("records.0.fs", -250, ["'records[0].fs'", "-250"]),
    ("records.0.fs", "fast", ["'records[0].fs'", "'fast'"]),
    ("version", 99, ["'version' is 99"]),
    ("covariance", [[1.0, 2.0], [3.0, 4.0]], ["'covariance'", "6 x 6", "2 rows"]),
    ("free", ["g_valve", "g_bogus"], ["'free' names 'g_bogus'"]),
    ("format", "something else", ["'format' is 'something else'"]),
    ("params.g_valve.value", 1e308, ["'params.g_valve.value'", "beyond g_valve's box"]),
])
def test_an_edited_fit_json_is_refused_naming_the_key(path, value, words, fitjs, tmp_path,
                                                     capsys) -> None:
    from hhra_phys.errors import HHRAError
    from hhra_phys.result import FitResult

    p = tmp_path / "edited.json"
    p.write_text(json.dumps(_edit(fitjs, path, value)))
    with pytest.raises(HHRAError) as info:
        FitResult.load(p)
    for w in ["edited.json", *words]:
        assert w in str(info.value), (w, str(info.value))
    err = refused(["design", p, "--duration", "2", "--out", tmp_path / "u.csv"], 1,
                  ["edited.json", *words], tmp_path, capsys)
    assert "designing" not in err


def test_a_fit_json_without_format_still_says_missing(fitjs, tmp_path) -> None:
    from hhra_phys.errors import DataError
    from hhra_phys.result import FitResult

    p = tmp_path / "noformat.json"
    p.write_text(json.dumps({k: v for k, v in fitjs.items() if k != "format"}))
    with pytest.raises(DataError, match="missing 'format'"):
        FitResult.load(p)


def test_the_public_record_ships_with_the_package(tmp_path, monkeypatch) -> None:
    import hashlib
    import re

    from hhra_phys.data import public

    monkeypatch.delenv("HHRA_SHARED_DATA", raising=False)
    monkeypatch.chdir(tmp_path)  # no shared/data above it
    found = public.find_public_data()
    assert found == Path(public.__file__).resolve().parent / public.PUBLIC_ACTUATOR_FILE
    assert hashlib.sha256(found.read_bytes()).hexdigest() == public.PUBLIC_ACTUATOR_SHA256
    assert public.PUBLIC_ACTUATOR_SHA256 in (REPO / "docs" / "data.md").read_text()
    config = (REPO / "pyproject.toml").read_text()  # (tomllib is Python 3.11+)
    section = config.split("[tool.setuptools.package-data]", 1)[1].split("\n[", 1)[0]
    shipped = re.search(r'^"hhra_phys.data" = \[(.*)\]$', section, re.M)
    assert shipped and f'"{public.PUBLIC_ACTUATOR_FILE}"' in shipped.group(1)  # pip install .


def test_an_infinite_stiffness_is_no_overflow_in_plan() -> None:
    from hhra_phys import HHRAModel, Simulator

    model = HHRAModel()
    p = model.nominal()
    p[model.params.index("g_valve")] = 1e308
    method, substeps, reason = Simulator(model, fs=250.0).plan(p * 1e10)
    assert reason == "non-finite state Jacobian" and substeps == 2


# -- silent acceptance refused -----------------------------------------------------------------


@pytest.mark.parametrize(("argv", "words"), [
    (["fit", "{rec}", "--input-col", "y", *QUICK],
     ["--input-col 'y'", "default column of --output-col"]),
    (["fit", "{rec}", "--output-col", "u", *QUICK],
     ["--output-col 'u'", "default column of --input-col"]),
    (["diagnose", "{rec}", "--input-col", "t"], ["--input-col 't'", "--time-col"]),
    (["compare", "{rec}", "--y", "u", "--methods", "ls"], ["--output-col 'u'"]),
    (["simulate", "--out", "{out}/s.csv", "--generator", "reference",
      "--effect", "gravity_load:g_grav_cos=1,g_grav_sin=0",
      "--effect", "gravity_load:g_grav_cos=2,g_grav_sin=0"],
     ["--effect gravity_load is given twice"]),
    (["simulate", "--out", "{out}/s.csv", "--effect", "coulomb_friction:g_coulomb=1"],
     ["--effect needs --generator reference"]),
    (["fit", "{rec}", "--free", "", *QUICK], ["--free ''", "empty list"]),
    (["fit", "{rec}", "--free", " , ", *QUICK], ["--free ' , '"]),
    (["diagnose", "{rec}", "--effects", ""], ["--effects ''", "empty list"]),
])
def test_silent_acceptance_is_refused_round3(argv, words, rec, tmp_path, capsys) -> None:
    argv = [a.format(rec=rec, out=tmp_path) for a in argv]
    err = refused(argv, 2, words, tmp_path, capsys)
    assert "fitting" not in err and "diagnosing" not in err


def test_a_swapped_pair_of_columns_is_still_accepted(tmp_path, capsys) -> None:
    """Naming both columns the other way round is a choice, not a mistake."""
    p = tmp_path / "swap.csv"
    ds = simulate_rig(seed=0, duration=2.0)
    rows = "\n".join(f"{a!r},{b!r},{c!r}" for a, b, c in zip(ds.t.tolist(), ds.y.tolist(),
                                                              ds.u.tolist(), strict=True))
    p.write_text(f"t,u,y\n{rows}\n")
    code, _, err = run(["fit", p, "--input-col", "y", "--output-col", "u", *QUICK], capsys)
    assert code == 0, err


PRINTING_MODEL = """
print("hello from the model file")
from hhra_phys.models.hhra.model import HHRAModel

def make_model(data=None):
    print("building the model")
    return HHRAModel()
"""


@pytest.mark.parametrize("cmd", ["fit", "diagnose"])
def test_json_to_stdout_stays_json_when_user_code_prints(cmd, rec, tmp_path, capsys) -> None:
    model = tmp_path / "printing_model.py"
    model.write_text(PRINTING_MODEL)
    extra = (QUICK if cmd == "fit" else ["--pop", "4", "--iters", "1", "--max-effects", "0",
                                          "--no-discover"])
    code, out, err = run([cmd, rec, "--model", f"{model}:make_model", *extra, "--json", "-"],
                         capsys)
    assert code == 0, err
    json.loads(out)  # the JSON alone
    assert "hello from the model file" in err and "building the model" in err


def test_design_refuses_a_model_other_than_the_fits(fitjs, tmp_path, capsys) -> None:
    fit_path = tmp_path / "fit.json"
    fit_path.write_text(json.dumps(fitjs))
    other = tmp_path / "other_model.py"
    other.write_text("from hhra_phys.models.hhra.model import HHRAModel\n"
                     "def make_model(data=None):\n    return HHRAModel(valve='linear')\n")
    refused(["design", fit_path, "--duration", "2", "--out", tmp_path / "u.csv", "--model",
             f"{other}:make_model"], 2,
            ["--model", "LinearValve", "OrificeValve", "would be ignored"], tmp_path, capsys)


NAN_EFFECT = '''
from dataclasses import dataclass
from typing import ClassVar

import casadi as ca

from hhra_phys import Effect, Parameter, register_effect


@register_effect
@dataclass(frozen=True)
class NanEffect35(Effect):
    stage: ClassVar[str] = "motion"
    name: ClassVar[str] = "nan_effect_35"
    reads: ClassVar[tuple] = ("omega",)
    writes: ClassVar[tuple] = ("omega",)
    entry: ClassVar[str] = "rate:omega"
    signature: ClassVar[str] = "none"
    regressors: ClassVar[tuple] = ()

    @property
    def parameters(self):
        return (Parameter("g_nan35", "1/s", 1.0, 0.1, 10.0, "log", "a rate"),)

    def apply(self, ctx):
        ctx.add_rate("omega", ctx.p["g_nan35"] * ca.sqrt(-1 - ctx.x["omega"] ** 2))
'''


def test_an_effect_that_simulates_to_nan_is_named(rec, tmp_path, capsys) -> None:
    from hhra_phys.parts import EFFECTS

    src = tmp_path / "nan_effect_35.py"
    src.write_text(NAN_EFFECT)
    try:
        err = refused(["diagnose", rec, "--pop", "4", "--iters", "1", "--no-discover",
                       "--effects-from", src], 1,
                      ["--effects-from effect 'nan_effect_35'", "NaN or inf", "g_nan35=1"],
                      tmp_path, capsys)
        assert "diagnosing" not in err
    finally:
        EFFECTS.pop("nan_effect_35", None)


# -- README: every command runs, the install line agrees with the guide -------------------------


def _readme() -> str:
    return (REPO / "README.md").read_text()


def test_readme_and_guide_install_the_same_way() -> None:
    import re

    guide = (REPO / "docs" / "guide.md").read_text()
    install = re.search(r"python -m pip install [^\n&]+", guide)
    assert install is not None
    line = install.group(0).strip()
    quick = _readme()[_readme().index("## Quick start"):_readme().index("## Commands")]
    assert line in quick, line
    assert "7-8 minutes" in quick and "docs/testing.md" in quick


def test_every_flag_of_the_readme_table_exists() -> None:
    import re

    from hhra_phys.cli import build_parser

    sub = build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    table = _readme()[_readme().index("## Commands"):_readme().index("## Python")]
    rows = re.findall(r"^\| `hhra-phys (\w+)([^`]*)`", table, re.M)
    assert {cmd for cmd, _ in rows} == set(sub)
    for cmd, synopsis in rows:
        known = {s for a in sub[cmd]._actions for s in a.option_strings}
        for flag in re.findall(r"--[\w-]+", synopsis):
            assert flag in known, (cmd, flag)


def test_every_readme_command_runs(tmp_path, capsys) -> None:
    """Each command of the README's table, with its flags, cheaply (the demo runs in
    test_cli.py, ``demo --quick``; the Python block in test_bad_inputs.py)."""
    t = tmp_path
    cheap = ["--pop", "4", "--iters", "2"]
    for argv in (
            ["simulate", "--out", t / "r.csv", "--seed", "1", "--noise", "0.05", "--duration",
             "4"],
            ["simulate", "--out", t / "v.csv", "--seed", "2", "--duration", "4",
             "--generator", "reference", "--effect", "coulomb_friction:g_coulomb=1"],
            ["fit", t / "r.csv", "--optimizer", "hgwo", "--refine", "none", "--free",
             "g_valve,g_compress,g_leak,g_torque,g_damping", "--fix", "g_spring=0",
             "--json", t / "fit.json", "--plot", t / "fit.png", "--report", t / "fit.md", *cheap,
             "--quiet"],
            ["compare", t / "r.csv", "--json", t / "c.json", "--plot", t / "c.png",
             "--methods", "ls", "--quiet"],
            ["diagnose", t / "r.csv", "--validate", t / "v.csv", "--json", t / "d.json",
             "--report", t / "d.md", "--max-effects", "0", "--no-discover", *cheap[:3], "1"],
            ["design", t / "fit.json", "--duration", "2", "--out", t / "u.csv", "--criterion",
             "d", "--draws", "1"],
            ["benchmark", "--runs", "1", "--functions", "f1", "--methods", "gwo", "--json",
             t / "b.json", "--plot", t / "b.png", "--pop", "5", "--iters", "2"]):
        code, _, err = run(argv, capsys)
        assert code == 0, (argv, err[-2000:])
    for name in ("r.csv", "v.csv", "fit.json", "fit.png", "fit.md", "fit_fit.png", "c.json",
                 "c.png", "d.json", "d.md", "u.csv", "b.json", "b.png"):
        assert (t / name).is_file(), name
