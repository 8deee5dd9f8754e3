"""Typed estimates, derived quantities by the delta method, and the one serialiser.

The delta method (:func:`hhra_phys.result.derived_estimates`) is checked against two
oracles it does not share code with: a Monte Carlo propagation of the covariance
(a small covariance, where the linearisation is exact to a few per cent) and the
gradient by central differences. The quantities are of this file's own making: a
product, a ratio, a sum with a held parameter and a square root, several covariances
and seeds.
"""

from __future__ import annotations

import json
import math

import casadi as ca
import numpy as np
import pytest

from hhra_phys.model import DerivedQuantity
from hhra_phys.result import Estimate, derived_estimates

NAMES = ["k1", "k2", "k3"]
QUANTITIES = {
    "product": DerivedQuantity("m", lambda d: d["k1"] * d["k2"], positive=True),
    "ratio": DerivedQuantity("-", lambda d: d["k1"] / (d["k3"] + d["h"])),
    "mixed": DerivedQuantity("s", lambda d: d["k2"] ** 2 - 3.0 * d["k1"] * d["k3"] + d["h"]),
    "root": DerivedQuantity("1/s", lambda d: ca.sqrt(d["k1"] * d["k3"]) + d["k2"],
                            positive=True),
    "held": DerivedQuantity("-", lambda d: 2.0 * d["h"]),
}


def _case(seed: int) -> tuple[dict[str, float], np.ndarray]:
    """Values and a covariance of a few per cent relative spread, correlated."""
    rng = np.random.default_rng(seed)
    values = dict(zip(NAMES, rng.uniform(1.0, 5.0, 3), strict=True))
    values["h"] = float(rng.uniform(0.5, 2.0))  # held: not free
    a = rng.normal(size=(3, 3))
    corr = a @ a.T
    d = np.sqrt(np.diag(corr))
    corr = corr / np.outer(d, d)
    sd = 0.01 * np.array([values[n] for n in NAMES]) * rng.uniform(0.5, 2.0, 3)
    return values, corr * np.outer(sd, sd)


def _numeric(name: str, values: dict[str, float]) -> float:
    return float(QUANTITIES[name].function(values))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_delta_method_matches_monte_carlo(seed):
    values, cov = _case(seed)
    est = derived_estimates(QUANTITIES, values, NAMES, cov)
    rng = np.random.default_rng(100 + seed)
    draws = rng.multivariate_normal([values[n] for n in NAMES], cov, size=40000)
    for name, q in QUANTITIES.items():
        if name == "held":
            continue
        g = np.array([_numeric(name, {**values, **dict(zip(NAMES, x, strict=True))})
                      for x in draws])
        e = est[name]
        assert e.value == pytest.approx(_numeric(name, values), rel=1e-12)
        # The Monte Carlo standard deviation has a relative error of about 0.4 %; the
        # linearisation at a 1-2 % spread another percent or two.
        assert e.std == pytest.approx(float(np.std(g)), rel=0.04), name
        lo, hi = np.quantile(g, [0.025, 0.975])
        width = hi - lo
        assert e.ci95[0] == pytest.approx(lo, abs=0.05 * width), name
        assert e.ci95[1] == pytest.approx(hi, abs=0.05 * width), name
        assert e.status == "free" and e.unit == q.unit


@pytest.mark.parametrize("seed", [4, 5])
def test_delta_method_gradient_matches_central_differences(seed):
    values, _ = _case(seed)
    for name in ("product", "ratio", "mixed", "root"):
        grad = []
        for n in NAMES:
            h = 1e-6 * values[n]
            up = _numeric(name, {**values, n: values[n] + h})
            down = _numeric(name, {**values, n: values[n] - h})
            grad.append((up - down) / (2 * h))
        for i, n in enumerate(NAMES):  # one parameter at a time: var = grad_i^2 * var_i
            cov = np.zeros((3, 3))
            cov[i, i] = (0.01 * values[n]) ** 2
            sd = derived_estimates({name: QUANTITIES[name]}, values, NAMES, cov)[name].std
            assert sd == pytest.approx(abs(grad[i]) * 0.01 * values[n], rel=1e-6, abs=1e-12)


def test_positive_quantity_interval_is_on_its_logarithm_and_stays_positive():
    values = {"k1": 1.0, "k2": 1.0, "k3": 1.0, "h": 1.0}
    cov = np.diag([0.36, 0.36, 0.0])  # 60 % spread: a symmetric interval would cross zero
    e = derived_estimates(QUANTITIES, values, NAMES, cov)
    lo, hi = e["product"].ci95
    assert lo > 0 and lo * hi == pytest.approx(e["product"].value ** 2, rel=1e-12)
    lo, hi = e["ratio"].ci95  # not declared positive: symmetric
    assert (lo + hi) / 2 == pytest.approx(e["ratio"].value, rel=1e-12) and lo < 0


def test_a_positive_quantity_the_fit_hardly_determines_gets_an_open_interval():
    """A relative spread whose exp overflows: the interval is (0, inf), not an error
    (a gravity base fit with a far-off damping raised OverflowError here)."""
    values = {"k1": 1.0, "k2": 1.0, "k3": 1.0, "h": 1.0}
    cov = np.diag([1e6, 1e6, 0.0])  # sd 1000 x the value
    e = derived_estimates(QUANTITIES, values, NAMES, cov)
    lo, hi = e["product"].ci95
    assert lo == 0.0 and hi == math.inf and e["product"].value == pytest.approx(1.0)
    moderate = derived_estimates(QUANTITIES, values, NAMES, np.diag([0.04, 0.0, 0.0]))
    lo, hi = moderate["product"].ci95  # the same rule below the overflow
    assert lo == pytest.approx(math.exp(-1.96 * 0.2), rel=1e-9)
    assert hi == pytest.approx(math.exp(1.96 * 0.2), rel=1e-9)


def test_held_undetermined_and_edge_statuses():
    values, cov = _case(7)
    e = derived_estimates(QUANTITIES, values, NAMES, cov)
    assert e["held"].status == "fixed" and e["held"].ci95 is None
    assert e["held"].value == pytest.approx(2 * values["h"])
    bad = cov.copy()
    bad[2, :] = bad[:, 2] = np.nan
    bad[2, 2] = np.inf  # k3 not determined by the data
    e = derived_estimates(QUANTITIES, values, NAMES, bad, at_edge=["k2"])
    assert not e["ratio"].determined and math.isnan(e["ratio"].ci95[0])
    assert e["product"].determined and e["product"].status == "at-edge"
    assert e["ratio"].status == "free"
    none = derived_estimates(QUANTITIES, values, NAMES, None)
    assert none["product"].ci95 is None and none["product"].status == "free"
    missing = {"need": DerivedQuantity("-", lambda d: d["absent"])}
    assert derived_estimates(missing, values, NAMES, cov) == {}


@pytest.mark.parametrize("est", [
    Estimate(1.5, "1/s", (1.0, 2.0), "free", 0.25, "a rate"),
    Estimate(3.0, "m"),
    Estimate(2.0, "-", None, "fixed"),
    Estimate(0.5, "rad", (math.nan, math.nan), "at-edge", math.inf),
])
def test_estimate_json_round_trip(est):
    d = json.loads(json.dumps(_strict(est.to_json())))
    back = Estimate.from_json(d)
    assert json.dumps(_strict(back.to_json())) == json.dumps(_strict(est.to_json()))
    assert back.free == (est.status != "fixed") and d["free"] == back.free


def _strict(d):
    from hhra_phys.outputs import jsonable

    return jsonable(d)
