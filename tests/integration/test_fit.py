"""Physical fitting: recovery, derivatives, refiners, uncertainty, persistence."""

from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import ClassVar

import casadi as ca
import numpy as np
import pytest

from hhra_phys import HHRAModel, Model, Simulator, State
from hhra_phys.data import DataError, Dataset
from hhra_phys.fit import fit, fit_many
from hhra_phys.models.hhra.rig import perturbed_physical, simulate_rig
from hhra_phys.parameters import Parameter
from hhra_phys.parts import Context, Part
from hhra_phys.problem import Problem
from hhra_phys.refine import (
    STALL_ITER,
    CompiledLeastSquares,
    least_squares_cost,
    refine_ipopt,
    refine_nlopt,
)
from hhra_phys.result import FitResult

GROUPS = ["g_valve", "g_compress", "g_leak", "g_torque", "g_damping"]


@pytest.fixture(scope="module")
def clean():
    # Truth away from the nominal values (and so from the box centre).
    return simulate_rig(seed=2, noise=0.0, duration=6.0, physical=perturbed_physical(6))


@pytest.fixture(scope="module")
def noisy():
    return simulate_rig(seed=4, noise=0.05, duration=6.0)


def _perturbed(problem: Problem, data: Dataset, factors: np.ndarray) -> np.ndarray:
    truth = np.array([data.metadata["true_params"][n] for n in GROUPS])
    return problem.to_z(np.append(truth * factors, np.radians(data.y[0])))


def test_recovers_truth_from_noise_free_data(clean):
    res = fit(clean, pop_size=20, max_iter=25, seed=3)
    truth = clean.metadata["true_params"]
    nominal = HHRAModel().params
    assert all(abs(np.log(truth[n] / nominal[n].nominal)) > 0.2 for n in ("g_compress", "g_torque"))
    for name in GROUPS:
        assert res.values[name] == pytest.approx(truth[name], rel=0.01), name
    assert res.metrics["val"]["rmse"] < 0.01
    names = [s["name"] for s in res.stages]
    assert names == ["hgwo", "ipopt"]


def test_residual_jacobian_matches_finite_differences(noisy):
    est, _ = noisy.split(0.5)
    problem = Problem(HHRAModel(), est, initial_state="fit")
    z = _perturbed(problem, noisy, np.array([1.1, 0.9, 1.2, 0.95, 1.05]))
    z_sym = ca.MX.sym("z", problem.n_free)
    r = problem.residual_function()(z_sym)
    J = np.array(ca.Function("J", [z_sym], [ca.jacobian(r, z_sym)])(z))
    r0 = np.array(problem.residual_function()(z)).ravel()
    np.testing.assert_allclose(r0, problem.simulate_values(problem.from_z(z)) - est.y, atol=1e-9)
    for i in range(problem.n_free):
        h = 1e-6
        zp, zm = z.copy(), z.copy()
        zp[i] += h
        zm[i] -= h
        fd = (problem.simulate_values(problem.from_z(zp))
              - problem.simulate_values(problem.from_z(zm))) / (2 * h)
        np.testing.assert_allclose(J[:, i], fd, rtol=1e-4, atol=1e-5 * np.abs(fd).max())


def test_compiled_sensitivities_equal_casadi_jacobian(noisy):
    est, _ = noisy.split(0.5)
    problem = Problem(HHRAModel(), est, initial_state="fit")
    z = _perturbed(problem, noisy, np.array([0.9, 1.1, 1.3, 1.05, 0.8]))
    engine = CompiledLeastSquares(problem)
    r, J = engine(z)
    # The residual alone (IPOPT's cost at trial points) is the same, bit for bit, from a
    # fresh engine (no cached point) and at another point than the Jacobian's.
    assert np.array_equal(CompiledLeastSquares(problem).residual(z), r)
    z2 = z + 0.01
    assert np.array_equal(engine.residual(z2), CompiledLeastSquares(problem)(z2)[0])
    z_sym = ca.MX.sym("z", problem.n_free)
    rs = problem.residual_function()(z_sym)
    J_ad = np.array(ca.Function("J", [z_sym], [ca.jacobian(rs, z_sym)])(z))
    np.testing.assert_allclose(r, np.array(problem.residual_function()(z)).ravel(), atol=1e-9)
    np.testing.assert_allclose(J, J_ad, rtol=1e-6, atol=1e-8 * np.abs(J_ad).max())


@pytest.fixture(scope="module")
def refine_case(noisy):
    """Problem, a perturbed start, and the least-squares minimum reached from the truth."""
    est, _ = noisy.split(0.5)
    problem = Problem(HHRAModel(), est, initial_state="fit")
    z_truth = _perturbed(problem, noisy, np.ones(len(GROUPS)))
    reference = refine_ipopt(problem, z_truth)
    return problem, _perturbed(problem, noisy, np.array([1.15, 1.1, 0.8, 0.9, 1.3])), reference


