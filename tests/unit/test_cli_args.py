"""Property-based tests of the CLI's argument handling (hypothesis).

Whatever text a user types for an option, the parser either accepts a value that satisfies
the option's constraint or stops with exit code 2 and a message naming the option; it never
raises anything else. ``--fix`` values are accepted exactly when finite, of the parameter's
sign and inside its box (or outside it with ``--allow-outside-box``).
"""

from __future__ import annotations

import argparse
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hhra_phys.cli import build_parser
from hhra_phys.cli._common import FILE_OPTIONS, load_records, parse_fixed
from hhra_phys.errors import ParameterError
from hhra_phys.models.hhra.model import HHRAModel

PARSER = build_parser()
PARAMS = HHRAModel().params
SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])

# Text a user might type: numbers in every spelling, words, empty, signs, unicode.
TEXT = st.one_of(
    st.integers(-10**6, 10**6).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["", " ", "-", "1e400", "nan", "inf", "0x10", "1_000", "½", "٣", "1,5"]),
    st.text(max_size=8),
).filter(lambda s: not s.startswith("-") or s[1:2].isdigit() or s == "-")

#: option -> (command, check of the parsed value)
CONSTRAINTS = {
    "--pop": ("fit", lambda v: isinstance(v, int) and v >= 4),
    "--iters": ("fit", lambda v: isinstance(v, int) and v >= 1),
    # A fraction in (0, 1], or an integer sample index above 1 (as compare, diagnose).
    "--split": ("fit", lambda v: 0 < v <= 1 or (isinstance(v, int) and v > 1)),
    "--seed": ("fit", lambda v: isinstance(v, int) and v >= 0),
    "--rig-seed": ("diagnose", lambda v: isinstance(v, int) and v >= 0),
    "--starts": ("fit", lambda v: isinstance(v, int) and v >= 1),
    "--fs": ("fit", lambda v: math.isfinite(v) and v > 0),
    "--time-unit": ("fit", lambda v: v in ("s", "ms", "us")),
    "--top": ("diagnose", lambda v: isinstance(v, int) and v >= 1),
    "--max-effects": ("diagnose", lambda v: isinstance(v, int) and v >= 0),
    "--folds": ("diagnose", lambda v: isinstance(v, int) and 2 <= v <= 10),
}


def parse(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[argparse.Namespace | None, str]:
    try:
        return PARSER.parse_args(argv), ""
    except SystemExit as exc:
        assert exc.code == 2
        return None, capsys.readouterr().err


@pytest.mark.parametrize("option", sorted(CONSTRAINTS))
@SETTINGS
@given(text=TEXT)
def test_an_option_value_is_valid_or_a_usage_error_naming_it(option, text, capsys) -> None:
    command, ok = CONSTRAINTS[option]
    args, err = parse([command, "rec.csv", f"{option}={text}"], capsys)
    if args is None:
        assert option in err and "Traceback" not in err
    else:
        assert ok(getattr(args, option.lstrip("-").replace("-", "_")))


NAMES = st.sampled_from(PARAMS.names)
VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                   st.floats(-1e3, 1e3), st.floats(1e-3, 1e3))


@SETTINGS
@given(name=NAMES, value=VALUES, allow=st.booleans())
def test_fix_values_are_checked_against_sign_and_box(name, value, allow) -> None:
    par = PARAMS[PARAMS.index(name)]
    try:
        fixed = parse_fixed([f"{name}={value!r}"])
        PARAMS.check_values(fixed, allow_outside_box=allow)
    except ParameterError as exc:
        assert name in str(exc)
        bad_sign = par.scale == "log" and value <= 0
        outside = not par.lower <= value <= par.upper
        assert not math.isfinite(value) or bad_sign or (outside and not allow)
    else:
        assert math.isfinite(value) and not (par.scale == "log" and value <= 0)
        assert allow or par.lower <= value <= par.upper


@SETTINGS
@given(item=st.text(max_size=12))
def test_fix_text_is_parsed_or_refused_with_its_words(item) -> None:
    try:
        out = parse_fixed([item])
    except ParameterError as exc:
        assert "--fix" in str(exc)
    else:
        assert len(out) == 1 and "=" in item


@SETTINGS
@given(data=st.sampled_from([None, "rig", "public", "RIG"]),
       given_opts=st.lists(st.sampled_from([flag for _, flag in FILE_OPTIONS]), unique=True,
                           min_size=1))
def test_file_options_without_a_file_are_refused(data, given_opts) -> None:
    values = {"--time-col": "t", "--input-col": "u", "--output-col": "y", "--fs": "10",
              "--delimiter": ";", "--time-unit": "ms"}
    argv = ["fit"] + ([data] if data else [])
    for flag in given_opts:
        argv += [flag, values[flag]]
    args = PARSER.parse_args(argv)
    with pytest.raises(ParameterError) as err:
        load_records(args)
    assert all(flag in str(err.value) for flag in given_opts)
