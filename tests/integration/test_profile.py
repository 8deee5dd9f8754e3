"""Profile-likelihood intervals: agreement where the fit is quadratic, threshold crossings."""

from __future__ import annotations

import numpy as np
import pytest

from hhra_phys.errors import ParameterError
from hhra_phys.fit import default_model, fit
from hhra_phys.likelihood import _Profiler, profile_parameter, threshold
from hhra_phys.models.hhra.rig import simulate_rig
from hhra_phys.problem import Problem, default_free
from hhra_phys.refine import CompiledLeastSquares
from hhra_phys.result import FitResult

GROUPS = ["g_valve", "g_compress", "g_leak", "g_torque", "g_damping"]


@pytest.fixture(scope="module")
def fitted():
    data = simulate_rig(seed=7, noise=0.05, duration=6.0)
    truth = data.metadata["true_params"]
    model, bounds = default_model(data)
    free = default_free(model)
    problem = Problem(model, data, bounds={k: v for k, v in bounds.items() if k in free},
                      start={n: truth[n] for n in GROUPS}, initial_state="fit")
    res = fit(data, problem=problem, optimizer="none", split=1.0, intervals="profile")
    values = [res.values[n] if n in res.values else res.x0_param(n) for n in problem.free_names]
    return problem, res, problem.to_z(np.array(values))


def test_profile_matches_linearised_interval_where_the_cost_is_quadratic(fitted):
    problem, res, _ = fitted
    assert res.intervals["method"] == "profile"
    linear = res.intervals["linear"]
    for name in problem.free_names:
        lo, hi = res.ci95[name]
        value = res.values[name] if name in res.values else res.x0_param(name)
        assert lo < value < hi, name
        if name == "g_damping":
            continue  # poorly determined on 6 s: its profile is not quadratic (checked below)
        llo, lhi = linear[name]
        if name.startswith("g_"):
            ratio = np.log(hi / lo) / np.log(lhi / llo)
        else:
            ratio = (hi - lo) / (lhi - llo)
        assert 0.9 < ratio < 1.1, (name, ratio)


def test_interval_ends_lie_on_the_threshold(fitted):
    problem, _, z_hat = fitted
    engine = CompiledLeastSquares(problem)
    prof = profile_parameter(problem, z_hat, "g_damping", engine=engine)
    assert prof.open_ends == (False, False)
    check = _Profiler(problem, z_hat, engine)
    i = problem.free_names.index("g_damping")
    for end in prof.z_interval:
        ssr, _ = check.solve(i, end, z_hat)
        assert ssr == pytest.approx(prof.threshold, rel=1e-4)
    inside = [s for c, s in prof.points if prof.z_interval[0] < c < prof.z_interval[1]]
    assert inside and max(inside) <= prof.threshold * (1 + 1e-9)
    assert min(inside) <= check.ssr_min * (1 + 1e-9)


def test_profile_result_round_trips_and_is_reported(fitted, tmp_path):
    _, res, _ = fitted
    again = FitResult.load(res.save(tmp_path / "fit.json"))
    assert again.intervals["method"] == "profile"
    for name, ci in res.ci95.items():
        assert again.ci95[name] == pytest.approx(ci)
    assert "(profile)" in again.summary()


def test_threshold_and_bad_requests():
    # F(0.95; 1, large) -> chi2(0.95; 1) = 3.841: the linearised 1.96-sigma rule.
    assert threshold(100.0, 100_001, 1) == pytest.approx(100.0 * (1 + 3.8415 / 100_000), rel=1e-6)
    with pytest.raises(ParameterError, match="level"):
        threshold(1.0, 10, 2, level=1.5)
    with pytest.raises(ParameterError, match="intervals"):
        fit(simulate_rig(seed=1, duration=2.0), optimizer="none", intervals="bootstrap")


def test_unknown_parameter_is_refused(fitted):
    problem, _, z_hat = fitted
    with pytest.raises(ParameterError, match="not a free parameter"):
        profile_parameter(problem, z_hat, "g_spring")


def test_profile_from_a_point_that_is_not_the_minimum(fitted):
    problem, _, z_hat = fitted
    engine = CompiledLeastSquares(problem)
    off = z_hat.copy()
    off[problem.free_names.index("g_valve")] += 0.05  # 12 % away along a correlated group
    from_off = profile_parameter(problem, off, "g_leak", engine=engine)
    from_opt = profile_parameter(problem, z_hat, "g_leak", engine=engine)
    assert from_off.moved and not from_opt.moved
    assert not from_off.lower_minimum and not from_opt.lower_minimum
    assert from_off.ssr_min == pytest.approx(from_opt.ssr_min, rel=1e-8)
    assert from_off.interval == pytest.approx(from_opt.interval, rel=1e-3)


def test_unrefined_fit_warns_that_profiles_are_centred_elsewhere(fitted):
    problem, _, _ = fitted
    res = fit(problem.data, problem=problem, optimizer="none", refine="none", split=1.0,
              intervals="profile")
    assert any("did not end at the least-squares minimum" in w for w in res.warnings)
    assert "polished_ssr" in res.intervals


def test_last_step_reaches_the_box_so_open_ends_are_the_bounds(fitted):
    problem, _, z_hat = fitted
    i = problem.free_names.index("g_damping")
    box = problem.bounds_z()[i]
    prof = profile_parameter(problem, z_hat, "g_damping", max_steps=1)
    for end, is_open, bound in zip(prof.z_interval, prof.open_ends, box, strict=True):
        if is_open:
            assert end == bound
        else:
            ssr, _ = _Profiler(problem, z_hat, CompiledLeastSquares(problem)).solve(i, end, z_hat)
            assert ssr == pytest.approx(prof.threshold, rel=1e-4)
