"""The linear cylinder: package model against an independent plant, its linearisation, a fit.

The plant in :mod:`hhra_phys.reference.cylinder` is written in physical SI variables
with SciPy and shares no code with the package model, so agreement checks the
normalisation, the group mapping and the signs of the valve law (data from the model's
own equations cannot catch their bugs: docs/model.md, "An independent reference").
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from hhra_phys.effects import make_effect
from hhra_phys.errors import ParameterError
from hhra_phys.fit import fit
from hhra_phys.model import Model
from hhra_phys.models.cylinder import (
    DEFAULT_FREE,
    MM_PER_M,
    CylinderChambers,
    CylinderOrificeValve,
    CylinderPhysical,
    LinearCylinderModel,
    LinearMotion,
    PositionOutput,
    perturbed_physical,
    simulate_cylinder,
)
from hhra_phys.models.hhra import CurrentCommand
from hhra_phys.reference.cylinder import cylinder_rhs
from hhra_phys.simulate import Simulator

FS = 250.0


def _plants() -> list[CylinderPhysical]:
    """Nominal, two perturbed cylinders and one with a spring and a load force."""
    base = CylinderPhysical()
    return [base, perturbed_physical(1), perturbed_physical(2),
            replace(perturbed_physical(3), K=4.0e4, F_L=-3.0e3)]


def _model_rates(model: Model, phys: CylinderPhysical, states: np.ndarray, currents: np.ndarray):
    """Package rates in physical units (dx, dv, dP_L) for states rows (x, v, p) [m, m/s, -]."""
    f = model.functions(1.0 / FS)["f"]
    p = model.params.vector({k: v for k, v in phys.groups().items() if k in model.params})
    order = [model.state_names.index(n) for n in ("x", "v", "p")]
    out = []
    for s, i in zip(states, currents, strict=True):
        xm = np.empty(model.nx)
        xm[order] = s
        rate = np.array(f(xm, [i], p)).ravel()[order]
        out.append(rate * np.array([1.0, 1.0, phys.p_s]))
    return np.array(out)


def _grid() -> tuple[np.ndarray, np.ndarray]:
    """States x [m], v [m/s], p [-] and currents [mA] covering all four (I, p) sign quadrants."""
    rows = list(itertools.product((-0.2, 0.0, 0.15), (-0.15, 0.0, 0.1), (-0.8, -0.25, 0.3, 0.85),
                                  (-5.0, -0.4, 0.0, 0.5, 4.0)))
    arr = np.array(rows)
    return arr[:, :3], arr[:, 3]


@pytest.mark.parametrize("sharp", [False, True])
def test_rate_function_matches_reference_rhs(sharp):
    states, currents = _grid()
    assert {(np.sign(i), np.sign(p)) for i, p in zip(currents, states[:, 2], strict=True)} >= {
        (1, 1), (1, -1), (-1, 1), (-1, -1)}
    if sharp:
        # Nearly unsmoothed orifice law: agreement must then be near round-off.
        model = Model([CurrentCommand(), CylinderOrificeValve(sign_eps=1e-9, sqrt_delta=1e-14),
                       CylinderChambers(), LinearMotion(), PositionOutput()])
    else:
        model = LinearCylinderModel()
    for phys in _plants():
        got = _model_rates(model, phys, states, currents)
        ref = np.array([cylinder_rhs(0.0, (x, v, p * phys.p_s), i, phys.plant())
                        for (x, v, p), i in zip(states, currents, strict=True)])
        scale = np.abs(ref).max(axis=0)
        # The default smoothing of the root (delta = 1e-6) is within 1.3e-3 of the exact
        # root for drops >= 0.15 p_s, which the grid respects; cancellation of the flow
        # terms is why the tolerance is relative to each rate's largest magnitude.
        tol = 1e-6 if sharp else 2e-3
        np.testing.assert_allclose(got / scale, ref / scale, rtol=0, atol=tol)


def test_reference_seal_friction_is_the_librarys_coulomb_friction_on_the_piston():
    """The reference's optional friction ``F_c*tanh(v/v_c)`` (records that the cylinder
    model lacks, experiments/cylinder_friction.py) is what the library's
    ``coulomb_friction`` adds when it binds to the piston velocity by role: tanh profile,
    width ``v_c``, level ``F_c/m`` [m/s^2]."""
    states, currents = _grid()
    base = LinearCylinderModel()
    for f_c, v_c in ((800.0, 1e-3), (2500.0, 0.02)):
        eff = make_effect("coulomb_friction", model=base, profile="tanh", width=v_c)
        model = base.with_parts(eff)
        for phys in _plants()[:2]:
            fun = model.functions(1.0 / FS)["f"]
            values = {k: v for k, v in phys.groups().items() if k in model.params}
            values["g_coulomb"] = f_c / phys.m
            p = model.params.vector(values)
            order = [model.state_names.index(n) for n in ("x", "v", "p")]
            got, ref = [], []
            for st, i in zip(states, currents, strict=True):
                xm = np.empty(model.nx)
                xm[order] = st
                got.append(np.array(fun(xm, [i], p)).ravel()[order] * [1.0, 1.0, phys.p_s])
                ref.append(cylinder_rhs(0.0, (st[0], st[1], st[2] * phys.p_s), i,
                                        {**phys.plant(), "F_c": f_c, "v_c": v_c}))
            got, ref = np.array(got), np.array(ref)
            plain = np.array([cylinder_rhs(0.0, (x, v, pp * phys.p_s), i, phys.plant())
                              for (x, v, pp), i in zip(states, currents, strict=True)])
            scale = np.abs(ref).max(axis=0)
            np.testing.assert_allclose(got / scale, ref / scale, rtol=0, atol=2e-3)
            # the friction is there: the rate of v differs from the plain plant's
            assert np.abs(ref[:, 1] - plain[:, 1]).max() > 0.5 * f_c / phys.m


def test_record_with_seal_friction_is_validated_and_said():
    with pytest.raises(ParameterError, match="coulomb must be"):
        simulate_cylinder(seed=1, duration=4.0, coulomb=-1.0)
    with pytest.raises(ParameterError, match="coulomb_width"):
        simulate_cylinder(seed=1, duration=4.0, coulomb=100.0, coulomb_width=0.0)
    a = simulate_cylinder(seed=1, duration=4.0, coulomb=800.0)
    b = simulate_cylinder(seed=1, duration=4.0)
    assert a.metadata["coulomb"]["force_N"] == 800.0 and "coulomb" not in b.metadata
    np.testing.assert_array_equal(a.u, b.u)
    assert np.abs(a.y - b.y).max() > 0.1  # mm: the friction moves the piston's path


def test_linearisation_is_the_hand_derived_transfer_function():
    for phys, valve in [(perturbed_physical(4), "orifice"),
                        (replace(perturbed_physical(5), K=6.0e4), "orifice"),
                        (perturbed_physical(6), "linear")]:
        model = LinearCylinderModel(valve=valve)
        g = {k: v for k, v in phys.groups().items() if k in model.params}
        if valve == "linear":
            g["c_kp"] = 7.5
        p = model.params.vector(g)
        A, B, C, D = model.linearize(p)
        # Closed form (module docstring): x/I = kv / (s^3 + b s^2 + c s + d).
        leak = g["c_leak"] + g.get("c_kp", 0.0)
        b = g["c_damping"] + leak
        c = g["c_spring"] + g["c_damping"] * leak + g["c_force"] * g["c_compress"]
        d = g["c_spring"] * leak
        kv = g["c_force"] * g["c_valve"]
        assert model.tf_coefficients(p) == pytest.approx({"a": 1.0, "b": b, "c": c, "d": d,
                                                          "kv": kv})
        poles = np.sort_complex(np.linalg.eigvals(A))
        np.testing.assert_allclose(poles, np.sort_complex(np.roots([1.0, b, c, d])),
                                   rtol=1e-9, atol=1e-9)
        if d == 0.0:  # integrator and a damped pair: -b/2 +- j sqrt(c - b^2/4)
            pair = -b / 2 + 1j * np.sqrt(c - b * b / 4)
            np.testing.assert_allclose(np.sort_complex(poles),
                                       np.sort_complex([0.0, pair, pair.conjugate()]),
                                       atol=1e-9 * abs(pair))
        for w in (0.3, 10.0, np.sqrt(c), 400.0):
            s = 1j * w
            lin = (C @ np.linalg.solve(s * np.eye(3) - A, B) + D).item()
            hand = MM_PER_M * kv / (s**3 + b * s**2 + c * s + d)
            assert lin == pytest.approx(hand, rel=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_simulated_record_stays_in_stroke_and_matches_the_package_simulator(seed):
    phys = perturbed_physical(seed)
    ds = simulate_cylinder(seed=seed, truth=phys, noise=0.0)
    meta = ds.metadata
    assert len(ds) == 5000 and ds.output_unit == "mm" and ds.input_unit == "mA"
    half_stroke_mm = 0.5 * phys.stroke * MM_PER_M
    assert np.abs(ds.y).max() < 0.8 * half_stroke_mm  # inside the stroke, with margin
    assert np.ptp(ds.y) > 50.0  # the piston really moves
    assert 0.15 < meta["max_abs_pressure"] < 0.8  # the orifice law is exercised, no cavitation
    assert abs(ds.u.mean()) < 1e-12  # inverse-repeat: zero-mean current
    assert np.unique(np.round(np.abs(ds.u[ds.u != 0]), 9)).size >= 3  # multi-level
    model = LinearCylinderModel()
    truth = meta["truth"]
    assert set(truth) == set(model.params.names)
    assert truth == pytest.approx({k: v for k, v in phys.groups().items() if k != "c_kp"})
    # The package model (RK4, smoothed valve) reproduces the independent plant far
    # below the measurement noise.
    y = Simulator(model, fs=FS).simulate(ds.u, model.params.vector(truth))
    assert np.abs(y - ds.y).max() < 0.2 * 0.05


def test_record_is_seeded_and_noise_is_in_mm():
    a = simulate_cylinder(seed=7, duration=4.0, noise=0.1)
    b = simulate_cylinder(seed=7, duration=4.0, noise=0.1)
    clean = simulate_cylinder(seed=7, duration=4.0, noise=0.0)
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.u, clean.u)
    assert (a.y - clean.y).std() == pytest.approx(0.1, rel=0.1)
    assert not np.array_equal(a.u, simulate_cylinder(seed=8, duration=4.0).u)
    groups = perturbed_physical(2).groups()
    by_groups = simulate_cylinder(seed=7, duration=4.0, truth=groups)
    assert by_groups.metadata["truth"] == pytest.approx(
        {k: v for k, v in groups.items() if k != "c_kp"})


def test_saved_model_reloads_with_the_same_equations():
    model = LinearCylinderModel(nominal={"c_damping": 33.0})
    again = Model.from_json(model.to_json())
    assert again.params.names == model.params.names
    np.testing.assert_array_equal(again.nominal(), model.nominal())
    x = np.array([0.3, 0.05, -0.1])
    np.testing.assert_array_equal(np.array(again.functions(0.004)["f"](x, [1.5], again.nominal())),
                                  np.array(model.functions(0.004)["f"](x, [1.5], model.nominal())))


@pytest.mark.parametrize(("seeds", "need"), [
    pytest.param((0,), 1, id="seed0"),
    pytest.param(tuple(range(5)), 4, id="seeds0-4", marks=pytest.mark.slow),
])
def test_fit_recovers_output_and_groups_over_seeds(seeds, need):
    """Five short records, truths away from nominal; each split in estimation and validation.

    Measured (pop 30, 40 iterations, 8 s records): validation RMSE/noise 0.98-1.01 and
    every free group inside its 95 % interval on 8 of 8 records (seeds 0-7); with the
    valve's pressure sign flipped, RMSE/noise 1.8-14 and 1 of 5 covered. The test asks
    for every record within 1.1 of the noise and all groups covered on at least 4 of 5.
    The default run fits seed 0 (within 1.1, all covered); the rate over 5 seeds is slow.
    """
    noise = 0.05
    ratios, covered = [], 0
    for seed in seeds:
        phys = perturbed_physical(100 + seed)
        record = simulate_cylinder(seed=seed, duration=16.0, truth=phys, noise=noise)
        # The model's defaults: c_spring and c_load held, the initial position fitted;
        # the validation half starts mid-motion and gets its initial state estimated.
        res = fit(record, model=LinearCylinderModel(), pop_size=30, max_iter=40, seed=seed)
        assert sorted(res.free) == sorted([*DEFAULT_FREE, "x0_x"])
        est = record
        truth = est.metadata["truth"]
        ratios.append(res.metrics["val"]["rmse"] / noise)
        covered += all(res.ci95[n][0] <= truth[n] <= res.ci95[n][1] for n in DEFAULT_FREE)
    assert max(ratios) <= 1.1, ratios
    assert covered >= need, (covered, ratios)
