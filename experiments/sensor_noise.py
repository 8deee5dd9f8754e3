"""A sensor that is not ideal adds nothing: the loop on records with coloured noise,
quantisation and drift, and a hidden effect under coloured noise.

Records come from the independent reference implementation
(:func:`hhra_phys.reference.reference_record`, 8 s at 250 Hz, 4-level excitation),
whose physics the base HHRA model covers, measured by a sensor that is not ideal:

* ``white``: Gaussian noise 0.05 deg (the control);
* ``ar``: AR(1) noise with coefficient 0.9, standard deviation 0.05 deg;
* ``quant``: a 12-bit encoder (``360/4096`` deg steps) over 0.01 deg white noise;
* ``drift``: white noise 0.05 deg and a drift of 0.2 deg over the record;
* ``ar+valve_deadzone`` (and other ``ar+EFFECT``): AR(1) 0.9 noise and a hidden
  library effect the loop must still find.

:func:`hhra_phys.loop.augment` then runs with the three-way split, library effects
only (``--discover`` adds discovery), base fit pop 20 x 30 iterations. Per record:
what was added, the noise level the loop used against the true sensor noise, the
earlier difference estimate, selection and test RMSE, why it stopped and the time.
``--estimator difference`` swaps the earlier estimator (sample-to-sample
differences) back in at the loop's call sites, to measure the change.

    python experiments/sensor_noise.py [--seeds 5] [--estimator spectral|difference]
        [--cases white,ar,quant,drift,ar+valve_deadzone] [--discover]
        [--out FILE.json]

``--estimates FIGURE.png`` runs no loop: for every case (and ``white+EFFECT``) and seed
the base HHRA is fitted once (pop 20 x 30, estimation half) and both noise estimates of
its estimation residual are compared with what the sensor added; the figure shows
the ratios and, for two residuals, the input-free periodogram under which the noise
model is fitted (JSON beside the figure).

``--coverage`` runs no loop either: the base fit of clean records with white and with
AR(1) 0.9 noise, per seed, and how often its 95 % intervals hold the true parameters.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings

import numpy as np

from hhra_phys.diagnosis import discovery, residual, stopping
from hhra_phys.diagnosis.engine import augment
from hhra_phys.noise import difference_level, noise_level
from hhra_phys.outputs import atomic_write_text, check_output_path, jsonable
from hhra_phys.reference import reference_record

#: Sensor of each clean case: keyword arguments of reference_record.
SENSORS: dict[str, dict[str, float]] = {
    "white": {"noise_deg": 0.05},
    "ar": {"noise_deg": 0.05, "noise_ar": 0.9},
    "quant": {"noise_deg": 0.01, "quantization": 360.0 / 4096},
    "drift": {"noise_deg": 0.05, "drift_deg": 0.2},
}
#: Hidden effects for ``ar+EFFECT`` cases (small sizes of experiments/closed_loop.py).
EFFECTS: dict[str, dict[str, float]] = {
    "valve_deadzone": {"i_dead": 0.05},
    "gravity_load": {"g_grav_cos": 3.0, "g_grav_sin": -4.0},
    "coulomb_friction": {"g_coulomb": 30.0},
    "input_delay": {"delay": 4.0},
}


def make_record(case: str, seed: int, duration: float):
    """The record of a case (sensor, and the hidden effect after ``+``)."""
    sensor, _, effect = case.partition("+")
    effects = {effect: EFFECTS[effect]} if effect else None
    return reference_record(seed=seed, duration=duration, levels=4, effects=effects,
                            **SENSORS[sensor])


def _use_difference() -> None:
    """Swap the earlier estimator in at the loop's call sites (for comparison only)."""
    def old(residual, inputs=None, **_):
        return difference_level(residual)
    stopping.noise_level = old
    discovery.noise_level = old
    residual.noise_level = old


