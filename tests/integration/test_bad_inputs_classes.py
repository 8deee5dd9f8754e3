"""Bad input, second round: every case of issue 24 and the class it stands for.

Each class is tested through ``hhra_phys.cli.main`` in this process (fast: every case fails
before any long work, which is the point), and where a class is "every flag of a kind",
the flags are taken from the parser itself, so a flag added later is checked too:

- no traceback (negative seeds on every seed flag, user code that raises or exits, bad
  --dask addresses, a binary FIT.json, Ctrl-C while importing, anything unforeseen);
- no unguarded allocation (sizes refused with the number and the flag, a time estimate
  before a long design);
- no silent replacement (an output is never an input of the same run, two outputs never
  share a path, a suffix never contradicts what is written);
- no partial file (every output checked before work; the demo leaves nothing when stopped);
- no silent acceptance and no weak message (the cases of the issue, each with its
  neighbours).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import textwrap
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from hhra_phys.cli import build_parser, main
from hhra_phys.cli._guards import output_path, seed, split_value
from hhra_phys.data import save
from hhra_phys.models.hhra.rig import simulate_rig

REPO = Path(__file__).resolve().parents[2]
USER_MODELS = Path(__file__).resolve().parent / "user_models"
QUICK = ["--pop", "8", "--iters", "2", "--refine", "none", "--quiet"]


# -- fixtures -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def d(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Tiny records and a fit result, written once for the module."""
    base = tmp_path_factory.mktemp("inputs")
    ds = simulate_rig(seed=0, duration=2.0)
    out = {"dir": base, "rig": base / "rig.csv"}
    save(ds, out["rig"])
    t, u, y = ds.t, ds.u, ds.y

    def csv(name: str, header: str, cols: tuple[np.ndarray, ...], sep: str = ",",
            enc: str = "utf-8", fmt: str = "{!r}") -> None:
        rows = "\n".join(sep.join(fmt.format(float(v)) for v in r) for r in zip(*cols,
                                                                                strict=True))
        (base / name).write_bytes(f"{header}\n{rows}\n".encode(enc))
        out[name.rsplit(".", 1)[0]] = base / name

    csv("u1e300.csv", "t,u,y", (t, u * 1e300, y))
    cell = y.copy()
    cell[100] = 1e300
    csv("cell.csv", "t,u,y", (t, u, cell))
    csv("huge.csv", "t,u,y", (t, u, y * 1e30))
    csv("const.csv", "t,u,y", (t, u, 0 * y + 3.0))
    csv("comma.csv", "t;u;y", (t, u, y), sep=";", enc="latin-1", fmt="{:.6f}")
    (base / "comma.csv").write_bytes((base / "comma.csv").read_bytes().replace(b".", b","))
    csv("blanks.csv", "Zeit [s];Strom [mA];Winkel [°]", (t, u, y), sep=";", enc="latin-1")
    import scipy.io

    scipy.io.savemat(base / "notime.mat", {"u": u, "y": y})
    out["notime"] = base / "notime.mat"
    np.save(base / "one.npy", np.c_[t, u, y])
    (base / "one.npy").rename(base / "renamed.npz")
    np.savez(base / "objects.npz", t=np.array([{"a": 1}] * t.size, dtype=object), u=u, y=y)
    np.savez(base / "zerod.npz", t=np.float64(1.0), u=u, y=y)
    (base / "corrupt.npz").write_bytes(bytes(range(256)) * 4)
    for name in ("renamed", "objects", "zerod", "corrupt"):
        out[name] = base / f"{name}.npz"
    (base / "binary.json").write_bytes(bytes(range(128, 256)) * 20)
    out["binary"] = base / "binary.json"
    from hhra_phys.fit import fit

    res = fit(ds, optimizer="none", refine="none")
    out["fit"] = res.save(base / "fit.json")
    # User code: a part whose apply raises, a file that exits, an effect that raises,
    # a file that registers nothing, one that shadows the library.
    (base / "badpart.py").write_text(textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(USER_MODELS)!r})
        from dataclasses import dataclass
        import two_tank
        from hhra_phys import Model, Parameter, Part, register_part

        @register_part
        @dataclass(frozen=True)
        class BadPump(Part):
            name = "bad_pump"
            stage = "pump"

            @property
            def parameters(self):
                return (Parameter("k_pump", "cm/(s*V)", 0.5, 0.05, 5.0, "log", "gain"),)

            def apply(self, ctx):
                ctx.signals["inflow"] = ctx.p["nope"] * ctx.u

        def make():
            return Model([BadPump(), two_tank.UpperTank(), two_tank.LowerTank(),
                          two_tank.LevelSensor()])
        """))
    (base / "exits.py").write_text("import sys\nsys.exit(3)\n")
    (base / "nothing.py").write_text("X = 1\n")
    (base / "shadow.py").write_text(textwrap.dedent("""
        from dataclasses import dataclass
        from hhra_phys import register_effect
        from hhra_phys.effects import EFFECTS

        @register_effect
        @dataclass(frozen=True)
        class MyCoulomb(EFFECTS["coulomb_friction"]):
            name = "coulomb_friction"
        """))
    (base / "raising_effect.py").write_text(textwrap.dedent("""
        from dataclasses import dataclass
        from hhra_phys import register_effect
        from hhra_phys.effects import EFFECTS

        @register_effect
        @dataclass(frozen=True)
        class BrokenFriction(EFFECTS["coulomb_friction"]):
            name = "broken_friction_t24"

            def apply(self, ctx):
                raise RuntimeError("broken on purpose")
        """))
    for name in ("badpart", "exits", "nothing", "shadow", "raising_effect"):
        out[name] = base / f"{name}.py"
    return out


def run(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    """Exit code, stdout and stderr of ``hhra-phys ARGV``; never a traceback."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own usage errors
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return code, out, err


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` with its bytes (to prove nothing changed)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    return parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]


def required_args(cmd: str, tmp: Path, d: dict[str, Path]) -> list[str]:
    """The least a command needs to get to its option checks."""
    return {"simulate": ["--out", str(tmp / "s.csv")],
            "design": [str(d["fit"]), "--duration", "2", "--out", str(tmp / "u.csv")],
            "demo": ["--out", str(tmp / "demo")],
            "fit": [str(d["rig"])], "diagnose": [str(d["rig"])],
            "compare": [str(d["rig"]), "--methods", "ls"],
            "benchmark": ["--runs", "1", "--functions", "f1", "--methods", "gwo"]}[cmd]


# -- tracebacks -----------------------------------------------------------------------------


SEED_FLAGS = [(cmd, a.option_strings[0]) for cmd, p in subparsers().items()
              for a in p._actions if a.dest in ("seed", "rig_seed")]


def test_every_command_has_its_seed_flags_checked() -> None:
    assert len(SEED_FLAGS) >= 9  # seven --seed, two --rig-seed
    for cmd, p in subparsers().items():
        for a in p._actions:
            if a.dest in ("seed", "rig_seed"):
                assert a.type is seed, (cmd, a.option_strings)


@pytest.mark.parametrize(("cmd", "flag"), SEED_FLAGS)
def test_a_negative_seed_is_a_usage_error_before_anything(cmd, flag, d, tmp_path, capsys):
    argv = [cmd, *required_args(cmd, tmp_path, d), flag, "-1"]
    if flag == "--rig-seed":
        argv = [cmd, flag, "-1"]
    code, _, err = run(argv, capsys)
    assert code == 2 and flag in err and "integer >= 0" in err
    assert not list(tmp_path.iterdir())  # demo: not even its folder


def test_an_input_scaled_by_1e300_is_named(d, capsys) -> None:
    code, _, err = run(["fit", d["u1e300"], *QUICK], capsys)
    assert code == 1 and "u1e300.csv" in err and "column 'u'" in err and "1e+100" in err


@pytest.mark.parametrize("cmd", ["fit", "diagnose"])
def test_a_user_part_that_raises_is_named_with_its_file(cmd, d, tmp_path, capsys) -> None:
    tank = tmp_path / "tank.csv"
    sys.path.insert(0, str(USER_MODELS))
    try:
        import two_tank

        save(two_tank.simulate_record(seed=1, q_side=0.0).slice(0, 200), tank)
    finally:
        sys.path.remove(str(USER_MODELS))
    code, _, err = run([cmd, tank, "--model", f"{d['badpart']}:make", "--pop", "8",
                        "--iters", "2"], capsys)
    assert code == 1
    for words in ("part 'bad_pump'", "badpart.py", "line ", "KeyError: 'nope'", "ctx.p"):
        assert words in err, (words, err)


def test_a_model_file_calling_sys_exit_is_reported(d, capsys) -> None:
    code, _, err = run(["fit", d["rig"], "--model", f"{d['exits']}:make", *QUICK], capsys)
    assert code == 1 and "exits.py" in err and "sys.exit(3)" in err


@pytest.mark.parametrize(("address", "words"), [
    ("", "--dask ''"), ("not-an-address", "not a scheduler address"),
    ("tcp://host:port", "not a scheduler address"), ("127.0.0.1:99999", "not a scheduler"),
])
def test_bad_dask_addresses(address, words, d, capsys) -> None:
    code, _, err = run(["fit", d["rig"], "--dask", address, *QUICK], capsys)
    assert code == 2 and words in err


@pytest.fixture
def server() -> Iterator[callable]:
    """``start(reply)``: a local TCP server answering ``reply`` (None: silent); its port."""
    socks: list[socket.socket] = []

    def start(reply: bytes | None) -> int:
        srv = socket.socket()
        srv.bind(("127.0.0.1", 0))
        srv.listen(4)
        socks.append(srv)

        def serve() -> None:
            while True:
                try:
                    conn, _ = srv.accept()
                except OSError:
                    return
                socks.append(conn)
                if reply is not None:
                    conn.sendall(reply)

        threading.Thread(target=serve, daemon=True).start()
        return srv.getsockname()[1]

    yield start
    for s in socks:
        s.close()


@pytest.mark.parametrize(("reply", "words"), [
    (b"HTTP/1.1 400 Bad Request\r\n\r\n", "not a Dask scheduler"),  # was a 3 EiB read
    (None, "did not answer as a Dask scheduler"),
])
def test_dask_to_something_that_is_not_a_scheduler(reply, words, server, d, capsys,
                                                     monkeypatch) -> None:
    pytest.importorskip("distributed")
    from hhra_phys import cluster

    monkeypatch.setattr(cluster, "PROBE_TIMEOUT", 0.5)
    port = server(reply)
    code, _, err = run(["fit", d["rig"], "--dask", f"tcp://127.0.0.1:{port}", *QUICK], capsys)
    assert code == 2 and words in err and str(port) in err


def test_nothing_listening_at_the_dask_address(d, capsys) -> None:
    pytest.importorskip("distributed")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nothing listens
    code, _, err = run(["fit", d["rig"], "--dask", f"127.0.0.1:{port}", *QUICK], capsys)
    assert code == 2 and "cannot reach" in err


@pytest.mark.parametrize(("argv", "words"), [
    (["--generator", "reference", "--effect", "coulomb_friction:nope=1"],
     ["no parameter 'nope'", "g_coulomb"]),
    (["--generator", "reference", "--effect", "coulomb_friction"], ["g_coulomb=VALUE"]),
    (["--generator", "reference", "--noise", "-1"], ["--noise"]),
    (["--noise", "-1"], ["--noise"]),
    (["--noise", "nan"], ["--noise"]),
    (["--quantization", "0"], ["--quantization"]),
    (["--effect", "coulomb_friction:g_coulomb=8"], ["--generator reference"]),
])
def test_simulate_option_errors(argv, words, tmp_path, capsys) -> None:
    code, _, err = run(["simulate", "--out", tmp_path / "s.csv", "--duration", "2", *argv],
                       capsys)
    assert code == 2 and all(w in err for w in words), err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(("name", "words"), [
    ("binary", ["binary.json", "not a text file"]),
    ("rig", ["rig.csv", "not a JSON fit result"]),
])
def test_design_of_a_file_that_is_not_a_fit(name, words, d, tmp_path, capsys) -> None:
    code, _, err = run(["design", d[name], "--duration", "2", "--out", tmp_path / "u.csv"],
                       capsys)
    assert code == 1 and all(w in err for w in words)
    assert not list(tmp_path.iterdir())


def test_design_of_an_incomplete_fit(d, tmp_path, capsys) -> None:
    js = tmp_path / "cut.json"
    js.write_text(json.dumps({"format": "hhra-phys fit result"}))
    code, _, err = run(["design", js, "--duration", "2", "--out", tmp_path / "u.csv"], capsys)
    assert code == 1 and "cut.json" in err and "not a complete" in err


def test_an_unforeseen_error_is_one_line_and_exit_1(d, capsys, monkeypatch) -> None:
    from hhra_phys.cli import fit as fit_cli

    def broken(args):
        raise RuntimeError("something nobody checked")

    monkeypatch.setattr(fit_cli, "run", broken)
    code, _, err = run(["fit", d["rig"]], capsys)
    assert code == 1 and "unexpected RuntimeError: something nobody checked" in err
    assert "HHRA_PHYS_DEBUG" in err
    monkeypatch.setenv("HHRA_PHYS_DEBUG", "1")
    assert main(["fit", str(d["rig"])]) == 1
    assert "Traceback" in capsys.readouterr().err  # on request


CTRL_C_IN_IMPORTS = textwrap.dedent("""
    import importlib.abc, os, signal, sys, time

    # A terminal's Ctrl-C reaches Python's handler; a suite started in the background of a
    # non-interactive shell inherits SIGINT ignored, and the child would never see it.
    signal.signal(signal.SIGINT, signal.default_int_handler)

    class CtrlCOnCasadi(importlib.abc.MetaPathFinder):  # a user's Ctrl-C mid-import
        def find_spec(self, name, path=None, target=None):
            if name == "casadi":
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.5)
            return None

    sys.meta_path.insert(0, CtrlCOnCasadi())
    import hhra_phys_cli
    sys.exit(hhra_phys_cli.main())
    """)


def test_ctrl_c_while_importing_exits_130_quietly() -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-c", CTRL_C_IN_IMPORTS, "fit", "--help"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 130, proc.stderr[-2000:]
    assert "interrupted while starting; nothing written" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_the_console_script_is_the_guarded_entry() -> None:
    text = (REPO / "pyproject.toml").read_text()
    assert 'hhra-phys = "hhra_phys_cli:main"' in text


# -- sizes ----------------------------------------------------------------------------------


@pytest.mark.parametrize(("cmd", "argv", "flag"), [
    ("simulate", ["--duration", "1e7"], "--duration 1e+07"),
    ("simulate", ["--duration", "2e5", "--fs", "1000"], "--fs 1000"),
    ("compare", ["--duration", "1e7", "--methods", "ls"], "--duration 1e+07"),
    ("design", ["--duration", "1e6"], "--duration 1e+06"),
])
def test_a_record_too_large_is_refused_with_the_number_and_the_flag(cmd, argv, flag, d,
                                                                    tmp_path, capsys) -> None:
    base = {"simulate": ["--out", tmp_path / "s.csv"], "compare": ["--quiet"],
            "design": [d["fit"], "--out", tmp_path / "u.csv"]}[cmd]
    code, _, err = run([cmd, *base, *argv], capsys)
    assert code == 2 and flag in err and "of memory" in err and "samples" in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(("argv", "words"), [
    (["--generator", "reference", "--effect", "input_delay:delay=1e6"],
     ["delay=1e+06", "outside its box", "[0, 8]"]),
    (["--fs", "1e7"], ["--fs 1e+07", "between"]),
    (["--amplitude", "1e300"], ["--amplitude 1e+300", "300 mA"]),
    (["--duration", "0.1"], ["--duration 0.1", "--fs 250", "25 samples"]),
    (["--fs", "5"], ["--duration 2", "--fs 5", "lengthen --duration or raise --fs"]),
])
def test_simulate_values_outside_what_the_rig_means(argv, words, tmp_path, capsys) -> None:
    code, _, err = run(["simulate", "--out", tmp_path / "s.csv", "--duration", "2", *argv],
                       capsys)
    assert code == 2 and all(w in err for w in words), err
    assert not list(tmp_path.iterdir())


def test_compare_on_a_rig_too_short_names_duration(capsys) -> None:
    code, _, err = run(["compare", "--duration", "0.05", "--methods", "ls", "--quiet"], capsys)
    assert code == 2 and "--duration 0.05" in err and "lengthen --duration" in err


def test_a_scaled_down_amplitude_is_noted(tmp_path, capsys) -> None:
    code, _, err = run(["simulate", "--out", tmp_path / "s.csv", "--duration", "2",
                        "--amplitude", "50"], capsys)
    assert code == 0 and "--amplitude 50 mA" in err and "scaled to" in err


def test_the_memory_budget_follows_the_machine(monkeypatch) -> None:
    from hhra_phys.cli import _guards
    from hhra_phys.errors import ParameterError

    monkeypatch.setattr(_guards, "available_memory", lambda: 8 * 2**20)  # 8 MiB free
    with pytest.raises(ParameterError, match="--duration 400"):
        _guards.check_size(400 * 250, "--duration 400")
    _guards.check_size(1000, "--duration 4")
    monkeypatch.setattr(_guards, "available_memory", lambda: None)
    assert _guards.record_budget() == _guards.MAX_RECORD_BYTES
    with pytest.raises(ParameterError):
        _guards.check_size(float("nan"), "--duration nan")


def test_a_long_reference_simulation_says_how_long_before_it_starts(tmp_path, capsys,
                                                                     monkeypatch) -> None:
    import time

    import hhra_phys.reference
    from hhra_phys.errors import HHRAError

    def slow(*, duration, fs, **kw):
        if duration * fs <= 2000:  # the calibration: 0.7 s for 2000 samples
            time.sleep(0.7)
            return None
        raise HHRAError("stopped by the test")

    monkeypatch.setattr(hhra_phys.reference, "reference_record", slow)
    code, _, err = run(["simulate", "--generator", "reference", "--duration", "800", "--out",
                        tmp_path / "r.csv"], capsys)
    assert code == 1 and "estimated" in err and "--duration and --fs" in err
    assert err.index("estimated") < err.index("stopped by the test")
    assert not list(tmp_path.iterdir())


def test_a_long_design_says_how_long_before_it_starts(d, tmp_path, capsys,
                                                      monkeypatch) -> None:
    import hhra_phys.design
    from hhra_phys.errors import HHRAError

    def stop(*args, **kw):  # the design itself: not run here
        raise HHRAError("stopped by the test")

    monkeypatch.setattr(hhra_phys.design, "design_input", stop)
    code, _, err = run(["design", d["fit"], "--duration", "2000", "--out", tmp_path / "u.csv"],
                       capsys)
    assert code == 1 and "stopped by the test" in err
    assert "estimated" in err and "--duration and --draws" in err
    assert err.index("estimated") < err.index("stopped by the test")


# -- a user's file silently replaced --------------------------------------------------------


def _user_files_unchanged(d: dict[str, Path], argv: list[str], capsys,
                          words: list[str]) -> None:
    before = snapshot(d["dir"])
    code, _, err = run(argv, capsys)
    assert code == 2, err
    for w in words:
        assert w in err, (w, err)
    assert snapshot(d["dir"]) == before


@pytest.mark.parametrize(("argv", "words"), [
    (["fit", "{rig}", "--json", "{rig}", "--overwrite"], ["--json", "rig.csv"]),
    (["fit", "{rig}", "--model", "{badpart}:make", "--json", "{badpart}", "--overwrite"],
     ["is the input --model", "--overwrite never applies"]),
    (["diagnose", "{rig}", "--effects-from", "{nothing}", "--json", "{nothing}",
      "--overwrite"], ["is the input --effects-from"]),
    (["design", "{fit}", "--duration", "2", "--out", "{dir}/fit.csv", "--overwrite"],
     ["side-car", "is the input FIT.json"]),
    (["fit", "{rig}", "--validate", "{val}", "--json", "{val}", "--overwrite"],
     ["--json", "val.csv"]),
    (["compare", "{rig}", "--methods", "ls", "--report", "{badpart}", "--overwrite"],
     ["--report", "Markdown"]),
])
def test_overwrite_never_applies_to_an_input_of_the_same_run(argv, words, d, capsys) -> None:
    if not (d["dir"] / "val.csv").exists():
        save(simulate_rig(seed=1, duration=2.0), d["dir"] / "val.csv")
    _user_files_unchanged(d, [a.format(val=d["dir"] / "val.csv", **d) for a in argv], capsys,
                          words)


def test_an_output_that_is_a_link_to_the_input_is_refused(d, tmp_path, capsys) -> None:
    link = tmp_path / "link.json"
    link.symlink_to(d["fit"])
    _user_files_unchanged(d, ["design", d["fit"], "--duration", "2", "--out",
                              tmp_path / "link.csv", "--overwrite"], capsys,
                          ["is the input FIT.json"])


@pytest.mark.parametrize(("argv", "words"), [
    (["diagnose", "{rig}", "--json", "{out}/d.md", "--report", "{out}/d.md"],
     ["--json and --report are the same file"]),
    (["compare", "{rig}", "--methods", "ls", "--json", "{out}/d.md", "--report", "{out}/d.md"],
     ["--json and --report are the same file"]),
    (["benchmark", "--runs", "1", "--json", "{out}/d.md", "--markdown", "{out}/d.md"],
     ["--json and --markdown are the same file"]),
    (["diagnose", "{rig}", "--report", "{out}/x.png"], ["--report", "x.png", "Markdown", ".md"]),
    (["compare", "{rig}", "--methods", "ls", "--report", "{out}/x.png"], ["Markdown"]),
    (["benchmark", "--runs", "1", "--markdown", "{out}/x.png"], ["--markdown", "Markdown"]),
    (["diagnose", "{rig}", "--report", "{out}/d.md", "--json", "{out}/d_before.png"],
     ["JSON, not a .png"]),
    (["compare", "{rig}", "--methods", "ls", "--plot", "{out}/p.png", "--json",
      "{out}/p_convergence.png"], ["JSON, not a .png"]),
])
def test_two_outputs_never_share_a_path_and_suffixes_say_what_is_written(argv, words, d,
                                                                         tmp_path, capsys):
    argv = [a.format(out=tmp_path, **d) for a in argv]
    code, _, err = run(argv, capsys)
    assert code == 2 and all(w in err for w in words), err
    assert not list(tmp_path.iterdir())


def test_a_diagnose_report_figure_is_not_the_json(d, tmp_path, capsys) -> None:
    code, _, err = run(["diagnose", d["rig"], "--report", tmp_path / "r.md", "--json",
                        tmp_path / "r_before.png"], capsys)
    assert code == 2 and not list(tmp_path.iterdir())


# -- partial outputs ------------------------------------------------------------------------


@pytest.mark.parametrize("argv", [
    ["fit", "{rig}", "--json", "{out}/o.png", "--plot", "{out}/o.png", *QUICK],
    ["fit", "{rig}", "--json", "{out}/o.json", "--plot", "{out}/o.json", *QUICK],
    ["fit", "{rig}", "--json", "{out}/o.json", "--plot", "{out}/o.xyz", *QUICK],
    ["compare", "{rig}", "--methods", "ls", "--json", "{out}/o.png", "--report", "{out}/o.md",
     "--plot", "{out}/o.png", "--quiet"],
    ["diagnose", "{rig}", "--json", "{out}/o.json", "--report", "{out}/o.png"],
])
def test_every_output_is_checked_before_any_work(argv, d, tmp_path, capsys) -> None:
    code, _, err = run([a.format(out=tmp_path, **d) for a in argv], capsys)
    assert code == 2 and "fitting" not in err and ", split" not in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("stop", [KeyboardInterrupt, OSError])
@pytest.mark.parametrize("cmd", ["fit", "compare", "design"])
def test_a_run_stopped_between_its_writes_leaves_none(cmd, stop, d, tmp_path, capsys,
                                                       monkeypatch) -> None:
    """The first output is written, the second write is stopped: neither file stays."""
    import hhra_phys.compare
    from hhra_phys.cli import design as design_cli
    from hhra_phys.cli import fit as fit_cli

    def second_write(*a, **k):
        raise stop(28, "No space left on device") if stop is OSError else stop

    if cmd == "fit":
        monkeypatch.setattr(fit_cli, "plot_result", second_write)
        argv = ["fit", d["rig"], "--json", tmp_path / "f.json", "--plot", tmp_path / "f.png",
                *QUICK]
    elif cmd == "compare":
        monkeypatch.setattr(hhra_phys.compare, "plot_outputs", second_write)
        argv = ["compare", d["rig"], "--methods", "ls", "--json", tmp_path / "c.json",
                "--report", tmp_path / "c.md", "--plot", tmp_path / "c.png", "--quiet"]
    else:
        import hhra_phys.design

        class Design:  # the search itself is not what is tested
            t, u = np.arange(50) / 250.0, np.zeros(50)
            fs, criterion, value, family, peak_output, evaluations = 250.0, "d", 1.0, "x", 1, 1
            limits = {"duration": 0.2}
            widths = {"g_valve": 0.1}
            split, n_est, widths_whole = 0.5, 25, {"g_valve": 0.08}

            def check(self):
                return []

        monkeypatch.setattr(hhra_phys.design, "design_input", lambda *a, **k: Design())
        real = design_cli.atomic_write_text
        calls = []

        def writes(path, text):
            calls.append(path)
            return real(path, text) if len(calls) == 1 else second_write()

        monkeypatch.setattr(design_cli, "atomic_write_text", writes)
        argv = ["design", d["fit"], "--duration", "2", "--out", tmp_path / "u.csv"]
    code, _, err = run(argv, capsys)
    assert code == (130 if stop is KeyboardInterrupt else 1), err
    assert not list(tmp_path.iterdir())


@pytest.fixture
def quick_demo(monkeypatch):
    """The demo with its fits replaced by quick ones; returns the hook of its last write."""
    import hhra_phys.fit
    from hhra_phys.cli import demo

    real = hhra_phys.fit.fit
    monkeypatch.setattr(hhra_phys.fit, "fit",
                        lambda data, **kw: real(data, optimizer="none", refine="none"))

    class Loop:
        def to_json(self) -> dict:
            return {"chosen": []}

    monkeypatch.setattr(demo, "_close_loop", lambda *a, **k: (Loop(),
                                                               simulate_rig(seed=1,
                                                                            duration=2.0)))
    return lambda fn: monkeypatch.setattr(demo, "plot_loop", fn)


@pytest.mark.parametrize("stop", [KeyboardInterrupt, OSError])
def test_the_demo_stopped_in_its_last_step_leaves_nothing(stop, quick_demo, tmp_path,
                                                          capsys) -> None:
    def last_write(*a, **k):
        raise stop(28, "No space left on device") if stop is OSError else stop

    quick_demo(last_write)
    code, _, err = run(["demo", "--quick", "--out", tmp_path / "new"], capsys)
    assert code == (130 if stop is KeyboardInterrupt else 1)
    assert "[6/6] writing" in err
    assert not (tmp_path / "new").exists()  # its files and the folder it made
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "mine.txt").write_text("keep")
    code, _, err = run(["demo", "--quick", "--out", tmp_path / "old"], capsys)
    assert [p.name for p in (tmp_path / "old").iterdir()] == ["mine.txt"]


# -- silent acceptance ----------------------------------------------------------------------


@pytest.mark.parametrize(("argv", "code", "words"), [
    (["fit", "{rig}", "--time-unit", "ms"], 1,
     ["--time-unit ms", "2.5e+05 Hz", "fastest mode", "leave --time-unit out"]),
    (["fit", "{rig}", "{rig}"], 2, ["twice in DATA"]),
    (["fit", "{rig}", "--validate", "{rig}"], 2, ["as DATA and as --validate"]),
    (["diagnose", "{rig}", "--validate", "{rig}"], 2, ["as DATA and as --validate"]),
    (["compare", "{rig}", "{rig}", "--methods", "ls"], 2, ["twice in DATA"]),
    (["fit", "{rig}", "--refine", ""], 2, ["--refine ''"]),
    (["fit", "{rig}", "--refine", "ipopt+"], 2, ["--refine 'ipopt+'"]),
    (["fit", "{rig}", "--input-col", "u", "--output-col", "u"], 2,
     ["--input-col and --output-col both name column 'u'"]),
    (["compare", "{rig}", "--time-col", "t", "--u", "t"], 2, ["--time-col and --input-col"]),
    (["fit", "{rig}", "--fix", "g_leak=6.4", "--fix", "g_leak=3"], 2,
     ["--fix g_leak is given twice"]),
    (["fit", "{rig}", "--fix", "g_leak=6.4", "g_leak=3"], 2, ["--fix g_leak is given twice"]),
    (["diagnose", "{rig}", "--dask", ""], 2, ["--dask ''"]),
    (["compare", "{rig}", "--plugin", "os", "--methods", "ls"], 2,
     ["--plugin os", "registered no comparison method"]),
    (["diagnose", "{rig}", "--effects-from", "{nothing}"], 2, ["registered no effect"]),
    (["diagnose", "{rig}", "--effects-from", "{shadow}"], 2,
     ["'coulomb_friction'", "already registered"]),
    (["diagnose", "{rig}", "--effects-from", "{raising_effect}", "--pop", "8"], 1,
     ["broken_friction_t24", "raising_effect.py", "RuntimeError: broken on purpose"]),
    (["compare", "{rig}", "--split", "1", "--methods", "ls"], 2, ["--split 1"]),
    (["compare", "{rig}", "--box", "5", "-5", "--methods", "gwo"], 2, ["--box"]),
    (["compare", "{rig}", "--zeta", "-1", "--methods", "hgwo"], 2, ["--zeta"]),
    (["diagnose", "{rig}", "--margin", "-1"], 2, ["--margin"]),
    (["diagnose", "{rig}", "--noise-tol", "nan"], 2, ["--noise-tol"]),
    (["fit", "{rig}", "--lam", "nan"], 2, ["--lam"]),
    (["fit", "{rig}", "--split", "5000"], 2, ["--split 5000", "500 samples"]),
])
def test_silent_acceptance_is_refused(argv, code, words, d, tmp_path, capsys) -> None:
    argv = [a.format(**d) for a in argv]
    if argv[0] == "fit":
        argv += ["--pop", "8", "--iters", "2", "--quiet"]
        argv += [] if "--refine" in argv else ["--refine", "none"]
    got, _, err = run(argv, capsys)
    assert got == code, err
    for w in words:
        assert w in err, (w, err)


def test_a_refused_shadowing_effect_leaves_the_library_as_it_was(d, capsys) -> None:
    from hhra_phys.effects import EFFECTS

    before = EFFECTS["coulomb_friction"]
    run(["diagnose", d["rig"], "--effects-from", d["shadow"]], capsys)
    assert EFFECTS["coulomb_friction"] is before


def test_a_split_index_means_the_same_in_every_command(d, capsys, monkeypatch) -> None:
    """fit, compare and diagnose read --split alike: 0.4 a fraction, 200 a sample index."""
    for cmd in ("fit", "compare", "diagnose"):
        action = next(a for a in subparsers()[cmd]._actions if a.dest == "split")
        assert action.type is split_value, cmd
    assert split_value("0.4") == 0.4 and split_value("200") == 200 and split_value("1") == 1.0
    for bad in ("0", "-3", "1.5", "nan", "half"):
        with pytest.raises(argparse.ArgumentTypeError):
            split_value(bad)
    js = d["dir"] / "split.json"
    code, _, err = run(["fit", d["rig"], "--split", "200", "--json", js, "--overwrite",
                        *QUICK], capsys)
    assert code == 0, err
    res = json.loads(js.read_text())
    assert res["settings"]["split"] == pytest.approx(0.4)  # 200 of 500 samples
    code, out, _ = run(["compare", d["rig"], "--split", "200", "--methods", "ls", "--json", "-",
                        "--quiet"], capsys)
    assert code == 0 and json.loads(out)["split"] == 200


def test_fit_validate_with_another_signal_is_refused(tmp_path, capsys) -> None:
    sys.path.insert(0, str(USER_MODELS))
    try:
        import two_tank

        rec = two_tank.simulate_record(seed=1, q_side=0.0).slice(0, 200)
    finally:
        sys.path.remove(str(USER_MODELS))
    save(rec, tmp_path / "level.csv")
    volts = rec._replace(output_unit="V", output_name="voltage")
    save(volts, tmp_path / "volts.csv")
    code, _, err = run(["fit", tmp_path / "level.csv", "--validate", tmp_path / "volts.csv",
                        "--model", f"{USER_MODELS / 'two_tank.py'}:make_model", *QUICK],
                       capsys)
    assert code == 1 and "volts.csv" in err and "'V'" in err


def test_a_mat_file_without_time_is_noted(d, capsys) -> None:
    code, _, err = run(["fit", d["notime"], "--input-col", "u", "--output-col", "y",
                        "--refine", "none", "--pop", "8", "--iters", "1", "--quiet"], capsys)
    assert "no time variable" in err and "--fs" in err and "--time-col" in err


EMPTY_OUTPUTS = [(cmd, a.option_strings[0]) for cmd, p in subparsers().items()
                 for a in p._actions if a.type is output_path]


def test_every_output_flag_refuses_an_empty_name() -> None:
    flags = {f for _, f in EMPTY_OUTPUTS}
    assert {"--json", "--plot", "--report", "--out", "--markdown"} <= flags
    assert len(EMPTY_OUTPUTS) >= 11


@pytest.mark.parametrize(("cmd", "flag"), EMPTY_OUTPUTS)
def test_an_empty_output_name_is_a_usage_error(cmd, flag, d, tmp_path, capsys) -> None:
    argv = [cmd, *required_args(cmd, tmp_path, d)]
    if flag in argv:
        argv[argv.index(flag) + 1] = ""
    else:
        argv += [flag, ""]
    code, _, err = run(argv, capsys)
    assert code == 2 and flag in err and "empty" in err


@pytest.mark.parametrize(("argv", "flag"), [
    (["diagnose", "{rig}", "--report", "-"], "--report"),
    (["compare", "{rig}", "--methods", "ls", "--report", "-"], "--report"),
    (["benchmark", "--runs", "1", "--markdown", "-"], "--markdown"),
    (["design", "{fit}", "--duration", "2", "--out", "-"], "--out"),
    (["fit", "{rig}", "--plot", "-"], "--plot"),
])
def test_only_json_goes_to_stdout(argv, flag, d, tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    code, _, err = run([a.format(**d) for a in argv], capsys)
    assert code == 2 and flag in err
    assert not list(tmp_path.iterdir())  # no file named '-'


@pytest.mark.parametrize("cmd", ["fit", "diagnose", "compare", "benchmark"])
def test_json_dash_goes_to_stdout(cmd, d, tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    argv = {"fit": ["fit", d["rig"], *QUICK],
            "diagnose": ["diagnose", d["rig"], "--pop", "8", "--iters", "2", "--max-effects",
                         "0", "--no-discover"],
            "compare": ["compare", d["rig"], "--methods", "ls", "--quiet"],
            "benchmark": ["benchmark", "--runs", "1", "--pop", "8", "--iters", "2",
                          "--functions", "f1", "--methods", "gwo", "--tables", "results",
                          "--no-scipy", "--quiet"]}[cmd]
    code, out, _ = run([*argv, "--json", "-"], capsys)
    assert code == 0
    json.loads(out)  # stdout holds the JSON alone
    assert not list(tmp_path.iterdir())  # no file named '-'


# -- weak messages --------------------------------------------------------------------------


@pytest.mark.parametrize(("cmd", "flag"), [("fit", "--json"), ("fit", "--plot"),
                                           ("diagnose", "--json"), ("compare", "--report"),
                                           ("simulate", "--out"), ("design", "--out"),
                                           ("benchmark", "--markdown")])
def test_an_unwritable_folder_is_found_before_the_work(cmd, flag, d, tmp_path, capsys,
                                                       monkeypatch) -> None:
    import tempfile

    from hhra_phys import outputs

    real = tempfile.mkstemp

    def read_only(*a, **k):  # what /proc or a read-only mount answers, even to root
        if k.get("dir") and Path(k["dir"]).name == "ro":
            raise OSError(30, "Read-only file system")
        return real(*a, **k)

    monkeypatch.setattr(outputs.tempfile, "mkstemp", read_only)
    ro = tmp_path / "ro"
    ro.mkdir()
    name = {"--plot": "x.png", "--report": "x.md", "--markdown": "x.md",
            "--out": "x.csv"}.get(flag, "x.json")
    argv = [cmd, *required_args(cmd, tmp_path, d)]
    if flag in argv:
        argv[argv.index(flag) + 1] = str(ro / name)
    else:
        argv += [flag, str(ro / name)]
    code, _, err = run(argv, capsys)
    assert code == 2 and str(ro / name) in err and "Read-only file system" in err
    assert ".tmp" not in err and ".check" not in err  # the user's path, not a temporary


def test_a_failed_write_names_the_users_path(d, tmp_path, capsys, monkeypatch) -> None:
    def disk_full(src, dst):
        raise OSError(28, "No space left on device", str(src))

    monkeypatch.setattr(os, "replace", disk_full)
    js = tmp_path / "fit.json"
    code, _, err = run(["fit", d["rig"], "--json", js, *QUICK], capsys)
    assert code == 1 and str(js) in err and ".tmp" not in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(("name", "words"), [
    ("huge", ["huge.csv", "span of", "plausible 36000 deg", "scaled"]),
    ("cell", ["cell.csv", "row 100", "line 102", "1e+300"]),
])
def test_absurd_values_are_named_before_the_fit(name, words, d, capsys) -> None:
    code, _, err = run(["fit", d[name], *QUICK], capsys)
    assert code == 1 and all(w in err for w in words), err
    assert "bounds" not in err and "fitting" not in err


def test_a_constant_output_is_refused_before_the_fit(d, capsys, monkeypatch) -> None:
    from hhra_phys.cli import fit as fit_cli

    def no_fit(*a, **k):
        raise AssertionError("the fit started")

    monkeypatch.setattr(fit_cli, "fit_many", no_fit)
    for cmd in ("fit", "compare"):
        code, _, err = run([cmd, d["const"], "--quiet"], capsys)
        assert code == 1 and "const.csv" in err and "constant" in err and "--output-col" in err


def test_design_of_a_user_model_fit_needs_and_takes_model(tmp_path, capsys,
                                                         monkeypatch) -> None:
    sys.path.insert(0, str(USER_MODELS))
    try:
        import two_tank

        rec = two_tank.simulate_record(seed=1, q_side=0.0).slice(0, 200)
    finally:
        sys.path.remove(str(USER_MODELS))
    save(rec, tmp_path / "tank.csv")
    spec = f"{USER_MODELS / 'two_tank.py'}:make_model"
    js = tmp_path / "tank_fit.json"
    assert main(["fit", str(tmp_path / "tank.csv"), "--model", spec, "--json", str(js),
                 *QUICK]) == 0
    capsys.readouterr()
    import hhra_phys.parts

    # As in a new process: the user's parts are not registered, their file not imported.
    for name in [k for k in hhra_phys.parts.PART_TYPES
                 if k.rpartition(".")[2] in ("Pump", "UpperTank", "LowerTank", "LevelSensor")]:
        monkeypatch.delitem(hhra_phys.parts.PART_TYPES, name)
    for mod in [m for m in sys.modules if m.startswith("hhra_user_") and "two_tank" in m]:
        monkeypatch.delitem(sys.modules, mod)
    code, _, err = run(["design", js, "--duration", "200", "--out", tmp_path / "u.csv",
                        "--draws", "0"], capsys)
    assert code == 1 and "needs the same --model here" in err
    code, _, err = run(["design", js, "--duration", "200", "--out", tmp_path / "u.csv",
                        "--draws", "0", "--model", spec], capsys)
    assert code == 0, err
    assert (tmp_path / "u.csv").exists() and (tmp_path / "u.json").exists()


@pytest.mark.parametrize(("body", "words"), [
    ("import sys\nsys.exit(3)\n", "sys.exit(3)"),
    ("raise RuntimeError('plugin broken')\n", "RuntimeError: plugin broken"),
])
def test_a_plugin_that_exits_or_raises_is_named(body, words, d, tmp_path, capsys,
                                                monkeypatch) -> None:
    name = f"plugin_t24_{abs(hash(body)) % 10**6}"
    (tmp_path / f"{name}.py").write_text(body)
    monkeypatch.syspath_prepend(str(tmp_path))
    code, _, err = run(["compare", d["rig"], "--plugin", name, "--methods", "ls"], capsys)
    assert code == 2 and f"--plugin {name}" in err and words in err


def test_compare_where_every_method_failed_exits_1(d, tmp_path, capsys, monkeypatch) -> None:
    plugin = tmp_path / "failing_rows_t24.py"
    plugin.write_text(textwrap.dedent("""
        from hhra_phys.compare import register_method
        from hhra_phys.errors import HHRAError

        def always_fails(est, val, settings):
            raise HHRAError("no stable candidate (on purpose)")

        register_method("fails_t24", always_fails)
        """))
    monkeypatch.syspath_prepend(str(tmp_path))
    # the method registry is global: the test's own method leaves with the test
    import hhra_phys.compare.registry as registry

    saved = [(t, dict(t)) for t in (registry.METHODS, registry.METHOD_LABELS)]
    try:
        code, out, err = run(["compare", d["rig"], "--plugin", "failing_rows_t24",
                              "--methods", "fails_t24", "--quiet"], capsys)
        assert code == 1 and "every method failed" in err and "fails_t24" in err
        code, _, err = run(["compare", d["rig"], "--plugin", "failing_rows_t24",
                            "--methods", "fails_t24,ls", "--quiet"], capsys)
        assert code == 0  # one method scored: the table is the answer
    finally:
        for table, content in saved:
            table.clear()
            table.update(content)


@pytest.mark.parametrize(("name", "argv", "words", "absent"), [
    ("comma", [], ["decimal comma", "'0,"], []),
    ("blanks", [], ["Zeit [s]", "--time-col"], ["whitespace"]),
    ("renamed", [], ["single NumPy array", "np.savez"], ["context manager"]),
    ("objects", [], ["Python objects", "run code"], ["allow_pickle"]),
    ("zerod", [], ["single number", "one value per sample"], ["shape ;"]),
    ("corrupt", [], ["not a readable .npz archive", "np.savez"], ["allow_pickle"]),
])
def test_file_format_messages(name, argv, words, absent, d, capsys) -> None:
    code, _, err = run(["fit", d[name], *argv, *QUICK], capsys)
    assert code == 1 and d[name].name in err
    for w in words:
        assert w in err, (w, err)
    for w in absent:
        assert w not in err, (w, err)


# -- for a newcomer -------------------------------------------------------------------------


def test_readme_says_how_long_the_demo_takes_and_where_it_writes() -> None:
    text = (REPO / "README.md").read_text()
    quick = text[text.index("## Quick start"):text.index("## Commands")]
    assert re.search(r"The demo takes [^.]*minute[^.]*\(measured \d+ s", quick)
    assert "hhra-demo-" in quick and "--out" in quick
    table = text[text.index("## Commands"):]
    assert "`hhra-phys design " in table


