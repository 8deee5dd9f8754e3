"""Simulator benchmark: compiled CasADi population simulator against a plain C loop.

Measures, side by side in one run on this machine:

* the hhra-phys :class:`~hhra_phys.Simulator` (CasADi mapaccum + thread map,
  compiled) on a population of 100 parameter vectors over 5000 samples, both
  as vector code (SIMD across the population, the default) and as scalar code;
* the simulator's fused cost (:meth:`~hhra_phys.Simulator.simulate_cost`, what
  a fit's global search calls), which never returns the trajectories;
* a plain C RK4 loop of the same model equations, the same substeps, the same
  population and the same number of threads (pthreads), compiled with the same
  compiler and flags (scalar code, like CasADi's own generated C);
* a ``scipy.integrate.solve_ivp`` baseline as a user would write it by hand,
  restarted at every sample so the zero-order hold is exact (timed on one
  trajectory and scaled to the population);
* the integration error of the compiled simulator against the CVODES reference.

Run::

    python benchmarks/bench_simulator.py [--pop 100] [--samples 5000] [--repeats 15]
        [--write docs/performance.md]

Timings are the minimum over interleaved repeats (this machine is shared and
noisy); the ratio of the two minima is the figure of merit.
"""

from __future__ import annotations

import argparse
import ctypes
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from hhra_phys import HHRAModel, Simulator
from hhra_phys.compile import CFLAGS, find_compiler
from hhra_phys.models.hhra.rig import default_input

C_SOURCE = r"""
#include <math.h>
#include <pthread.h>
/* The HHRA with the orifice valve, exactly as hhra_phys.model assembles it.
   Parameters per member: g_valve, g_compress, g_leak, g_torque, g_damping,
   g_spring, g_load. States: theta, omega, p. Output: theta in degrees. */
#define SIGN_EPS 1e-3
#define SQRT_DELTA 1e-6
typedef struct { const double *P, *u; double *Y; int N, nsub, i0, i1; double dt; } job_t;
static inline void rhs(const double *x, double u, const double *p, double *d) {
    double sg = u / sqrt(u * u + SIGN_EPS * SIGN_EPS);
    double z = 1.0 - sg * x[2];
    double mag = (sqrt(fabs(z) + SQRT_DELTA) - sqrt(SQRT_DELTA))
                 / (sqrt(1.0 + SQRT_DELTA) - sqrt(SQRT_DELTA));
    double root = z > 0 ? mag : (z < 0 ? -mag : 0.0);
    d[0] = x[1];
    d[1] = p[3] * x[2] - p[4] * x[1] - p[5] * x[0] - p[6];
    d[2] = p[0] * u * root - p[1] * x[1] - p[2] * x[2];
}
static void *worker(void *arg) {
    job_t *j = (job_t *)arg;
    double h = j->dt / j->nsub;
    for (int i = j->i0; i < j->i1; i++) {
        const double *p = j->P + 7 * i;
        double x[3] = {0, 0, 0}, k1[3], k2[3], k3[3], k4[3], t[3];
        double *y = j->Y + (long)i * j->N;
        for (int k = 0; k < j->N; k++) {
            double u = j->u[k];
            y[k] = x[0] * 57.29577951308232;
            for (int s = 0; s < j->nsub; s++) {
                rhs(x, u, p, k1); for (int q = 0; q < 3; q++) t[q] = x[q] + h / 2 * k1[q];
                rhs(t, u, p, k2); for (int q = 0; q < 3; q++) t[q] = x[q] + h / 2 * k2[q];
                rhs(t, u, p, k3); for (int q = 0; q < 3; q++) t[q] = x[q] + h * k3[q];
                rhs(t, u, p, k4);
                for (int q = 0; q < 3; q++) x[q] += h / 6 * (k1[q] + 2 * k2[q] + 2 * k3[q] + k4[q]);
            }
        }
    }
    return 0;
}
void simulate(const double *P, const double *u, double *Y, int npop, int N, int nsub,
              double dt, int nthreads) {
    pthread_t th[64]; job_t jobs[64];
    int chunk = (npop + nthreads - 1) / nthreads;
    for (int t = 0; t < nthreads; t++) {
        int i0 = t * chunk, i1 = (t + 1) * chunk < npop ? (t + 1) * chunk : npop;
        jobs[t] = (job_t){P, u, Y, N, nsub, i0, i1, dt};
        pthread_create(&th[t], 0, worker, &jobs[t]);
    }
    for (int t = 0; t < nthreads; t++) pthread_join(th[t], 0);
}
"""


