"""The selection rule's first home, kept so that code written for it runs unchanged: the
rule is :mod:`hhra_phys.diagnosis.selection`.
"""

from __future__ import annotations

from hhra_phys.diagnosis.selection import (
    COLOURED_P,
    DECISIVE_CRITERION,
    METRIC_KEYS,
    NOISE_TOL,
    NOISE_Z,
    REGIME_THIN,
    Step,
    acceptance,
    at_noise_level,
    backward_decision,
    choose,
    estimation_samples,
    information_criterion,
    judge,
    needs_rotation,
    noise_allowance,
    noise_tolerance,
    pooled_rmse,
    rotated_verdict,
    round_settled,
    split_record,
    stops_at_noise,
    thin_part,
    tie_break,
    votes,
)

#: Where these names live now (docs/make_api.py lists them there).
__moved_to__ = "hhra_phys.diagnosis"

__all__ = [
    "NOISE_TOL",
    "NOISE_Z",
    "DECISIVE_CRITERION",
    "noise_tolerance",
    "METRIC_KEYS",
    "Step",
    "information_criterion",
    "estimation_samples",
    "noise_allowance",
    "acceptance",
    "judge",
    "choose",
    "tie_break",
    "round_settled",
    "backward_decision",
    "COLOURED_P",
    "at_noise_level",
    "stops_at_noise",
    "split_record",
    "REGIME_THIN",
    "votes",
    "thin_part",
    "needs_rotation",
    "pooled_rmse",
    "rotated_verdict",
]
