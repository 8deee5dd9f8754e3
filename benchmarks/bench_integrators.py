"""Integrator benchmark: RK4 against the linearly implicit ROS2 on stiff and non-stiff models.

Measures, side by side in one run on this machine:

* accuracy: the maximum output error [deg] of the compiled simulator with each
  method and a range of substeps against CVODES (``Simulator.reference``, same
  equations, rtol = atol = 1e-10, restarted at every sample) on

  - ``nominal``: the rig's HHRA (not stiff: about 95 1/s at rest),
  - ``stiff42``: the 42 Hz parameter set of ``tests/integration/test_reference_rig.py``,
  - ``friction``: the rig's HHRA with Coulomb friction (``g_coulomb`` 12 rad/s^2)
    switching within 0.005 rad/s (the library's default width; about 2400 1/s
    at rest),

  - ``backlash``: the rig's HHRA with a backlash of 1.5 deg play whose contact is
    0.01 deg wide (the library's default; about 2900 1/s while carried at 0.5 rad/s),

  and, for the friction and backlash models, the error against the *exact*
  stick-slip friction and ideal play operator of
  :func:`hhra_phys.reference.simulate_reference` (``smooth=False``): the
  modelling error of a smooth switch of that width, next to the integration error
  (with the reference's wall time);
* edges: dead zone (``i_dead`` 0.15 and 0.3 mA) and saturation (``i_sat`` 0.3 and
  0.5 mA) of the package (automatic method) against the reference's exact ``clip``
  and dead band, with the default quadratic corners;
* cost: time per population (100 members over the record, vector code when
  available) of each method at the substeps ``Simulator(method="auto")`` chooses,
  and at equal substeps, timed alternately; for a stiff model also RK4 at 2 and 4
  times the substeps.

Run::

    python benchmarks/bench_integrators.py [--seconds 20] [--pop 100] [--repeats 7]
        [--write docs/performance.md]
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

from hhra_phys.effects import make_effect
from hhra_phys.models.hhra import NOMINAL_GROUPS, HHRAModel
from hhra_phys.models.hhra.rig import default_input
from hhra_phys.reference import simulate_reference
from hhra_phys.simulate import Simulator

FS = 250.0
G_COULOMB = 12.0
PLAY = 1.5
EDGES = [("valve_deadzone", {"i_dead": 0.15}), ("valve_deadzone", {"i_dead": 0.3}),
         ("valve_saturation", {"i_sat": 0.3}), ("valve_saturation", {"i_sat": 0.5})]


def _stiff() -> dict[str, float]:
    """The 42 Hz set of tests/integration/test_reference_rig.py (7.8x stiffer oil column)."""
    n = dict(NOMINAL_GROUPS)
    k = (42.0 * 2 * math.pi) ** 2 / (n["g_torque"] * n["g_compress"])
    return dict(n, g_compress=n["g_compress"] * k, g_leak=n["g_leak"] * k,
                g_valve=n["g_valve"] * k, g_damping=290.0)


def _cases() -> dict[str, tuple[HHRAModel, dict[str, float]]]:
    base = HHRAModel()
    fric = HHRAModel(effects=[make_effect("coulomb_friction")])
    back = HHRAModel(effects=[make_effect("backlash")])
    return {
        "nominal": (base, dict(NOMINAL_GROUPS)),
        "stiff42": (base, _stiff()),
        "friction": (fric, dict(NOMINAL_GROUPS, g_coulomb=G_COULOMB)),
        "backlash": (back, dict(NOMINAL_GROUPS, play=PLAY)),
    }


#: The exact (smooth=False) reference effect of each case with a sharp switch, and the
#: reference's integrator (stick-slip friction is stiff; exact backlash leaves the
#: shaft's equations as they are, the play operator is applied afterwards).
EXACT = {"friction": ({"coulomb_friction": {"g_coulomb": G_COULOMB}}, "Radau"),
         "backlash": ({"backlash": {"play": PLAY}}, "LSODA")}


def _x0(model: HHRAModel) -> np.ndarray:
    x0 = model.x0().astype(float)
    x0[0] = 0.1
    return x0


def _vector(model: HHRAModel, values: dict[str, float]) -> np.ndarray:
    return np.array([values[n] for n in model.params.names])


def _time(fn, repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="record length [s]")
    ap.add_argument("--pop", type=int, default=100, help="population for the timings")
    ap.add_argument("--repeats", type=int, default=7, help="timing repeats (minimum kept)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the input")
    ap.add_argument("--write", type=Path, default=None, help="write a Markdown report here")
    args = ap.parse_args(argv)
    if args.seconds <= 0 or args.pop < 1 or args.repeats < 1:
        ap.error("--seconds, --pop and --repeats must be positive")
    u = default_input(args.seconds, FS, seed=args.seed)
    lines = [f"machine: {platform.machine()}, python {platform.python_version()}; "
             f"record {args.seconds:g} s at {FS:g} Hz ({u.size} samples), seed {args.seed}"]
    lines.append("accuracy: max |simulator - CVODES| [deg] (same equations, rtol 1e-10)")
    grid = {"rk4": (2, 4, 8, 16, 32), "ros4": (2, 4, 8, 16), "ros2": (2, 8, 32)}
    auto: dict[str, Simulator] = {}
    for name, (model, values) in _cases().items():
        p = _vector(model, values)
        x0 = _x0(model)
        ref_sim = Simulator(model, FS, substeps=2, method="rk4", backend="casadi")
        y_ref = ref_sim.reference(u, p, x0=x0)
        sim_auto = Simulator(model, FS)
        auto[name] = sim_auto
        y_auto = sim_auto.simulate(u, p, x0=x0)
        row = [f"  {name:<9} auto -> {sim_auto.last_method} x {sim_auto.last_substeps}: "
               f"{np.max(np.abs(y_auto - y_ref)):.2e}   ({sim_auto.method_reason})"]
        for method, steps in grid.items():
            errs = []
            for n in steps:
                sim = Simulator(model, FS, substeps=n, method=method)
                P = p[None, :]  # a population of one: no refinement, the method as given
                y = sim.simulate(u, P, x0=x0)[0]
                errs.append(f"{n}: {np.max(np.abs(y - y_ref)):.2e}" if np.isfinite(y).all()
                            else f"{n}: unstable")
            row.append(f"    {method:<5} substeps " + ", ".join(errs))
        lines += row
        if name in EXACT:
            t0 = time.perf_counter()
            effects, method = EXACT[name]
            exact = simulate_reference(u, FS, values, x0=x0, smooth=False, method=method,
                                       effects=effects)
            t_exact = time.perf_counter() - t0
            what = ("smooth switch (width 0.005 rad/s) vs exact stick-slip friction"
                    if name == "friction" else
                    "contact 0.01 deg wide vs the exact play operator")
            what += f" ({method})"
            lines.append(f"    {what}: {np.max(np.abs(y_ref - exact)):.2e} deg max, "
                         f"{np.sqrt(np.mean((y_ref - exact) ** 2)):.2e} deg RMS; auto vs exact "
                         f"{np.max(np.abs(y_auto - exact)):.2e} deg max (exact reference "
                         f"{t_exact:.1f} s)")
    lines += _edges(u)
    lines.append(f"cost: ms per population of {args.pop} (minimum of {args.repeats}, "
                 "alternating)")
    for name, (model, values) in _cases().items():
        rng = np.random.default_rng(0)
        P = _vector(model, values)[None, :] * np.exp(0.1 * rng.standard_normal((args.pop, 1)))
        x0 = _x0(model)
        chosen = auto[name]
        sims = {f"auto ({chosen.method} x {chosen.substeps})": chosen}
        sims[f"rk4 x {chosen.substeps}"] = Simulator(model, FS, substeps=chosen.substeps,
                                                     method="rk4")
        for method in ("ros4", "ros2"):
            sims[f"{method} x {chosen.substeps}"] = Simulator(
                model, FS, substeps=chosen.substeps, method=method)
        if chosen.method != "rk4":  # what RK4 needs to approach ROS4's accuracy
            for k in (2, 4):
                n = k * chosen.substeps
                sims[f"rk4 x {n}"] = Simulator(model, FS, substeps=n, method="rk4")
        for s in sims.values():
            s.simulate(u, P, x0=x0)  # build and compile outside the timing
        times = {k: math.inf for k in sims}
        for _ in range(args.repeats):
            for k, s in sims.items():
                times[k] = min(times[k], _time(lambda s=s, P=P, x0=x0: s.simulate(u, P, x0=x0), 1))
        width = next(iter(sims.values())).vector_width(args.pop)
        timed = ", ".join(f"{k}: {1e3 * v:.1f}" for k, v in times.items())
        lines.append(f"  {name:<9} {timed}  (SIMD width {width})")
    print("\n".join(lines))
    if args.write:
        write_report(args.write, lines, argv)
    return 0


def _edges(u: np.ndarray) -> list[str]:
    """Dead zone and saturation (automatic method) against the exact reference."""
    lines = ["edges: max |package - exact clip/dead band| [deg] (reference smooth=False); "
             "input levels " + ", ".join(f"{v:.3g}" for v in np.unique(np.abs(u))) + " mA"]
    for name, size in EDGES:
        row = []
        for label, settings in (("quadratic corners (default)", {}),):
            model = HHRAModel(effects=[make_effect(name, **settings)])
            values = dict(NOMINAL_GROUPS, **size)
            x0 = _x0(model)
            exact = simulate_reference(u, FS, values, x0=x0, smooth=False, effects={name: size})
            y = Simulator(model, FS).simulate(u, _vector(model, values), x0=x0)
            row.append(f"{label} {np.max(np.abs(y - exact)):.2e}")
        lines.append(f"  {name} {size}: " + ", ".join(row))
    return lines


def write_report(path: Path, lines: list[str], argv: list[str] | None) -> None:
    """Replace the integrator section of the performance report with these results."""
    cmd = "python benchmarks/bench_integrators.py " + " ".join(argv or sys.argv[1:])
    start, end = "<!-- bench_integrators:start -->", "<!-- bench_integrators:end -->"
    # docs/ carry no dates (the dated record is benchmarks/notes/)
    section = (f"{start}\nCommand: `{cmd.strip()}`\n\n```\n"
               + "\n".join(lines) + f"\n```\n{end}")
    text = path.read_text() if path.exists() else "# Performance\n\n"
    if start in text and end in text:
        text = text[: text.index(start)] + section + text[text.index(end) + len(end):]
    else:
        text = text.rstrip() + "\n\n" + section + "\n"
    path.write_text(text)
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
