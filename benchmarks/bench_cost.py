"""``hhra-phys fit`` and ``hhra-phys diagnose`` on several records, this checkout beside others.

The cost issue's side-by-side measurement: each record is written once (the independent
reference implementation, :func:`hhra_phys.reference.reference_record`, 20 s at 250 Hz by
default, ``--duration`` for longer), then each command runs on it as a subprocess under
every checkout in turn (this one first, then each ``--against`` folder, a checkout of
another commit: ``git worktree add --detach DIR COMMIT``), so the load of the machine falls
alike on all. Each checkout has its own compiled-code cache, warmed by one unrecorded run of
each command on every record first (steady state: what a user's second run costs; warmed on
the first record only, a later record's diagnose compiled the candidates the first one's
settled round never refitted: 55 objects, 16 of a delay record's 30 CPU seconds), or, with
``--cold``, emptied before every run (what a first run on a new machine costs). Per run: CPU
seconds (the command's and every process it waited for: workers, the C compiler) beside wall
seconds, and the score the command reports (fit: validation RMSE; diagnose: the final
model's test RMSE and the chosen effects).

    python benchmarks/bench_cost.py --commands fit --set fit [--against ../old]
    python benchmarks/bench_cost.py --commands fit,diagnose --set diagnose --json OUT.json

``--set fit``: three records with an effect the base model lacks (a dead zone, sharp
Coulomb friction, an input delay) and two clean ones. ``--set diagnose``: dead zones of
two sizes, Coulomb friction, an input delay, clean.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hhra_phys.data import save_csv
from hhra_phys.reference import reference_record

#: (name, seed, hidden effects) of each record set.
SETS: dict[str, list[tuple[str, int, dict[str, dict[str, float]]]]] = {
    "fit": [("deadzone", 1, {"valve_deadzone": {"i_dead": 0.1}}),
            ("friction", 2, {"coulomb_friction": {"g_coulomb": 30.0}}),
            ("delay", 3, {"input_delay": {"delay": 4.0}}),
            ("clean", 4, {}),
            ("clean", 5, {})],
    "diagnose": [("deadzone-small", 1, {"valve_deadzone": {"i_dead": 0.05}}),
                 ("deadzone-large", 2, {"valve_deadzone": {"i_dead": 0.15}}),
                 ("friction", 3, {"coulomb_friction": {"g_coulomb": 30.0}}),
                 ("delay", 4, {"input_delay": {"delay": 4.0}}),
                 ("clean", 5, {})],
}


def _run(cmd: list[str], env: dict[str, str]) -> tuple[float, float, int]:
    """Wall and CPU seconds of ``cmd`` (CPU: it and the processes it waited for), exit code.

    Runs in the cache's folder: ``python -m`` puts the working directory first on the
    path, so a run from a checkout would import that checkout whatever PYTHONPATH says.
    """
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    rc = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                        cwd=Path(env["HHRA_PHYS_CACHE"]).parent).returncode
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), rc


def _commit(tree: str) -> str:
    """The checkout's commit (with ``+`` when its working tree differs from it)."""
    def git(*a: str) -> str:
        return subprocess.run(["git", "-C", tree, *a], capture_output=True,
                              text=True).stdout.strip()
    return git("rev-parse", "--short", "HEAD") + ("+" if git("status", "--porcelain") else "")


def _score(command: str, out: Path) -> dict[str, object]:
    """What the command's JSON says of the fit's quality."""
    try:
        d = json.loads(out.read_text())
    except (OSError, ValueError):
        return {"error": "no JSON"}
    if command == "fit":
        return {"val_rmse": d["val"]["rmse"]}
    return {"test_rmse": d["final"]["test"]["rmse"], "val_rmse": d["final"]["val"]["rmse"],
            "chosen": d["chosen"]}


def _command(command: str, rec: Path, out: Path, extra: list[str]) -> list[str]:
    cmd = [sys.executable, "-m", "hhra_phys.cli", command, str(rec), "--json", str(out),
           "--overwrite"]
    return cmd + (["--quiet"] if command == "fit" else []) + extra


