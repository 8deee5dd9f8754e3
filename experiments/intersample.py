"""Inter-sample behaviour: holding an input that moved between samples, and the foh fix.

Records: :func:`hhra_phys.reference.resonant.multisine_resonator_record`, a lightly
damped resonator (10 Hz, damping 0.05) driven by a continuous 60-line multisine up to
twice its natural frequency, integrated with the continuous input and sampled at
``--spp`` samples per resonance period (default 9), white noise ``--noise`` V; one
record with a hidden cubic stiffening of the spring (``--cubic``, 1/V^2) and one
linear. Each record is split 50/50 (estimation, test) and fitted with the resonator
model of :mod:`hhra_phys.models.resonator` (``make_model``: linear; with
``cubic=True`` the model that has the hidden term) under each inter-sample behaviour,
``zoh`` (what a plain CSV is read as), ``foh`` (input linear between samples) and
``cubic`` (cubic convolution through four samples). Printed and written
(``--json``) per seed: test RMSE of every fit and its ratio to the noise, the fitted
parameters, and the loop's candidate (:func:`hhra_phys.intersample.refit_with_hold`
from the zoh fit: signature and selection RMSE with foh). ``--figure`` draws seed 1:
a stretch of the test part with every hold's simulation and residual, and the test
RMSE over the noise for every seed. ``--records DIR`` writes the cubic records as CSV
(side-car without an inter-sample property, so they read as zoh) for
``hhra-phys diagnose``. ``--hhra`` instead checks the signature where the input was
held: HHRA records (the package's rig, and reference-rig records clean, with a hidden
two-sample input delay, and with a valve current linear between samples but read as
held), 8 s each, fitted with the HHRA (H-GWO 20 x 20, IPOPT) as zoh.

    python experiments/intersample.py [--seeds 1 2 3 4 5] [--spp 9] [--noise 0.05]
        [--cubic 0.003] [--json experiments/results/intersample_study.json]
        [--figure docs/figures/intersample_fit.png] [--records DIR]
    python experiments/intersample.py --hhra
    python experiments/intersample.py --floor [--bands 1.25 1.5 2] [--spps 8 9 10]

``--floor`` fits nothing with the package: it computes, with scipy alone, how much of
the noise-free output of the linear record each hold leaves unexplained at its best
parameters (the hold's own interpolation error, see :func:`floor`).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from hhra_phys.data import save
from hhra_phys.fit import fit
from hhra_phys.intersample import hold_suspected, refit_with_hold
from hhra_phys.models.resonator import make_model
from hhra_phys.outputs import atomic_write_text, jsonable
from hhra_phys.reference.resonant import multisine_resonator_record


def _fit(ds: Any, cubic: bool, kind: str, seed: int, pop: int, iters: int) -> Any:
    est, test = ds.with_intersample(kind).split(0.5)
    model = make_model(ds, cubic=cubic)
    return fit(est, model, validation=test, cost="mse", pop_size=pop, max_iter=iters,
               seed=seed), test


def run_seed(seed: int, args: argparse.Namespace) -> dict[str, Any]:
    out: dict[str, Any] = {"seed": seed, "records": {}}
    for label, cubic in (("cubic", args.cubic), ("linear", 0.0)):
        ds = multisine_resonator_record(seed=seed, samples_per_period=args.spp, cubic=cubic,
                                        noise=args.noise, periods=args.periods)
        if args.records and cubic > 0:
            save(ds, Path(args.records) / f"multisine_resonator_seed{seed}.csv", overwrite=True)
        rec: dict[str, Any] = {"truth": ds.metadata["truth"] | {"multisine": "omitted"},
                               "fits": {}}
        models = (("linear", False), ("cubic", True)) if cubic > 0 else (("linear", False),)
        for mname, with_cubic in models:
            for kind in ("zoh", "foh", "cubic"):
                t0 = time.perf_counter()
                res, test = _fit(ds, with_cubic, kind, seed, args.pop, args.iters)
                rmse = float(res.metrics["val"]["rmse"])
                rec["fits"][f"{mname}/{kind}"] = {
                    "test_rmse": rmse, "over_noise": rmse / args.noise,
                    "values": res.values, "seconds": time.perf_counter() - t0}
                if kind == "zoh":
                    # The loop's candidate: same model, other hold, judged on selection
                    # (here the test part stands in for the selection part).
                    cand = refit_with_hold(res, res.problem, test)
                    rec["fits"][f"{mname}/zoh"]["candidate"] = {
                        "signature": cand.signature,
                        "suspected": hold_suspected(cand.signature),
                        "rmse_before": cand.rmse_before["selection"],
                        "rmse_foh": cand.rmse("selection")}
        out["records"][label] = rec
    return out


def _print(r: dict[str, Any], noise: float) -> None:
    for label, rec in r["records"].items():
        for key, f in rec["fits"].items():
            line = (f"seed {r['seed']} {label:6s} record, {key:10s}: test RMSE "
                    f"{f['test_rmse']:.4f} V = {f['over_noise']:5.2f} x noise")
            if "candidate" in f:
                c = f["candidate"]
                line += (f" | lead {c['signature']['lead']:+.2f} samples, explains "
                         f"{100 * c['signature']['explained']:.0f} %, suspected "
                         f"{c['suspected']}, foh candidate {c['rmse_foh']:.4f}")
            print(line, flush=True)


def figure(path: str, results: list[dict[str, Any]], args: argparse.Namespace) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seed = results[0]["seed"]
    ds = multisine_resonator_record(seed=seed, samples_per_period=args.spp, cubic=args.cubic,
                                    noise=args.noise, periods=args.periods)
    fig, axes = plt.subplots(3, 1, figsize=(8, 8.5))
    ax0, ax1, ax2 = axes
    sims = {}
    for kind in ("zoh", "foh", "cubic"):
        res, test = _fit(ds, True, kind, seed, args.pop, args.iters)
        sims[kind] = res.predict(test)
    t = test.t
    span = slice(200, 290)  # ten resonance periods of the test part
    ax0.plot(t[span], test.y[span], "k.", ms=4, label="measured (samples)")
    for kind, style in (("zoh", "C3-"), ("foh", "C0-"), ("cubic", "C2--")):
        ax0.plot(t[span], sims[kind][span], style, lw=1,
                 label=f"model with the cubic spring, {kind} hold")
        ax1.plot(t[span], (test.y - sims[kind])[span], style, lw=1, label=f"{kind} hold")
    ax1.axhspan(-args.noise, args.noise, color="0.85", label="+-1 noise std")
    ax0.set_ylabel("response [V]")
    ax0.set_title(f"seed {seed}, {args.spp:g} samples per resonance period, test part")
    ax0.legend(fontsize=8, loc="upper right")
    ax1.set_ylabel("residual [V]")
    ax1.set_xlabel("t [s]")
    ax1.legend(fontsize=8, loc="upper right")
    keys = [("cubic", "cubic/zoh"), ("cubic", "cubic/foh"), ("cubic", "cubic/cubic"),
            ("cubic", "linear/zoh"), ("cubic", "linear/foh"), ("linear", "linear/zoh"),
            ("linear", "linear/foh"), ("linear", "linear/cubic")]
    width = 0.8 / len(keys)
    for j, (rec, key) in enumerate(keys):
        vals = [r["records"][rec]["fits"][key]["over_noise"] for r in results]
        model, kind = key.split("/")
        ax2.bar(np.arange(len(results)) + j * width, vals, width,
                label=f"{rec} record, {model} model, {kind} hold")
    ax2.axhline(1.0, color="k", lw=0.8)
    ax2.set_yscale("log")
    ax2.set_ylim(0.5, 300)  # room for the legend above the bars
    ax2.set_xticks(np.arange(len(results)) + 0.4 - width / 2)
    ax2.set_xticklabels([f"seed {r['seed']}" for r in results])
    ax2.set_ylabel("test RMSE / noise std")
    ax2.legend(fontsize=7, ncol=2, loc="upper center")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def hhra_signatures() -> None:
    """Print the hold signature of zoh fits of HHRA records (``--hhra``)."""
    from hhra_phys.intersample import hold_signature
    from hhra_phys.models.hhra.rig import simulate_rig
    from hhra_phys.reference import reference_record

    records = (
        ("package rig, seed 0", simulate_rig(seed=0, duration=8.0)),
        ("reference rig, seed 2", reference_record(seed=2, duration=8.0)),
        ("reference rig, 2-sample input delay, seed 1",
         reference_record(seed=1, duration=8.0, effects={"input_delay": {"delay": 2.0}})),
        ("reference rig, current linear between samples, seed 3",
         reference_record(seed=3, duration=8.0, intersample="foh").with_intersample("zoh")),
        # Missing effects: their residuals follow the output's curvature at order one.
        ("reference rig, dead zone 0.1 mA, seed 1",
         reference_record(seed=1, duration=8.0, effects={"valve_deadzone": {"i_dead": 0.1}})),
        ("reference rig, backlash 1.5 deg, seed 1",
         reference_record(seed=1, duration=8.0, effects={"backlash": {"play": 1.5}})),
        ("reference rig, Coulomb friction 30, seed 2",
         reference_record(seed=2, duration=8.0,
                          effects={"coulomb_friction": {"g_coulomb": 30.0}})),
    )
    for name, ds in records:
        res = fit(ds, pop_size=20, max_iter=20, seed=0)
        pr = res.problem
        values = np.array([res.values[n] if n in res.values else res.x0_param(n)
                           for n in pr.free_names])
        sig = hold_signature(pr.data.y, pr.simulate_values(values))
        print(f"{name}: lead {sig['lead']:+.3f} samples, explains "
              f"{100 * sig['explained']:.1f} %; curvature {sig['curvature']:+.3f} samples^2, "
              f"explains {100 * sig['curvature_explained']:.2f} %; suspected "
              f"{hold_suspected(sig)}, "
              f"selection RMSE {res.metrics['val']['rmse']:.4f} deg", flush=True)


def _lsim(p: np.ndarray, u: np.ndarray, fs: float, kind: str) -> np.ndarray:
    """The linear resonator driven by ``u`` read as ``kind``, by scipy (not the package).

    ``zoh`` and ``foh`` are exact (``lsim`` with a held or a linear input); ``cubic``
    evaluates the cubic convolution at 20 points per sample and integrates the
    piecewise-linear input through them (exact up to that resampling).
    """
    from scipy import signal as sps

    g, w, z = p
    lti = sps.lti([g * w * w], [1.0, 2 * z * w, w * w])
    t = np.arange(u.size) / fs
    if kind in ("zoh", "foh"):
        return sps.lsim(lti, u, t, interp=kind == "foh")[1]
    k = 20
    up = np.concatenate([[u[0]], u, [u[-1], u[-1]]])
    s = np.arange(k) / k
    p0, p1, p2, p3 = up[:-3, None], up[1:-2, None], up[2:-1, None], up[3:, None]
    fine = (p1 + 0.5 * (p2 - p0) * s + (p0 - 2.5 * p1 + 2 * p2 - 0.5 * p3) * s ** 2
            + 0.5 * (3 * p1 - p0 - 3 * p2 + p3) * s ** 3).ravel()
    return sps.lsim(lti, fine, np.arange(fine.size) / (fs * k), interp=True)[1][::k]


def floor(args: argparse.Namespace) -> list[dict[str, Any]]:
    """Each hold's own error on noise-free linear records: the best fit's residual.

    The linear resonator is fitted (least squares from the truth, 100 samples of
    start-up skipped) to the noise-free output under each hold, computed by scipy
    alone: what remains is the hold's interpolation error that no gain, frequency or
    damping absorbs, the floor of a fit's error. Over the noise it gives the test
    RMSE ratio a perfect fit would reach, ``sqrt(1 + (floor / noise)^2)``.
    """
    from scipy.optimize import least_squares

    truth = np.array([1.0, 2 * np.pi * 10.0, 0.05])
    rows = []
    for band in args.bands:
        for spp in args.spps:
            for seed in args.seeds:
                ds = multisine_resonator_record(seed=seed, samples_per_period=spp, noise=0.0,
                                                periods=args.periods, band=band)
                row = {"band": band, "spp": spp, "seed": seed,
                       "output_rms": float(np.std(ds.y))}
                for kind in ("foh", "cubic"):
                    sol = least_squares(
                        lambda q, k=kind, d=ds: (_lsim(q, d.u, d.fs, k) - d.y)[100:], truth,
                        x_scale=truth)
                    err = float(np.sqrt(np.mean(sol.fun ** 2)))
                    row[kind] = {"floor": err, "values": sol.x.tolist(),
                                 "over_noise": float(np.hypot(1.0, err / args.noise))}
                rows.append(row)
                print(f"band {band:g} f_n, {spp:g} samples per period, seed {seed}: output RMS "
                      f"{row['output_rms']:.3f} V; foh floor {row['foh']['floor']:.4f} V "
                      f"({row['foh']['over_noise']:.3f} x noise {args.noise:g}), gain "
                      f"{row['foh']['values'][0]:.4f}; cubic floor {row['cubic']['floor']:.4f} V "
                      f"({row['cubic']['over_noise']:.3f} x)", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--spp", type=float, default=9.0, help="samples per resonance period")
    ap.add_argument("--periods", type=float, default=240.0, help="record length in periods")
    ap.add_argument("--noise", type=float, default=0.05, help="output noise std [V]")
    ap.add_argument("--cubic", type=float, default=0.003, help="hidden cubic stiffening [1/V^2]")
    ap.add_argument("--pop", type=int, default=24, help="H-GWO population")
    ap.add_argument("--iters", type=int, default=40, help="H-GWO iterations")
    ap.add_argument("--json", default=None, help="write the results here")
    ap.add_argument("--figure", default=None, help="write the figure here (.png)")
    ap.add_argument("--records", default=None, help="write the cubic records (CSV) here")
    ap.add_argument("--hhra", action="store_true",
                    help="only the signature on HHRA records whose input was held")
    ap.add_argument("--floor", action="store_true",
                    help="only each hold's own error on noise-free linear records (scipy)")
    ap.add_argument("--bands", type=float, nargs="+", default=[2.0],
                    help="--floor: highest multisine line over f_n")
    ap.add_argument("--spps", type=float, nargs="+", default=[9.0],
                    help="--floor: samples per resonance period")
    args = ap.parse_args(argv)
    if args.floor:
        rows = floor(args)
        if args.json:
            atomic_write_text(Path(args.json), json.dumps(
                jsonable({"settings": vars(args), "loadavg": os.getloadavg(),
                          "rows": rows}), indent=1) + "\n")
        return 0
    if args.hhra:
        hhra_signatures()
        return 0
    if not (args.spp > 2 and args.noise > 0 and args.cubic >= 0 and args.periods > 10):
        ap.error("--spp must exceed 2, --noise be positive, --cubic >= 0, --periods > 10")
    if args.records:
        Path(args.records).mkdir(parents=True, exist_ok=True)
    results = []
    for seed in args.seeds:
        r = run_seed(seed, args)
        _print(r, args.noise)
        results.append(r)
    if args.json:
        atomic_write_text(Path(args.json), json.dumps(
            jsonable({"settings": vars(args), "results": results}), indent=1) + "\n")
    if args.figure:
        figure(args.figure, results, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