@pytest.mark.parametrize("refiner", ["ipopt", "ipopt-ms", "LD_LBFGS", "LN_BOBYQA"])
def test_refiners_reach_the_minimum_from_a_perturbed_start(refine_case, refiner):
    """Each refiner, from a start 10-30 % off, ends at the minimum found from the truth.

    Measured (seed 4, 6 s): the start costs 38 times the minimum; IPOPT (single and
    multiple shooting) and L-BFGS end at its cost to 2e-14 relative with every group
    within 3e-8 of it; BOBYQA (derivative-free, 300 evaluations) within 0.9 % of its cost
    with the NLopt build of that time, 3.1 % with NLopt 2.11.0 (2026-11-25: the same start,
    budget and problem; its path depends on the build), so 5 % is asked.
    """
    problem, z0, reference = refine_case
    before = least_squares_cost(problem, z0)
    if refiner == "ipopt":
        st = refine_ipopt(problem, z0)
    elif refiner == "ipopt-ms":
        st = refine_ipopt(problem, z0, shooting="multiple", segments=4)
    else:
        st = refine_nlopt(problem, z0, algorithm=refiner, max_eval=300)
    assert st.cost_before == pytest.approx(before)
    assert before > 10 * reference.cost  # the start is far from the minimum
    if refiner == "LN_BOBYQA":
        assert st.cost <= 1.05 * reference.cost
    else:
        assert st.cost == pytest.approx(reference.cost, rel=1e-6)
        groups = problem.from_z(st.z)[: len(GROUPS)]
        np.testing.assert_allclose(groups, problem.from_z(reference.z)[: len(GROUPS)], rtol=1e-4)
    assert st.nfev > 0 and st.seconds > 0


def test_ipopt_stops_where_its_iterate_stalls(refine_case):
    """At the minimum with a tolerance no sum of squares can meet, IPOPT's line search only
    cuts its steps; with ``stall_iter`` it stops once the iterate has not moved for that
    many iterations, at the same cost, with fewer evaluations than running to ``max_iter``
    (the default, ``stall_iter=0``).
    """
    problem, _, reference = refine_case
    kw = {"tol": 1e-30, "max_iter": 40}
    st = refine_ipopt(problem, reference.z, stall_iter=STALL_ITER, **kw)
    assert st.info["stalled"] and st.info["status"] == "Stalled"
    assert st.info["iterations"] < 40
    assert st.cost == pytest.approx(reference.cost, rel=1e-9)
    off = refine_ipopt(problem, reference.z, **kw)
    assert not off.info["stalled"] and off.info["status"] != "Stalled"
    assert off.nfev > st.nfev
    assert off.cost == pytest.approx(st.cost, rel=1e-9)


def test_fixed_parameters_stay_fixed(noisy):
    truth = noisy.metadata["true_params"]
    res = fit(noisy, fixed={"g_leak": 5.0, "g_damping": truth["g_damping"]},
              pop_size=10, max_iter=5, seed=1)
    assert res.values["g_leak"] == 5.0
    assert res.values["g_damping"] == truth["g_damping"]
    assert "g_leak" not in res.free and "g_leak" not in res.ci95
    assert res.values["g_spring"] == 0.0 and res.values["g_load"] == 0.0


def test_confidence_intervals_shrink_with_more_data():
    widths = []
    for duration in (4.0, 16.0):
        data = simulate_rig(seed=7, noise=0.05, duration=duration)
        truth = data.metadata["true_params"]
        res = fit(data, optimizer="none", start={n: truth[n] for n in GROUPS}, split=1.0)
        widths.append(np.array([np.log(res.ci95[n][1] / res.ci95[n][0]) for n in GROUPS]))
    assert np.all(widths[1] < widths[0])


def test_save_load_round_trip_reproduces_predictions(noisy, tmp_path):
    res = fit(noisy, pop_size=10, max_iter=5, seed=0)
    path = res.save(tmp_path / "fit.json")
    with pytest.raises(FileExistsError, match="exists"):
        res.save(path)
    again = FitResult.load(path)
    u = simulate_rig(seed=9, duration=2.0).u
    x0 = {"theta": 0.1}
    np.testing.assert_allclose(again.simulate(u, x0=x0), res.simulate(u, x0=x0), atol=1e-12)
    assert again.ci95.keys() == res.ci95.keys()
    for name, ci in res.ci95.items():
        assert again.ci95[name] == pytest.approx(ci)
    d = again.to_json()
    for key in ("params", "tf", "est", "val", "stages", "seed"):
        assert key in d
    assert set(d["tf"]) >= {"a", "b", "c", "kv"}
    assert d["params"]["g_valve"]["unit"] == "1/(s*mA)"


