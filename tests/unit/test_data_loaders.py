"""Loaders that never traceback: encodings, delimiters, side-car conflicts, binary files, pandas.

The property tests write random records with random encodings and delimiters and check that
``hhra_phys.data.load`` returns exactly what was written or raises a ``DataError``, never
another exception.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hhra_phys import data as D
from hhra_phys.cli import main
from hhra_phys.data import Dataset
from hhra_phys.errors import DataError, ParameterError

# tmp_path is shared by the examples of one test; each example writes its own files.
_TMP = [HealthCheck.function_scoped_fixture]

N = 40


def _rows(n: int = N, sep: str = ",") -> list[str]:
    # uniform time, an exciting input, a smooth output
    return [sep.join([repr(k * 0.01), repr(float(k % 7)), repr(0.5 * k)]) for k in range(n)]


def _write(path: Path, header: str, rows: list[str], encoding: str = "utf-8") -> Path:
    path.write_bytes(("\n".join([header, *rows]) + "\n").encode(encoding))
    return path


# --------------------------------------------------------------------------- encodings


@pytest.mark.parametrize("encoding", ["utf-8", "utf-8-sig", "utf-16", "latin-1", "cp1252"])
def test_header_with_degree_sign_reads_in_every_encoding(tmp_path: Path, encoding: str) -> None:
    path = _write(tmp_path / "w.csv", "Zeit [s],Strom [mA],Winkel [°]", _rows(), encoding)
    ds = D.load(path, t="Zeit [s]", u="Strom [mA]", y="Winkel [°]")
    assert ds.n == N
    np.testing.assert_array_equal(ds.y, 0.5 * np.arange(N))


def test_utf16_without_bom_is_named_as_undecodable(tmp_path: Path) -> None:
    path = _write(tmp_path / "w.csv", "t,u,y", _rows(), "utf-16-le")
    with pytest.raises(D.DataFormatError, match=r"w\.csv: binary.*byte-order mark"):
        D.load(path)


def test_binary_file_is_a_data_error_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "image.csv"
    path.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(D.DataFormatError, match=r"image\.csv: binary or undecodable"):
        D.load(path)


def test_explicit_wrong_encoding_is_a_data_error(tmp_path: Path) -> None:
    path = _write(tmp_path / "w.csv", "t,u,Winkel [°]", _rows(), "latin-1")
    with pytest.raises(D.DataFormatError, match=r"w\.csv: not valid utf-8 text"):
        D.load(path, y="Winkel [°]", encoding="utf-8")


def test_cli_reports_a_binary_file_without_traceback(tmp_path: Path, capsys) -> None:
    path = tmp_path / "junk.csv"
    path.write_bytes(b"\x00\x01\x02PK\x03\x04" * 100)
    assert main(["fit", str(path), "--quiet", "--iters", "1", "--pop", "4"]) == 1  # data error
    err = capsys.readouterr().err
    assert "junk.csv" in err and "binary" in err and "Traceback" not in err


# --------------------------------------------------------------------------- delimiters


@pytest.mark.parametrize("sep", [",", ";", "\t", " ", "   "])
def test_delimiter_is_detected(tmp_path: Path, sep: str) -> None:
    path = _write(tmp_path / "d.csv", sep.join("tuy"), _rows(sep=sep))
    ds = D.load(path)
    np.testing.assert_array_equal(ds.u, np.arange(N) % 7)


def test_semicolon_file_with_comma_delimiter_gets_a_hint(tmp_path: Path) -> None:
    path = _write(tmp_path / "s.csv", "t;u;y", _rows(sep=";"))
    with pytest.raises(D.MissingColumnError) as err:
        D.load(path, delimiter=",")
    assert "the header looks ';'-delimited: pass --delimiter ';'" in str(err.value)
    assert str(err.value).startswith(f"{path}: no column 't'")


def test_decimal_commas_are_read_as_semicolon_file(tmp_path: Path) -> None:
    # "0,5;1,0;2,0": ';' splits every line the same way, ',' does not
    rows = [";".join(r.replace(",", ";").split(";")) for r in _rows(sep=";")]
    rows = [r.replace(".", ",") for r in rows]
    path = _write(tmp_path / "dec.csv", "t;u;y", rows)
    with pytest.raises(D.NonNumericError, match="column 't'"):
        D.load(path)  # detected ';' and the cells are named, not a ragged-row error


def test_cli_delimiter_flag(tmp_path: Path, capsys) -> None:
    path = _write(tmp_path / "s.csv", "t|u|y", _rows(sep="|"))
    assert main(["fit", str(path), "--delimiter", ",", "--iters", "1", "--pop", "4",
                 "--quiet", "--refine", "none"]) == 1  # a data error, not a usage error
    assert "no column 't'" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse rejects a bad delimiter up front
        main(["fit", str(path), "--delimiter", "ab"])
    with pytest.raises(ParameterError, match="delimiter"):
        D.load_csv(path, delimiter="ab")
    assert D.load(path, delimiter="|").n == N


def test_delimiter_is_refused_for_binary_formats(tmp_path: Path) -> None:
    ds = Dataset.from_arrays(np.arange(N) % 5, np.arange(N), fs=10.0)
    path = D.save(ds, tmp_path / "r.npz")
    assert D.load(path, delimiter=None).n == N
    with pytest.raises(ParameterError, match="text files"):
        D.load(path, delimiter=";")


# --------------------------------------------------------------------------- side-car


@pytest.fixture
def saved(tmp_path: Path) -> Path:
    ds = Dataset.from_arrays(
        np.arange(N) % 5, np.arange(N) * 0.1, fs=100.0, extra={"p": np.ones(N)}
    )
    return D.save_csv(ds, tmp_path / "rig.csv")


def _edit_sidecar(csv_path: Path, **changes: object) -> None:
    side = D.sidecar_path(csv_path)
    info = json.loads(side.read_text())
    info.update(changes)
    side.write_text(json.dumps(info))


@pytest.mark.parametrize(
    ("change", "pattern"),
    [
        ({"n": 99}, r"says n = 99 samples but .*rig\.csv has 40"),
        ({"fs": 250.0}, r"says fs = 250 Hz but the time column .* implies fs = 100 Hz"),
        ({"extra": ["p", "q"]}, r"lists extra channel 'q' but .* no such column"),
        ({"n": "forty"}, r"field 'n' must be int, got 'forty'"),
        ({"metadata": [1, 2]}, r"field 'metadata' must be dict"),
    ],
)
def test_sidecar_that_disagrees_with_the_file(saved: Path, change: dict, pattern: str) -> None:
    _edit_sidecar(saved, **change)
    with pytest.raises(DataError, match=pattern):
        D.load(saved)
    assert D.load(saved, sidecar=False).n == N  # the file itself is fine


def test_sidecar_unit_against_header_unit(tmp_path: Path) -> None:
    path = _write(tmp_path / "h.csv", "t,u,angle [rad]", _rows())
    side = {"format": "hhra-phys dataset", "output_unit": "deg"}
    D.sidecar_path(path).write_text(json.dumps(side))
    with pytest.raises(DataError, match=r"output_unit = 'deg' but the header .* says 'rad'"):
        D.load(path, y="angle [rad]")


def test_sidecar_fs_builds_the_missing_time_axis(saved: Path) -> None:
    lines = saved.read_text().splitlines()
    saved.write_text("\n".join(",".join(line.split(",")[1:]) for line in lines) + "\n")
    ds = D.load(saved)  # no t column: the side-car's fs = 100 Hz gives the time axis
    assert ds.fs == pytest.approx(100.0) and ds.time_unit == "s"


def test_binary_sidecar_is_a_data_error(saved: Path) -> None:
    D.sidecar_path(saved).write_bytes(b"\x00\xff" * 50)
    with pytest.raises(D.DataFormatError, match=r"rig\.json: binary"):
        D.load(saved)


def test_npz_meta_that_disagrees(tmp_path: Path) -> None:
    ds = Dataset.from_arrays(np.arange(N) % 5, np.arange(N) * 0.1, fs=100.0)
    path = D.save_npz(ds, tmp_path / "r.npz")
    with np.load(path) as archive:
        arrays = dict(archive)
    meta = json.loads(str(arrays["__hhra_meta__"]))
    meta["fs"] = 1.0
    arrays["__hhra_meta__"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(DataError, match=r"__hhra_meta__ entry .* says fs = 1 Hz"):
        D.load(tmp_path / "bad.npz")


# --------------------------------------------------------------------------- pandas


def test_pandas_round_trip() -> None:
    pytest.importorskip("pandas")
    ds = Dataset.from_arrays(
        np.arange(N) % 5, np.arange(N) * 0.1, fs=50.0, extra={"p": np.arange(N) * 2.0},
        output_name="pressure", output_unit="bar", name="run", note="x",
    )
    df = ds.to_dataframe()
    assert list(df.columns) == ["t", "u", "y", "p"]
    back = Dataset.from_dataframe(df, extra=["p"])
    for attr in ("t", "u", "y"):
        np.testing.assert_array_equal(getattr(back, attr), getattr(ds, attr))
    np.testing.assert_array_equal(back.extra["p"], ds.extra["p"])
    assert (back.output_name, back.output_unit, back.name) == ("pressure", "bar", "run")
    assert back.metadata == ds.metadata


def test_from_dataframe_columns_and_errors() -> None:
    pd = pytest.importorskip("pandas")
    df = pd.DataFrame({"time": np.arange(N) * 0.1, "I": np.arange(N) % 3, "phi": np.ones(N)})
    ds = Dataset.from_dataframe(df, time="time", input="I", output="phi", extra={"i2": "I"})
    assert ds.fs == pytest.approx(10.0) and set(ds.extra) == {"i2"}
    with pytest.raises(D.MissingColumnError, match="no column 'u'.*columns: time, I, phi"):
        Dataset.from_dataframe(df)
    df["phi"] = pd.array([1.0, None] + [1.0] * (N - 2), dtype="Float64")
    with pytest.raises(D.NonFiniteError, match="row 1"):
        Dataset.from_dataframe(df, time="time", input="I", output="phi")


def test_pandas_missing_gives_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    import builtins

    real_import = builtins.__import__

    def no_pandas(name: str, *args: object, **kw: object) -> object:
        if name == "pandas":
            raise ImportError("no pandas here")
        return real_import(name, *args, **kw)

    monkeypatch.setattr(builtins, "__import__", no_pandas)
    ds = Dataset.from_arrays(np.arange(N) % 5, np.arange(N) * 0.1)
    with pytest.raises(ImportError, match=r"hhra-phys\[pandas\]"):
        ds.to_dataframe()


# --------------------------------------------------------------------------- properties

# Header characters: ASCII plus accented letters of Latin-1 that are all >= 0xC0. Their
# Latin-1 bytes can never form valid UTF-8 (that needs continuation bytes 0x80-0xBF), so
# a Latin-1 file is never mistaken for UTF-8 -- an ambiguity no detector can resolve.
_NAME = st.text(
    alphabet=st.sampled_from("abcdefghijklmnopqrstuvwxyzABCXYZ_0123456789äöüßéÄÖÜÉ"),
    min_size=1,
    max_size=8,
).filter(lambda s: s not in ("t", "u", "y"))
_VALUE = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False).map(lambda v: v + 0.0)


@st.composite
def records(draw: st.DrawFn) -> tuple[list[str], np.ndarray]:
    names = draw(st.lists(_NAME, min_size=0, max_size=3, unique=True))
    n = draw(st.integers(min_value=20, max_value=40))
    dt = draw(st.sampled_from([0.001, 0.004, 0.1, 1.0]))
    cols = [np.arange(n) * dt]
    for _ in range(2 + len(names)):
        cols.append(np.array(draw(st.lists(_VALUE, min_size=n, max_size=n))))
    return ["t", "u", "y", *names], np.column_stack(cols)


@settings(max_examples=60, deadline=None, suppress_health_check=_TMP)
@given(
    rec=records(),
    sep=st.sampled_from([",", ";", "\t", " "]),
    encoding=st.sampled_from(["utf-8", "utf-8-sig", "utf-16", "latin-1"]),
    explicit=st.booleans(),
)

def test_written_records_load_back_or_raise_data_error(
    tmp_path: Path, rec: tuple[list[str], np.ndarray], sep: str, encoding: str, explicit: bool
) -> None:
    header, values = rec
    lines = [sep.join(header)] + [sep.join(repr(float(v)) for v in row) for row in values]
    path = tmp_path / "prop.csv"
    path.write_bytes(("\n".join(lines) + "\n").encode(encoding))
    delimiter = ("whitespace" if sep == " " else sep) if explicit else None
    try:
        ds = D.load(path, extra=header[3:], delimiter=delimiter, sidecar=False)
    except DataError:
        return  # e.g. a constant input or a non-uniform time axis: named, not a traceback
    np.testing.assert_array_equal(ds.t, values[:, 0])
    np.testing.assert_array_equal(ds.u, values[:, 1])
    np.testing.assert_array_equal(ds.y, values[:, 2])
    assert list(ds.extra) == header[3:]
    for k, name in enumerate(header[3:]):
        np.testing.assert_array_equal(ds.extra[name], values[:, 3 + k])


def test_property_generator_mostly_loads() -> None:
    # guards the property above against passing only through its DataError branch
    u = np.array([1.5, -2.0, 3.25] * 10)
    header, values = ["t", "u", "y", "ä1"], np.column_stack([np.arange(30) * 0.1, u, u, u])
    text = "\n".join([";".join(header)] + [";".join(map(repr, r)) for r in values.tolist()])
    path = Path(__import__("tempfile").mkdtemp()) / "ok.csv"
    path.write_bytes(text.encode("latin-1"))
    ds = D.load(path, extra=["ä1"])
    np.testing.assert_array_equal(ds.extra["ä1"], u)


@settings(max_examples=150, deadline=None, suppress_health_check=_TMP)
@given(content=st.one_of(
    st.binary(max_size=400),
    st.text(max_size=400).map(lambda s: s.encode("utf-8")),
    st.lists(st.sampled_from(["t", "u", "y", ",", ";", "\t", " ", "\n", "\r", "1", "2.5",
                              "-", "e", "nan", "#", '"', "\x00", "°"]),
             max_size=200).map(lambda parts: "".join(parts).encode("utf-16")),
))
def test_arbitrary_bytes_give_a_dataset_or_a_data_error(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "any.csv"
    path.write_bytes(content)
    try:
        ds = D.load(path, sidecar=False, checks=D.DataChecks(min_samples=2,
                                                             require_excitation=False))
    except DataError as exc:
        assert str(path) in str(exc)
    else:
        assert isinstance(ds, Dataset)
