"""Tests of hhra_phys.data: Dataset, validation errors, loaders and writers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from hhra_phys import data as D
from hhra_phys.data import DataChecks, Dataset
from hhra_phys.errors import DataError, HHRAError, ParameterError

N = 200
FS = 250.0


@pytest.fixture
def ds() -> Dataset:
    rng = np.random.default_rng(1)
    t = np.arange(N) / FS
    return Dataset(
        t=t,
        u=rng.normal(size=N),
        y=np.cumsum(rng.normal(size=N)),
        extra={"p1": rng.normal(size=N)},
        metadata={"truth": {"k_v": np.float64(2.5), "vec": np.arange(3)}, "seed": 1},
        name="rig",
    )


def write_csv(path: Path, header: str, rows: list[str]) -> Path:
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


def good_rows(n: int = 40) -> list[str]:
    rng = np.random.default_rng(2)
    return [f"{k * 0.004!r},{rng.normal()!r},{rng.normal()!r}" for k in range(n)]


# --------------------------------------------------------------------------- Dataset


def test_dataset_basics(ds: Dataset) -> None:
    assert ds.n == len(ds) == N
    assert ds.dt == pytest.approx(1 / FS)
    assert ds.fs == pytest.approx(FS)
    assert ds.duration == pytest.approx(N / FS)
    assert ds.t.dtype == ds.u.dtype == ds.y.dtype == np.float64
    assert (ds.input_name, ds.input_unit, ds.output_name, ds.output_unit) == (
        "current",
        "mA",
        "angle",
        "deg",
    )
    assert ds.time_unit == "s"
    assert "n=200" in repr(ds)


def test_dataset_copies_inputs() -> None:
    u = np.linspace(-1, 1, 50)
    meta = {"a": [1, 2]}
    ds = Dataset(np.arange(50.0), u, u.copy(), metadata=meta)
    u[:] = 0.0
    assert ds.u[0] == -1.0
    other = ds.with_metadata(b=3)
    assert "b" not in ds.metadata and other.metadata["b"] == 3
    other.metadata["a"].append(3)
    assert meta == {"a": [1, 2]} and ds.metadata == {"a": [1, 2]}


def test_pressure_output_possible() -> None:
    ds = Dataset.from_arrays(
        np.sin(np.arange(100)), np.arange(100.0), output_name="pressure", output_unit="raw"
    )
    assert (ds.output_name, ds.output_unit) == ("pressure", "raw")


def test_from_arrays_time_axis() -> None:
    u = np.sin(np.arange(100) / 5)
    ds = Dataset.from_arrays(u, u, fs=100.0, operator="me", input_unit="A")
    assert ds.t[1] == pytest.approx(0.01) and ds.fs == pytest.approx(100.0)
    assert ds.metadata == {"operator": "me"} and ds.input_unit == "A"
    units = Dataset.from_arrays(u, u)
    assert units.fs == 1.0 and units.time_unit == "samples"
    with pytest.raises(DataError, match="fs = 50 Hz"):
        Dataset.from_arrays(u, u, fs=50.0, t=np.arange(100) / 100.0)


def test_split_convention() -> None:
    u = np.sin(np.arange(1024) / 7)
    ds = Dataset.from_arrays(u, u, fs=FS, name="rec")
    est, val = ds.split()
    assert (est.n, val.n) == (512, 512)
    assert val.t[0] == ds.t[512]  # validation keeps the original time axis
    assert est.metadata["split"] == {
        "part": "estimation",
        "index": 512,
        "fraction": 0.5,
        "n_total": 1024,
    }
    assert val.metadata["split"]["part"] == "validation"
    assert val.metadata["segment"] == {"start": 512, "stop": 1024}
    assert "split" not in ds.metadata
    # segments compose to absolute indices
    sub = val.slice(100, 200)
    assert sub.metadata["segment"] == {"start": 612, "stop": 712}
    np.testing.assert_array_equal(sub.u, ds.u[612:712])
    a, b = ds.split_at(-24)
    assert (a.n, b.n) == (1000, 24)
    assert ds.split(0.7)[0].n == round(0.7 * 1024)


@pytest.mark.parametrize("fraction", [0.0, 1.0, -0.5, 2])
def test_split_bad_fraction(fraction: float) -> None:
    u = np.sin(np.arange(100.0))
    with pytest.raises(ParameterError):
        Dataset.from_arrays(u, u).split(fraction)


def test_split_too_short_part_names_segment() -> None:
    u = np.sin(np.arange(100.0))
    with pytest.raises(D.TooFewSamplesError, match=r"only 10 samples.*segment 0:10"):
        Dataset.from_arrays(u, u).split(0.1)


# --------------------------------------------------------------------------- validation


def test_nonfinite_rows_listed() -> None:
    y = np.sin(np.arange(100.0))
    y[[3, 10, 11, 12, 40, 41, 90]] = np.nan
    y[50] = np.inf
    with pytest.raises(D.NonFiniteError) as err:
        Dataset.from_arrays(np.cos(np.arange(100.0)), y, source="rig.csv")
    msg = str(err.value)
    assert "rig.csv" in msg and "'y'" in msg and "8 non-finite" in msg
    assert "rows 3, 10, 11, 12, 40, ... (8 in all)" in msg


def test_length_mismatch() -> None:
    with pytest.raises(D.LengthMismatchError, match=r"'u' 99, 'y' 100"):
        Dataset(np.arange(100.0), np.sin(np.arange(99.0)), np.arange(100.0))


def test_non_monotonic_time_names_row() -> None:
    t = np.arange(60.0)
    t[30] = 28.5
    msg = r"row 30: t\[30\] = 28.5 follows t\[29\] = 29"
    with pytest.raises(D.NonMonotonicTimeError, match=msg):
        Dataset(t, np.sin(t), t)


def test_non_uniform_time_names_row_and_tolerance() -> None:
    t = np.arange(60) * 0.004
    t[45:] += 0.001
    u = np.sin(np.arange(60.0))
    with pytest.raises(D.NonUniformTimeError, match=r"row 45.*time_rtol = 0.001"):
        Dataset(t, u, u)
    # a looser tolerance accepts it
    assert Dataset(t, u, u, checks=DataChecks(time_rtol=0.5)).n == 60
    assert issubclass(D.NonUniformTimeError, D.TimeAxisError)


def test_too_few_samples_configurable() -> None:
    u = np.sin(np.arange(10.0))
    with pytest.raises(D.TooFewSamplesError, match="only 10 samples; at least 20"):
        Dataset.from_arrays(u, u)
    assert Dataset.from_arrays(u, u, checks=DataChecks(min_samples=5)).n == 10


@pytest.mark.parametrize("noise", [0.0, 1e-6])
def test_non_exciting_input(noise: float) -> None:
    rng = np.random.default_rng(0)
    u = 5.0 + noise * rng.normal(size=100)
    with pytest.raises(D.NonExcitingInputError, match=r"'u' \(current \[mA\]\) is constant"):
        Dataset.from_arrays(u, np.arange(100.0))
    relaxed = DataChecks(require_excitation=False)
    assert Dataset.from_arrays(u, np.arange(100.0), checks=relaxed).n == 100


def test_wrong_dimension_and_non_numeric() -> None:
    t = np.arange(30.0)
    with pytest.raises(D.DimensionError, match=r"'u' must be 1-D.*\(30, 2\)"):
        Dataset(t, np.ones((30, 2)), t)
    bad = np.array([1.0] * 29 + ["x"], dtype=object)
    with pytest.raises(D.NonNumericError, match=r"'y'.*'x'.*row 29"):
        Dataset(t, np.sin(t), bad)


def test_bad_checks_rejected() -> None:
    with pytest.raises(ParameterError):
        DataChecks(min_samples=1)
    with pytest.raises(ParameterError):
        DataChecks(time_rtol=-1.0)


def test_error_hierarchy() -> None:
    for cls in (
        D.DataFileNotFoundError,
        D.DataFileExistsError,
        D.MissingColumnError,
        D.NonNumericError,
        D.NonFiniteError,
        D.LengthMismatchError,
        D.NonMonotonicTimeError,
        D.NonUniformTimeError,
        D.TooFewSamplesError,
        D.NonExcitingInputError,
        D.DimensionError,
        D.DataFormatError,
        D.UnsupportedFormatError,
    ):
        assert issubclass(cls, DataError) and issubclass(cls, HHRAError)
    assert issubclass(D.DataFileNotFoundError, FileNotFoundError)
    assert issubclass(D.MissingColumnError, KeyError)
    assert str(D.MissingColumnError("no column 'x'")) == "no column 'x'"  # no KeyError quotes


# --------------------------------------------------------------------------- CSV


def test_csv_round_trip_with_sidecar(ds: Dataset, tmp_path: Path) -> None:
    path = D.save_csv(ds.with_metadata(note="x"), tmp_path / "rig.csv")
    side = tmp_path / "rig.json"
    assert side.is_file() and D.sidecar_path(path) == side
    assert path.read_text().splitlines()[0] == "t,u,y,p1"
    info = json.loads(side.read_text())
    assert info["metadata"]["truth"] == {"k_v": 2.5, "vec": [0, 1, 2]}
    back = D.load_csv(path)
    for attr in ("t", "u", "y"):
        np.testing.assert_array_equal(getattr(back, attr), getattr(ds, attr))  # exact
    np.testing.assert_array_equal(back.extra["p1"], ds.extra["p1"])
    assert back.metadata == {"truth": {"k_v": 2.5, "vec": [0, 1, 2]}, "seed": 1, "note": "x"}
    assert back.name == "rig" and back.source == str(path)
    assert D.load(path).n == N


def test_csv_round_trip_units(tmp_path: Path) -> None:
    u = np.sin(np.arange(50.0))
    ds = Dataset.from_arrays(u, u**2, fs=10.0, output_name="pressure", output_unit="raw")
    back = D.load_csv(D.save_csv(ds, tmp_path / "p.csv"))
    assert (back.output_name, back.output_unit) == ("pressure", "raw")
    # explicit arguments override the side-car
    assert D.load_csv(tmp_path / "p.csv", output_unit="bar").output_unit == "bar"


def test_save_refuses_overwrite(ds: Dataset, tmp_path: Path) -> None:
    path = D.save_csv(ds, tmp_path / "rig.csv")
    with pytest.raises(D.DataFileExistsError, match="rig.*overwrite=True"):
        D.save_csv(ds, path)
    (tmp_path / "rig.csv").unlink()  # the side-car alone also blocks
    with pytest.raises(D.DataFileExistsError, match="rig.json"):
        D.save_csv(ds, path)
    D.save_csv(ds, path, overwrite=True)
    npz = D.save_npz(ds, tmp_path / "rig.npz")
    with pytest.raises(D.DataFileExistsError, match="rig.npz"):
        D.save_npz(ds, npz)
    D.save_npz(ds, npz, overwrite=True)


def test_csv_missing_file(tmp_path: Path) -> None:
    with pytest.raises(D.DataFileNotFoundError, match="nothere.csv") as err:
        D.load_csv(tmp_path / "nothere.csv")
    assert isinstance(err.value, FileNotFoundError)


def test_csv_missing_column_lists_available(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "a.csv", "time,current,angle", good_rows())
    with pytest.raises(D.MissingColumnError) as err:
        D.load_csv(path)
    msg = str(err.value)
    assert "a.csv" in msg and "'t'" in msg and "time, current, angle" in msg
    ds = D.load_csv(path, t="time", u="current", y="angle")
    assert ds.n == 40
    with pytest.raises(D.MissingColumnError, match="'zz'.*extra"):
        D.load_csv(path, t="time", u="current", y="angle", extra=["zz"])


def test_csv_non_numeric_cell(tmp_path: Path) -> None:
    rows = good_rows()
    rows[7] = "0.028,0.1,oops"
    path = write_csv(tmp_path / "b.csv", "t,u,y", rows)
    with pytest.raises(D.NonNumericError) as err:
        D.load_csv(path)
    msg = str(err.value)
    assert "b.csv" in msg and "'y'" in msg and "row 7 (file line 9)" in msg and "'oops'" in msg
    rows[7] = "0.028,,0.2"
    write_csv(path, "t,u,y", rows)
    with pytest.raises(D.NonNumericError, match=r"'u'.*row 7.*empty cell"):
        D.load_csv(path)


def test_csv_nan_rows_with_lines(tmp_path: Path) -> None:
    rows = good_rows()
    rows[3] = "0.012,nan,1"
    rows[20] = "0.08,inf,1"
    path = write_csv(tmp_path / "c.csv", "# a comment\nt,u,y", rows)
    with pytest.raises(D.NonFiniteError) as err:
        D.load_csv(path)
    msg = str(err.value)
    assert "c.csv" in msg and "'u'" in msg and "rows 3, 20 (file lines 6, 23)" in msg


def test_csv_non_uniform_time_in_file(tmp_path: Path) -> None:
    rows = good_rows()
    rows[25] = "0.1004," + rows[25].split(",", 1)[1]
    path = write_csv(tmp_path / "d.csv", "t,u,y", rows)
    with pytest.raises(D.NonUniformTimeError, match=r"d.csv.*rows 25, 26 \(file lines 27, 28\)"):
        D.load_csv(path)


def test_csv_ragged_row(tmp_path: Path) -> None:
    rows = good_rows()
    rows[4] = "0.016,1"
    with pytest.raises(D.DataFormatError, match="line 6 has 2 fields"):
        D.load_csv(write_csv(tmp_path / "e.csv", "t,u,y", rows))


def test_csv_time_from_fs_and_options(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    lines = [";".join(map(repr, row)) for row in rng.normal(size=(30, 3)).tolist()]
    path = write_csv(tmp_path / "f.csv", "cur;ang;press", lines)
    ds = D.load_csv(path, u="cur", y="ang", extra=["press"], delimiter=";", fs=250.0)
    assert ds.fs == pytest.approx(250.0) and ds.t[0] == 0.0 and "press" in ds.extra
    units = D.load_csv(path, t=None, u=0, y=1, delimiter=";")
    assert units.time_unit == "samples" and units.dt == 1.0
    ws = write_csv(tmp_path / "g.txt", "t u y", [r.replace(",", "  ") for r in good_rows()])
    assert D.load_csv(ws, delimiter=None).n == 40
    with pytest.raises(DataError, match="fs = 100"):
        D.load_csv(write_csv(tmp_path / "h.csv", "t,u,y", good_rows()), fs=100.0)


def test_load_dispatch_unsupported(tmp_path: Path) -> None:
    with pytest.raises(D.UnsupportedFormatError, match=r"x.xlsx.*\.csv"):
        D.load(tmp_path / "x.xlsx")


# --------------------------------------------------------------------------- NPZ / MAT


def test_npz_round_trip(ds: Dataset, tmp_path: Path) -> None:
    path = D.save_npz(ds, tmp_path / "rig.data")  # no ".npz" appended
    assert path == tmp_path / "rig.data" and path.is_file()
    back = D.load_npz(path)
    np.testing.assert_array_equal(back.y, ds.y)
    np.testing.assert_array_equal(back.extra["p1"], ds.extra["p1"])
    assert back.metadata == {"truth": {"k_v": 2.5, "vec": [0, 1, 2]}, "seed": 1}
    assert back.name == "rig"
    D.save_npz(ds, tmp_path / "rig.npz")
    assert D.load(tmp_path / "rig.npz").n == N


def test_mat_round_trip_row_and_column_specs(ds: Dataset, tmp_path: Path) -> None:
    path = tmp_path / "rec.mat"
    scipy.io.savemat(path, {"X": np.vstack([ds.u, ds.extra["p1"]]), "y": ds.y[None, :]})
    back = D.load_mat(path, u="X[0]", y="y", extra={"p1": "X[1,:]"}, fs=FS)
    np.testing.assert_array_equal(back.u, ds.u)
    np.testing.assert_array_equal(back.y, ds.y)
    np.testing.assert_array_equal(back.extra["p1"], ds.extra["p1"])
    assert back.fs == pytest.approx(FS)
    cols = tmp_path / "cols.mat"
    scipy.io.savemat(cols, {"D": np.column_stack([ds.t, ds.u, ds.y])})
    back = D.load(cols, t="D[:,0]", u="D[:,1]", y="D[:,2]")
    np.testing.assert_array_equal(back.t, ds.t)
    units = D.load_mat(path, u="X[0]", y="y[0]")
    assert units.time_unit == "samples" and units.fs == 1.0


def test_mat_spec_errors(tmp_path: Path) -> None:
    path = tmp_path / "m.mat"
    rng = np.random.default_rng(4)
    scipy.io.savemat(path, {"X": rng.normal(size=(2, 40)), "y": rng.normal(size=(1, 40))})
    with pytest.raises(D.MissingColumnError, match=r"m.mat.*'Z'.*X \(2x40\), y \(1x40\)"):
        D.load_mat(path, u="Z")
    with pytest.raises(D.DimensionError, match=r"'X' has shape 2x40; say which row"):
        D.load_mat(path, u="X")
    with pytest.raises(D.MissingColumnError, match=r"'X\[2\]'.*2 rows"):
        D.load_mat(path, u="X[2]")
    with pytest.raises(ParameterError, match="bad"):
        D.load_mat(path, u="X[0][1]")
    with pytest.raises(D.LengthMismatchError, match=r"m.mat.*'X\[:,0\]' 2, 'y\[0\]' 40$"):
        D.load_mat(path, u="X[:,0]")
    with pytest.raises(D.DataFormatError, match="not a readable MATLAB"):
        D.load_mat(write_csv(tmp_path / "x.mat", "t,u,y", good_rows()))


# --------------------------------------------------------------------------- public data


def test_public_actuator_loads_if_present() -> None:
    try:
        path = D.find_public_data()
    except D.DataFileNotFoundError:
        pytest.skip("public data not available")
    ds = D.load_public_actuator(path)
    assert ds.n == 1024 and ds.time_unit == "samples" and ds.fs == 1.0
    assert (ds.output_name, ds.output_unit) == ("pressure", "raw")
    assert set(ds.extra) == {"x1"}
    raw = scipy.io.loadmat(path)
    np.testing.assert_array_equal(ds.u, raw["X"][0])
    np.testing.assert_array_equal(ds.extra["x1"], raw["X"][1])
    np.testing.assert_array_equal(ds.y, raw["y"][0])
    est, val = ds.split()
    assert est.n == val.n == ds.metadata["usual_split_index"] == 512


def test_public_actuator_search_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(D.DataFileNotFoundError, match="nowhere.mat.*HHRA_SHARED_DATA"):
        D.load_public_actuator(tmp_path / "nowhere.mat")
    # the environment variable comes before the ../shared/data fallbacks
    fake_dir = tmp_path / "fake"
    fake_dir.mkdir()
    rng = np.random.default_rng(5)
    scipy.io.savemat(
        fake_dir / D.PUBLIC_ACTUATOR_FILE,
        {"X": rng.normal(size=(2, 64)), "y": rng.normal(size=(1, 64))},
    )
    monkeypatch.setenv("HHRA_SHARED_DATA", str(fake_dir))
    assert D.find_public_data() == fake_dir / D.PUBLIC_ACTUATOR_FILE
    assert D.load_public_actuator().n == 64
    # an explicit directory works too
    assert D.load_public_actuator(fake_dir).n == 64


def test_csv_extra_mapping_and_name_clash(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "k.csv", "t,u,y,u2", [r + ",1.5" for r in good_rows()])
    ds = D.load_csv(path, u="y", y="u2", extra={"first_u": "u"})
    assert set(ds.extra) == {"first_u"}
    with pytest.raises(DataError, match="k.csv: extra channel name 'u' clashes"):
        D.load_csv(path, extra=["u"])