def build_c_reference(workdir: Path) -> ctypes.CDLL:
    """Compile the plain C reference with the simulator's compiler and flags."""
    src = workdir / "ref.c"
    src.write_text(C_SOURCE)
    lib = workdir / "ref.so"
    cc = find_compiler()
    if cc is None:
        sys.exit("no C compiler: the benchmark needs one")
    subprocess.run([cc, *CFLAGS, str(src), "-o", str(lib), "-lm"], check=True)
    dll = ctypes.CDLL(str(lib))
    dp = ctypes.POINTER(ctypes.c_double)
    dll.simulate.argtypes = [dp, dp, dp, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                             ctypes.c_double, ctypes.c_int]
    return dll


def solve_ivp_baseline(model: HHRAModel, u: np.ndarray, p: np.ndarray, dt: float) -> np.ndarray:
    """What a user would write by hand: NumPy right-hand side, solve_ivp restarted per sample.

    The right-hand side mirrors the model's equations (the same smoothing as the
    compiled model), so the accuracy comparison is like for like.
    """
    d = model.params.as_dict(p)
    eps, delta = 1e-3, 1e-6
    norm = 1.0 / (np.sqrt(1.0 + delta) - np.sqrt(delta))

    def rhs(_t: float, x: np.ndarray, uk: float) -> np.ndarray:
        z = 1.0 - uk / np.sqrt(uk * uk + eps * eps) * x[2]
        root = np.sign(z) * (np.sqrt(abs(z) + delta) - np.sqrt(delta)) * norm
        return np.array([
            x[1],
            d["g_torque"] * x[2] - d["g_damping"] * x[1] - d["g_spring"] * x[0] - d["g_load"],
            d["g_valve"] * uk * root - d["g_compress"] * x[1] - d["g_leak"] * x[2],
        ])

    x = model.x0()
    y = np.empty(u.size)
    for k, uk in enumerate(u):
        y[k] = np.degrees(x[0])
        sol = solve_ivp(rhs, (0.0, dt), x, method="RK45", rtol=1e-8, atol=1e-10, args=(uk,))
        x = sol.y[:, -1]
    return y


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pop", type=int, default=100)
    ap.add_argument("--samples", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--ivp-samples", type=int, default=500,
                    help="samples of the solve_ivp baseline (timed, then scaled)")
    ap.add_argument("--write", type=Path, default=None, help="write a Markdown report here")
    args = ap.parse_args(argv)

    model = HHRAModel()
    fs = 250.0
    sim = Simulator(model, fs=fs, threads=args.threads)
    scalar = Simulator(model, fs=fs, threads=args.threads, simd=None)
    u = default_input(duration=args.samples / fs, fs=fs, seed=1)[: args.samples]
    rng = np.random.default_rng(0)
    P = model.nominal() * rng.uniform(0.7, 1.3, size=(args.pop, model.n_params))
    P[:, model.params.index("g_spring")] = 0.0
    P[:, model.params.index("g_load")] = 0.0

    t0 = time.perf_counter()
    Y = sim.simulate(u, P)
    t_build = time.perf_counter() - t0
    y_meas = Y[0] + 0.05 * rng.standard_normal(args.samples)
    sim.simulate_cost(u, P, y_meas)
    width = sim.vector_width(args.pop)
    Y_scalar = scalar.simulate(u, P)
    with tempfile.TemporaryDirectory() as tmp:
        ref = build_c_reference(Path(tmp))
        Pc = np.ascontiguousarray(P)
        Yc = np.empty((args.pop, args.samples))
        dp = ctypes.POINTER(ctypes.c_double)

        def run_c() -> None:
            ref.simulate(Pc.ctypes.data_as(dp), u.ctypes.data_as(dp), Yc.ctypes.data_as(dp),
                         args.pop, args.samples, sim.substeps, sim.dt, args.threads)

        run_c()
        t_sim, t_scalar, t_cost, t_c = [], [], [], []
        for _ in range(args.repeats):  # interleaved: the machine's load hits all alike
            t0 = time.perf_counter()
            Y = sim.simulate(u, P)
            t_sim.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            scalar.simulate(u, P)
            t_scalar.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            sim.simulate_cost(u, P, y_meas)
            t_cost.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            run_c()
            t_c.append(time.perf_counter() - t0)
    agree = float(np.nanmax(np.abs(Y - Yc)))
    same = bool(np.array_equal(Y, Y_scalar, equal_nan=True))

    # Accuracy against CVODES on a few members.
    errs = []
    for i in range(3):
        yr = sim.reference(u, P[i])
        errs.append(float(np.max(np.abs(Y[i] - yr))))
    y_ref_nominal = sim.reference(u, model.nominal())
    err_nominal = float(np.max(np.abs(sim.simulate(u, model.nominal()) - y_ref_nominal)))

    n_ivp = min(args.ivp_samples, args.samples)
    t0 = time.perf_counter()
    y_ivp = solve_ivp_baseline(model, u[:n_ivp], model.nominal(), sim.dt)
    t_ivp_one = (time.perf_counter() - t0) * args.samples / n_ivp
    err_ivp = float(np.max(np.abs(y_ivp - y_ref_nominal[:n_ivp])))

    best_sim, best_c = min(t_sim), min(t_c)
    best_scalar, best_cost = min(t_scalar), min(t_cost)
    ivp_pop = t_ivp_one * args.pop

    def ms(ts: list[float]) -> str:
        return f"{1e3 * min(ts):.1f} ms per population (median {1e3 * float(np.median(ts)):.1f})"

    lines = [
        f"machine: {platform.processor() or platform.machine()}, {args.threads} threads, "
        f"python {platform.python_version()}",
        f"population {args.pop}, samples {args.samples}, RK4 substeps {sim.substeps}, "
        f"block {sim.block}, native={sim.native}, SIMD width {width} "
        f"({' '.join(sim.simd.flags) if sim.simd else 'off'})",
        f"first call (build + compile or load from cache): {t_build:.2f} s",
        f"Simulator, vector code:  {ms(t_sim)}",
        f"Simulator, scalar code:  {ms(t_scalar)}",
        f"Simulator.simulate_cost: {ms(t_cost)}",
        f"plain C RK4 loop:        {ms(t_c)}",
        f"ratio scalar Simulator / plain C: {best_scalar / best_c:.3f}  (target <= 1.25)",
        f"ratio vector Simulator / plain C: {best_sim / best_c:.3f}",
        f"ratio simulate_cost / plain C:    {best_cost / best_c:.3f}",
        f"vector and scalar outputs identical: {same}; "
        f"max |Simulator - plain C| = {agree:.2e} deg",
        f"solve_ivp restarted per sample: {t_ivp_one:.2f} s per simulation "
        f"(timed on {n_ivp} samples), {ivp_pop:.1f} s per population; "
        f"ratio solve_ivp / Simulator: {ivp_pop / best_sim:.0f}",
        f"integration error vs CVODES (max abs, deg): nominal {err_nominal:.2e}, "
        f"population members {', '.join(f'{e:.2e}' for e in errs)}; solve_ivp {err_ivp:.2e}",
    ]
    print("\n".join(lines))
    if args.write:
        write_report(args.write, lines, argv)
    return 0


def write_report(path: Path, lines: list[str], argv: list[str] | None) -> None:
    """Replace the simulator section of the performance report with these results."""
    cmd = "python benchmarks/bench_simulator.py " + " ".join(argv or sys.argv[1:])
    section = (
        "<!-- bench_simulator:start -->\n"
        f"Command: `{cmd.strip()}`\n\n```\n"  # docs/ carry no dates: the notes do
        + "\n".join(lines)
        + "\n```\n<!-- bench_simulator:end -->"
    )
    text = path.read_text() if path.exists() else "# Performance\n\n"
    start, end = "<!-- bench_simulator:start -->", "<!-- bench_simulator:end -->"
    if start in text and end in text:
        text = text[: text.index(start)] + section + text[text.index(end) + len(end):]
    else:
        text = text.rstrip() + "\n\n" + section + "\n"
    path.write_text(text)
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
