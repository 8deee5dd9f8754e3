"""Long records of our own making, each diagnosed from a user's model: what does it cost?

Issue 31 ("cost linear in the record") and issue 32 (the physics named on a user's model).
Two records that resemble real ones, simulated here in plain NumPy/SciPy (independent of
the package), and two user models written only with the public API (``from hhra_phys
import Model, Parameter, Part, State, ...``, as ``tests/integration/user_models/two_tank.py``
and ``docs/guide.md``, "Your own system"):

``drive``
    A prismatic drive: states ``q`` [m] and ``v`` [m/s], input the motor command ``u``
    [V]. The user's model: ``dq/dt = v``, ``dv/dt = k_motor*u - c_visc*v`` (mass
    normalised). The machine also has Coulomb friction ``f_coulomb*tanh(v/1e-4)`` and a
    constant force offset ``f_offset`` at ``rate:v``. 25 s at 1 kHz, the command from a
    discrete PD position controller tracking steps and ramps (closed loop simulated with
    fixed-step RK4, 10 substeps per sample, the command held over the sample), encoder
    noise 1e-6 m; a separate test experiment (another reference, another seed) given to
    ``--validate``.
``duffing``
    A Duffing resonator ``x'' + 2 zeta w x' + w^2 x + k3 x^3 = b u``, output ``x`` [mm]
    plus noise, input a band-limited random-phase multisine (5-60 Hz around the 30 Hz
    resonance) sampled at 610 Hz, the truth integrated by ``scipy.integrate.solve_ivp``
    (DOP853, rtol 1e-10) with the input between samples the cubic convolution
    (Catmull-Rom) of the samples, which the record's side-car says
    (``intersample="cubic"``). 8,000 estimation + 4,000 selection + 32,000 test samples
    (``--split 8000 --test 32000/44000``). The user's model is the linear resonator.

For each record the script writes the user's model (``drive_model.py:make_model``), the
true structure as user parts (``drive_truth.py:make_model``: the user's model plus the
missing physics) and the records (CSV + JSON side-car), then runs as subprocesses from the
repository's root, one after the other, timing wall and CPU (``getrusage`` of the
children, as ``benchmarks/bench_loop.py``):

1. ``python -m hhra_phys.cli fit`` of the user's model (what a user runs first);
2. ``python -m hhra_phys.cli diagnose --model FILE.py:make_model ... --json``;
3. the true structure's refit on the same split: ``diagnose --max-effects 0
   --no-discover --keep-intersample`` of ``*_truth.py`` (its base fit is what the loop
   should reach), unless ``--no-truth``.

Writes ``DIR/rows.json`` (one row per record and seed) and prints a summary.

    python experiments/long_records.py --out /tmp/long [--records drive,duffing]
        [--seeds 1] [--quick] [--budget SECONDS] [--workers N] [--pop P --iters I]
        [--drive-seconds 25]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from hhra_phys.data import Dataset, save_csv

REPO = Path(__file__).resolve().parents[1]

# --- the user's models, as the files a user writes ------------------------------------

DRIVE_MODEL = '''\
"""A user's prismatic drive, written only with the public API.

States: position q [m], velocity v [m/s]; input the motor command u [V]; output q.
Mass normalised: dv/dt = k_motor*u - c_visc*v (motor gain and viscous friction).
"""
from dataclasses import dataclass

from hhra_phys import Model, Parameter, Part, State, register_part


@register_part
@dataclass(frozen=True)
class DriveMotor(Part):
    name = "drive_motor"
    stage = "motor"

    @property
    def parameters(self):
        return (Parameter("k_motor", "m/(s^2*V)", 0.5, 0.01, 50.0, "log",
                          "motor force per volt over the moving mass"),)

    def apply(self, ctx):
        ctx.signals["force"] = ctx.p["k_motor"] * ctx.u


@register_part
@dataclass(frozen=True)
class DriveCarriage(Part):
    name = "drive_carriage"
    stage = "motion"

    @property
    def parameters(self):
        return (Parameter("c_visc", "1/s", 2.0, 0.01, 200.0, "log",
                          "viscous friction over the moving mass"),)

    @property
    def states(self):
        return (State("q", "m", 0.0, "carriage position", scale=0.05, role="position"),
                State("v", "m/s", 0.0, "carriage velocity", scale=0.05, role="velocity"))

    def apply(self, ctx):
        v = ctx.x["v"]
        ctx.add_rate("q", v)
        ctx.add_rate("v", ctx.signal("force", self.name) - ctx.p["c_visc"] * v)


@register_part
@dataclass(frozen=True)
class DriveEncoder(Part):
    name = "drive_encoder"
    stage = "sensor"

    def apply(self, ctx):
        ctx.signals["y"] = ctx.x["q"]


def make_model():
    return Model([DriveMotor(), DriveCarriage(), DriveEncoder()], name="drive")
'''

DRIVE_TRUTH_PARTS = '''

# --- the physics the user's model lacks (the record's truth), as user parts ---------
import casadi as ca  # noqa: E402


@register_part
@dataclass(frozen=True)
class DriveCoulomb(Part):
    """Coulomb friction, as sharp as the record's: f_coulomb*tanh(v/width)."""

    name = "drive_coulomb"
    stage = "motion"
    width: float = 1e-4

    @property
    def parameters(self):
        return (Parameter("f_coulomb", "m/s^2", 0.1, 1e-3, 5.0, "log",
                          "Coulomb friction over the moving mass"),)

    def apply(self, ctx):
        ctx.add_rate("v", -ctx.p["f_coulomb"] * ca.tanh(ctx.x["v"] / self.width))


