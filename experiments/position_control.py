"""Position control of the HHRA designed on a fitted model (docs/control.md).

1. Fit the physical model to the simulated rig (seed 0, 20 s at 250 Hz, 0.05 deg noise).
2. Linearise the fit at rest (``hhra_phys.control.linearize``) and design, at 250 Hz,

   * **A: P + notch**: a notch on the fitted hydraulic resonance (zeros on the fitted poles,
     poles at damping 0.7), the largest gain with gain margin >= 12 dB and phase margin >= 60
     deg on the design model, Tustin-discretised with prewarping at the resonance;
   * **B: pole placement**: discrete state feedback on the zero-order-hold model with
     closed-loop poles at ``s = -30 +- 30j, -90`` [1/s] and a predictor observer three times
     faster; the observer is fed the *applied* (limited) current, so it stays right when the
     valve saturates (a callable controller).

3. Check margins across 200 linear models drawn from the fit's covariance.
4. Run both designs, valve current limited to +-2 mA, on the linear design model, on the
   nonlinear fitted model and on the rig's truth: a 2 deg step (linear range), a 30 deg step
   (saturating) and a 15 deg, 0.5 Hz sine; report rise time, overshoot, steady-state error,
   tracking error and the largest design-model vs nonlinear difference.

Writes ``summary.json`` to ``--out`` (default ``out/control``) and the figures
``control_bode_family.png``, ``control_steps.png``, ``control_tracking.png`` to ``--figures``
(default: the ``--out`` directory). The numbers in docs/control.md come from::

    python experiments/position_control.py --figures docs/figures
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import control as ct
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hhra_phys import control as hc  # noqa: E402
from hhra_phys.fit import fit  # noqa: E402
from hhra_phys.models.hhra.rig import rig_model, simulate_rig  # noqa: E402

DT = 0.004  # controller period [s]: the rig's 250 Hz
CURRENT_LIMIT = 2.0  # [mA]
MIN_GM_DB, MIN_PM_DEG = 12.0, 60.0
POLES_B = np.array([-30 + 30j, -30 - 30j, -90.0])  # [1/s]
OBSERVER_SPEEDUP = 3.0


def resonance(sys: ct.StateSpace) -> tuple[float, float]:
    """Natural frequency [rad/s] and damping of the complex pole pair of ``sys``."""
    ev = np.linalg.eigvals(sys.A)
    pole = ev[np.argmax(ev.imag)]
    wn = abs(pole)
    return float(wn), float(-pole.real / wn)


def design_notch(plant: ct.StateSpace) -> tuple[ct.TransferFunction, float]:
    """P + notch: the largest gain meeting the margin targets on ``plant``."""
    wn, zeta = resonance(plant)
    notch = ct.tf([1, 2 * zeta * wn, wn**2], [1, 2 * 0.7 * wn, wn**2])
    best = None
    for gain in np.arange(0.05, 3.0, 0.01):
        c = (gain * notch).sample(DT, "tustin", prewarp_frequency=wn)
        m = hc.loop_margins(plant, c)
        if m["gm"][0] >= MIN_GM_DB and m["pm"][0] >= MIN_PM_DEG and m["stable"][0]:
            best = (c, float(gain))
        else:
            break
    if best is None:
        raise RuntimeError("no gain meets the margin targets")
    return best


class ObserverFeedback:
    """Discrete state feedback with a predictor observer, ``u = -K xhat + N r``.

    A callable controller for :class:`hhra_phys.control.ClosedLoop`; it clips its own output
    to the valve limit and feeds the clipped current to the observer (so a saturating valve
    does not corrupt the estimate).
    """

    def __init__(self, plant_d: ct.StateSpace, poles_s: np.ndarray, limit: float) -> None:
        self.A, self.B, self.C = (np.asarray(m) for m in (plant_d.A, plant_d.B, plant_d.C))
        dt = float(plant_d.dt)
        self.K = ct.place(self.A, self.B, np.exp(poles_s * dt))
        self.L = ct.place(self.A.T, self.C.T, np.exp(OBSERVER_SPEEDUP * poles_s * dt)).T
        # theta is state 0 and y = (180/pi) theta: N makes the DC gain from r to y one.
        self.N = float(self.K[0, 0] / self.C[0, 0])
        self.limit = limit
        self.reset()

    def reset(self) -> None:
        self.x = np.zeros(self.A.shape[0])

    def __call__(self, t: float, r: float, y: float) -> float:
        u = float(np.clip(-self.K[0] @ self.x + self.N * r, -self.limit, self.limit))
        innovation = y - float(self.C[0] @ self.x)
        self.x = self.A @ self.x + self.B[:, 0] * u + self.L[:, 0] * innovation
        return u

    def as_lti(self) -> ct.StateSpace:
        """The unclipped controller as a discrete system with inputs ``[r, y]``."""
        A = self.A - self.B @ self.K - self.L @ self.C
        B = np.column_stack([self.B[:, 0] * self.N, self.L[:, 0]])
        return ct.ss(A, B, -self.K, [[self.N, 0.0]], dt=DT)


def run_all(args: argparse.Namespace) -> dict:
    out: dict = {"settings": vars(args).copy()}
    t0 = time.perf_counter()
    data = simulate_rig(seed=args.seed)
    res = fit(data, pop_size=args.pop, max_iter=args.iters, seed=args.seed)
    out["fit"] = {"seconds": time.perf_counter() - t0, "values": res.values, "ci95": res.ci95,
                  "val": res.metrics["val"], "tf": res.tf}
    truth_model, truth_p = rig_model()
    plant = hc.linearize(res)
    truth_lin = hc.linearize(truth_model, params=truth_p)
    wn, zeta = resonance(plant)
    wn_t, zeta_t = resonance(truth_lin)
    out["plant"] = {"wn": wn, "zeta": zeta, "wn_truth": wn_t, "zeta_truth": zeta_t,
                    "velocity_gain_deg_s_mA": res.tf["kv"] / res.tf["c"] * 180 / math.pi}

    ctrl_a, gain_a = design_notch(plant)
    plant_d = hc.discretize(plant, DT, "zoh")
    ctrl_b = ObserverFeedback(plant_d, POLES_B, CURRENT_LIMIT)
    lti_b = ctrl_b.as_lti()
    loop_b = -lti_b[0, 1]  # the y -> u channel, as a controller acting on r - y
    out["designs"] = {"A": {"gain_mA_per_deg": gain_a}, "B": {"K": ctrl_b.K.tolist(),
                      "L": ctrl_b.L.ravel().tolist(), "N": ctrl_b.N}}

    # Margins on the design model, on the truth and across the uncertainty family.
    family = hc.sample_models(res, args.samples, seed=args.seed)
    for name, c in (("A", ctrl_a), ("B", loop_b)):
        nom = hc.loop_margins(plant, c)
        tru = hc.loop_margins(truth_lin, c)
        fam = hc.loop_margins(family, c)
        out["designs"][name]["margins"] = {
            "design": {k: float(v[0]) for k, v in nom.items()},
            "truth": {k: float(v[0]) for k, v in tru.items()},
            "family": {"gm_min": float(fam["gm"].min()), "gm_median": float(np.median(fam["gm"])),
                       "pm_min": float(fam["pm"].min()), "pm_median": float(np.median(fam["pm"])),
                       "sm_min": float(fam["sm"].min()), "sm_median": float(np.median(fam["sm"])),
                       "stable_fraction": float(fam["stable"].mean())},
        }

    # Closed-loop runs.
    plants = {"design": (plant, None), "fitted": (res, None), "truth": (truth_model, truth_p)}
    refs = {
        "step2": np.full(int(1.5 / DT) + 1, 2.0),
        "step30": np.full(int(2.0 / DT) + 1, 30.0),
        "sine": 15.0 * np.sin(2 * math.pi * 0.5 * np.arange(int(4.0 / DT) + 1) * DT),
    }
    runs: dict = {}
    out["runs"] = {}
    for dname, ctrl in (("A", ctrl_a), ("B", ctrl_b)):
        for pname, (pl, params) in plants.items():
            loop = hc.ClosedLoop(pl, ctrl, DT, params=params, current_limit=CURRENT_LIMIT)
            for rname, r in refs.items():
                if isinstance(ctrl, ObserverFeedback):
                    ctrl.reset()
                resp = loop.run(r)
                runs[dname, pname, rname] = resp
                entry = (resp.step_info() if rname.startswith("step")
                         else resp.tracking_error(skip=1.0))
                entry["peak_current"] = float(np.max(np.abs(resp.u)))
                out["runs"][f"{dname}/{pname}/{rname}"] = entry
        for pname in ("fitted", "truth"):
            for rname in refs:
                d = np.max(np.abs(runs[dname, pname, rname].y - runs[dname, "design", rname].y))
                out["runs"][f"{dname}/{pname}/{rname}"]["max_diff_vs_design"] = float(d)
    out["seconds"] = time.perf_counter() - t0

    figs = Path(args.figures or args.out)
    figs.mkdir(parents=True, exist_ok=True)
    plot_family(figs / "control_bode_family.png", plant, truth_lin, family[:60], ctrl_a, loop_b)
    plot_runs(figs / "control_steps.png", runs, ("step2", "step30"))
    plot_runs(figs / "control_tracking.png", runs, ("sine",))
    return out


def plot_family(path: Path, plant, truth, family, ctrl_a, loop_b) -> None:
    w = np.logspace(0, 2.6, 400)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for sys, style in [(s, dict(color="0.7", lw=0.6)) for s in family] + [
            (plant, dict(color="C0", lw=1.8, label="fitted")),
            (truth, dict(color="k", ls="--", lw=1.2, label="truth"))]:
        g = sys(1j * w).ravel()
        axes[0, 0].semilogx(w, 20 * np.log10(np.abs(g)), **style)
        axes[1, 0].semilogx(w, np.degrees(np.unwrap(np.angle(g))), **style)
        for j, c in enumerate((ctrl_a, loop_b)):
            sd = hc.discretize(ct.ss(sys), DT)
            cl = ct.feedback(c * sd, 1)
            resp = ct.step_response(cl, np.arange(0, 1.0, DT))
            axes[j, 1].plot(resp.time, resp.outputs.ravel(), **style)
    axes[0, 0].set_ylabel("|G| [dB deg/mA]")
    axes[1, 0].set_ylabel("phase [deg]")
    axes[1, 0].set_xlabel("frequency [rad/s]")
    axes[0, 0].legend()
    axes[0, 0].set_title(f"plant: fitted, truth and {len(family)} draws from the fit's covariance")
    axes[0, 1].set_title("A: P + notch, unit step (linear)")
    axes[1, 1].set_title("B: pole placement (loop y -> u), unit step (linear)")
    axes[1, 1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_runs(path: Path, runs: dict, refs: tuple[str, ...]) -> None:
    fig, axes = plt.subplots(2, 2 * len(refs), figsize=(6 * len(refs) + 4, 6), squeeze=False)
    for i, rname in enumerate(refs):
        for j, dname in enumerate(("A", "B")):
            ax, axu = axes[0, 2 * i + j], axes[1, 2 * i + j]
            for pname, style in (("design", dict(color="C0", lw=1.5)),
                                 ("fitted", dict(color="C1", lw=1.2)),
                                 ("truth", dict(color="k", ls="--", lw=1.0))):
                resp = runs[dname, pname, rname]
                ax.plot(resp.t, resp.y, label=pname, **style)
                axu.plot(resp.t, resp.u, **style)
            ax.plot(resp.t, resp.r, color="0.6", lw=0.8, label="reference")
            ax.set_title(f"{'P + notch' if dname == 'A' else 'pole placement'}: {rname}")
            ax.set_ylabel("angle [deg]")
            axu.set_ylabel("current [mA]")
            axu.set_xlabel("time [s]")
    axes[0, 0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(out: dict) -> str:
    lines = ["| design | plant | reference | rise [s] | overshoot [%] | ss error [deg] "
             "| RMS / max error [deg] | peak I [mA] | max diff vs design [deg] |",
             "|---|---|---|---|---|---|---|---|---|"]
    for key, e in out["runs"].items():
        d, p, r = key.split("/")
        rise = f"{e['rise_time']:.3f}" if "rise_time" in e else ""
        ov = f"{e['overshoot']:.1f}" if "overshoot" in e else ""
        ss = f"{e['steady_state_error']:+.4f}" if "steady_state_error" in e else ""
        tr = f"{e['rms']:.3f} / {e['max']:.3f}" if "rms" in e else ""
        diff = f"{e['max_diff_vs_design']:.4f}" if "max_diff_vs_design" in e else ""
        lines.append(f"| {d} | {p} | {r} | {rise} | {ov} | {ss} | {tr} | "
                     f"{e['peak_current']:.2f} | {diff} |")
    lines += ["", "| design | model | GM [dB] | PM [deg] | vector margin min 1+L "
              "| crossover [rad/s] / stable |", "|---|---|---|---|---|---|"]
    for d, info in out["designs"].items():
        for which in ("design", "truth"):
            m = info["margins"][which]
            lines.append(f"| {d} | {which} | {m['gm']:.1f} | {m['pm']:.1f} | {m['sm']:.3f} "
                         f"| {m['wcp']:.2f} |")
        f = info["margins"]["family"]
        lines.append(f"| {d} | family (min / median) | {f['gm_min']:.1f} / {f['gm_median']:.1f} "
                     f"| {f['pm_min']:.1f} / {f['pm_median']:.1f} "
                     f"| {f['sm_min']:.3f} / {f['sm_median']:.3f} | stable "
                     f"{100 * f['stable_fraction']:.0f} % |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/control", help="output directory (summary.json)")
    ap.add_argument("--figures", default=None, help="directory of the figures (default --out)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pop", type=int, default=40, help="global-search population")
    ap.add_argument("--iters", type=int, default=40, help="global-search iterations")
    ap.add_argument("--samples", type=int, default=200, help="models drawn from the covariance")
    args = ap.parse_args(argv)
    out = run_all(args)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "summary.json").write_text(json.dumps(out, indent=1, default=float))
    print(f"fit {out['fit']['seconds']:.1f} s, total {out['seconds']:.1f} s")
    print(json.dumps({"plant": out["plant"], "designs": {k: {kk: vv for kk, vv in v.items()
                      if kk != "margins"} for k, v in out["designs"].items()}}, indent=1))
    print(markdown(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
