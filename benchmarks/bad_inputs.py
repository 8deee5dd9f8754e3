"""Feed classes of bad input through the CLI and count how each is answered.

Usage::

    PYTHONPATH=$PWD python benchmarks/bad_inputs.py [--json OUT.json]

Every case is a command line with something wrong in it (the record, its units, an option,
an output path, a combination of options). Each is run in this process through
``hhra_phys.cli.main`` and classified:

clear
    the expected exit code (2 usage, 1 data or runtime error; 0 with a warning for
    records that are plausible-looking but likely in the wrong unit), no traceback, and
    the message names the file, column or flag at fault;
vague
    an error, but the wrong exit code or a message that does not name what is wrong;
silent
    exit 0 and no word about the problem;
traceback
    an exception escaped.

Four more outcomes are counted on every case, whatever its message (issue 24):

replaced
    a file that was there before the case (a record, a fit, a model file) changed;
partial
    the case failed and left a file behind (an output of a run that did not finish);
hang
    the case ran longer than :data:`HANG_S` seconds (stopped there);
allocation
    the case's Python-tracked memory peaked above :data:`MAX_ALLOCATION` bytes.

Fits that get past the checks run with ``--pop 4 --iters 1 --refine none`` on a 4 s
record, so the whole run takes a few minutes. The table goes to stdout; ``docs/data.md``
and ``docs/testing.md`` quote it.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hhra_phys.cli import main
from hhra_phys.data import save
from hhra_phys.models.hhra.model import HHRAModel
from hhra_phys.models.hhra.rig import simulate_rig

QUICK = ["--pop", "4", "--iters", "1", "--refine", "none", "--quiet"]

#: A case running longer than this [s] is a hang (every case should fail or end in seconds).
HANG_S = 120

#: A case allocating more than this [bytes] (tracemalloc's peak) is an unguarded allocation.
MAX_ALLOCATION = 512 * 2**20

#: The outcomes counted on every case besides its class.
OUTCOMES = ("replaced", "partial", "hang", "allocation")


@dataclass
class Case:
    """One bad command line: the class it belongs to, what must happen, what must be named."""

    group: str
    argv: list[str]
    code: int
    token: str
    warn: bool = False  # exit 0 is right, but only with a warning containing ``token``
    #: A Python call instead of a command line (issue 35): it must raise an ``HHRAError``
    #: (or a TypeError/ValueError) whose message contains ``token``.
    call: Callable[[], object] | None = None
    #: A context manager around the run (a signal sent from inside a writer, issue 35).
    patch: Callable[[], contextlib.AbstractContextManager[object]] | None = None
    #: Exit 0 is right only if stdout holds nothing but JSON (``--json -``, issue 35).
    json_stdout: bool = False


def _rows(t: np.ndarray, u: np.ndarray, y: np.ndarray, sep: str = ",") -> str:
    return "\n".join(sep.join(repr(v) for v in r) for r in zip(t.tolist(), u.tolist(),
                                                                  y.tolist(), strict=True))


def cases(d: Path) -> Iterator[Case]:
    """Every bad input, class by class, written into folder ``d``."""
    ds = simulate_rig(seed=0, duration=4.0)
    rig = d / "rig.csv"
    save(ds, rig)
    t, u, y = ds.t, ds.u, ds.y

    def file(name: str, text: str | bytes) -> str:
        p = d / name
        p.write_bytes(text if isinstance(text, bytes) else text.encode())
        return str(p)

    body = _rows(t, u, y)
    # -- file contents ---------------------------------------------------------------------
    g = "file content"
    yield Case(g, ["fit", file("junk.csv", b"\x00\x01PK\x03" * 200)], 1, "junk.csv")
    yield Case(g, ["fit", file("empty.csv", "")], 1, "empty.csv")
    yield Case(g, ["fit", file("header.csv", "t,u,y\n")], 1, "header.csv")
    yield Case(g, ["fit", str(d / "missing.csv")], 1, "missing.csv")
    yield Case(g, ["fit", file("notcsv.xlsx", "x")], 1, "notcsv.xlsx")
    yield Case(g, ["fit", str(d)], 1, str(d))
    for k, enc in enumerate(("utf-16", "utf-8-sig", "latin-1")):  # readable: no error wanted
        p = d / f"enc{k}.csv"
        p.write_bytes(f"t,u,Winkel [°]\n{body}\n".encode(enc))
        yield Case(g, ["fit", str(p), "--output-col", "Winkel", *QUICK], 0, "")
    # -- columns and values -----------------------------------------------------------------
    g = "columns and values"
    for col in ("time", "current", "angle", "T", ""):
        yield Case(g, ["fit", str(rig), "--input-col", col, *QUICK], 1 if col else 1,
                   f"'{col}'" if col else "column")
    for i, bad in enumerate(("nan", "abc", "", "1,5", "inf")):
        rows = body.split("\n")
        rows[50] = f"{t[50]!r},{bad},{y[50]!r}"
        yield Case(g, ["fit", file(f"cell{i}.csv", "t,u,y\n" + "\n".join(rows)), *QUICK], 1,
                   "line 52")
    tt = t.copy()
    tt[100] = tt[99]
    yield Case(g, ["fit", file("mono.csv", "t,u,y\n" + _rows(tt, u, y)), *QUICK], 1, "row")
    tt = t.copy()
    tt[100:] += 0.5
    yield Case(g, ["fit", file("gap.csv", "t,u,y\n" + _rows(tt, u, y)), *QUICK], 1, "row")
    yield Case(g, ["fit", file("short.csv", "t,u,y\n" + _rows(t[:5], u[:5], y[:5])), *QUICK],
               1, "short.csv")
    yield Case(g, ["fit", file("flat.csv", "t,u,y\n" + _rows(t, 0 * u, y)), *QUICK], 1,
               "flat.csv")
    yield Case(g, ["fit", file("dup.csv", "t,u,u\n" + body), *QUICK], 1, "u")
    # -- delimiters -------------------------------------------------------------------------
    g = "delimiters"
    for sep, name in ((";", "semi"), ("\t", "tab"), ("|", "pipe")):
        p = file(f"{name}.csv", f"t{sep}u{sep}y\n" + _rows(t, u, y, sep))
        yield Case(g, ["fit", p, "--delimiter", ",", *QUICK], 1, "--delimiter")
    for bad in ("ab", "", "\\n"):
        yield Case(g, ["fit", str(rig), "--delimiter", bad], 2, "--delimiter")
    # -- units and scales -------------------------------------------------------------------
    g = "units and scales"
    yield Case(g, ["fit", file("ms.csv", "t,u,y\n" + _rows(t * 1000, u, y)), *QUICK], 1,
               "--time-unit ms")
    yield Case(g, ["fit", file("us.csv", "t,u,y\n" + _rows(t * 1e6, u, y)), *QUICK], 1,
               "--time-unit ms")
    yield Case(g, ["fit", file("rad.csv", "t,u,y\n" + _rows(t, u, np.deg2rad(y))), *QUICK], 0,
               "radians", warn=True)
    yield Case(g, ["fit", file("e5.csv", "t,u,y\n" + _rows(t, u, y * 1e5)), *QUICK], 0,
               "scaled", warn=True)
    yield Case(g, ["fit", file("amp.csv", "t,u,y\n" + _rows(t, u / 1000, y)), *QUICK], 0,
               "in A rather than mA", warn=True)
    # (a warning before the fit; the fit then diverges, exit 1)
    yield Case(g, ["fit", file("kilo.csv", "t,u,y\n" + _rows(t, u * 1000, y)), *QUICK], 1,
               "scaled")
    yield Case(g, ["compare", d / "ms.csv", "--methods", "ls", "--quiet"], 0, "--time-unit ms",
               warn=True)
    yield Case(g, ["fit", file("volt.csv", "t,u,y [V]\n" + body), *QUICK], 1, "'V'")
    yield Case(g, ["fit", file("lbl.csv", "t,u [A],y [rad]\n" + _rows(t, u / 1000,
                                                                     np.deg2rad(y))), *QUICK],
               0, "converted", warn=True)
    # -- --fix values -----------------------------------------------------------------------
    g = "--fix values"
    for par in HHRAModel().params:
        if par.scale == "log":
            for v in (-1.0, 0.0):
                yield Case(g, ["fit", str(rig), "--fix", f"{par.name}={v}"], 2,
                           f"--fix {par.name}")
        for v in (par.upper * 1e3 if par.upper > 0 else 1e9, par.lower - abs(par.upper) * 10):
            if par.scale == "log" and v <= 0:
                continue
            yield Case(g, ["fit", str(rig), "--fix", f"{par.name}={v}"], 2, "--allow-outside-box")
    for item in ("g_leak", "g_leak=", "g_leak=abc", "g_bogus=1", "=1", "g_leak=nan",
                 "g_leak=inf"):
        yield Case(g, ["fit", str(rig), "--fix", item], 2, "g_" if "g_" in item else "--fix")
    # -- numeric options ---------------------------------------------------------------------
    g = "numeric options"
    for opt, values in (("--pop", ("0", "-1", "2", "abc", "1.5")),
                        ("--iters", ("0", "-5", "x")),
                        ("--split", ("0", "1.5", "-0.1", "nan", "half")),
                        ("--fs", ("0", "-250", "nan", "inf", "fast"))):
        for v in values:
            yield Case(g, ["fit", str(rig), f"{opt}={v}"], 2, opt)
    yield Case(g, ["fit", str(rig), "--starts", "0"], 2, "--starts")
    for opt, values in (("--top", ("0", "-1", "one")), ("--max-effects", ("-1", "x")),
                        ("--split", ("1",)), ("--folds", ("1", "11", "three"))):
        for v in values:
            yield Case(g, ["diagnose", str(rig), f"{opt}={v}"], 2, opt)
    for opt, values in (("--pop", ("0", "3")), ("--iters", ("0",)), ("--split", ("0", "-3")),
                        ("--box", ("1",))):
        for v in values:
            yield Case(g, ["compare", str(rig), f"{opt}={v}"], 2, opt)
    # -- output paths -------------------------------------------------------------------------
    g = "output paths"
    exists = file("exists.json", "{}")
    (d / "adir").mkdir()
    for cmd in (["fit", str(rig), *QUICK], ["diagnose", str(rig)],
                ["compare", str(rig), "--methods", "ls"]):
        yield Case(g, [*cmd, "--json", exists], 2, "--overwrite")
        yield Case(g, [*cmd, "--json", str(d / "no" / "x.json")], 2, "does not exist")
        yield Case(g, [*cmd, "--json", str(d / "adir")], 2, "directory")
    for cmd in (["fit", str(rig), *QUICK], ["compare", str(rig), "--methods", "ls"]):
        for suffix in (".xyz", "", ".json"):
            yield Case(g, [*cmd, "--plot", str(d / f"fig{suffix}")], 2, "suffix")
    yield Case(g, ["simulate", "--out", str(rig)], 2, "--overwrite")
    yield Case(g, ["simulate", "--out", str(d / "x.txt")], 1, "x.txt")
    yield Case(g, ["demo", "--out", str(exists)], 1, "exists.json")
    # -- combinations of options --------------------------------------------------------------
    g = "option combinations"
    yield Case(g, ["fit", str(rig), "--rig-seed", "2"], 2, "--rig-seed")
    yield Case(g, ["diagnose", "public", "--rig-seed", "2"], 2, "--rig-seed")
    for opt, v in (("--time-col", "t"), ("--input-col", "u"), ("--fs", "100"),
                   ("--time-unit", "ms"), ("--delimiter", ";")):
        yield Case(g, ["fit", opt, v], 2, opt)
        yield Case(g, ["compare", "rig", opt, v], 2, opt)
    yield Case(g, ["fit", str(rig), "--fs", "250", "--time-unit", "ms"], 2, "--time-unit")
    yield Case(g, ["compare", str(rig), "--public"], 2, "--public")
    yield Case(g, ["fit", str(rig), "--model", "nofile.py:make"], 1, "nofile.py")
    yield Case(g, ["fit", str(rig), "--validate", str(d / "nothere.csv"), *QUICK], 1,
               "nothere.csv")
    yield Case(g, ["fit", str(rig), str(d / "nothere.csv"), *QUICK], 1, "nothere.csv")
    yield Case(g, ["diagnose", str(rig), "--test", "0.6"], 2, "test")
    yield Case(g, ["design", str(d / "nofit.json"), "--duration", "2", "--out",
                   str(d / "u.csv")], 1, "nofit.json")
    yield Case(g, ["fit", str(rig), "--model", "x.py:make", "--valve", "linear"], 2, "--valve")
    yield from round_two(d, rig, file)
    yield from round_three(d, rig, file)


def round_two(d: Path, rig: Path, file: Callable[[str, str | bytes], str]) -> Iterator[Case]:
    """The cases of issue 24 and their neighbours, class by class."""
    from hhra_phys.cli import build_parser
    from hhra_phys.fit import fit

    ds = simulate_rig(seed=0, duration=4.0)
    fitjs = str(fit(ds, optimizer="none", refine="none").save(d / "fit2.json"))
    file("exit_plugin2.py", "import sys\nsys.exit(3)\n")
    if str(d) not in sys.path:
        sys.path.insert(0, str(d))  # --plugin takes a module name
    sub = build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    need = {"simulate": ["--out", str(d / "s2.csv")],
            "design": [fitjs, "--duration", "2", "--out", str(d / "u2.csv")],
            "demo": ["--out", str(d / "demo2")], "fit": [str(rig)], "diagnose": [str(rig)],
            "compare": [str(rig), "--methods", "ls"],
            "benchmark": ["--runs", "1", "--functions", "f1", "--methods", "gwo"]}
    # -- tracebacks: every seed flag of every command, user code, --dask, binary files -----
    g = "issue 24: no traceback"
    for cmd, p in sub.items():
        for a in p._actions:
            if a.dest in ("seed", "rig_seed"):
                flag = a.option_strings[0]
                argv = [cmd, flag, "-1"] if flag == "--rig-seed" else [cmd, *need[cmd], flag,
                                                                       "-1"]
                yield Case(g, argv, 2, flag)
    body = _rows(ds.t, ds.u * 1e300, ds.y)
    yield Case(g, ["fit", file("u300.csv", "t,u,y\n" + body), *QUICK], 1, "'u'")
    bad = file("badpart2.py", (
        "from dataclasses import dataclass\n"
        "from hhra_phys import Model, Parameter, Part, State, register_part\n"
        "@register_part\n@dataclass(frozen=True)\nclass Leak2(Part):\n"
        "    name = 'leak2'\n    stage = 'tank'\n"
        "    @property\n    def parameters(self):\n"
        "        return (Parameter('k', '1/s', 1.0, 0.1, 10.0, 'log', 'rate'),)\n"
        "    @property\n    def states(self):\n        return (State('h', 'cm', 0.0, 'level'),)\n"
        "    def apply(self, ctx):\n        ctx.add_rate('h', ctx.p['nope'] * ctx.u)\n"
        "        ctx.signals['y'] = ctx.x['h']\n"
        "def make():\n    return Model([Leak2()])\n"))
    for cmd in ("fit", "diagnose"):
        yield Case(g, [cmd, str(rig), "--model", f"{bad}:make", *QUICK[:4]], 1, "'leak2'")
    yield Case(g, ["fit", str(rig), "--model", file("exit3.py", "import sys\nsys.exit(3)\n")
                   + ":make", *QUICK], 1, "sys.exit(3)")
    for address in ("not-an-address", "tcp://host:port", "127.0.0.1:99999"):
        yield Case(g, ["fit", str(rig), "--dask", address, *QUICK], 2, "--dask")
    yield Case(g, ["fit", str(rig), "--dask", f"127.0.0.1:{_server(b'HTTP/1.1 400 Bad')}",
                   *QUICK], 2, "not a Dask scheduler")
    yield Case(g, ["simulate", "--out", str(d / "e.csv"), "--generator", "reference",
                   "--effect", "coulomb_friction:nope=1"], 2, "nope")
    for gen in ("model", "reference"):
        yield Case(g, ["simulate", "--out", str(d / "n.csv"), "--generator", gen, "--noise",
                       "-1"], 2, "--noise")
    binary = file("binary2.json", bytes(range(128, 256)) * 20)
    yield Case(g, ["design", binary, "--duration", "2", "--out", str(d / "b.csv")], 1,
               "binary2.json")
    # -- sizes ---------------------------------------------------------------------------
    g = "issue 24: size guards"
    for argv in (["simulate", "--out", str(d / "big.csv"), "--duration", "1e7"],
                 ["simulate", "--out", str(d / "big.csv"), "--duration", "1e5", "--fs", "1e6"],
                 ["compare", "--duration", "1e7", "--quiet"],
                 ["design", fitjs, "--duration", "1e6", "--out", str(d / "big.csv")]):
        yield Case(g, argv, 2, "--duration")
    yield Case(g, ["simulate", "--out", str(d / "big.csv"), "--generator", "reference",
                   "--effect", "input_delay:delay=1e6"], 2, "outside its box")
    yield Case(g, ["simulate", "--out", str(d / "big.csv"), "--fs", "1e7"], 2, "--fs")
    # -- a user's file replaced ------------------------------------------------------------
    g = "issue 24: replacement"
    yield Case(g, ["fit", str(rig), "--json", str(rig), "--overwrite", *QUICK], 2, "--json")
    yield Case(g, ["fit", str(rig), "--model", f"{bad}:make", "--json", bad, "--overwrite",
                   *QUICK], 2, "is the input")
    yield Case(g, ["design", fitjs, "--duration", "2", "--out", str(d / "fit2.csv"),
                   "--overwrite"], 2, "is the input")
    for cmd, extra in (("diagnose", []), ("compare", ["--methods", "ls"])):
        yield Case(g, [cmd, str(rig), *extra, "--json", str(d / "r.md"), "--report",
                       str(d / "r.md")], 2, "same file")
        yield Case(g, [cmd, str(rig), *extra, "--report", str(d / "x.png")], 2, "Markdown")
    yield Case(g, ["benchmark", "--runs", "1", "--json", str(d / "b.md"), "--markdown",
                   str(d / "b.md")], 2, "same file")
    # -- partial outputs -----------------------------------------------------------------
    g = "issue 24: partial outputs"
    yield Case(g, ["fit", str(rig), "--json", str(d / "o.png"), "--plot", str(d / "o.png"),
                   *QUICK], 2, "--json")
    yield Case(g, ["fit", str(rig), "--json", str(d / "o.json"), "--plot", str(d / "o.xyz"),
                   *QUICK], 2, "suffix")
    yield Case(g, ["compare", str(rig), "--methods", "ls", "--report", str(d / "o.md"),
                   "--json", str(d / "o2.png"), "--quiet"], 2, "--json")
    # -- silent acceptance ---------------------------------------------------------------
    g = "issue 24: silent acceptance"
    for argv, token in (
            (["fit", str(rig), "--time-unit", "ms", *QUICK], "--time-unit ms"),
            (["fit", str(rig), str(rig), *QUICK], "twice"),
            (["fit", str(rig), "--validate", str(rig), *QUICK], "--validate"),
            (["fit", str(rig), "--refine", "", "--quiet"], "--refine"),
            (["fit", str(rig), "--input-col", "u", "--output-col", "u", *QUICK], "--output-col"),
            (["fit", str(rig), "--fix", "g_leak=6.4", "--fix", "g_leak=3", *QUICK], "twice"),
            (["fit", str(rig), "--dask", "", *QUICK], "--dask"),
            (["compare", str(rig), "--plugin", "os", "--methods", "ls"], "--plugin os"),
            (["diagnose", str(rig), "--effects-from", file("nothing2.py", "X = 1\n"),
              "--pop", "4", "--iters", "1", "--max-effects", "0", "--no-discover"],
             "registered no effect"),
            (["simulate", "--out", str(d / "a.csv"), "--amplitude", "1e300"], "--amplitude"),
            (["fit", str(rig), "--json", "", *QUICK], "--json"),
            (["compare", str(rig), "--split", "1", "--methods", "ls"], "--split")):
        yield Case(g, argv, 1 if "--time-unit" in argv else 2, token)
    # -- weak messages -------------------------------------------------------------------
    g = "issue 24: messages"
    yield Case(g, ["fit", file("huge2.csv", "t,u,y\n" + _rows(ds.t, ds.u, ds.y * 1e30)),
                   *QUICK], 1, "span")
    cell = ds.y.copy()
    cell[7] = 1e300
    yield Case(g, ["fit", file("cell2.csv", "t,u,y\n" + _rows(ds.t, ds.u, cell)), *QUICK], 1,
               "row 7")
    yield Case(g, ["fit", file("const2.csv", "t,u,y\n" + _rows(ds.t, ds.u, 0 * ds.y)),
                   *QUICK], 1, "constant")
    yield Case(g, ["simulate", "--out", str(d / "short2.csv"), "--duration", "0.1"], 2,
               "--duration")
    semi = "\n".join(";".join(f"{v:.5f}".replace(".", ",") for v in r)
                      for r in zip(ds.t, ds.u, ds.y, strict=True))
    yield Case(g, ["fit", file("semi2.csv", ("t;u;y\n" + semi).encode("latin-1")), *QUICK],
               1, "decimal comma")
    np.save(d / "one.npy", np.c_[ds.t, ds.u, ds.y])
    (d / "one.npy").rename(d / "renamed2.npz")
    yield Case(g, ["fit", str(d / "renamed2.npz"), *QUICK], 1, ".npy")
    # options the library checked under its Python names (lam, margin, zeta_s, bounds)
    for argv, flag in ((["compare", str(rig), "--box", "5", "-5", "--methods", "gwo"], "--box"),
                       (["compare", str(rig), "--zeta", "-1", "--methods", "hgwo"], "--zeta"),
                       (["diagnose", str(rig), "--margin", "-1", *QUICK[:4]], "--margin"),
                       (["diagnose", str(rig), "--noise-tol", "nan", *QUICK[:4]],
                        "--noise-tol"),
                       (["fit", str(rig), "--lam", "nan", *QUICK], "--lam"),
                       (["diagnose", str(rig), "--report", "-", "--pop", "4", "--iters", "1",
                         "--max-effects", "0", "--no-discover"], "--report"),
                       (["compare", str(rig), "--methods", "ls", "--plugin", "exit_plugin2"],
                        "sys.exit(3)")):
        yield Case(g, argv, 2, flag)


def round_three(d: Path, rig: Path, file: Callable[[str, str | bytes], str]) -> Iterator[Case]:
    """The cases of issue 35 and their neighbours, class by class."""
    import copy

    from hhra_phys.fit import fit

    ds = simulate_rig(seed=0, duration=4.0)
    fitted = fit(ds, optimizer="none", refine="none")
    base = json.loads(json.dumps(fitted.to_json()))
    fitjs = file("fit3.json", json.dumps(base))
    val = d / "val3.csv"
    save(simulate_rig(seed=1, duration=4.0), val)
    side, val_side = str(rig.with_suffix(".json")), str(val.with_suffix(".json"))
    nothing = file("nothing3.py", "X = 1\n")
    # -- lost: no output is an input of the run, --overwrite or not ------------------------
    g = "issue 35: lost"
    yield Case(g, ["fit", str(rig), *QUICK, "--json", side, "--overwrite"], 2,
               "DATA's side-car")
    yield Case(g, ["fit", str(rig), "--validate", str(val), *QUICK, "--json", val_side,
                   "--overwrite"], 2, "--validate's side-car")
    yield Case(g, ["diagnose", str(rig), "--json", side, "--overwrite"], 2, "DATA's side-car")
    yield Case(g, ["compare", str(rig), "--methods", "ls", "--json", side, "--overwrite"], 2,
               "DATA's side-car")
    yield Case(g, ["diagnose", str(rig), "--effects-from", nothing, "--json", nothing,
                   "--overwrite"], 2, "is the input --effects-from")
    # -- partial: SIGTERM (and SIGINT) while writing leave nothing ----------------------------
    g = "issue 35: signals while writing"
    for sig, code in (("SIGTERM", 143), ("SIGINT", 130)):
        yield Case(g, ["diagnose", str(rig), "--pop", "4", "--iters", "1", "--max-effects", "0",
                       "--no-discover", "--json", str(d / "d3.json"), "--report",
                       str(d / "r3.md")], code, "nothing written",
                   patch=partial_signal(sig, "hhra_phys.loop", "LoopResult", "report"))
        yield Case(g, ["fit", str(rig), *QUICK, "--json", str(d / "f3.json"), "--plot",
                       str(d / "f3.png")], code, "nothing written",
                   patch=partial_signal(sig, "hhra_phys.cli.fit", None, "plot_result"))
        yield Case(g, ["simulate", "--out", str(d / "s3.csv"), "--duration", "2"], code,
                   "nothing written",
                   patch=partial_signal(sig, "hhra_phys.data.formats", None,
                                        "atomic_write_text", after=1))
    # -- hang and allocation: sizes refused before the work ---------------------------------
    g = "issue 35: sizes"
    for argv, token in ((["fit", str(rig), *QUICK[2:], "--iters", "1000000000"], "--iters"),
                        (["fit", str(rig), *QUICK[2:], "--pop", "1000000000"], "--pop"),
                        (["diagnose", str(rig), "--pop", "1000000000"], "--pop"),
                        (["compare", str(rig), "--iters", "1000000000"], "--iters"),
                        (["benchmark", "--pop", "1000000000"], "--pop"),
                        (["benchmark", "--pop", "4", "--runs", "1"], "--no-scipy"),
                        (["fit", str(rig), "--pop", "10000", "--iters", "1000000", "--quiet"],
                         "--pop/--iters"),
                        (["compare", str(rig), "--na", "100000", "--methods", "ls", "--json",
                          str(d / "c3.json")], "--na 100000"),
                        (["compare", str(rig), "--nb", "600", "--nk", "600", "--methods",
                          "ls"], "--nb 600")):
        yield Case(g, argv, 2, token)
    # -- tracebacks of the Python API --------------------------------------------------------
    g = "issue 35: Python API"
    from hhra_phys import HHRAModel, Parameter
    from hhra_phys.result import FitResult

    bad_value = copy.deepcopy(base)
    bad_value["params"]["g_leak"]["value"] = "abc"
    str_value = file("strvalue3.json", json.dumps(bad_value))
    for call, token in (
            (lambda: fit(ds, model="HHRA"), "model must be"),
            (lambda: fit(ds, model=HHRAModel), "model must be"),
            (lambda: Parameter(3, "1", 1.0, 0.1, 10.0), "name must be a str"),  # type: ignore
            (lambda: Parameter("k", "1", "1", 0.1, 10.0), "nominal must be"),  # type: ignore
            (lambda: fit(42), "data must be"),  # type: ignore[arg-type]
            (lambda: fit("rec.csv"), "data must be"),  # type: ignore[arg-type]
            (lambda: fit(ds, fixed={"g_leak": "abc"}), "fixed g_leak"),
            (lambda: fit(ds, start={"g_leak": "abc"}), "start g_leak"),
            (lambda: fit(ds, start={"g_leak": -1.0}), "start g_leak"),
            (lambda: fit(ds, start={"g_nope": 1.0}), "start g_nope"),
            (lambda: fit(ds, start=[1.0]), "start"),  # type: ignore[arg-type]
            (lambda: fit(ds, pop_size=10**9), "pop_size"),
            (lambda: FitResult.load(str_value), "'params.g_leak.value'")):
        yield Case(g, ["python"], 1, token, call=call)
    # -- silent acceptance ----------------------------------------------------------------------
    g = "issue 35: silent acceptance"
    for argv, token in (
            (["fit", str(rig), "--input-col", "y", *QUICK], "--input-col 'y'"),
            (["fit", str(rig), "--output-col", "u", *QUICK], "--output-col 'u'"),
            (["compare", str(rig), "--u", "t", "--methods", "ls"], "--input-col 't'"),
            (["simulate", "--out", str(d / "e3.csv"), "--generator", "reference", "--effect",
              "gravity_load:g_grav_cos=1,g_grav_sin=0", "--effect",
              "gravity_load:g_grav_cos=2,g_grav_sin=0"], "given twice"),
            (["simulate", "--out", str(d / "e3.csv"), "--generator", "reference", "--effect",
              "sensor_offset:y_offset=1", "--effect", "sensor_offset:y_offset=2"],
             "given twice")):
        yield Case(g, argv, 2, token)
    printing = file("printing3.py", "print('hello from the model file')\n"
                    "from hhra_phys.models.hhra.model import HHRAModel\n"
                    "def make_model(data=None):\n    print('building')\n"
                    "    return HHRAModel()\n")
    for cmd, extra in (("fit", QUICK), ("diagnose", ["--pop", "4", "--iters", "1",
                                                     "--max-effects", "0", "--no-discover"])):
        yield Case(g, [cmd, str(rig), "--model", f"{printing}:make_model", *extra, "--json",
                       "-"], 0, "", json_stdout=True)
    other = file("other3.py", "from hhra_phys.models.hhra.model import HHRAModel\n"
                 "def make_model(data=None):\n    return HHRAModel(valve='linear')\n")
    yield Case(g, ["design", fitjs, "--duration", "2", "--out", str(d / "u3.csv"), "--model",
                   f"{other}:make_model"], 2, "would be ignored")

    def edited(name: str, path: str, value: object) -> str:
        out = copy.deepcopy(base)
        *keys, last = path.split(".")
        target = out
        for k in keys:
            target = target[int(k)] if isinstance(target, list) else target[k]
        target[last] = value
        return file(name, json.dumps(out))

    for name, path, value, token in (
            ("neg3.json", "params.g_valve.value", -31.7, "'params.g_valve.value'"),
            ("model3.json", "model.class", "Bogus", "'model.class'"),
            ("fsneg3.json", "records.0.fs", -250, "'records[0].fs'"),
            ("fsstr3.json", "records.0.fs", "fast", "'records[0].fs'"),
            ("v99.json", "version", 99, "'version'")):
        yield Case(g, ["design", edited(name, path, value), "--duration", "2", "--out",
                       str(d / "u3.csv")], 1, token)
    for name, text, token in (("is3", {"intersample": "bogus"}, "'intersample'"),
                              ("fs3", {"fs": -250}, "'fs'"),
                              ("list3", [], "JSON object")):
        csv = d / f"{name}.csv"
        csv.write_bytes(rig.read_bytes())
        car = (text if isinstance(text, list) else
               {**json.loads(rig.with_suffix(".json").read_text()), **text})
        (d / f"{name}.json").write_text(json.dumps(car))
        yield Case(g, ["fit", str(csv), *QUICK], 1, f"{name}.json")
        yield Case(g, ["fit", str(csv), *QUICK], 1, token)
    # -- weak messages ----------------------------------------------------------------------
    g = "issue 35: messages"
    yield Case(g, ["fit", str(rig), "--free", "", *QUICK], 2, "--free ''")
    yield Case(g, ["diagnose", str(rig), "--effects", ""], 2, "--effects ''")
    nan_effect = file("nan_effect3.py", NAN_EFFECT)
    yield Case(g, ["diagnose", str(rig), "--pop", "4", "--iters", "1", "--no-discover",
                   "--effects-from", nan_effect], 1, "'nan_effect_b35'")
    for name, path, value, token in (
            ("cov3.json", "covariance", [[1.0, 2.0], [3.0, 4.0]], "'covariance'"),
            ("free3.json", "free", ["g_valve", "g_bogus"], "'free' names 'g_bogus'"),
            ("fmt3.json", "format", "something else", "'format' is 'something else'"),
            ("inf3.json", "params.g_valve.value", 1e308, "'params.g_valve.value'")):
        yield Case(g, ["design", edited(name, path, value), "--duration", "2", "--out",
                       str(d / "u3.csv")], 1, token)


#: A user's effect whose simulation is NaN (issue 35).
NAN_EFFECT = """
from dataclasses import dataclass
from typing import ClassVar

