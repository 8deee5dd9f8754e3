"""Discovery of a term outside the effect library (hhra_phys.discover).

Records with outside-library terms come from the independent reference model
(:mod:`hhra_phys.reference.outside`) for the HHRA, and from a truth built of parts
(a user's own two-tank model with an overflow of its upper tank, an unmeasured
state) for the generic path. Short records, small populations; the loop is run
with no library effects (``candidates=[]``, one addition) so that discovery is what is
tested (the library
rounds are tested in test_diagnose.py).
"""

from __future__ import annotations

import json
import math
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from hhra_phys import Parameter, Part, Simulator, register_part
from hhra_phys.data import Dataset
from hhra_phys.diagnosis.engine import augment
from hhra_phys.diagnosis.screening import lasso_path
from hhra_phys.diagnosis.selection import acceptance
from hhra_phys.fit import fit
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.reference.outside import outside_record
from hhra_phys.result import FitResult
from hhra_phys.terms import _CA, _NP, FAMILIES, DiscoveredTerm, _basis

sys.path.insert(0, str(Path(__file__).parent / "user_models"))
import two_tank  # noqa: E402

NOISE = 0.05
LOOP = {"candidates": [], "max_effects": 1, "pop_size": 20, "max_iter": 30}


def _run(ds, model=None, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return augment(ds, model, **{**LOOP, **kw})


def _discovered(res):
    return [s for s in res.steps if s.to_json().get("discovered")]


# --- the part ------------------------------------------------------------------------------


def test_basis_numpy_and_casadi_agree():
    q = np.linspace(-1.3, 1.3, 9)
    for fam in (*FAMILIES, "sin", "cos"):
        knot = 0.3 if fam.startswith("hinge") else 0.0
        ref = np.asarray(_basis(fam, [q], knot, _NP), dtype=float)
        x = ca.SX.sym("x")
        f = ca.Function("f", [x], [_basis(fam, [x], knot, _CA)])
        got = np.array([float(f(v)) for v in q])
        assert np.allclose(got, ref, atol=1e-12), fam
    # Closed forms (the two implementations above share the formulas).
    exact = {"lin": q, "sq": q ** 2, "cube": q ** 3, "odd2": q * np.abs(q), "sat": np.tanh(2 * q),
             "sin": np.sin(q), "cos": np.cos(q)}
    for fam, ref in exact.items():
        assert np.allclose(_basis(fam, [q], 0.0, _NP), ref, atol=1e-12), fam
    assert np.allclose(_basis("abs", [q], 0.0, _NP), np.abs(q), atol=0.02)
    # The smooth forms are close to their exact counterparts away from the kink.
    far = np.abs(q) > 0.2
    assert np.allclose(_basis("sign", [q], 0.0, _NP)[far], np.sign(q)[far], atol=0.01)
    assert np.allclose(_basis("hinge+", [q], 0.3, _NP)[np.abs(q - 0.3) > 0.2],
                       np.maximum(q - 0.3, 0)[np.abs(q - 0.3) > 0.2], atol=0.002)
    assert np.allclose(_basis("hinge-", [q], 0.3, _NP)[np.abs(q + 0.3) > 0.2],
                       np.maximum(-q - 0.3, 0)[np.abs(q + 0.3) > 0.2], atol=0.002)


def test_discovered_term_expression_save_and_reload(tmp_path):
    term = DiscoveredTerm(target="rate:omega", index=1, terms=("odd2(omega)", "hinge+(theta)"),
                          variables=("omega", "theta"), scales=(2.0, 0.5), start=(-4.0, 1.0),
                          bound=(50.0, 50.0), knots=(0.0, 0.2), knot_max=(0.0, 0.5),
                          unit="rad/s^2", var_units=("rad/s", "rad"))
    assert term.name == "discovered_rate_omega_1"
    assert term.uses == ["omega", "theta"] and term.writes == ("omega",)
    assert term.expression({}) == ("d omega/dt += -1*omega*|omega| + 2*relu(theta - 0.2) "
                                   "[rad/s^2]")
    model = HHRAModel().with_parts(term)
    assert term.applicable(HHRAModel()) is None
    # One record through the fit and back from disk: same model, same simulation.
    rec = outside_record("none", 0.0, seed=1, duration=2.0)
    res = fit(rec, model, optimizer="none", refine="none",
              free=["g_valve", "disc1_a1"], split=0.7)
    path = res.save(tmp_path / "fit.json")
    back = FitResult.load(path)
    assert back.model.part_names() == model.part_names()
    assert json.loads(Path(path).read_text())["model"]["parts"][-1]["type"] == "DiscoveredTerm"
    assert np.allclose(back.simulate(rec.u, x0=res.x0), res.simulate(rec.u, x0=res.x0),
                       atol=1e-9)
    assert back.values["disc1_a1"] == res.values["disc1_a1"]


def test_lasso_path_finds_the_true_support_first():
    rng = np.random.default_rng(4)
    S = rng.standard_normal((400, 8))
    r = 2.0 * S[:, 3] - 1.0 * S[:, 6] + 0.1 * rng.standard_normal(400)
    supports = lasso_path(S, r, 3)
    assert supports[0] == [3]
    assert sorted(supports[1]) == [3, 6]


def test_discovered_terms_face_the_library_rule():
    """Terms are accepted by the loop's one rule (its cases: tests/unit/test_loop_rule.py)."""
    assert acceptance(1.0, 0.85, 0.0, -5.0, 0.1)[0]
    assert not acceptance(1.0, 0.95, 0.0, -5.0, 0.1)[0]  # gain below the margin
    assert not acceptance(1.0, 0.5, 0.0, 5.0, 0.1)[0]  # the criterion disagrees
    # within the noise allowance: 0.06 -> 0.0535 with noise 0.05 and tolerance 0.15
    assert not acceptance(0.06, 0.0535, 0.0, -5.0, 0.1, noise=0.05, noise_tol=0.15)[0]


# --- discovery in the loop ----------------------------------------------------------------


def _found(js, signal):
    """Whether a loop's JSON passes the discovery claim: one accepted term, using the true
    variable, with the validation RMSE 3x lower or at 1.5x the noise."""
    accepted = [s for s in js["steps"] if s["effect"].startswith("discovered_")
                and s["accepted"]]
    base, final = js["base"]["val"]["rmse"], js["final"]["val"]["rmse"]
    return (len(accepted) == 1 and signal in accepted[0]["uses"]
            and (final <= base / 3 or final <= 1.5 * NOISE))


def _cli_args(folder, term, size, seed):
    """Write an outside-term record into ``folder``: the arguments of ``hhra-phys diagnose
    --effects none --max-effects 1`` on it (record and search seed ``seed``, as in
    experiments/discover.py), JSON and report written to ``folder``."""
    from hhra_phys.data import save

    data = folder / f"rec{seed}.csv"
    save(outside_record(term, size, seed=seed, noise_deg=NOISE), data)
    return ["diagnose", str(data), "--json", str(folder / f"d{seed}.json"), "--report",
            str(folder / f"d{seed}.md"), "--effects", "none", "--max-effects", "1", "--pop",
            "20", "--iters", "30", "--seed", str(seed)]


def _cli(tmp_path, term, size, seed):
    """The diagnose of :func:`_cli_args`, in this process: the JSON and the report's path."""
    from hhra_phys.cli import main

    assert main(_cli_args(tmp_path, term, size, seed)) == 0
    return json.loads((tmp_path / f"d{seed}.json").read_text()), tmp_path / f"d{seed}.md"


#: The CLI's drag run starts with the session in its own process (tests/conftest.py,
#: ``background``); its test reads the outcome.
BACKGROUND = {"test_outside_library_term_is_discovered_by_the_cli":
              lambda folder: _cli_args(folder, "quadratic_drag", 400.0, 3)}


def test_outside_library_term_is_discovered_by_the_cli(background):
    """The CLI's contract on the drag record, seed 3 (the claim held on 5 of 5 seeds)."""
    run = background["test_outside_library_term_is_discovered_by_the_cli"]
    code, _, err = run.result()
    assert code == 0, err[-3000:]
    tmp_path = run.out
    js, rep = json.loads((tmp_path / "d3.json").read_text()), tmp_path / "d3.md"
    found = [s for s in js["steps"] if s["effect"].startswith("discovered_")]
    accepted = [s for s in found if s["accepted"]]
    assert len(accepted) == 1, [s["reason"] for s in found]
    step = accepted[0]
    # The contract outside checks use.
    assert isinstance(step["expression"], str) and step["expression"].startswith(
        ("d ", "u +=", "y +="))
    assert isinstance(step["val"]["rmse"], float)
    assert js["chosen"] == [step["effect"]]
    assert _found(js, "omega"), (js["base"]["val"], js["final"]["val"])
    text = rep.read_text()
    assert "Discovered terms" in text and step["expression"] in text and "95 % CI" in text
    assert (tmp_path / "d3_discovery.png").exists()


@pytest.mark.slow
def test_cubic_spring_is_discovered_over_seeds(tmp_path):
    """Measured through the CLI at this size on seeds 1-5 (docs/diagnosis.md): the claim
    held on 4 of 5 (on seed 2 the base model had absorbed the spring: base at the noise,
    nothing to find); with the drag, 9 of 10. Asserted: 2 of seeds 3-5."""
    ok = [_found(_cli(tmp_path, "cubic_spring", 1000.0, seed)[0], "theta")
          for seed in (3, 4, 5)]
    assert sum(ok) >= 2, ok


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 5])
def test_clean_record_discovers_nothing(seed):
    res = _run(outside_record("none", 0.0, seed=seed, noise_deg=NOISE), seed=seed)
    assert res.chosen == []
    assert not any(s.accepted for s in res.steps)
    assert res.settings["discover"] is True


