"""Case study: the closed loop on the public measured hydraulic-actuator record.

Valve opening -> oil pressure, 1024 samples in sample time (fs = 1): estimation
1-512, selection 513-768 (chooses among candidates), test 769-1024 (chooses
nothing). Base model: ``HHRAModel(output="pressure")`` with the groups rescaled to
the record's resonance (:func:`hhra_phys.loop.base_model_for`). The loop then tries
every applicable library effect (backlash and sensor_offset do not apply to a
pressure output with its own offset), then the discovery (terms and resonant
modes, :mod:`hhra_phys.discover`).

    HHRA_SHARED_DATA=/work/shared/data python experiments/public_case.py
        [--pop 60] [--iters 100] [--seed 0] [--max-effects 4] [--probe-resonance]

Writes experiments/results/diagnosis_public.json (``--json``) and the residual figures
docs/figures/diagnosis_public_before.png / _after.png (and _discovery.png: residuals
just before and after each discovered term), and prints the summary.

``--probe-resonance`` then checks whether the final model's own hydraulic mode is
mis-tuned (docs/diagnosis.md, "Public measured record"): it prints the measured
output's spectral peak on each part, the model's own resonance, and IPOPT refits of
the final model (on estimation only, its free groups, its boxes) started with
``g_torque`` moved so that the mode sits at each of :data:`PROBE_PERIODS`, and
unseeded H-GWO searches (pop 60 x 100, :data:`PROBE_SEEDS`) of the final structure on
estimation and, as a diagnostic of what the structure can reach there, on the
selection part alone (never used to choose). With a
pressure output ``g_torque*g_compress`` sets the mode (``g_compress`` is held
because only the product is observable), so ``g_torque`` alone moves it.
"""

from __future__ import annotations

import argparse
import json
import math
import warnings

import numpy as np

from hhra_phys.data import Dataset, load_public_actuator
from hhra_phys.diagnosis.discovery import _resonances
from hhra_phys.diagnosis.engine import augment, base_model_for
from hhra_phys.diagnosis.plots import plot_loop_residuals
from hhra_phys.fit import fit
from hhra_phys.outputs import atomic_write_text, jsonable
from hhra_phys.result import FitResult

#: Periods [samples] the resonance probe starts the final model's own mode at.
PROBE_PERIODS: tuple[float, ...] = (20.0, 22.5, 25.0, 27.5, 30.0)
#: Seeds of the probe's global searches.
PROBE_SEEDS: tuple[int, ...] = (0, 1)


def spectral_peak(y: np.ndarray, shortest: float = 8.0, longest: float = 60.0) -> float:
    """Period [samples] of the largest Hann-windowed spectral peak of ``y`` (shape (N,))
    between ``shortest`` and ``longest`` samples."""
    y = np.asarray(y, dtype=float) - np.mean(y)
    f = np.fft.rfftfreq(y.size)
    power = np.abs(np.fft.rfft(y * np.hanning(y.size))) ** 2
    band = (f > 1.0 / longest) & (f < 1.0 / shortest)
    return float(1.0 / f[band][np.argmax(power[band])])


def own_periods(res: FitResult, data: Dataset) -> list[tuple[float, float]]:
    """``(period [samples], damping ratio)`` of the fitted model's own oscillatory modes,
    linearised at +-half the record's largest input (:func:`hhra_phys.discover._resonances`)."""
    P = np.array([res.values[n] for n in res.model.params.names])
    return [(2 * math.pi / w, z) for w, z in _resonances(res.model, P, data, 1.0, 0.0, math.inf)]