import casadi as ca

from hhra_phys import Effect, Parameter, register_effect


@register_effect
@dataclass(frozen=True)
class NanEffectB35(Effect):
    stage: ClassVar[str] = "motion"
    name: ClassVar[str] = "nan_effect_b35"
    reads: ClassVar[tuple] = ("omega",)
    writes: ClassVar[tuple] = ("omega",)
    entry: ClassVar[str] = "rate:omega"
    signature: ClassVar[str] = "none"
    regressors: ClassVar[tuple] = ()

    @property
    def parameters(self):
        return (Parameter("g_nanb", "1/s", 1.0, 0.1, 10.0, "log", "a rate"),)

    def apply(self, ctx):
        ctx.add_rate("omega", ctx.p["g_nanb"] * ca.sqrt(-1 - ctx.x["omega"] ** 2))
"""


def partial_signal(sig: str, module: str, cls: str | None, name: str, after: int = 0
                   ) -> Callable[[], contextlib.AbstractContextManager[object]]:
    """A patch that sends ``sig`` to this process from inside ``module.[cls.]name``, on its
    call number ``after`` (0: the first), when the run has written part of its outputs."""
    import importlib
    import os
    import signal

    @contextlib.contextmanager
    def patched() -> Iterator[object]:
        owner = importlib.import_module(module)
        if cls is not None:
            owner = getattr(owner, cls)
        real = getattr(owner, name)
        calls = [0]

        def wrapper(*a: object, **k: object) -> object:
            calls[0] += 1
            if calls[0] == after + 1:
                os.kill(os.getpid(), getattr(signal, sig))
            return real(*a, **k)

        setattr(owner, name, wrapper)
        try:
            yield None
        finally:
            setattr(owner, name, real)

    return patched


def _server(reply: bytes) -> int:
    """A local TCP server that answers ``reply`` to every connection; its port."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)

    def serve() -> None:
        while True:
            conn, _ = srv.accept()
            conn.sendall(reply)

    threading.Thread(target=serve, daemon=True).start()
    return srv.getsockname()[1]