def run_case(case: str, seed: int, duration: float, loop_kw: dict) -> dict:
    ds = make_record(case, seed, duration)
    clean = reference_record(seed=seed, duration=duration, levels=4,
                             effects={case.split("+")[1]: EFFECTS[case.split("+")[1]]}
                             if "+" in case else None, noise_deg=0.0)
    sensor = ds.y - clean.y  # what the sensor added (noise, quantisation, drift)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = augment(ds, seed=seed, **loop_kw)
    hidden = case.split("+")[1] if "+" in case else None
    # The base fit's estimation residual: both estimates against the sensor's own size.
    prob = res.base.problem
    yb = res.base.simulate(prob.data.u, x0=res.base.x0) if prob is not None else None
    est = {}
    if yb is not None and np.all(np.isfinite(yb)):
        r = prob.data.y - yb
        est = {"spectral": noise_level(r, (prob.data.u, yb)), "difference": difference_level(r),
               "rmse": float(np.sqrt(np.mean(r ** 2)))}
    n_est = len(prob.data) if prob is not None else int(0.5 * len(ds))
    return {
        "case": case, "seed": seed, "hidden": hidden, "chosen": res.chosen,
        "added": [n for n in res.chosen if n != hidden],
        "found": bool(hidden and hidden in res.chosen),
        "sensor_std": float(np.std(sensor[:n_est])),
        "base_estimates": est,
        "noise_levels": res.settings.get("noise_levels"),
        "base_val": res.base.metrics["val"]["rmse"], "final_val": res.final.metrics["val"]["rmse"],
        "base_test": res.test_scores.get("base", {}).get("rmse"),
        "final_test": res.test_scores.get("final", {}).get("rmse"),
        "stop": res.settings.get("stop"),
        "steps": [{"round": s.round, "effect": s.effect, "action": s.action,
                   "reason": s.reason} for s in res.steps],
        "seconds": time.perf_counter() - t0,
    }


