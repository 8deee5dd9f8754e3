"""Rates of the diagnosis loop on records of the independent reference rig.

The loop (:func:`hhra_phys.loop.augment`, three-way split, library effects only,
``discover=False``) runs on short records (8 s at 250 Hz, the pair 6 s; 0.05 deg noise) of
:func:`hhra_phys.reference.reference_record`, whose plant is written without the
package's model, so the library model never matches it exactly. The rates asserted
are those measured in the study of ``docs/diagnosis.md`` ("Simulated study",
``experiments/closed_loop.py``, raw rows in
``experiments/results/diagnosis_reference_study*.json``) on the same seeds and settings,
set at or below the measured counts, not tuned.
"""

from __future__ import annotations

import warnings

import pytest

from hhra_phys.diagnosis.engine import augment
from hhra_phys.reference import reference_record

# The rates over seeds are slow (loops of about 10 s each, a pair about 40 s); one seed of
# the sharp friction runs by default.

SEEDS = (1, 2, 3)
#: The study's loop settings (experiments/closed_loop.py).
LOOP_KW = {"max_effects": 2, "pop_size": 20, "max_iter": 30, "discover": False}
NOISE = 0.05
#: Dead zone + sharp friction found together on at least this many of seeds 1-2.
PAIR_MIN = 2


def _loop(seed: int, effects: dict[str, dict[str, float]], smooth: bool, workers):
    ds = reference_record(seed=seed, duration=8.0, noise_deg=NOISE, levels=4,
                          effects=effects, smooth=smooth)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return augment(ds, seed=seed, executor=workers, **LOOP_KW)


@pytest.mark.parametrize(("seeds", "min_in_ci"), [
    pytest.param((1,), 1, id="seed1"),
    pytest.param(SEEDS, 2, id="seeds1-3", marks=pytest.mark.slow),
])
def test_sharp_friction_found_first_with_truth_in_ci(loop_workers, seeds, min_in_ci):
    """Exact stick-slip Coulomb friction (smooth=False) of 30 rad/s^2 hidden in the plant.

    Measured on seeds 1-3: found first on 3 of 3, truth in the 95 % CI on 2 of 3 (seed 2:
    31.6 fitted, just outside), no other effect accepted, test RMSE 0.048-0.050 deg
    (within 15 % of the 0.05 deg noise) on all three. The default run: seed 1 (found
    first, truth in the CI); the rate over seeds 1-3 is slow.
    """
    truth = 30.0
    runs = [_loop(s, {"coulomb_friction": {"g_coulomb": truth}}, smooth=False,
                  workers=loop_workers) for s in seeds]
    first = sum(bool(r.chosen) and r.chosen[0] == "coulomb_friction" for r in runs)
    in_ci = 0
    for r in runs:
        lo, hi = r.final.ci95.get("g_coulomb", (float("nan"),) * 2)
        in_ci += bool(lo <= truth <= hi)
    wrong = [n for r in runs for n in r.chosen if n != "coulomb_friction"]
    assert first == len(seeds), [r.chosen for r in runs]
    assert in_ci >= min_in_ci, [(r.final.values.get("g_coulomb"), r.final.ci95.get("g_coulomb"))
                             for r in runs]
    assert not wrong, wrong
    for r in runs:
        assert r.test["rmse"] < 1.15 * NOISE, r.test


@pytest.mark.slow
def test_clean_records_add_nothing(loop_workers):
    """No hidden effect: the loop must stop at the noise level without adding any.

    Measured: 6 of 6 clean records (seeds 1-3, 11-13) add nothing, test RMSE
    0.048-0.052 deg.
    """
    runs = [_loop(s, {}, smooth=True, workers=loop_workers) for s in SEEDS]
    assert all(not r.chosen for r in runs), [r.chosen for r in runs]
    assert all(r.test["rmse"] < 1.15 * NOISE for r in runs), [r.test for r in runs]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "regression measured 2026-11-26 (experiments/notes/diagnosis.md, pair rerun at dd64702, "
    "again on the session's merged main): seed 2 ends with the friction alone, its dead-zone "
    "refit ends worse than the model without it; the pair study is 3 of 5 (4 of 5 before)"))
def test_dead_zone_and_sharp_friction_both_found(loop_workers):
    """A dead zone and exact stick-slip friction hidden together (issue 16).

    Reference records with every switch exact (``smooth=False``: the dead zone is a clip,
    the friction sticks), 6 s, both at the study's large sizes; every candidate refitted
    (with the two best-ranked only, the friction ranked 7th of 8 after the dead zone and a
    backlash stand-in was accepted: 0 of 5). Measured with these settings (docs/diagnosis.md,
    seeds 1-5, ``experiments/results/diagnosis_reference_study_pair_dz_friction.json``): both
    found on 4 of 5 (seed 3: the friction alone), no other effect, selection RMSE
    0.050-0.058 deg. Here on seeds 1-2: both found on both, no other effect, selection
    RMSE within 20 % of the noise.
    """
    truth = {"valve_deadzone": {"i_dead": 0.2}, "coulomb_friction": {"g_coulomb": 30.0}}
    runs = []
    for seed in SEEDS[:2]:
        ds = reference_record(seed=seed, duration=6.0, noise_deg=NOISE, levels=4,
                              effects=truth, smooth=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            runs.append(augment(ds, seed=seed, executor=loop_workers, **LOOP_KW))
    found = [r for r in runs if sorted(r.chosen) == sorted(truth)]
    assert len(found) >= PAIR_MIN, [r.chosen for r in runs]
    assert not [c for r in runs for c in r.chosen if c not in truth], [r.chosen for r in runs]
    for r in found:
        assert r.final.metrics["val"]["rmse"] < 1.2 * NOISE, r.final.metrics["val"]
