"""Experiment design (:mod:`hhra_phys.design`) and ``hhra-phys design``.

The fit to design from is made on a short reference-rig record (independent of
the model) with a truth away from the nominal values.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from hhra_phys.cli import main
from hhra_phys.design import InformationModel, criterion_value, design_input, shortest_hold
from hhra_phys.errors import ParameterError
from hhra_phys.fit import fit
from hhra_phys.models.hhra.rig import perturbed_physical
from hhra_phys.reference.hhra import reference_record

FAST = {"candidates": 6, "local_steps": 15, "draws": 1}


@pytest.fixture(scope="module")
def fitted():
    truth = {k: v for k, v in perturbed_physical(11).groups().items() if k != "g_kp"}
    rec = reference_record(seed=3, params=truth, duration=6.0)
    return fit(rec, split=1.0, pop_size=20, max_iter=20, seed=0), rec


@pytest.mark.parametrize(("seed", "criterion"), [(0, "d"), (1, "a"), (2, "e")])
def test_a_designed_input_respects_every_limit(fitted, seed, criterion):
    res, _ = fitted
    d = design_input(res, 4.0, max_input=0.6, output_limit=30.0, min_hold=0.2,
                     criterion=criterion, seed=seed, **FAST)
    assert d.check() == []
    assert d.u.size == 1000 and d.fs == 250.0
    assert np.max(np.abs(d.u)) <= 0.6
    if d.family != "multisine":
        assert shortest_hold(d.u) >= 50
    # the output limit, checked again here by an independent simulation of the fitted model
    y = res.simulate(d.u, x0=res.model.x0())
    assert np.max(np.abs(y)) <= 30.0


def test_the_design_predicts_narrower_intervals_than_the_fitted_input(fitted):
    # measured: designed widths 0.2-0.35 of the paper input's on 20 s records (docs/design.md)
    res, rec = fitted
    info = InformationModel(res)
    for seed in (0, 1):
        d = design_input(res, rec.duration, reference_input=rec.u, seed=seed, **FAST)
        designed, paper = info.widths(d.u), info.widths(rec.u)
        gm = lambda w: np.exp(np.mean(np.log(list(w.values()))))  # noqa: E731
        assert gm(designed) < gm(paper)
        assert d.limits["max_input"] == pytest.approx(np.max(np.abs(rec.u)))


def test_criteria_and_bad_limits():
    cov = np.diag([1e-2, 4e-2])
    assert criterion_value(cov, "d") == pytest.approx(np.log(4e-4))
    assert criterion_value(cov, "a") == pytest.approx(5e-2)
    assert criterion_value(cov, "e") == pytest.approx(4e-2)
    assert criterion_value(np.diag([1.0, -1.0]), "d") == np.inf
    assert shortest_hold(np.array([1, 1, 2, 2, 2, 3])) == 2  # the last hold is cut
    assert shortest_hold(np.array([1, 2, 2, 2, 3, 3])) == 1


def test_bad_arguments_are_named(fitted):
    res, _ = fitted
    with pytest.raises(ParameterError, match="criterion"):
        design_input(res, 4.0, max_input=1.0, criterion="x")
    with pytest.raises(ParameterError, match="max_input"):
        design_input(res, 4.0)
    with pytest.raises(ParameterError, match="min_hold"):
        design_input(res, 4.0, max_input=1.0, min_hold=-1)


def test_cli_design_writes_t_u_and_a_sidecar(fitted, tmp_path, capsys):
    from hhra_phys.data import save_csv

    res, rec = fitted
    data = save_csv(rec, tmp_path / "rec.csv")
    fit_json = tmp_path / "fit.json"
    assert main(["fit", str(data), "--split", "1", "--pop", "10", "--iters", "5",
                 "--json", str(fit_json), "--quiet"]) == 0
    out = tmp_path / "designed.csv"
    rc = main(["design", str(fit_json), "--duration", "3", "--out", str(out), "--seed", "4",
               "--draws", "1", "--output-limit", "40", "--criterion", "d"])
    assert rc == 0
    header = out.read_text().splitlines()[0]
    assert header == "t,u"
    ds = np.loadtxt(out, delimiter=",", skiprows=1)
    assert ds.shape == (750, 2) and np.allclose(np.diff(ds[:, 0]), 0.004)
    assert np.max(np.abs(ds[:, 1])) <= np.max(np.abs(rec.u)) + 1e-9
    side = json.loads((tmp_path / "designed.json").read_text())
    assert side["limits_broken"] == []
    # the fit used its whole record (--split 1): so is the design, and the command says so
    assert side["split"] == 1.0 and side["designed"]["n_est"] == 750
    assert side["fit_command"].startswith("hhra-phys fit RECORD.csv --split 1 --validate ")
    assert side["fitted_record"]["n_est"] == rec.n
    assert side["fit_command"] in capsys.readouterr().out
    assert set(side["designed"]["widths"]) == set(side["fitted_record"]["widths"])
    assert side["peak_output"] <= 40.0
    # bad input: an error naming the flag, before any design work
    assert main(["design", str(fit_json), "--duration", "-2", "--out",
                 str(tmp_path / "x.csv")]) == 2
    assert "--duration" in capsys.readouterr().err
    assert main(["design", str(fit_json), "--duration", "2", "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["design", str(fit_json), "--duration", "2", "--split", "1.5"])
    assert exc.value.code == 2 and "--split" in capsys.readouterr().err


def test_cli_design_is_made_for_the_part_the_default_fit_estimates_from(tmp_path, capsys):
    """The default workflow in small: fit -> design -> rig -> fit, no extra flags.

    The design knows the default fit estimates from the first half: it designs that
    half, and the fit of the measured record shows the predicted widths.
    """
    from hhra_phys.data import save

    truth = {k: v for k, v in perturbed_physical(17).groups().items() if k != "g_kp"}
    for seed in (5, 6):
        d = tmp_path / f"s{seed}"
        d.mkdir()
        rec = reference_record(seed=seed, params=truth, duration=8.0)
        save(rec, d / "a.csv")
        fast = ["--pop", "20", "--iters", "30", "--quiet"]
        assert main(["fit", str(d / "a.csv"), "--json", str(d / "fit.json"), *fast]) == 0
        capsys.readouterr()
        assert main(["design", str(d / "fit.json"), "--duration", "8", "--draws", "1",
                     "--seed", str(seed)]) == 0
        printed = capsys.readouterr().out
        side = json.loads((d / "design.json").read_text())  # default --out: beside the fit
        assert side["split"] == 0.5 and side["designed"]["n_est"] == 1000
        assert "hhra-phys fit RECORD.csv --split 0.5" in printed
        assert side["fitted_record"]["n_est"] == 1000 and side["limits_broken"] == []
        u = np.loadtxt(d / "design.csv", delimiter=",", skiprows=1)[:, 1]
        assert u.size == 2000 and np.std(u[1000:]) > 0  # a validation input, not a rest
        measured = reference_record(seed=100 + seed, params=truth, u=u, duration=8.0)
        save(measured, d / "designed.csv")
        assert main(["fit", str(d / "designed.csv"), "--json", str(d / "dfit.json"),
                     *fast]) == 0
        params = json.loads((d / "dfit.json").read_text())["params"]
        realised = {g: (p["ci95"][1] - p["ci95"][0]) / p["value"] for g, p in params.items()
                    if p["free"] and g.startswith("g_")}
        gm = lambda w: float(np.exp(np.mean(np.log(list(w.values())))))  # noqa: E731
        assert gm(side["designed"]["widths"]) == pytest.approx(gm(realised), rel=0.3)
        assert gm(realised) < 0.7 * side["fitted_record"]["geomean"]


def test_the_split_the_design_assumes_is_the_fits_own():
    from types import SimpleNamespace

    from hhra_phys.cli.design import fit_command, fit_split

    def res(split, n, n_est, n_val):
        return SimpleNamespace(settings={"split": split, "data": {"n": n, "n_est": n_est,
                                                                 "n_val": n_val}})

    assert fit_split(res(0.5, 5000, 2500, 2500)) == 0.5
    assert fit_split(res(0.7, 5000, 3500, 1500)) == 0.7
    assert fit_split(res(1.0, 5000, 5000, 0)) == 1.0
    # validated on another record: every sample of this one was used for estimation
    assert fit_split(res(0.5, 5000, 5000, 3000)) == 1.0
    assert fit_command(0.5, "a.csv") == ("hhra-phys fit RECORD.csv --split 0.5 "
                                         "--json RECORD-fit.json")
    assert "--split 1 --validate a.csv" in fit_command(1.0, "a.csv")


def test_the_python_api_designs_for_the_fits_own_split(fitted):
    _, rec = fitted
    res = fit(rec, pop_size=20, max_iter=20, seed=1)  # the default split, 0.5
    d = design_input(res, 4.0, reference_input=rec.u, output_limit=40.0, seed=3, **FAST)
    assert d.split == 0.5 and d.n_est == 500 and d.u.size == 1000 and d.check() == []
    info = InformationModel(res)
    assert d.widths == pytest.approx(info.widths(d.u[:500]), rel=1e-9)
    # the whole record is more informative than its first half, which is what the fit uses
    gm = lambda w: np.exp(np.mean(np.log(list(w.values()))))  # noqa: E731
    assert gm(d.widths_whole) < gm(d.widths)
    whole = design_input(res, 4.0, reference_input=rec.u, output_limit=40.0, seed=3, split=1,
                         **FAST)
    assert whole.split == 1.0 and whole.n_est == 1000 and whole.widths_whole == {}