def test_the_guide_shows_design() -> None:
    text = (REPO / "docs" / "guide.md").read_text()
    assert "hhra-phys design " in text


def test_max_effects_help_says_what_zero_still_adds() -> None:
    """0 adds nothing at all: every addition, discovered terms too, counts (the one loop)."""
    action = next(a for a in subparsers()["diagnose"]._actions if a.dest == "max_effects")
    assert "0 adds nothing" in action.help and "discovered" in action.help


def test_the_noise_level_stop_does_not_contradict_itself() -> None:
    from hhra_phys.diagnosis.stopping import _why_at_noise

    coloured = {"ljung_box_p": 5.6e-6, "white": False, "ratio": 1.1}
    white = {"ljung_box_p": 0.4, "white": True, "ratio": 1.6}
    assert "not white" in _why_at_noise(coloured, 0.2)
    assert "within the allowance" in _why_at_noise(coloured, 0.2)
    assert _why_at_noise(white, 0.2).startswith("white")


def test_the_public_record_from_an_installed_copy(tmp_path, monkeypatch) -> None:
    from hhra_phys.data import public
    from hhra_phys.errors import DataError

    fake = tmp_path / "venv" / "lib" / "site-packages" / "hhra_phys" / "data" / "public.py"
    monkeypatch.setattr(public, "__file__", str(fake))
    monkeypatch.delenv("HHRA_SHARED_DATA", raising=False)
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    with pytest.raises(DataError, match="HHRA_SHARED_DATA"):
        public.find_public_data()
    data = tmp_path / "shared" / "data"
    data.mkdir(parents=True)
    (data / public.PUBLIC_ACTUATOR_FILE).write_bytes(b"")
    assert public.find_public_data() == (data / public.PUBLIC_ACTUATOR_FILE).resolve()
