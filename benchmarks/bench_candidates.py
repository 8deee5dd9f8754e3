"""CPU seconds of each library candidate's refit in one round; the stiff ones against the median.

Target (issue 25): a backlash, sharp friction or stiff-edge refit costs at most 3 times the
median candidate refit of its round. The round: a reference-rig record (the independent
implementation, :func:`hhra_phys.reference.reference_record`, seed 1, 20 s at 250 Hz) with
a hidden dead zone (``i_dead = 0.1``), diagnosed with ``valve_deadzone`` left out of the
library so that no candidate settles the round, serially, without discovery. The loop's
first round hands its jobs to :func:`hhra_phys.loop.refit_candidate`; this script keeps
them and refits each again ``--repeat`` times in a rotating order (warm compile cache, one
process, so CPU seconds are the refit's own), then prints per candidate the median CPU
seconds, its ratio to the median of the round, and what decides the round (selection and
estimation RMSE, information criterion, accepted by the loop's rule) so that a change of
speed can be checked for a change of decision in the same run.

    python benchmarks/bench_candidates.py [--effect valve_deadzone] [--repeat 3] [--seed 1]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

STIFF = ("backlash", "coulomb_friction")


def main() -> None:
    import hhra_phys.diagnosis.engine as loop
    from hhra_phys.diagnosis.selection import judge
    from hhra_phys.effects import EFFECTS
    from hhra_phys.reference import reference_record

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effect", default="valve_deadzone",
                    help="hidden effect of the record, left out of the library "
                         "('clean': none hidden, every candidate refitted)")
    ap.add_argument("--size", default="", help="the hidden effect's parameters, e.g. "
                    "'i_dead=0.1' (default: the dead zone's 0.1 mA, else the reference's)")
    ap.add_argument("--seed", type=int, default=1, help="record seed")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--duration", type=float, default=20.0)
    args = ap.parse_args()
    size = dict(kv.split("=") for kv in args.size.split(",") if kv)
    kw = {k: float(v) for k, v in size.items()}
    if args.effect == "valve_deadzone" and not kw:
        kw = {"i_dead": 0.1}
    effects = {} if args.effect == "clean" else {args.effect: kw}
    rec = reference_record(seed=args.seed, duration=args.duration, effects=effects)
    names = tuple(n for n in EFFECTS if n != args.effect)

    jobs: list = []
    original = loop.refit_candidate

    def keep(job):  # the round's jobs, as the loop built them
        jobs.append(job)
        return original(job)

    loop.refit_candidate = keep
    t0 = time.process_time()
    res = loop.augment(rec, candidates=names, discover=False, max_effects=1, background=False,
                       backward=False, progress=None)
    loop.refit_candidate = original
    first_cpu = time.process_time() - t0
    jobs = [j for j in jobs if j.round == 1]
    noise_sel = float(res.settings["noise_levels"][0]["noise"])
    tol = float(res.settings["noise_tol"])
    print(f"record: {args.effect} {kw}, seed {args.seed}, {rec.n} samples; library without "
          f"{args.effect}; first loop (base fit, compile, round 1) {first_cpu:.1f} s CPU")
    cpu: dict[str, list[float]] = {j.effect: [] for j in jobs}
    steps: dict[str, object] = {}
    for r in range(args.repeat):
        order = jobs[r % len(jobs):] + jobs[:r % len(jobs)]  # rotate: no fixed position
        for job in order:
            c0 = time.process_time()
            out = loop.refit_candidate(job)
            cpu[job.effect].append(time.process_time() - c0)
            steps[job.effect] = out.step
        print(f"repeat {r + 1}: load average {os.getloadavg()[0]:.1f}", flush=True)
    med = {n: statistics.median(v) for n, v in cpu.items()}
    round_median = statistics.median(med.values())
    print(f"\n{'candidate':<20} {'CPU s (median)':>14} {'runs':>22} {'/ median':>9} "
          f"{'sel RMSE':>10} {'est RMSE':>10} {'BIC':>12} accepted  widened")
    j0 = jobs[0]
    for n, m in med.items():
        st = steps[n]
        if st is None:
            print(f"{n:<20} {m:>14.2f}   refit failed")
            continue
        ok = judge(st, j0.rmse_cur, j0.crit_cur, noise_sel, 0.1, tol, "bic")
        wid = sum("widened" in s or "opened" in s for s in st.notes)
        runs = ", ".join(f"{c:.2f}" for c in cpu[n])
        print(f"{n:<20} {m:>14.2f} {runs:>22} {m / round_median:>9.2f} "
              f"{st.val['rmse']:>10.5f} {st.est['rmse']:>10.5f} {st.criterion:>12.1f} "
              f"{'yes' if ok else 'no':>8}  {wid}")
    print(f"\nmedian candidate {round_median:.2f} s CPU; "
          + "; ".join(f"{n} / median = {med[n] / round_median:.2f}" for n in STIFF if n in med)
          + f" (target <= 3); load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