def estimates(cases: list[str], seeds: list[int], duration: float, figure: str) -> None:
    """Both noise estimates of base-fit residuals against the sensor's own noise (no loop)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hhra_phys.fit import fit
    from hhra_phys.models.hhra import HHRAModel
    from hhra_phys.noise import fit_noise_model, noise_spectrum

    rows, examples = [], {}
    for case in cases:
        for seed in seeds:
            ds = make_record(case, seed, duration)
            effect = case.partition("+")[2]
            clean = reference_record(seed=seed, duration=duration, levels=4, noise_deg=0.0,
                                     effects={effect: EFFECTS[effect]} if effect else None)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                res = fit(ds, HHRAModel(), pop_size=20, max_iter=30, seed=seed, split=0.5)
            pr = res.problem
            y = res.simulate(pr.data.u, x0=res.x0)
            r = pr.data.y - y
            sensor = float(np.std((ds.y - clean.y)[:len(pr.data)]))
            row = {"case": case, "seed": seed, "sensor_std": sensor,
                   "rmse": float(np.sqrt(np.mean(r ** 2))),
                   "spectral": noise_level(r, (pr.data.u, y)), "difference": difference_level(r)}
            rows.append(row)
            print(f"{case:24s} seed {seed}: sensor {sensor:.4f} rmse {row['rmse']:.4f} "
                  f"spectral {row['spectral']:.4f} difference {row['difference']:.4f}",
                  flush=True)
            if seed == seeds[0] and case in ("ar", "white+valve_deadzone"):
                spec = noise_spectrum(r, (pr.data.u, y), fs=ds.fs)
                examples[case] = (spec, fit_noise_model(spec), ds.fs)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    ax = axes[0]
    for k, case in enumerate(cases):
        rr = [r for r in rows if r["case"] == case]
        jit = np.linspace(-0.12, 0.12, len(rr))
        ax.plot(k + jit - 0.15, [r["difference"] / r["sensor_std"] for r in rr], "v",
                color="tab:red", label="differences (earlier)" if k == 0 else None)
        ax.plot(k + jit + 0.15, [r["spectral"] / r["sensor_std"] for r in rr], "o",
                color="tab:blue", label="input-free spectrum (now)" if k == 0 else None)
        ax.plot(k + jit, [r["rmse"] / r["sensor_std"] for r in rr], "_", color="0.4",
                markersize=10, label="residual RMSE" if k == 0 else None)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xticks(range(len(cases)), cases, rotation=30, ha="right")
    ax.set_ylabel("estimate / sensor noise std")
    ax.set_title("noise level of the base fit's residual")
    ax.legend(fontsize=8)
    for ax, case in zip(axes[1:], ("ar", "white+valve_deadzone"), strict=True):
        if case not in examples:
            ax.set_visible(False)
            continue
        spec, model, fs = examples[case]
        f = spec["f"][1:]
        w = 2 * np.pi * f / fs
        lam, a, c = model["lam"], model["a"], model["c"]
        fitted = lam * (1 + c * c + 2 * c * np.cos(w)) / (1 + a * a - 2 * a * np.cos(w))
        # Periodogram units to one-sided density: x 2/fs.
        ax.loglog(f, spec["residual"][1:], color="0.6", label="residual")
        ax.loglog(f, spec["noise"][1:], color="tab:blue", label="not coherent with input")
        ax.loglog(f, fitted * 2 / fs, "k--", label=f"noise model a={a:.2f}, c={c:+.2f}")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("density [deg^2/Hz]")
        level = min(model["variance"], spec["variance"]) ** 0.5
        ax.set_title(f"{case}, seed {seeds[0]}: noise level {level:.4f} deg")
        ax.legend(fontsize=8)
    fig.tight_layout()
    out = check_output_path(figure, overwrite=True, what="--estimates", suffixes=(".png",))
    fig.savefig(out, dpi=110)
    atomic_write_text(str(out.with_suffix(".json")), json.dumps(jsonable(
        {"rows": rows, "duration": duration, "sensors": SENSORS, "effects": EFFECTS,
         "loadavg": os.getloadavg(), "command": "python " + " ".join(sys.argv)}), indent=1))
    print(f"wrote {out}")


def coverage(seeds: list[int], duration: float, out_path: str) -> None:
    """How often the base fit's 95 % intervals hold the truth, white against AR(1) 0.9 noise.

    Clean physics (the base HHRA covers the record), one fit per seed and noise (pop
    20 x 30, the whole record), the intervals as the fit reports them. Per parameter:
    the share of seeds whose interval holds the true value, the spread of the estimates
    over the seeds against the mean reported standard deviation (an honest interval
    has a ratio near 1), and the share once widened by the factor the fit estimates
    from its residual's noise model (``intervals["coloured_noise"]``, 1 when absent or
    when the fit's intervals already come from that noise model).
    """
    from hhra_phys.fit import fit
    from hhra_phys.models.hhra import HHRAModel

    out = (check_output_path(out_path, overwrite=True, what="--out", suffixes=(".json",))
           if out_path else None)
    rows = []
    load_start = os.getloadavg()
    for case in ("white", "ar"):
        for seed in seeds:
            ds = make_record(case, seed, duration)
            truth = ds.metadata["true_params"]
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                res = fit(ds, HHRAModel(), pop_size=20, max_iter=30, seed=seed)
            colour = res.intervals.get("coloured_noise", {})
            # Intervals the fit already made from the noise model are not widened again.
            factor = 1.0 if "widened" in colour else float(colour.get("factor", 1.0))
            row = {"case": case, "seed": seed, "factor": factor, "params": {},
                   "seconds": time.perf_counter() - t0}
            for name, (lo, hi) in res.ci95.items():
                if name not in truth or not (np.isfinite(lo) and np.isfinite(hi)):
                    continue
                v, tv = float(res.values[name]), float(truth[name])
                # Positive parameters are fitted in log coordinates, where the
                # intervals are symmetric: judge them there.
                f = np.log if lo > 0 and tv > 0 else (lambda x: x)
                mid, half = 0.5 * (f(hi) + f(lo)), 0.5 * (f(hi) - f(lo))
                row["params"][name] = {
                    "value": v, "truth": tv, "ci95": [lo, hi], "coordinate": float(f(v)),
                    "std": float(half / 1.96), "covers": bool(lo <= tv <= hi),
                    "covers_widened": bool(abs(f(tv) - mid) <= factor * half)}
            rows.append(row)
            print(f"coverage {case:5s} seed {seed}: factor {factor:.2f}, covers "
                  + " ".join(f"{n}={int(q['covers'])}" for n, q in row["params"].items()),
                  flush=True)
    summary: dict[str, dict[str, dict[str, float]]] = {}
    for case in ("white", "ar"):
        rr = [r for r in rows if r["case"] == case]
        names = sorted({n for r in rr for n in r["params"]})
        summary[case] = {}
        for n in names:
            q = [r["params"][n] for r in rr if n in r["params"]]
            vals = np.array([x["coordinate"] for x in q])
            summary[case][n] = {
                "seeds": len(q), "covered": float(np.mean([x["covers"] for x in q])),
                "covered_widened": float(np.mean([x["covers_widened"] for x in q])),
                "spread_over_reported": float(np.std(vals, ddof=1)
                                              / np.mean([x["std"] for x in q]))
                if len(q) > 1 else float("nan")}
        print(f"\n{case}: median factor {np.median([r['factor'] for r in rr]):.2f}")
        print("| parameter | seeds | 95 % interval holds the truth | widened by the factor | "
              "spread over the seeds / reported std |")
        print("|---|---|---|---|---|")
        for n, v in summary[case].items():
            print(f"| {n} | {v['seeds']} | {100 * v['covered']:.0f} % | "
                  f"{100 * v['covered_widened']:.0f} % | {v['spread_over_reported']:.2f} |")
    if out is not None:
        atomic_write_text(out, json.dumps(jsonable(
            {"duration": duration, "sensors": SENSORS, "loadavg_start": load_start,
             "loadavg_now": os.getloadavg(), "command": "python " + " ".join(sys.argv),
             "summary": summary, "rows": rows}), indent=1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="5", help="N (seeds 1..N) or a comma-separated list")
    ap.add_argument("--duration", type=float, default=8.0, help="record length [s]")
    ap.add_argument("--cases", default="white,ar,quant,drift,ar+valve_deadzone",
                    help="comma-separated cases: " + ", ".join(SENSORS)
                    + ", or SENSOR+EFFECT with EFFECT one of " + ", ".join(EFFECTS))
    ap.add_argument("--estimator", choices=("spectral", "difference"), default="spectral",
                    help="noise level the loop uses (difference: the earlier estimate)")
    ap.add_argument("--discover", action="store_true", help="let the loop discover terms too")
    ap.add_argument("--max-effects", type=int, default=2)
    ap.add_argument("--out", default=None,
                    help="write the rows here (.json); default: print the table only")
    ap.add_argument("--estimates", default=None, metavar="FIGURE.png",
                    help="no loop: compare the noise estimates on base-fit residuals")
    ap.add_argument("--coverage", action="store_true",
                    help="no loop: coverage of the base fit's 95 %% intervals, white against "
                         "AR(1) 0.9 noise (written to --out)")
    args = ap.parse_args()
    try:
        seeds = ([int(x) for x in args.seeds.split(",")] if "," in args.seeds
                 else list(range(1, int(args.seeds) + 1)))
    except ValueError:
        ap.error(f"--seeds: expected N or a comma-separated list of integers, got {args.seeds!r}")
    cases = [c for c in args.cases.split(",") if c]
    for c in cases:
        sensor, _, effect = c.partition("+")
        if sensor not in SENSORS or (effect and effect not in EFFECTS):
            ap.error(f"--cases: unknown case {c!r}")
    if args.duration <= 0 or args.max_effects < 1:
        ap.error("--duration and --max-effects must be positive")
    if args.estimates:
        estimates(cases, seeds, args.duration, args.estimates)
        return
    if args.coverage:
        coverage(seeds, args.duration, args.out)
        return
    out = (check_output_path(args.out, overwrite=True, what="--out", suffixes=(".json",))
           if args.out else None)
    if args.estimator == "difference":
        _use_difference()
    loop_kw = {"max_effects": args.max_effects, "pop_size": 20, "max_iter": 30,
               "discover": args.discover}
    load_start = os.getloadavg()
    rows = []
    for case in cases:
        for seed in seeds:
            row = run_case(case, seed, args.duration, loop_kw)
            rows.append(row)
            e = row["base_estimates"]
            print(f"{case:22s} seed {seed}: chosen {row['chosen']} sensor std "
                  f"{row['sensor_std']:.4f}, base noise spectral {e.get('spectral', np.nan):.4f} "
                  f"difference {e.get('difference', np.nan):.4f} rmse {e.get('rmse', np.nan):.4f}"
                  f"; test {row['base_test'] or np.nan:.4g} -> {row['final_test'] or np.nan:.4g} "
                  f"stop {row['stop']} [{row['seconds']:.0f} s]", flush=True)
            # Written after every record, so an interrupted study keeps its rows.
            if out is not None:
                atomic_write_text(out, json.dumps(jsonable(
                    {"duration": args.duration, "loop": loop_kw, "estimator": args.estimator,
                     "sensors": SENSORS, "effects": EFFECTS, "loadavg_start": load_start,
                     "loadavg_now": os.getloadavg(), "command": "python " + " ".join(sys.argv),
                     "rows": rows}), indent=1))
    print("\n| case | seeds | added (records) | hidden found | sensor std | spectral / sensor "
          "(median) | difference / sensor (median) | stop |")
    print("|---|---|---|---|---|---|---|---|")
    for case in cases:
        rr = [r for r in rows if r["case"] == case]
        spec = [r["base_estimates"].get("spectral", np.nan) / r["sensor_std"] for r in rr]
        diff = [r["base_estimates"].get("difference", np.nan) / r["sensor_std"] for r in rr]
        found = (f"{sum(r['found'] for r in rr)} of {len(rr)}" if rr[0]["hidden"] else "-")
        stops = ", ".join(sorted({str(r["stop"]).split(" (")[0] for r in rr}))
        print(f"| {case} | {len(rr)} | {sum(bool(r['added']) for r in rr)} | {found} | "
              f"{np.median([r['sensor_std'] for r in rr]):.4f} | {np.median(spec):.2f} | "
              f"{np.median(diff):.2f} | {stops} |")


if __name__ == "__main__":
    main()
