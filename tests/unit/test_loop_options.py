"""The loop's settings object: every field validated, keyword overrides, clear errors."""

from __future__ import annotations

import pytest

from hhra_phys.diagnosis.engine import augment
from hhra_phys.diagnosis.options import LoopOptions
from hhra_phys.errors import ParameterError


def test_overrides_apply_on_top_of_given_options():
    base = LoopOptions(seed=3, max_effects=2)
    opts = LoopOptions.of(base, max_effects=1, candidates=["coulomb_friction"])
    assert (opts.seed, opts.max_effects, opts.candidates) == (3, 1, ("coulomb_friction",))
    assert base.max_effects == 2  # the given object is not changed (frozen)


@pytest.mark.parametrize(
    ("setting", "value", "words"),
    [
        ("criterion", "aicc", "criterion"),
        ("margin", 1.0, "margin"),
        ("noise_tol", -0.1, "noise_tol"),
        ("stop_on", "selection", "stop_on was removed"),
        ("max_effects", -1, "max_effects"),
        ("top_k", 0, "top_k"),
        ("pop_size", 0, "pop_size"),
        ("cand_iter", 0, "cand_iter"),
        ("backend", "gpu", "backend"),
        ("initial_state", "guess", "initial_state"),
        ("candidates", ["no_such_effect"], "no_such_effect"),
        ("discover_kw", {"n_entries": 2}, "n_entries"),
        ("budget", 0, "budget"),
        ("budget", float("inf"), "budget"),
        ("budget", "60", "budget"),
    ],
)
def test_each_bad_setting_is_named(setting, value, words):
    with pytest.raises(ParameterError, match=words):
        LoopOptions.of(**{setting: value})


def test_an_unknown_setting_is_refused_before_any_work():
    with pytest.raises(ParameterError, match="unknown loop setting.*max_effect\\b"):
        augment(None, max_effect=2)  # type: ignore[arg-type]  (no data needed: refused first)