def _summary(rows: list[dict], commands: list[str], here: str, trees: list[str]) -> None:
    """Per record and in total: this checkout's CPU against each other checkout's, and
    (with both commands) this checkout's diagnose against its fit."""
    for c in commands:
        mine = [r for r in rows if r["command"] == c and r["tree"] == here]
        for tree in trees[1:]:
            theirs = [r for r in rows if r["command"] == c and r["tree"] == tree]
            for a, b in zip(mine, theirs, strict=True):
                print(f"{c} {a['record']:16s} CPU {a['cpu_s']:7.1f} / {b['cpu_s']:7.1f} = "
                      f"{a['cpu_s'] / b['cpu_s']:.2f}x; wall {a['wall_s'] / b['wall_s']:.2f}x")
            total = sum(r["cpu_s"] for r in mine), sum(r["cpu_s"] for r in theirs)
            print(f"{c} total CPU {total[0]:.1f} / {total[1]:.1f} = {total[0] / total[1]:.2f}x "
                  f"(against {tree})")
    if {"fit", "diagnose"} <= set(commands):
        fits = {r["record"]: r for r in rows if r["command"] == "fit" and r["tree"] == here}
        for d in (r for r in rows if r["command"] == "diagnose" and r["tree"] == here):
            f = fits[d["record"]]
            print(f"diagnose / fit {d['record']:16s} CPU {d['cpu_s'] / f['cpu_s']:.2f}x, "
                  f"wall {d['wall_s'] / f['wall_s']:.2f}x")


def _records(recs: list, duration: float, tmp: str) -> list[Path]:
    """Each record written once as CSV (with its side-car) into ``tmp``."""
    paths = []
    for name, seed, eff in recs:
        p = Path(tmp, f"{name}-{seed}.csv")
        save_csv(reference_record(seed=seed, duration=duration, effects=eff or None), p)
        paths.append(p)
    return paths


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commands", default="fit", help="comma-separated: fit, diagnose")
    ap.add_argument("--set", default="fit", choices=sorted(SETS), dest="records")
    ap.add_argument("--against", action="append", default=[],
                    help="another checkout's folder (repeatable)")
    ap.add_argument("--only", default="", help="comma-separated record indices (0-based)")
    ap.add_argument("--extra", default="", help="extra options for every command")
    ap.add_argument("--duration", type=float, default=20.0,
                    help="record length [s] at 250 Hz (20: 5000 samples; the cost's growth "
                         "with the record: run at 20, 80 and 200)")
    ap.add_argument("--cold", action="store_true",
                    help="an empty compiled-code cache for every run (default: warmed on "
                         "every record first)")
    ap.add_argument("--json", help="write the rows here")
    args = ap.parse_args()
    here = str(Path(__file__).resolve().parents[1])
    trees = [here] + [str(Path(a).resolve()) for a in args.against]
    commands = [c for c in args.commands.split(",") if c]
    recs = SETS[args.records]
    if args.only:
        recs = [recs[int(i)] for i in args.only.split(",")]
    rows = []
    load0 = os.getloadavg()[0]
    extra = args.extra.split()
    with tempfile.TemporaryDirectory() as tmp:
        paths = _records(recs, args.duration, tmp)
        envs = {}
        for k, tree in enumerate(trees):
            Path(tmp, f"run{k}").mkdir()
            envs[tree] = dict(os.environ, PYTHONPATH=tree,
                              HHRA_PHYS_CACHE=str(Path(tmp, f"run{k}", "cache")))
            for c, rec in ((c, r) for c in commands for r in ([] if args.cold else paths)):
                _run(_command(c, rec, Path(tmp, "warm.json"), extra), envs[tree])  # unrecorded
        for (name, seed, _), rec in zip(recs, paths, strict=True):
            for c, (k, tree) in ((c, kt) for c in commands for kt in enumerate(trees)):
                out = Path(tmp, f"out{k}.json")
                out.unlink(missing_ok=True)
                if args.cold:
                    shutil.rmtree(envs[tree]["HHRA_PHYS_CACHE"], ignore_errors=True)
                wall, cpu, rc = _run(_command(c, rec, out, extra), envs[tree])
                row = {"record": f"{name}-{seed}", "command": c, "tree": tree,
                       "samples": int(round(args.duration * 250)), "commit": _commit(tree),
                       "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "exit": rc,
                       "cache": "cold" if args.cold else "warm", **_score(c, out)}
                rows.append(row)
                print(json.dumps(row), flush=True)
    print(f"\nload average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")
    _summary(rows, commands, here, trees)
    if args.json:
        Path(args.json).write_text(json.dumps({"load_start": load0, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