@register_part
@dataclass(frozen=True)
class DriveForceOffset(Part):
    """A constant force (cable drag, a tilt) over the moving mass."""

    name = "drive_force_offset"
    stage = "motion"

    @property
    def parameters(self):
        return (Parameter("f_offset", "m/s^2", 0.0, -2.0, 2.0, "linear",
                          "constant force over the moving mass"),)

    def apply(self, ctx):
        ctx.add_rate("v", ctx.p["f_offset"])


def make_model():  # noqa: F811  (the truth: the user's model plus what it lacks)
    return Model([DriveMotor(), DriveCarriage(), DriveCoulomb(), DriveForceOffset(),
                  DriveEncoder()], name="drive_truth")
'''

DUFFING_MODEL = '''\
"""A user's resonator (a shaker-driven beam, say), written only with the public API.

States: displacement x [mm], velocity v [mm/s]; input the drive u [V]; output x.
Linear: dv/dt = w_n^2*(gain*u - x) - 2*zeta*w_n*v.
"""
from dataclasses import dataclass

from hhra_phys import Model, Parameter, Part, State, register_part


@register_part
@dataclass(frozen=True)
class ShakerDrive(Part):
    name = "shaker_drive"
    stage = "drive"

    @property
    def parameters(self):
        return (Parameter("gain", "mm/V", 0.5, 0.01, 50.0, "log", "static gain"),)

    def apply(self, ctx):
        ctx.signals["drive"] = ctx.p["gain"] * ctx.u


@register_part
@dataclass(frozen=True)
class BeamMode(Part):
    name = "beam_mode"
    stage = "motion"

    @property
    def parameters(self):
        return (Parameter("w_n", "rad/s", 150.0, 10.0, 2000.0, "log", "natural frequency"),
                Parameter("zeta", "-", 0.1, 1e-3, 1.0, "log", "damping ratio"))

    @property
    def states(self):
        return (State("x", "mm", 0.0, "displacement", scale=1.0, role="position"),
                State("v", "mm/s", 0.0, "velocity", scale=200.0, role="velocity"))

    def apply(self, ctx):
        w, z = ctx.p["w_n"], ctx.p["zeta"]
        x, v = ctx.x["x"], ctx.x["v"]
        ctx.add_rate("x", v)
        ctx.add_rate("v", w * w * (ctx.signal("drive", self.name) - x) - 2 * z * w * v)


@register_part
@dataclass(frozen=True)
class DisplacementProbe(Part):
    name = "displacement_probe"
    stage = "sensor"

    def apply(self, ctx):
        ctx.signals["y"] = ctx.x["x"]


def make_model():
    return Model([ShakerDrive(), BeamMode(), DisplacementProbe()], name="resonator")
'''

DUFFING_TRUTH_PARTS = '''

# --- the physics the user's model lacks (the record's truth), as a user part --------


@register_part
@dataclass(frozen=True)
class CubicSpring(Part):
    """A hardening spring: dv/dt -= k3*x^3."""

    name = "cubic_spring"
    stage = "motion"

    @property
    def parameters(self):
        return (Parameter("k3", "1/(mm^2*s^2)", 100.0, 0.1, 1e5, "log",
                          "cubic stiffness over the mass"),)

    def apply(self, ctx):
        ctx.add_rate("v", -ctx.p["k3"] * ctx.x["x"] ** 3)


