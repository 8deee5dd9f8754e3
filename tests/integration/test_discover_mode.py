"""The discovered resonant mode (hhra_phys.discover.DiscoveredMode): a candidate with new states.

The part is checked against SciPy's filter of the package's own simulation (the
mode's equations), its save/load round trip and screening; the loop's use of it
against records of the independent reference model read through a resonant
sensor (:mod:`hhra_phys.reference.resonant`) and records without a resonance.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy import signal as sps

from hhra_phys import Simulator
from hhra_phys.diagnosis.engine import augment
from hhra_phys.diagnosis.screening import load_column, mode_column
from hhra_phys.errors import ModelError
from hhra_phys.fit import fit
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.reference.hhra import reference_record
from hhra_phys.reference.outside import outside_record
from hhra_phys.reference.resonant import loaded_record, resonant_record
from hhra_phys.result import FitResult
from hhra_phys.terms import (
    MODE_ENTRIES,
    DiscoveredMode,
    mode_entries,
    velocity_pairs,
    velocity_states,
)

NOISE = 0.05
LOOP = {"candidates": [], "max_effects": 1, "pop_size": 20, "max_iter": 30}


def _nominal(model):
    return np.array([q.nominal for q in model.params])


def test_output_mode_is_the_second_order_filter_of_the_output():
    rec = outside_record("none", 0.0, seed=1, duration=2.0, noise_deg=0.0)
    base = HHRAModel()
    w, z = 2 * math.pi / 0.1, 0.1
    for k in (1.0, 0.4):
        mode = DiscoveredMode(index=1, w=w, zeta=z, mix=k, w_min=1.0, w_max=1e3, unit="deg")
        m = base.with_parts(mode)
        assert m.state_names[-2:] == ["mode1_a", "mode1_b"] and np.all(m.x0()[-2:] == 0)
        y0 = Simulator(base, fs=rec.fs, substeps=4).simulate(rec.u, _nominal(base))
        y1 = Simulator(m, fs=rec.fs, substeps=4).simulate(rec.u, _nominal(m))
        t = np.arange(rec.n) / rec.fs
        _, yf, _ = sps.lsim(([w * w], [1, 2 * z * w, w * w]), y0 - y0[0], t)
        want = y0 + k * (yf + y0[0] - y0)
        # lsim interpolates the sampled output linearly: agreement to 1 % of the change
        assert np.max(np.abs(y1 - want)) < 0.01 * np.ptp(y0), k
        assert np.max(np.abs(y1 - y0)) > 0.1 * np.ptp(y0) * k  # the mode does act
    # The first-order column is the same filter (bilinear, at mix 1).
    col = mode_column(y0, 1 / rec.fs, w, z)
    assert np.max(np.abs(y0 + col - (yf + y0[0]))) < 0.01 * np.ptp(y0)


def test_input_mode_filters_the_input():
    base = HHRAModel()
    u = np.r_[np.zeros(50), np.ones(250)] * 0.5
    w, z = 2 * math.pi / 0.2, 0.2
    mode = DiscoveredMode(target="input", index=2, w=w, zeta=z, mix=1.0, w_min=1.0,
                          w_max=1e3, unit="mA")
    m = base.with_parts(mode)
    assert mode.name == "discovered_mode_input_2" and mode.stage == "input"
    assert [s.fit_initial for s in mode.states] == [True, False]
    # The HHRA's angle integrates the command: compare the rate of the two models.
    y_filtered = Simulator(m, fs=250.0, substeps=4).simulate(u, _nominal(m))
    t = np.arange(u.size) / 250.0
    _, uf, _ = sps.lsim(([w * w], [1, 2 * z * w, w * w]), u, t, interp=False)
    y_ref = Simulator(base, fs=250.0, substeps=4).simulate(uf, _nominal(base))
    # sampled filter input (held) against the exact in-sample filter: a small lag only
    assert np.max(np.abs(y_filtered - y_ref)) < 0.03 * np.ptp(y_ref)


def test_load_mode_is_the_reference_loaded_shaft():
    """The load mode at ``rate:omega`` against the independent two-mass reference
    (:func:`~hhra_phys.reference.resonant.loaded_record`: absolute load states,
    ``solve_ivp``), for a light and a heavy load."""
    base = HHRAModel()
    assert velocity_states(base) == ["omega"] and velocity_pairs(base) == {"omega": "theta"}
    assert mode_entries(base) == ["mode:output", "mode:input", "mode:rate:omega"]
    for period, ratio, z in ((0.1, 0.5, 0.1), (0.25, 0.3, 0.2)):
        rec = loaded_record(period, ratio, z, seed=1, duration=2.0, noise_deg=0.0)
        truth = rec.metadata["truth"]
        mode = DiscoveredMode(target="rate:omega", index=1, w=truth["w"], zeta=z, mix=ratio,
                              w_min=1.0, w_max=1e3, unit="rad/s", twist_unit="rad")
        assert [st.unit for st in mode.states] == ["rad", "rad/s"]
        assert mode.name == "discovered_mode_rate_omega_1" and mode.uses == ["omega"]
        assert mode.applicable(base) is None
        m = base.with_parts(mode)
        values = {**{q.name: q.nominal for q in m.params}, **truth["params"],
                  "mode1_w": truth["w"], "mode1_z": z, "mode1_k": ratio}
        P = np.array([values[n] for n in m.params.names])
        x0 = np.array([*(truth["x0"][n] for n in ("theta", "omega", "p")), 0.0, 0.0])
        y = Simulator(m, fs=rec.fs, substeps=8).simulate(rec.u, P, x0=x0)
        y_rigid = Simulator(base, fs=rec.fs, substeps=8).simulate(rec.u, P[:len(base.params)],
                                                                   x0=x0[:3])
        assert np.max(np.abs(y - rec.y)) < 1e-3, (period, ratio)  # deg, RK4 x 8
        assert np.max(np.abs(y_rigid - rec.y)) > 0.1, (period, ratio)  # the load does act
    # To first order in the ratio, the load's reaction is load_column of the velocity.
    rec = loaded_record(0.1, 0.01, 0.1, seed=1, duration=2.0, noise_deg=0.0)
    t = rec.metadata["truth"]
    vals = {**{q.name: q.nominal for q in base.params}, **t["params"]}
    P0 = np.array([vals[n] for n in base.params.names])
    x0 = np.array([t["x0"][n] for n in ("theta", "omega", "p")])
    _, X = Simulator(base, fs=rec.fs, substeps=8).simulate(rec.u, P0, x0=x0, states=True)
    col = load_column(X[:, 1], 1 / rec.fs, t["w"], 0.1)
    # the load's acceleration minus the shaft's, against the exact coupling at ratio 0.01
    m = base.with_parts(DiscoveredMode(target="rate:omega", index=1, w=t["w"], zeta=0.1,
                                       mix=0.01, w_min=1.0, w_max=1e3))
    P = np.r_[P0, t["w"], 0.1, 0.01]
    _, Xm = Simulator(m, fs=rec.fs, substeps=8).simulate(rec.u, P, x0=np.r_[x0, 0, 0],
                                                         states=True)
    f_c = t["w"] ** 2 * Xm[:, 3] + 0.2 * t["w"] * Xm[:, 4]
    assert np.max(np.abs(-f_c - col)) < 0.05 * np.max(np.abs(col))


def test_mode_validates_its_fields_and_round_trips(tmp_path):
    with pytest.raises(ModelError, match="the output, the input or the rate"):
        DiscoveredMode(target="sideways")
    assert "not one (velocity states: omega)" in DiscoveredMode(target="rate:p").applicable(
        HHRAModel())
    with pytest.raises(ModelError, match="w_min"):
        DiscoveredMode(w_min=2.0, w_max=1.0)
    assert set(MODE_ENTRIES) == {"mode:output", "mode:input"}
    mode = DiscoveredMode(index=1, w=60.0, zeta=0.1, mix=1.0, w_min=10.0, w_max=300.0,
                          unit="deg")
    assert mode.applicable(HHRAModel()) is None
    assert "period 0.105 s" in mode.expression({})
    rec = resonant_record(0.1, 0.1, seed=1, duration=2.0)
    res = fit(rec, HHRAModel().with_parts(mode), optimizer="none", refine="none",
              free=["g_valve", "mode1_w"], split=0.7)
    back = FitResult.load(res.save(tmp_path / "fit.json"))
    assert back.model.part_names() == res.model.part_names()
    assert np.allclose(back.simulate(rec.u, x0=res.x0), res.simulate(rec.u, x0=res.x0),
                       atol=1e-9)


def _run(ds, seed, entries=None):
    kw = {"entries": list(entries)} if entries else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return augment(ds, seed=seed, discover_kw=kw, **LOOP)


def _mode_steps(res):
    return [s.to_json() for s in res.steps if s.to_json().get("discovered")
            and "period" in s.to_json()["screening"]]


#: Hidden resonance of the tests: period 0.25 s, damping 0.1 (docs/diagnosis.md).
PERIOD, DAMPING = 0.25, 0.1


@pytest.mark.parametrize(("seeds", "need"), [
    pytest.param((1,), 1, id="seed1"),
    pytest.param((1, 2, 3), 2, id="seeds1-3", marks=pytest.mark.slow),
])
def test_hidden_resonance_is_found_with_its_frequency_in_the_ci(seeds, need):
    """Reference records read through a resonant sensor, modes only (library rounds off).

    Measured on seeds 1-3 (``experiments/discover.py``, docs/diagnosis.md): the output
    mode accepted with the true frequency inside its 95 % CI on 3 of 3; asserted 2 of 3
    (slow), seed 1 in the default run.
    """
    hits = []
    for seed in seeds:
        ds = resonant_record(PERIOD, DAMPING, seed=seed, noise_deg=NOISE)
        res = _run(ds, seed, MODE_ENTRIES)
        acc = [s for s in _mode_steps(res) if s["accepted"]]
        if acc:
            w_lo, w_hi = next(v for k, v in acc[0]["ci95"].items() if k.endswith("_w"))
            p_lo, p_hi = acc[0]["screening"]["period_ci95"]
            hits.append(w_lo <= ds.metadata["truth"]["w"] <= w_hi and p_lo <= PERIOD <= p_hi)
            assert acc[0]["expression"].startswith("y += ") and "period" in acc[0]["expression"]
            assert res.chosen == [acc[0]["effect"]]
    assert sum(hits) >= need, hits


#: Hidden load of the tests: period 0.25 s on its coupling, ratio 0.5, damping 0.1.
LOAD = (0.25, 0.5, 0.1)


@pytest.mark.slow
def test_hidden_load_is_found_with_its_frequency_and_ratio_in_the_ci():
    """Reference records whose shaft carries a compliant load, load mode only.

    Measured on seeds 1-3 (``experiments/discover.py --families load:0.25 --entries
    mode:rate:omega``, docs/diagnosis.md): accepted with the true period in its CI on 3
    of 3; asserted 2 of 3, the ratio's CI too.
    """
    period, ratio, damping = LOAD
    hits = []
    for seed in (1, 2, 3):
        ds = loaded_record(period, ratio, damping, seed=seed, noise_deg=NOISE)
        res = _run(ds, seed, ["mode:rate:omega"])
        acc = [s for s in _mode_steps(res) if s["accepted"]]
        if acc:
            ci = acc[0]["ci95"]
            w_lo, w_hi = next(v for k, v in ci.items() if k.endswith("_w"))
            k_lo, k_hi = next(v for k, v in ci.items() if k.endswith("_k"))
            hits.append(w_lo <= ds.metadata["truth"]["w"] <= w_hi and k_lo <= ratio <= k_hi)
            assert acc[0]["uses"] == ["omega"] and "compliant coupling" in acc[0]["expression"]
            assert res.chosen == ["discovered_mode_rate_omega_1"]
            units = {st.name: st.unit for st in res.final.model.states}
            assert units["mode1_a"] == "rad" and units["mode1_b"] == "rad/s"
            assert res.test_scores["final"]["rmse"] < 1.15 * NOISE
    assert sum(hits) >= 2, hits


@pytest.mark.slow
@pytest.mark.parametrize("seed,make", [
    (2, lambda: outside_record("none", 0.0, seed=2, noise_deg=NOISE)),
    (1, lambda: reference_record(seed=1, duration=6.0, noise_deg=NOISE, levels=4,
                                 effects={"valve_deadzone": {"i_dead": 0.2}})),
], ids=["clean-seed2", "deadzone-seed1"])
def test_no_mode_without_a_resonance(seed, make):
    """Modes only (output, input and load), library rounds off: records without a
    resonance get no mode.

    Measured (docs/diagnosis.md): no mode accepted on the clean records and the large
    dead zone, seeds 1-3 each (a mode was refitted and rejected on these two); the
    large input delay got one on 1 of 3 seeds (not tested here: in the loop the library's
    delay comes first and the loop stops at the noise level).
    """
    res = _run(make(), seed, mode_entries(HHRAModel()))
    assert not any(s["accepted"] for s in _mode_steps(res))
    assert res.chosen == []


def test_a_mode_at_a_box_bound_is_not_a_resolved_resonance():
    """Frequency, damping and mix (a load's ratio) at a bound: dropped (docs/diagnosis.md:
    an output mode with its mix at -3 stood in for a dead zone)."""
    from types import SimpleNamespace

    from hhra_phys.diagnosis.discovery import _mode_at_edge

    def edges(mode, **vals):
        values = {p.name: p.nominal for p in mode.parameters}
        values.update({mode.pname[k]: v for k, v in vals.items()})
        return _mode_at_edge(SimpleNamespace(term=mode, result=SimpleNamespace(values=values)))

    out = DiscoveredMode(index=1, w=60.0, zeta=0.1, mix=1.0, w_min=10.0, w_max=300.0)
    assert edges(out) == []
    assert edges(out, k=-3.0) == ["mix"] and edges(out, k=2.99) == ["mix"]
    assert edges(out, k=2.9) == [] and edges(out, k=-0.01) == []
    assert edges(out, z=0.005) == ["damping"] and edges(out, w=300.0) == ["frequency"]
    load = DiscoveredMode(target="rate:omega", index=1, w=60.0, zeta=0.1, mix=0.5,
                          w_min=10.0, w_max=300.0)
    assert edges(load) == [] and edges(load, k=10.0) == ["ratio"]
    assert edges(load, k=1e-3) == ["ratio"] and edges(load, k=0.002) == []
