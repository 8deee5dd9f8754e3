"""Tests of hhra_phys.compare and the ``hhra-phys compare`` command."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from hhra_phys import arx
from hhra_phys import compare as C
from hhra_phys.cli import main
from hhra_phys.data import Dataset, find_public_data
from hhra_phys.errors import DataError, ParameterError
from hhra_phys.metrics import mse
from hhra_phys.models.hhra.rig import simulate_rig

# Tiny budgets on a narrower box: in [-5, 5]^6 only about 1 candidate in 200 is stable, so a
# population of 10 may never find one (the method is then reported as failed).
SMALL = {"pop_size": 10, "max_iter": 4, "bounds": (-1.5, 1.5)}
SCORE_KEYS = {"mse", "rmse", "vaf", "itae", "fit"}


@pytest.fixture(scope="module")
def rig() -> Dataset:
    return simulate_rig(seed=3, duration=4.0)


@pytest.fixture
def registry() -> Iterator[None]:
    """Restore the method registry after a test that registers methods."""
    saved = dict(C.METHODS)
    yield
    C.METHODS.clear()
    C.METHODS.update(saved)


def _check_layout(report: dict, methods: tuple[str, ...]) -> None:
    assert {"dataset", "split", "methods"} <= set(report)
    assert tuple(report["methods"]) == methods
    for entry in report["methods"].values():
        assert SCORE_KEYS <= set(entry["est"]) and SCORE_KEYS <= set(entry["val"])
        assert {"noi", "nfev", "seconds"} <= set(entry)
    json.dumps(report, allow_nan=False)  # plain JSON, no NaN/inf


def test_compare_layout_and_free_run_scoring(rig: Dataset):
    report = C.compare(rig, split=0.5, seed=1, methods=C.ARX_METHODS, **SMALL)
    _check_layout(report, C.ARX_METHODS)
    assert report["dataset"] == "rig-seed3" and report["split"] == 0.5
    assert report["split_index"] == report["n_est"] == 500
    ls = report["methods"]["ls"]
    assert ls["noi"] is None and ls["nfev"] is None  # undefined for LS: JSON null
    hgwo = report["methods"]["hgwo"]
    assert hgwo["nfev"] == 10 * 2 + 4 * 20 and 0 <= hgwo["noi"] <= 4
    assert len(hgwo["convergence"]["best"]) == 5
    # The validation score is that of the free run from measured initial conditions ...
    est, val = rig.split(0.5)
    model = arx.fit_ls(est.u, est.y).model
    free = model.simulate(val.u, y_init=est.y, u_init=est.u)
    assert ls["val"]["mse"] == pytest.approx(mse(val.y, free), rel=1e-9)
    # ... not of the one-step prediction, which is much better.
    one_step = mse(val.y, model.predict(val.u, val.y, y_init=est.y, u_init=est.u))
    assert one_step < 0.5 * ls["val"]["mse"]
    assert ls["info"]["model"]["na"] == 3 and ls["paper"]["mse"] == 95.31
    again = C.compare(rig, split=0.5, seed=1, methods=["pso"], **SMALL)
    assert again["methods"]["pso"]["val"] == report["methods"]["pso"]["val"]  # seeded


def test_split_and_method_validation(rig: Dataset):
    report = C.compare(rig, split=300, methods=["ls", "rls"])
    assert report["split_index"] == 300 and report["n_val"] == rig.n - 300
    for bad in (1.5, 0.0, True, "half"):
        with pytest.raises(ParameterError, match="split"):
            C.compare(rig, split=bad, methods=["ls"])
    with pytest.raises(ParameterError, match="registered"):
        C.compare(rig, methods=["ls", "nope"])
    with pytest.raises(ParameterError, match="sequence"):
        C.compare(rig, methods="ls")
    with pytest.raises(ParameterError, match="unknown settings"):
        C.compare(rig, methods=["ls"], bogus=1)
    with pytest.raises(ParameterError, match="dataset"):
        C.compare(np.zeros(10), methods=["ls"])  # type: ignore[arg-type]


def test_register_method_plugs_in(rig: Dataset, registry: None):
    seen = {}

    @C.register_method("phys_dummy", label="Dummy")
    def dummy(est: Dataset, val: Dataset, settings: C.CompareSettings) -> C.MethodOutcome:
        seen["settings"] = settings
        return C.MethodOutcome(
            np.zeros(est.n),
            np.full(val.n, np.nan),
            noi=7,
            nfev=70,
            seconds=1.5,
            history=np.array([3.0, 2.0, 1.0]),
            history_nfev=np.array([10, 20, 30]),
            info={"initial_condition": "zero"},
        )

    assert "phys_dummy" in C.available_methods()
    comp = C.run_comparison(rig, methods=["ls", "phys_dummy"], seed=5, zeta_s=0.2)
    report = comp.to_dict()
    _check_layout(report, ("ls", "phys_dummy"))
    entry = report["methods"]["phys_dummy"]
    est, _ = rig.split(0.5)
    assert entry["est"]["mse"] == pytest.approx(float(np.mean(est.y**2)))
    assert entry["val"]["mse"] is None and entry["diverged"] is True  # NaN -> null
    assert (entry["noi"], entry["nfev"], entry["seconds"]) == (7, 70, 1.5)
    assert entry["info"] == {"initial_condition": "zero"} and entry["paper"] is None
    assert seen["settings"].seed == 5 and seen["settings"].zeta_s == 0.2
    assert "Dummy" in C.markdown_table(report)
    with pytest.raises(ParameterError, match="already registered"):
        C.register_method("phys_dummy", lambda e, v, s: None)
    C.register_method("phys_dummy", dummy, replace=True)
    for bad in ("Phys", "1x", "a-b", ""):
        with pytest.raises(ParameterError, match="method name"):
            C.register_method(bad, dummy)


def test_failing_and_malformed_methods(rig: Dataset, registry: None):
    def fails(est: Dataset, val: Dataset, s: C.CompareSettings) -> C.MethodOutcome:
        raise DataError("no stable candidate")

    def short(est: Dataset, val: Dataset, s: C.CompareSettings) -> C.MethodOutcome:
        return C.MethodOutcome(np.zeros(3), np.zeros(val.n))

    C.register_method("fails", fails)
    C.register_method("short", short)
    report = C.compare(rig, methods=["fails", "ls"])
    assert report["methods"]["fails"]["error"] == "no stable candidate"
    assert report["methods"]["fails"]["est"] is None
    assert report["methods"]["ls"]["error"] is None
    assert "failed: no stable candidate" in C.markdown_table(report)
    with pytest.raises(DataError, match="y_est has shape"):
        C.compare(rig, methods=["short"])


def test_aggregate_statistics(rig: Dataset):
    reports = [C.compare(rig, methods=["ls", "pso"], seed=s, **SMALL) for s in (0, 1, 2)]
    agg = C.aggregate(reports)
    vals = [r["methods"]["pso"]["val"]["mse"] for r in reports]
    st = agg["methods"]["pso"]["val"]["mse"]
    assert st["mean"] == pytest.approx(np.mean(vals))
    assert st["std"] == pytest.approx(np.std(vals, ddof=1))
    assert st["n"] == 3 and agg["methods"]["ls"]["val"]["mse"]["std"] == pytest.approx(0.0)
    assert "± " in C.markdown_summary(agg)
    with pytest.raises(ParameterError):
        C.aggregate([])


def test_cli_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    out = tmp_path / "r.json"
    args = "compare --duration 4 --seed 2 --pop 8 --iters 3 --box -1.5 1.5".split()
    args += ["--methods", ",".join(C.ARX_METHODS)]  # plug-ins (physical fits) are slower
    args += ["--json", str(out), "--plot", str(tmp_path / "f.png")]
    args += ["--report", str(tmp_path / "r.md")]
    assert main(args) == 0
    report = json.loads(out.read_text())
    _check_layout(report, C.ARX_METHODS)
    assert report["settings"]["pop_size"] == 8 and report["dataset"] == "rig-seed2"
    for name in ("f.png", "f_convergence.png", "r.md"):
        assert (tmp_path / name).stat().st_size > 1000
    assert "| FFRLS+H-GWO |" in capsys.readouterr().out
    before = out.read_text()
    assert main(args[:-2]) == 2  # outputs exist, no --overwrite
    assert "--overwrite" in capsys.readouterr().err and out.read_text() == before
    assert main([*args[:-2], "--methods", "ls", "--overwrite"]) == 0
    assert list(json.loads(out.read_text())["methods"]) == ["ls"]
    assert main(["compare", "--methods", "ls,nope", "--duration", "4"]) == 2
    assert "nope" in capsys.readouterr().err
    assert main(["compare", str(tmp_path / "missing.csv"), "--methods", "ls"]) == 1
    assert "missing.csv" in capsys.readouterr().err
    assert main(["compare", "--plugin", "no_such_module_xyz"]) == 2


def test_cli_public_record_reproduces_the_readme_baseline(tmp_path: Path):
    try:
        find_public_data()
    except DataError:
        pytest.skip("public actuator record not available")
    out = tmp_path / "p.json"
    argv = [
        "compare",
        "public",
        "--methods",
        "ls",
        "--na",
        "3",
        "--nb",
        "2",
        "--nk",
        "1",
        "--json",
        str(out),
        "--quiet",
    ]
    assert main(argv) == 0
    report = json.loads(out.read_text())
    assert report["split_index"] == 512
    # the record's published baseline (docs/data.md): ARX(3,2,1) validation free-run RMSE 1.013
    assert report["methods"]["ls"]["val"]["rmse"] == pytest.approx(1.013, abs=5e-4)
