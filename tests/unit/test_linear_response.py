"""The diagnosis's discrete linear response against scipy's ``dlsim``."""

import warnings

import numpy as np
import pytest
import scipy.signal as sps

from hhra_phys.diagnosis.first_order import _discrete_response


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("nx", [1, 3, 5])
def test_discrete_response_matches_dlsim(seed: int, nx: int) -> None:
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(nx, nx))
    A /= 1.02 * np.max(np.abs(np.linalg.eigvals(A)))  # stable, slowly decaying
    b, c, d = rng.normal(size=nx), rng.normal(size=nx), float(rng.normal())
    cols = rng.normal(size=(400, 4))
    got = _discrete_response(A, b, c, d, cols)
    for j in range(cols.shape[1]):
        _, y, _ = sps.dlsim((A, b[:, None], c[None, :], np.array([[d]]), 0.01), cols[:, j])
        np.testing.assert_allclose(got[:, j], y.ravel(), rtol=1e-12,
                                   atol=1e-12 * np.max(np.abs(y)))


def test_unstable_response_overflows_quietly() -> None:
    # An unstable A (a discovered term with a positive slope) grows without bound: the
    # response overflows to inf/nan without warnings; the callers check its finiteness.
    A = np.array([[1.5]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = _discrete_response(A, np.ones(1), np.ones(1), 0.0, np.ones((3000, 2)))
    assert not np.isfinite(got).all()
    assert np.isfinite(got[:10]).all()


def test_ranking_survives_an_unstable_linearisation(monkeypatch) -> None:
    # The analysis of a fit whose linearisation is unstable at an entry ranks the effects
    # there last (decided by their refit) instead of failing in least squares (a long
    # friction record's second round: "SVD did not converge").
    from hhra_phys.diagnosis import residual as diagnose
    from hhra_phys.models.cylinder import LinearCylinderModel, simulate_cylinder
    from hhra_phys.problem import Problem

    model = LinearCylinderModel()
    prob = Problem(model, simulate_cylinder(seed=3, duration=2.0, noise=0.02),
                   free=["c_force", "c_valve"])
    stable = diagnose._linear_response

    def unstable_at_input(problem, P, entry, cols, umax):
        S = stable(problem, P, entry, cols, umax)
        return np.full_like(S, np.inf) if entry == "input" else S

    monkeypatch.setattr(diagnose, "_linear_response", unstable_at_input)
    names = ["valve_deadzone", "sensor_offset"]
    diag = diagnose.analyse(prob, prob.start_values(), candidates=names)
    ev = {e.name: e for e in diag.evidence}
    assert "unstable at input" in ev["valve_deadzone"].note
    assert ev["valve_deadzone"].identifiable  # refitted, decided by its refit
    assert "unstable" not in ev["sensor_offset"].note
    assert diag.ranked()[-1].name == "valve_deadzone"