class Hang(BaseException):
    """Raised in a case that ran longer than :data:`HANG_S` (not an ``Exception``: the
    CLI's handlers must not catch it)."""


def _files(folder: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def outcomes(case: Case, folder: Path) -> tuple[str, str, list[str]]:
    """(class, stderr, outcomes) of one case run in ``folder``'s files."""
    import signal
    import tracemalloc

    before = _files(folder)

    def alarm(signum: int, frame: object) -> None:
        raise Hang

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(HANG_S)
    tracemalloc.start()
    found: list[str] = []
    try:
        kind, text, code = classify(case)
    except Hang:
        kind, text, code = "vague", f"ran over {HANG_S} s", None
        found.append("hang")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    if peak > MAX_ALLOCATION:
        found.append("allocation")
    after = _files(folder)
    changed = [p for p, b in before.items() if after.get(p) != b]
    if changed:
        found.append("replaced")
    new = [p for p in after if p not in before]
    if code not in (0, None) and new:
        found.append("partial")
    for p in new:  # the next case starts from the same files
        p.unlink()
    for p in changed:
        p.write_bytes(before[p])
    return kind, text, found


def classify(case: Case) -> tuple[str, str, int | None]:
    """(class, stderr, exit code) of one case."""
    if case.call is not None:
        return classify_call(case)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), (
            case.patch() if case.patch else contextlib.nullcontext()):
        try:
            code = main([str(a) for a in case.argv])
        except SystemExit as exc:
            code = int(exc.code) if isinstance(exc.code, int) else 2
        except Exception:  # noqa: BLE001 - an escaped exception is what is counted here
            return "traceback", traceback.format_exc(limit=3), 1
    text = err.getvalue()
    if case.json_stdout and "Traceback" not in text:
        try:
            json.loads(out.getvalue())
        except ValueError:
            return "silent", "stdout is not JSON: " + out.getvalue()[:200], code
        return ("clear" if code == 0 else "vague"), text, code
    if "Traceback" in text:
        return "traceback", text, code
    if case.code == 0 and not case.warn:  # a readable record: success expected
        return ("clear" if code == 0 else "vague"), text, code
    if code == 0 and not (case.warn and case.token in text):
        return "silent", text, code
    if code == case.code and case.token in text:
        return "clear", text, code
    return "vague", text, code


