"""Oracle: a discovered term's printed expression is the function the part adds.

The expression (what a user reads and would type into their own model) is evaluated here by a
small parser of its own, independently of the part's code, and compared with the part's
contribution at points away from the smoothing of |.|, sgn and relu.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from hhra_phys.terms import _NP, SMOOTH, DiscoveredTerm

VARS = ("omega", "theta", "u")
SCALES = (3.0, 0.7, 5.0)
UNITS = ("rad/s", "rad", "mA")


def _term(spec: str, coef: float, knot: float = 0.0) -> DiscoveredTerm:
    return DiscoveredTerm(target="rate:omega", index=1, terms=(spec,), variables=VARS,
                          scales=SCALES, start=(coef,), bound=(100.0,), knots=(knot,),
                          knot_max=(10.0,), unit="rad/s^2", var_units=UNITS)


def _evaluate(printed: str, values: dict[str, float]) -> float:
    """Value of a printed right-hand side ``2.5*omega^2 - 1*relu(theta - 0.1) [unit]``."""
    rhs = printed.split("+=", 1)[1].rsplit("[", 1)[0].strip()
    rhs = re.sub(r"\|([a-z_]+)\|", r"abs(\1)", rhs)
    rhs = rhs.replace("^", "**")
    env = {"abs": abs, "relu": lambda x: max(x, 0.0), "sgn": np.sign, "tanh": math.tanh,
           "sin": math.sin, "cos": math.cos, **values}
    return float(eval(rhs, {"__builtins__": {}}, env))  # noqa: S307 - our own printed text


EXACT = ["one()", "lin(omega)", "sq(omega)", "cube(theta)", "odd2(omega)", "sat(u)",
         "prod(omega,theta)", "sin(theta)", "cos(theta)"]
SMOOTHED = ["abs(omega)", "sign(omega)", "hinge+(theta)", "hinge-(theta)"]


@pytest.mark.parametrize("spec", EXACT + SMOOTHED)
@pytest.mark.parametrize("point", [(2.1, 0.45, -3.2), (-1.7, -0.62, 4.4)])
def test_printed_expression_is_the_parts_function(spec: str, point: tuple[float, ...]) -> None:
    coef, knot = -1.37, 0.12
    term = _term(spec, coef, knot if spec.startswith("hinge") else 0.0)
    values = dict(zip(VARS, point, strict=True))
    params = {"disc1_a1": coef, "disc1_c1": knot}
    part = float(term.contribution(lambda n: values[n], params, lib=_NP))
    printed = _evaluate(term.expression(params, digits=15), values)
    if spec in EXACT:
        assert printed == pytest.approx(part, rel=1e-9, abs=1e-12), term.expression(params)
    else:
        # The part smooths |.|, sgn and relu over SMOOTH of the variable's scale.
        assert printed == pytest.approx(part, abs=2 * SMOOTH * abs(coef)), term.expression(params)