def test_no_discover_flag_is_parsed():
    from hhra_phys.cli import build_parser

    args = build_parser().parse_args(["diagnose", "public", "--no-discover"])
    assert args.no_discover is True and args.discover_method == "threshold"


@register_part
@dataclass(frozen=True)
class Overflow(Part):
    """Truth only: an overflow from the upper tank, ``dh1/dt -= k_over*h1^2/10`` [cm/s]."""

    name = "overflow"
    stage = "tanks"

    @property
    def parameters(self):
        return (Parameter("k_over", "1/(cm*s)", 0.0, 0.0, 10.0, "linear", "overflow"),)

    def apply(self, ctx):
        h = ctx.x["h1"]
        ctx.add_rate("h1", -ctx.p["k_over"] * h * h / 10)


def _tank_record(seed: int, k_over: float) -> Dataset:
    rng = np.random.default_rng(seed)
    n, fs = 1600, 2.0
    u = np.repeat(rng.uniform(1.0, 4.0, n // 60 + 1), 60)[:n]
    truth = two_tank.make_model().with_parts(Overflow())
    values = {"k_pump": 0.4, "k_over": k_over}
    p = np.array([values.get(q.name, q.nominal) for q in truth.params])
    x0 = np.array([rng.uniform(2, 6), rng.uniform(4, 8)])
    y = Simulator(truth, fs=fs, substeps=8).simulate(u, p, x0=x0)
    y = y + NOISE * rng.standard_normal(n)
    return Dataset(t=np.arange(n) / fs, u=u, y=y, name="tanks", input_name="pump",
                   input_unit="V", output_name="level", output_unit="cm")


@pytest.mark.slow
def test_user_model_outside_term_uses_the_unmeasured_level():
    """Measured on record/search seeds 0-4 (docs/diagnosis.md): a term using ``h1``
    accepted, validation 3x lower or at 1.5x the noise, on 4 of 5 (seed 2: a term in
    ``u`` and ``h2`` instead); asserted: 2 of seeds 0-2."""
    ok = []
    for seed in (0, 1, 2):
        res = _run(_tank_record(seed, 0.2), two_tank.make_model(), seed=seed)
        found = [s.to_json() for s in _discovered(res) if s.accepted]
        base, final = res.base.metrics["val"]["rmse"], res.final.metrics["val"]["rmse"]
        assert not math.isnan(final)
        ok.append(len(found) == 1 and "h1" in found[0]["uses"]
                  and (final <= base / 3 or final <= 1.5 * NOISE))
    assert sum(ok) >= 2, ok