def classify_call(case: Case) -> tuple[str, str, int | None]:
    """(class, message, 1 or 0) of a Python call that must raise a named error."""
    from hhra_phys.errors import HHRAError

    assert case.call is not None
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(
                io.StringIO()):
            case.call()
    except (HHRAError, TypeError, ValueError) as exc:
        named = isinstance(exc, HHRAError) or case.token in str(exc)
        kind = "clear" if named and case.token in str(exc) else "vague"
        return kind, f"{type(exc).__name__}: {exc}", 1
    except Exception:  # noqa: BLE001 - an AttributeError ... is what is counted here
        return "traceback", traceback.format_exc(limit=3), 1
    return "silent", "no error", 0


def run(report: Callable[[str], None] = print,
        groups: list[str] | None = None) -> dict[str, dict[str, int]]:
    """Run every case (of the groups whose name contains one of ``groups``); returns
    ``{group: {class: count}}`` and prints the cases that are not clear."""
    table: dict[str, dict[str, int]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases(Path(tmp)):
            if groups and not any(g in case.group for g in groups):
                continue
            kind, text, found = outcomes(case, Path(tmp))
            row = table.setdefault(case.group, {"inputs": 0, "clear": 0, "vague": 0,
                                                "silent": 0, "traceback": 0,
                                                **dict.fromkeys(OUTCOMES, 0)})
            row["inputs"] += 1
            row[kind] += 1
            for o in found:
                row[o] += 1
            if kind != "clear" or found:
                report(f"[{kind}{''.join(' ' + o for o in found)}] "
                       f"{' '.join(map(str, case.argv))}\n    {text.strip()[-300:]}")
    return table


def markdown(table: dict[str, dict[str, int]]) -> str:
    """The table of :func:`run` as Markdown, with a total row."""
    cols = ("inputs", "clear", "vague", "silent", "traceback", *OUTCOMES)
    lines = ["| class of bad input | " + " | ".join(cols) + " |",
             "|---|" + "---|" * len(cols)]
    total = {c: sum(r[c] for r in table.values()) for c in cols}
    for name, row in [*table.items(), ("**all**", total)]:
        lines.append(f"| {name} | " + " | ".join(str(row[c]) for c in cols) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", help="also write the counts as JSON")
    ap.add_argument("--groups", nargs="+", default=None, metavar="TEXT",
                    help="only the classes whose name contains one of these (e.g. 'issue 24')")
    a = ap.parse_args()
    result = run(lambda line: print(line, file=sys.stderr), a.groups)
    print(markdown(result))
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=1))