def probe_resonance(res: FitResult, data: Dataset, bounds: dict[str, tuple[float, float]],
                    n_est: int, n_sel: int) -> None:
    """Print whether refits from other resonance starts find a better final model.

    Refits on ``data[:n_est]`` only; prints RMSE on estimation, selection
    (``n_est:n_est+n_sel``) and test (the rest) for each start.
    """
    parts = {"est": data.slice(0, n_est), "sel": data.slice(n_est, n_est + n_sel),
             "test": data.slice(n_est + n_sel, data.n)}

    def rmses(r: FitResult, names: tuple[str, ...] = ("est", "sel", "test")) -> str:
        err = {k: parts[k].y - r.predict(parts[k]) for k in names}
        return ", ".join(f"{k} {float(np.sqrt(np.mean(e ** 2))):.4f}" for k, e in err.items())

    print("measured spectral peak [samples]:",
          {k: round(spectral_peak(d.y), 1) for k, d in parts.items()})
    print("residual spectral peak [samples]:",
          {k: round(spectral_peak(d.y - res.predict(d)), 1) for k, d in parts.items()})
    own = own_periods(res, data)
    print("final model: own modes (period, damping)", [(round(p, 1), round(z, 3)) for p, z in own],
          "|", rmses(res))
    if not own:
        return
    free = [n for n in res.free if n in res.model.params.names]
    box = {k: v for k, v in bounds.items() if k in free}
    for period in PROBE_PERIODS:
        start = {n: res.values[n] for n in res.model.params.names}
        start["g_torque"] *= (own[0][0] / period) ** 2  # the mode's w^2 ~ g_torque*g_compress
        r = fit(parts["est"], model=res.model.with_nominal(start), validation=parts["sel"],
                optimizer="none", refine="ipopt", free=free, bounds=box, seed=0,
                refine_options={"max_iter": 200})
        print(f"start at {period:g} samples -> own modes",
              [(round(p, 1), round(z, 3)) for p, z in own_periods(r, data)],
              f"g_torque {r.values['g_torque']:.4g} |", rmses(r))
    # A global search of the final structure from the model's default nominals (not
    # seeded by the loop's values), and the same search on the selection part alone: a
    # diagnostic of what the structure can reach there at all, never a choice.
    for seed in PROBE_SEEDS:
        for on, other in (("est", "sel"), ("sel", "est")):
            r = fit(parts[on], model=res.model, validation=parts[other], optimizer="hgwo",
                    pop_size=60, max_iter=100, free=free, bounds=box, seed=seed,
                    seed_population=False)
            print(f"H-GWO 60x100 seed {seed} fitted on {on} -> own modes",
                  [(round(p, 1), round(z, 3)) for p, z in own_periods(r, data)], "|",
                  rmses(r) if on == "est" else rmses(r, ("est", "sel")),
                  "| at a bound:", [w for w in r.warnings if "bound" in w][:2])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pop", type=int, default=60)
    ap.add_argument("--iters", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-effects", type=int, default=4,
                    help="most additions, library effects and discovered terms alike "
                         "(default 4, the loop's)")
    ap.add_argument("--prefix", default="docs/figures/diagnosis_public",
                    help="the figures: PREFIX_before.png, _after.png, _discovery.png")
    ap.add_argument("--json", default="experiments/results/diagnosis_public.json",
                    help="the loop's result (raw rows of the study)")
    ap.add_argument("--probe-resonance", action="store_true",
                    help="after the loop, refit the final model from other own-mode periods")
    args = ap.parse_args()
    if args.max_effects < 0:
        ap.error(f"--max-effects must be >= 0, got {args.max_effects}")
    data = load_public_actuator()
    model, bounds = base_model_for(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = augment(data, model, split=512 / 1024, bounds=bounds,
                      max_effects=args.max_effects, top_k=4,
                      pop_size=args.pop, max_iter=args.iters, cand_pop=20, cand_iter=30,
                      seed=args.seed, progress=print)
    out = res.to_json()
    atomic_write_text(args.json, json.dumps(jsonable(out), indent=1))
    plot_loop_residuals(res, data, f"{args.prefix}_before.png", f"{args.prefix}_after.png",
                        overwrite=True, label="public record")
    found = [s for s in res.steps if getattr(s, "residuals", None)]
    if found:  # residuals just before and after each term of the discovery step
        from hhra_phys.diagnosis.plots import plot_discovery

        plot_discovery(found, f"{args.prefix}_discovery.png", overwrite=True)
    print("chosen:", res.chosen)
    for part in ("est", "val"):
        print(part, "base", out["base"][part], "final", out["final"][part])
    print("base values:", res.base.values)
    print("warnings:", res.warnings + res.final.warnings)
    if args.probe_resonance:
        n_est = round(512 / 1024 * data.n)
        probe_resonance(res.final, data, bounds, n_est, round(0.25 * data.n))


if __name__ == "__main__":
    main()