@dataclass(frozen=True)
class ValveScale(Part):
    """A second valve gain: only the product g_valve * k_extra is identifiable."""

    stage: ClassVar[str] = "flow"
    name: ClassVar[str] = "valve_scale"

    @property
    def parameters(self):
        return (Parameter("k_extra", "-", 1.0, 0.1, 10.0, "log", "redundant valve gain"),)

    def apply(self, ctx: Context) -> None:
        ctx.add_rate("p", (ctx.p["k_extra"] - 1.0) * ctx.signal("flow", self.name))


def test_product_of_two_parameters_triggers_identifiability_warning(noisy):
    model = HHRAModel(effects=[ValveScale()])
    truth = noisy.metadata["true_params"]
    res = fit(noisy, model, optimizer="none", start={n: truth[n] for n in GROUPS}, seed=0)
    text = " ".join(res.warnings)
    assert "k_extra" in text and "g_valve" in text
    assert "not identifiable" in text or "correlated" in text


def test_short_or_flat_data_gives_clear_errors():
    with pytest.raises(DataError, match="too few"):
        Problem(HHRAModel(), simulate_rig(seed=0, duration=0.16))
    with pytest.raises(DataError, match="excit|constant"):
        Dataset.from_arrays(np.full(500, 0.3), np.zeros(500), fs=250.0)


def test_fit_many_through_an_executor(clean):
    with ThreadPoolExecutor(max_workers=2) as ex:
        results = fit_many(seeds=[0, 1], executor=ex, data=clean, pop_size=8, max_iter=3,
                           refine="none")
    assert len(results) == 2
    assert results[0].seed == 0 and results[1].seed == 1
    # Each is the single fit with that seed, to the last digit; the two seeds differ.
    for res, seed in zip(results, (0, 1), strict=True):
        single = fit(clean, seed=seed, pop_size=8, max_iter=3, refine="none")
        assert res.values == single.values and res.history == single.history
    assert results[0].values != results[1].values


def test_result_crosses_a_process_boundary_and_predicts_the_same():
    """A result holds its live problem (compiled code); pickled, it rebuilds the model."""
    import pickle

    data = simulate_rig(seed=4, duration=4.0)
    res = fit(data, pop_size=10, max_iter=3, seed=0)
    assert res.problem is not None
    back = pickle.loads(pickle.dumps(res))
    assert back.problem is None and back.values == res.values
    other = simulate_rig(seed=5, duration=2.0)
    np.testing.assert_array_equal(back.predict(other), res.predict(other))


@dataclass(frozen=True)
class _Growth(Part):
    """``dx/dt = a*x + u``, ``y = x``: at a large ``a`` the state overflows to infinity."""

    stage: ClassVar[str] = "motion"
    name: ClassVar[str] = "growth"

    @property
    def parameters(self):
        return (Parameter("a", "1/s", -1.0, -5.0, 2000.0, "linear", "growth rate"),)

    @property
    def states(self):
        return (State("x", "m", 0.0, "state"),)

    def apply(self, ctx: Context) -> None:
        ctx.add_rate("x", ctx.p["a"] * ctx.x["x"] + ctx.u)


@dataclass(frozen=True)
class _Read(Part):
    stage: ClassVar[str] = "sensor"
    name: ClassVar[str] = "read_x"

    def apply(self, ctx: Context) -> None:
        ctx.signals["y"] = ctx.x["x"]


def test_ipopt_steps_back_from_a_diverged_simulation_without_warnings(capfd):
    """A start where the simulation overflows is an infinite cost IPOPT steps back from;
    CasADi's evaluation warnings and NumPy's on the NaN Jacobian stay out of the user's
    terminal (a long diagnosis printed dozens of them)."""
    t = np.arange(400) * 0.005
    u = np.sin(3 * t) + 0.5 * np.sign(np.sin(0.7 * t))
    model = Model([_Growth(), _Read()], name="growth")
    y = Simulator(model, fs=200.0).simulate(u, np.array([-2.0]))
    data = Dataset(t=t, u=u, y=np.asarray(y).ravel(), name="growth")
    problem = Problem(model, data)
    z0 = problem.to_z(np.array([1500.0]))
    assert not np.isfinite(least_squares_cost(problem, z0))  # the start overflows
    capfd.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a NumPy RuntimeWarning fails the test
        st = refine_ipopt(problem, z0)
    err = capfd.readouterr()
    assert "Inf detected" not in err.out + err.err
    assert "CasADi" not in err.out + err.err
    assert np.isfinite(st.cost) or st.cost == st.cost_before
