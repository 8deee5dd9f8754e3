"""A fit's report (``FitResult.report``, ``hhra-phys fit --report``): the Markdown with the
parameters and their intervals, the errors, and the fit's figure beside it."""

from __future__ import annotations

import pytest

from hhra_phys.errors import HHRAError, ParameterError
from hhra_phys.fit import fit
from hhra_phys.models.hhra.rig import simulate_rig


@pytest.fixture(scope="module")
def fitted():
    data = simulate_rig(seed=4, duration=4.0)
    return fit(data, pop_size=10, max_iter=10, seed=1), data


def test_the_report_holds_every_parameter_with_its_interval_and_the_figure(fitted, tmp_path):
    res, data = fitted
    path = res.report(tmp_path / "fit.md", data)
    text = path.read_text()
    figure = tmp_path / "fit_fit.png"
    assert figure.stat().st_size > 0 and "![fit](fit_fit.png)" in text
    assert "estimation 500, validation 500" in text  # the fit's own split, drawn so
    for name, est in res.params.items():
        row = next(ln for ln in text.splitlines() if ln.startswith(f"| {name} |"))
        if est["free"] and est["ci95"]:
            assert f"{est['ci95'][0]:.6g}" in row and f"{est['ci95'][1]:.6g}" in row
    assert f"| validation | {res.metrics['val']['rmse']:.4g} |" in text


def test_the_report_refuses_another_record_and_an_existing_file(fitted, tmp_path):
    res, data = fitted
    with pytest.raises(ParameterError, match="data has 750 samples"):
        res.report(tmp_path / "a.md", data.slice(0, 750))
    assert not list(tmp_path.iterdir())  # refused before anything is drawn
    (tmp_path / "b_fit.png").write_text("mine")
    with pytest.raises(HHRAError, match="exists"):
        res.report(tmp_path / "b.md", data)
    assert (tmp_path / "b_fit.png").read_text() == "mine" and not (tmp_path / "b.md").exists()


def test_cli_fit_writes_the_report_and_its_figure(tmp_path, capsys):
    from hhra_phys.cli import main

    out = tmp_path / "r.md"
    assert main(["fit", "rig", "--rig-seed", "2", "--pop", "10", "--iters", "10", "--quiet",
                 "--report", str(out)]) == 0
    assert "## Parameters" in out.read_text() and (tmp_path / "r_fit.png").exists()
    assert f"wrote {out}" in capsys.readouterr().out
