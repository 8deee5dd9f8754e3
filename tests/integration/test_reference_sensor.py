"""The reference rig's sensor options: coloured (AR(1)) noise, drift, quantisation."""

import numpy as np
import pytest

from hhra_phys.cli import main
from hhra_phys.data import load
from hhra_phys.reference import reference_record


@pytest.mark.parametrize("seed", [1, 2])
def test_coloured_noise_drift_and_quantisation(seed):
    clean = reference_record(seed=seed, duration=4.0, noise_deg=0.0)
    ar = reference_record(seed=seed, duration=4.0, noise_deg=0.05, noise_ar=0.9)
    n = ar.y - clean.y
    assert np.std(n) == pytest.approx(0.05, rel=0.35)
    assert np.corrcoef(n[:-1], n[1:])[0, 1] == pytest.approx(0.9, abs=0.06)
    assert ar.metadata["noise_ar"] == 0.9 and np.array_equal(ar.u, clean.u)
    drift = reference_record(seed=seed, duration=4.0, noise_deg=0.0, drift_deg=0.2)
    d = drift.y - clean.y
    assert d[0] == pytest.approx(0.0, abs=1e-12) and d[-1] == pytest.approx(0.2)
    q = 360.0 / 4096
    enc = reference_record(seed=seed, duration=4.0, noise_deg=0.01, quantization=q)
    assert np.allclose(enc.y / q, np.round(enc.y / q))
    # Reproducible from the seed.
    again = reference_record(seed=seed, duration=4.0, noise_deg=0.05, noise_ar=0.9)
    assert np.array_equal(again.y, ar.y)


@pytest.mark.parametrize("kw", [{"noise_ar": 1.0}, {"noise_ar": float("nan")},
                                {"drift_deg": float("inf")}, {"quantization": -1.0}])
def test_bad_sensor_options_are_refused(kw):
    with pytest.raises(ValueError, match=next(iter(kw)).split("_")[0]):
        reference_record(seed=0, duration=1.0, **kw)


def test_simulate_cli_sensor_flags(tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert main(["simulate", "--generator", "reference", "--duration", "2", "--noise-ar",
                 "0.9", "--drift", "0.1", "--out", str(out)]) == 0
    ds = load(out)
    assert ds.metadata.get("noise_ar") == 0.9 and ds.metadata.get("drift_deg") == 0.1
    assert main(["simulate", "--noise-ar", "0.5", "--out", str(tmp_path / "m.csv")]) == 2
    assert "--generator reference" in capsys.readouterr().err
    assert main(["simulate", "--generator", "reference", "--noise-ar", "1.5",
                 "--out", str(tmp_path / "b.csv")]) == 2


@pytest.mark.parametrize("seed", [1, 3])
def test_a_drift_is_fitted_as_the_sensors(seed):
    """sensor_drift takes a drifting encoder's trend: its rate, and the residual at the noise."""
    from hhra_phys.effects import make_effect
    from hhra_phys.fit import fit
    from hhra_phys.models.hhra import HHRAModel

    ds = reference_record(seed=seed, duration=4.0, noise_deg=0.02, drift_deg=0.3)
    rate = 0.3 / (ds.t[-1] - ds.t[0])  # deg/s
    base = fit(ds, HHRAModel(), pop_size=12, max_iter=15, seed=seed)
    model = HHRAModel(effects=[make_effect("sensor_drift", data=ds)])
    res = fit(ds, model, pop_size=12, max_iter=15, seed=seed)
    assert res.values["drift_rate"] == pytest.approx(rate, rel=0.2)
    assert res.metrics["est"]["rmse"] < base.metrics["est"]["rmse"]
    assert res.metrics["est"]["rmse"] < 1.1 * 0.02


def test_intervals_under_coloured_noise_come_from_its_noise_model():
    """AR(1) 0.9: the linear intervals are the sandwich ones (wider, said so); white: unchanged."""
    from hhra_phys.fit import fit
    from hhra_phys.models.hhra import HHRAModel

    ar = fit(reference_record(seed=2, duration=4.0, noise_deg=0.05, noise_ar=0.9), HHRAModel(),
             pop_size=12, max_iter=15, seed=2)
    colour = ar.intervals["coloured_noise"]
    assert colour["a"] > 0.7 and min(colour["widened"].values()) > 1.5
    assert any("sandwich covariance" in w for w in ar.warnings)
    white = fit(reference_record(seed=2, duration=4.0, noise_deg=0.05), HHRAModel(),
                pop_size=12, max_iter=15, seed=2)
    assert "coloured_noise" not in white.intervals
    assert not any("coloured" in w for w in white.warnings)


#: The drift records on which the loop once took the physics (the test below).
DRIFT_SEEDS = (1, 2)


def _drift_loop(seed: int) -> tuple[list[str], list[tuple[str, str, bool]]]:
    """The loop on one drift record: its choice and its steps' (effect, action, sensor).

    Module level so that a worker process runs it (the loop is the same there: it is
    reproducible from its seed).
    """
    import warnings

    from hhra_phys.diagnosis.engine import augment

    ds = reference_record(seed=seed, duration=8.0, levels=4, noise_deg=0.05, drift_deg=0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = augment(ds, seed=seed, max_effects=2, pop_size=20, max_iter=30)
    return res.chosen, [(s.effect, s.action, s.sensor) for s in res.steps]


@pytest.fixture(scope="module")
def drift_loops(request, loop_workers):
    """The selected seeds' loops started together, one per worker process (the two
    cores of the CI machine, where pytest itself uses one); each test waits for its own."""
    name = "test_a_drifting_encoder_adds_no_physics_to_the_loop"
    seeds = {item.callspec.params["seed"] for item in request.session.items
             if getattr(item, "module", None) is request.module
             and getattr(item, "originalname", None) == name}
    return {seed: loop_workers.submit(_drift_loop, seed) for seed in sorted(seeds)}


@pytest.mark.parametrize("seed", DRIFT_SEEDS)
def test_a_drifting_encoder_adds_no_physics_to_the_loop(seed, drift_loops):
    """On these drift records a valve bias or a load ties with the drift (or settles the
    round first when ranked above it); the loop must still try the sensor's explanation
    and keep it, never the physics (both took these records before the sensor kind)."""
    chosen, steps = drift_loops[seed].result()
    assert set(chosen) <= {"sensor_drift", "sensor_offset"}, chosen
    tried = {effect for effect, action, _ in steps if action == "add"}
    assert "sensor_drift" in tried
    drift = [sensor for effect, _, sensor in steps if effect == "sensor_drift"]
    assert all(drift)