def make_model():  # noqa: F811  (the truth: the user's model plus what it lacks)
    return Model([ShakerDrive(), BeamMode(), CubicSpring(), DisplacementProbe()],
                 name="resonator_truth")
'''

# --- the truths ------------------------------------------------------------------------

#: The drive's truth: motor gain, viscous, Coulomb (and its tanh width), force offset;
#: the PD controller (gains, derivative filter, command limit); encoder noise.
DRIVE = {"k_motor": 1.0, "c_visc": 5.0, "f_coulomb": 0.3, "width": 1e-4, "f_offset": 0.1,
         "kp": 400.0, "kd": 20.0, "d_filter_hz": 100.0, "u_max": 10.0, "noise": 1e-6,
         "fs": 1000.0, "substeps": 10}

#: The Duffing resonator: 30 Hz, zeta 0.03, static gain 1 mm/V, the cube 3-5 % of the
#: linear spring at the peaks; multisine 5-60 Hz; probe noise.
DUFFING = {"f_n": 30.0, "zeta": 0.03, "gain": 1.0, "k3": 800.0, "f_lo": 5.0, "f_hi": 60.0,
           "u_rms": 0.1, "noise": 2e-3, "fs": 610.0}


def drive_reference(rng: np.random.Generator, n: int, fs: float) -> np.ndarray:
    """Position reference [m]: holds, steps and ramps between levels within +-40 mm."""
    r = np.zeros(n)
    i, level = 0, 0.0
    while i < n:
        seg = int(rng.uniform(0.4, 1.5) * fs)
        new = rng.uniform(-0.04, 0.04)
        if rng.random() < 0.5:  # a step
            r[i:i + seg] = new
        else:  # a ramp over part of the segment, then a hold
            ramp = max(1, int(rng.uniform(0.2, 0.9) * seg))
            r[i:i + seg] = new
            m = r[i:i + ramp].size  # the record may end within the ramp
            r[i:i + m] = level + (new - level) * np.arange(1, m + 1) / ramp
        level, i = new, i + seg
    return r[:n]


def drive_record(seed: int, duration: float, name: str) -> Dataset:
    """The closed-loop drive: applied command u [V] and measured position [m], seeded."""
    P = DRIVE
    rng = np.random.default_rng(seed)
    fs, m = P["fs"], int(P["substeps"])
    n, dt = int(round(duration * fs)), 1.0 / fs
    h = dt / m
    r = drive_reference(rng, n, fs)
    noise = P["noise"] * rng.standard_normal(n)
    k, c, fc, w, f0 = P["k_motor"], P["c_visc"], P["f_coulomb"], P["width"], P["f_offset"]

    def acc(v: float, u: float) -> float:
        return k * u - c * v - fc * np.tanh(v / w) + f0

    alpha = 1.0 - np.exp(-2 * np.pi * P["d_filter_hz"] * dt)
    q = v = 0.0
    u_rec, y_rec = np.empty(n), np.empty(n)
    qm_prev, dq_f = 0.0, 0.0
    for i in range(n):
        qm = q + noise[i]
        dq_f += alpha * ((qm - qm_prev) / dt - dq_f)
        qm_prev = qm
        u = float(np.clip(P["kp"] * (r[i] - qm) - P["kd"] * dq_f, -P["u_max"], P["u_max"]))
        u_rec[i], y_rec[i] = u, qm
        for _ in range(m):  # RK4 with the command held over the sample
            k1q, k1v = v, acc(v, u)
            k2q, k2v = v + 0.5 * h * k1v, acc(v + 0.5 * h * k1v, u)
            k3q, k3v = v + 0.5 * h * k2v, acc(v + 0.5 * h * k2v, u)
            k4q, k4v = v + h * k3v, acc(v + h * k3v, u)
            q += h / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            v += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    truth = {kk: P[kk] for kk in ("k_motor", "c_visc", "f_coulomb", "width", "f_offset")}
    return Dataset(t=np.arange(n) * dt, u=u_rec, y=y_rec, name=name, input_name="motor command",
                   input_unit="V", output_name="position", output_unit="m",
                   metadata={"truth": truth, "seed": seed, "noise": P["noise"],
                             "controller": {"kp": P["kp"], "kd": P["kd"],
                                            "u_max": P["u_max"]}})


def drive_replay(u: np.ndarray, substeps: int) -> np.ndarray:
    """The drive's position [m] with the recorded command ``u`` [V] replayed open loop from
    rest through the generator's RK4 at ``substeps`` per sample (no noise, no controller)."""
    P = DRIVE
    k, c, fc, w, f0 = P["k_motor"], P["c_visc"], P["f_coulomb"], P["width"], P["f_offset"]
    h = 1.0 / P["fs"] / substeps
    q = v = 0.0
    out = np.empty(u.size)
    for i, uk in enumerate(u):
        out[i] = q
        for _ in range(substeps):
            v2 = v + 0.5 * h * (a1 := k * uk - c * v - fc * np.tanh(v / w) + f0)
            v3 = v + 0.5 * h * (a2 := k * uk - c * v2 - fc * np.tanh(v2 / w) + f0)
            v4 = v + h * (a3 := k * uk - c * v3 - fc * np.tanh(v3 / w) + f0)
            a4 = k * uk - c * v4 - fc * np.tanh(v4 / w) + f0
            q += h / 6 * (v + 2 * v2 + 2 * v3 + v4)
            v += h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
    return out


def generator_error(seeds: list[int], seconds: float, fine: int = 80) -> list[dict[str, Any]]:
    """How far the generator's own integration (RK4 at ``DRIVE["substeps"]``) is from the
    continuous plant, per test record: its command replayed at that count and at ``fine``.

    Why: at an encoder noise of 1e-6 m the discretisation of the sharp friction is a
    visible part of what a continuous-time model cannot follow (and what a refit at the
    generator's own count copies)."""
    rows = []
    for seed in seeds:
        test = drive_record(seed + 1000, seconds, f"drive test seed {seed + 1000}")
        d = drive_replay(test.u, int(DRIVE["substeps"])) - drive_replay(test.u, fine)
        rows.append({"record": test.name, "substeps": int(DRIVE["substeps"]), "fine": fine,
                     "rms_m": float(np.sqrt(np.mean(d * d))), "max_m": float(np.max(np.abs(d))),
                     "noise_m": DRIVE["noise"]})
        print(f"{test.name}: generator x {DRIVE['substeps']} vs x {fine}: RMS "
              f"{rows[-1]['rms_m']:.3g} m, max {rows[-1]['max_m']:.3g} m (noise "
              f"{DRIVE['noise']:g} m)", flush=True)
    return rows


def multisine(rng: np.random.Generator, n: int, fs: float, f_lo: float, f_hi: float,
              rms: float) -> np.ndarray:
    """Random-phase multisine of flat spectrum in [f_lo, f_hi] Hz, period n samples."""
    spec = np.zeros(n // 2 + 1, dtype=complex)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    band = (f >= f_lo) & (f <= f_hi)
    spec[band] = np.exp(2j * np.pi * rng.random(int(band.sum())))
    u = np.fft.irfft(spec, n)
    return u * (rms / np.std(u))


def catmull_rom(u: np.ndarray) -> np.ndarray:
    """Per-sample cubic coefficients (n, 4) of the cubic convolution (Keys a = -1/2).

    ``u(t_k + s*T) = c0 + c1 s + c2 s^2 + c3 s^3`` through ``u[k-1..k+2]``; before the
    record the first value, after it the last (edge padding).
    """
    p = np.concatenate([[u[0]], u, [u[-1], u[-1]]])
    p0, p1, p2, p3 = p[:-3], p[1:-2], p[2:-1], p[3:]
    return 0.5 * np.stack([2 * p1, p2 - p0, 2 * p0 - 5 * p1 + 4 * p2 - p3,
                           -p0 + 3 * p1 - 3 * p2 + p3], axis=1)


def duffing_record(seed: int, n: int, name: str) -> Dataset:
    """The Duffing resonator under a smooth multisine, integrated to tight tolerances."""
    P = DUFFING
    rng = np.random.default_rng(seed)
    fs = P["fs"]
    dt = 1.0 / fs
    u = multisine(rng, n, fs, P["f_lo"], P["f_hi"], P["u_rms"])
    coef = catmull_rom(u)
    w = 2 * np.pi * P["f_n"]
    zw2, w2, b, k3 = 2 * P["zeta"] * w, w * w, P["gain"] * w * w, P["k3"]

    def rhs(t: float, s: np.ndarray) -> list[float]:
        k = min(int(t * fs), n - 1)
        r = t * fs - k
        c0, c1, c2, c3 = coef[k]
        uu = c0 + r * (c1 + r * (c2 + r * c3))
        x, v = s
        return [v, b * uu - zw2 * v - w2 * x - k3 * x * x * x]

    t = np.arange(n) * dt
    sol = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], method="DOP853", t_eval=t, rtol=1e-10,
                    atol=1e-12, max_step=dt)
    if not sol.success:
        raise RuntimeError(f"the Duffing truth did not integrate: {sol.message}")
    x = sol.y[0]
    xpk = float(np.max(np.abs(x)))
    y = x + P["noise"] * rng.standard_normal(n)
    truth = {"w_n": w, "zeta": P["zeta"], "gain": P["gain"], "k3": k3}
    return Dataset(t=t, u=u, y=y, name=name, input_name="drive", input_unit="V",
                   output_name="displacement", output_unit="mm",
                   metadata={"truth": truth, "seed": seed, "noise": P["noise"],
                             "intersample": "cubic",
                             "cube_over_spring_at_peak": k3 * xpk ** 2 / w2,
                             "x_peak": xpk, "x_rms": float(np.std(x))})


# --- running the commands ------------------------------------------------------------


def timed(cmd: list[str], log: Path) -> tuple[float, float, int]:
    """Run ``cmd`` from the repository's root; wall and CPU seconds (it and its children)."""
    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg")
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        proc = subprocess.run(cmd, cwd=REPO, env=env, stdout=fh, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), proc.returncode


def _rmse(part: dict[str, Any] | None) -> dict[str, float | None]:
    part = part or {}
    return {k: (part.get(k) or {}).get("rmse") for k in ("est", "val", "test")}


def summarise(d: dict[str, Any]) -> dict[str, Any]:
    """What a row keeps of a diagnose JSON."""
    steps = [{"round": s.get("round"), "effect": s.get("effect"), "entry": s.get("entry"),
              "expression": s.get("expression"), "accepted": s.get("accepted"),
              "removed": s.get("removed"), "action": s.get("action"),
              "sensor": s.get("sensor"), "discovered": s.get("discovered", False),
              "seconds": s.get("seconds"), "val_rmse": (s.get("val") or {}).get("rmse")}
             for s in d.get("steps", [])]
    st = d.get("settings", {})
    return {"chosen": d.get("chosen"), "steps": steps, "base": _rmse(d.get("base")),
            "final": _rmse(d.get("final")), "stop": st.get("stop"),
            "stopped_by_budget": d.get("stopped_by_budget"), "loop_seconds": st.get("seconds"),
            "skipped": d.get("skipped"),
            "final_params": _final_values(d)}


def _final_values(d: dict[str, Any]) -> dict[str, float] | None:
    """The final fit's parameter values of a diagnose JSON (``fits.final.params``)."""
    params = ((d.get("fits") or {}).get("final") or {}).get("params")
    return None if params is None else {k: p["value"] for k, p in params.items()}


def step_seconds(log: Path) -> list[str]:
    """The diagnose log's lines that give seconds (per step, per round, the base fit)."""
    pat = re.compile(r"\[\d+(\.\d+)? s\]|\d+(\.\d+)? s\b|^(round|base|loop|stop)")
    return [ln.rstrip()[:300] for ln in log.read_text(errors="replace").splitlines()
            if pat.search(ln.strip()) and "\r" not in ln][:300]


def _tag(kind: str, seed: int, args: argparse.Namespace) -> str:
    """File stem of a record (a drive of another length than 25 s says its length)."""
    if kind == "drive" and args.drive_seconds != 25.0 and not args.quick:
        return f"drive{args.drive_seconds:g}s_seed{seed}"
    return f"{kind}_seed{seed}"


def run_record(kind: str, seed: int, out: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Write the record and the models, run fit, diagnose and the truth's refit; one row."""
    tag = _tag(kind, seed, args)
    t0 = time.perf_counter()
    if kind == "drive":
        dur, dur_test = ((1.5, 1.0) if args.quick
                         else (args.drive_seconds, args.drive_seconds))
        data = drive_record(seed, dur, f"drive seed {seed}")
        test = drive_record(seed + 1000, dur_test, f"drive test seed {seed + 1000}")
        src, truth_src = DRIVE_MODEL, DRIVE_MODEL + DRIVE_TRUTH_PARTS
        split_args = ["--validate", str(out / f"{tag}_test.csv")]
        fit_split = ["--validate", str(out / f"{tag}_test.csv")]
    else:
        n_est, n_sel, n_test = (400, 200, 600) if args.quick else (8000, 4000, 32000)
        n = n_est + n_sel + n_test
        data = duffing_record(seed, n, f"duffing seed {seed}")
        test = None
        src, truth_src = DUFFING_MODEL, DUFFING_MODEL + DUFFING_TRUTH_PARTS
        split_args = ["--split", str(n_est), "--test", repr(n_test / n)]
        fit_split = ["--split", str(n_est)]
    sim_s = time.perf_counter() - t0
    rec = out / f"{tag}.csv"
    save_csv(data, rec, overwrite=True)
    if test is not None:
        save_csv(test, out / f"{tag}_test.csv", overwrite=True)
    model_file, truth_file = out / f"{kind}_model.py", out / f"{kind}_truth.py"
    model_file.write_text(src)
    truth_file.write_text(truth_src)
    hhra = [sys.executable, "-m", "hhra_phys.cli"]
    search = ["--pop", str(args.pop), "--iters", str(args.iters)] if args.pop else []
    seed_args = ["--seed", str(seed)]
    cmds: dict[str, list[str]] = {
        "fit": hhra + ["fit", str(rec), "--model", f"{model_file}:make_model", *fit_split,
                       *search, *seed_args, "--quiet", "--overwrite",
                       "--json", str(out / f"{tag}_fit.json")],
        "diagnose": hhra + ["diagnose", str(rec), "--model", f"{model_file}:make_model",
                            *split_args, *search, *seed_args, "--overwrite",
                            "--json", str(out / f"{tag}_diagnose.json"),
                            *(["--budget", str(args.budget)] if args.budget else []),
                            *(["--workers", str(args.workers)] if args.workers else []),
                            *args.extra.split()],
    }
    if not args.no_truth:
        cmds["truth"] = hhra + ["diagnose", str(rec), "--model", f"{truth_file}:make_model",
                                *split_args, *search, *seed_args, "--max-effects", "0",
                                "--no-discover", "--keep-intersample", "--overwrite",
                                "--json", str(out / f"{tag}_truth.json"),
                                *(["--workers", str(args.workers)] if args.workers else [])]
    row: dict[str, Any] = {"record": tag, "kind": kind, "seed": seed, "samples": int(data.n),
                           "test_samples": int(test.n) if test is not None else None,
                           "simulate_s": round(sim_s, 2), "metadata": data.metadata,
                           "commands": {}, "load_before": os.getloadavg()}
    for key, cmd in cmds.items():
        log = out / f"{tag}_{key}.log"
        print(f"[{tag}] {key}: {' '.join(cmd)}", flush=True)
        wall, cpu, rc = timed(cmd, log)
        print(f"[{tag}] {key}: {wall:.1f} s wall, {cpu:.1f} s CPU, exit {rc}, load "
              f"{os.getloadavg()[0]:.2f}", flush=True)
        row["commands"][key] = {"command": " ".join(cmd), "wall_s": round(wall, 2),
                                "cpu_s": round(cpu, 2), "exit": rc, "log": str(log),
                                "load_after": os.getloadavg()}
    fit_json = out / f"{tag}_fit.json"
    if fit_json.exists():
        f = json.loads(fit_json.read_text())
        row["fit"] = {"val_rmse": (f.get("val") or {}).get("rmse"),
                      "est_rmse": (f.get("est") or {}).get("rmse"),
                      "params": {k: v.get("value") for k, v in f.get("params", {}).items()}}
    diag_json = out / f"{tag}_diagnose.json"
    if diag_json.exists():
        row["diagnose"] = summarise(json.loads(diag_json.read_text()))
        row["diagnose_log_seconds"] = step_seconds(out / f"{tag}_diagnose.log")
    truth_json = out / f"{tag}_truth.json"
    if truth_json.exists():
        t = json.loads(truth_json.read_text())
        row["truth_refit"] = {**_rmse(t.get("base")),
                              "params": _final_values(t)}
    c = row["commands"]
    if "fit" in c and "diagnose" in c:
        row["diagnose_over_fit"] = {
            "wall": round(c["diagnose"]["wall_s"] / max(c["fit"]["wall_s"], 1e-9), 2),
            "cpu": round(c["diagnose"]["cpu_s"] / max(c["fit"]["cpu_s"], 1e-9), 2)}
    if row.get("diagnose") and row.get("truth_refit"):
        ft, tt = row["diagnose"]["final"]["test"], row["truth_refit"]["test"]
        row["final_test_over_truth"] = (ft / tt) if ft and tt else None
    return row


def print_row(row: dict[str, Any]) -> None:
    c = row["commands"]
    print(f"\n== {row['record']} ({row['samples']} samples"
          f"{', test ' + str(row['test_samples']) if row['test_samples'] else ''})")
    for key, v in c.items():
        print(f"  {key:8s} {v['wall_s']:8.1f} s wall {v['cpu_s']:8.1f} s CPU  exit {v['exit']}")
    d = row.get("diagnose")
    if d:
        print(f"  chosen: {d['chosen']}; stop: {d['stop']}; budget spent: "
              f"{d['stopped_by_budget']}")
        for s in d["steps"]:
            print(f"    r{s['round']} {s['action'] or '':6s} {s['effect']:28s} "
                  f"{s['entry'] or '':10s} acc={s['accepted']} {s['seconds'] or 0:7.1f} s  "
                  f"{s['expression'] or ''}")
        print(f"  base  est/val/test RMSE: {d['base']}")
        print(f"  final est/val/test RMSE: {d['final']}")
    if row.get("truth_refit"):
        t = row["truth_refit"]
        print(f"  truth refit est/val/test: {t['est']}, {t['val']}, {t['test']}")
    if row.get("final_test_over_truth"):
        print(f"  final test / truth refit test: {row['final_test_over_truth']:.3f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", default="drive,duffing")
    ap.add_argument("--seeds", default="1", help="comma-separated seeds (default 1)")
    ap.add_argument("--out", required=True, help="output folder (created)")
    ap.add_argument("--quick", action="store_true",
                    help="short records and a tiny search (a smoke test)")
    ap.add_argument("--pop", type=int, default=0, help="search population (default: the CLI's)")
    ap.add_argument("--iters", type=int, default=0, help="search iterations (default: the CLI's)")
    ap.add_argument("--budget", type=float, default=0.0, help="diagnose --budget SECONDS")
    ap.add_argument("--workers", default="", help="diagnose --workers N (default: the CLI's)")
    ap.add_argument("--extra", default="", help="extra diagnose options")
    ap.add_argument("--no-truth", action="store_true", help="skip the true structure's refit")
    ap.add_argument("--drive-seconds", type=float, default=25.0,
                    help="length of the drive record and of its test experiment [s] at 1 kHz "
                         "(default 25; 5, 20 and 50 measure how the cost grows with the "
                         "record)")
    ap.add_argument("--generator-error", action="store_true",
                    help="only measure the drive generator's own integration error on the "
                         "seeds' test records (RK4 x 10 against x 80, the command replayed "
                         "open loop) into OUT/generator_error.json")
    args = ap.parse_args(argv)
    if not args.drive_seconds > 1.0:
        ap.error(f"--drive-seconds must be more than 1 s, got {args.drive_seconds:g}")
    kinds = [k.strip() for k in args.records.split(",") if k.strip()]
    bad = [k for k in kinds if k not in ("drive", "duffing")]
    if bad or not kinds:
        ap.error(f"--records: choose from drive, duffing (got {args.records!r})")
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        ap.error(f"--seeds: comma-separated integers, got {args.seeds!r}")
    if args.quick:
        args.pop = args.pop or 6
        args.iters = args.iters or 3
        args.extra = args.extra or "--max-effects 1 --no-discover --effects valve_deadzone"
    if bool(args.pop) != bool(args.iters):
        ap.error("give --pop and --iters together")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.generator_error:
        rows = generator_error(seeds, args.drive_seconds)
        (out / "generator_error.json").write_text(json.dumps({"argv": sys.argv, "rows": rows},
                                                             indent=1))
        return 0
    rows = []
    for kind in kinds:
        for seed in seeds:
            row = run_record(kind, seed, out, args)
            rows.append(row)
            print_row(row)
            (out / "rows.json").write_text(json.dumps(
                {"argv": sys.argv, "cpu_count": os.cpu_count(), "rows": rows}, indent=1,
                default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
