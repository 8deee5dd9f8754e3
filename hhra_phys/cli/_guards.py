"""Checks every command runs on its options before any work: one function per concern.

Each function raises :class:`~hhra_phys.errors.ParameterError` (exit 2) naming the flag
and the value at fault, or is an ``argparse`` type that makes argparse do so. They are
kept apart from :mod:`hhra_phys.cli._common` (loading and parsing) so that each concern
can be read, tested and extended on its own:

- seeds (:func:`seed`) and other integer options;
- the files of one run (:func:`check_run_files`): an output never replaces an input of
  the same run (``--overwrite`` or not), two outputs never share a path, a suffix never
  contradicts what is written (``--report x.png``), ``''`` is not a path, ``-`` is stdout;
- sizes (:func:`check_size`): the memory and time a record of N samples costs, estimated
  before the work and refused with the number and the flag;
- option values that would be silently ignored or replaced (:func:`check_columns`,
  :func:`check_fix_items`, :func:`check_refine`, :func:`check_distinct_records`,
  :func:`check_dask_address`) or that the library would check under its Python names
  (:func:`check_ranges`);
- records and models (:func:`check_output_varies`, :func:`check_sample_rate`,
  :func:`check_hopeless_range`, :func:`check_model_builds`): what the data or the model
  says is impossible, before a fit starts;
- writing (:func:`all_or_nothing`): an interrupted run leaves none of its outputs.

:func:`check_arguments` runs the option checks that apply to a command's namespace.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hhra_phys.errors import ParameterError
from hhra_phys.units import TIME_UNITS

if TYPE_CHECKING:
    from hhra_phys.data import Dataset

#: The output path that means standard output (the usual command-line convention).
STDOUT = "-"

#: Bytes of memory a simulated sample costs at most (time, input, output, the state
#: trajectory and the integrator's work arrays), measured with ``simulate --duration``
#: at 250 Hz: peak RSS grows by about 91 bytes per sample (docs/data.md).
BYTES_PER_SAMPLE = 128

#: The most memory a record may cost before it is refused [bytes]: a quarter of the
#: memory available when the run starts, at most 4 GiB.
MAX_RECORD_BYTES = 4 * 2**30

#: Suffixes of files a command reads or writes as data, figures or reports: a JSON result
#: or a Markdown report under one of these names would mislead the next reader.
DATA_SUFFIXES = (".csv", ".tsv", ".txt", ".mat", ".npz", ".npy")
REPORT_SUFFIXES = (".md", ".markdown", ".txt")


# -- integer options ----------------------------------------------------------------------


def seed(text: str) -> int:
    """argparse type: a seed, an integer >= 0 (NumPy's generators take no negative seed)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a seed (an integer >= 0), got {text!r}"
                                         ) from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a seed (an integer >= 0), got {value}")
    return value


# -- the files of one run -----------------------------------------------------------------


def output_path(text: str) -> str:
    """argparse type of an output file: not empty (``''`` would silently write nothing)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a file name, got an empty string")
    return text


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.expanduser().resolve() == b.expanduser().resolve()


def check_run_files(inputs: Mapping[str, str | Path | Sequence[str | Path] | None],
                    outputs: Mapping[str, str | Path | None]) -> None:
    """Refuse a run whose outputs collide with each other or with its inputs.

    Parameters
    ----------
    inputs : mapping
        ``{label: path or list of paths}`` of every file the run reads ("DATA",
        "--validate", "FIT.json" ...); ``None`` and non-files are skipped.
    outputs : mapping
        ``{label: path}`` of every file the run writes, derived ones included (a side-car,
        a figure beside a report); ``None`` and :data:`STDOUT` are skipped.

    Raises
    ------
    ParameterError
        An output is one of the inputs (``--overwrite`` never applies to an input of the
        same run), or two outputs share a path (one would replace the other).
    """
    ins: list[tuple[str, Path]] = []
    for label, value in inputs.items():
        items = value if isinstance(value, list | tuple) else [value]
        ins += [(label, Path(p)) for p in items if p and Path(p).is_file()]
    outs = [(label, Path(p)) for label, p in outputs.items() if p and str(p) != STDOUT]
    for i, (label, p) in enumerate(outs):
        for in_label, q in ins:
            if _same(p, q):
                raise ParameterError(
                    f"{label} {p} is the input {in_label} {q} of this run: it would be "
                    "replaced (--overwrite never applies to an input); write elsewhere")
        for other, q in outs[:i]:
            if _same(p, q):
                raise ParameterError(f"{other} and {label} are the same file {p}: one would "
                                     "replace the other; give two names")


def check_suffix(label: str, path: str | Path | None, *, allowed: Iterable[str] | None = None,
                 refused: Iterable[str] = ()) -> None:
    """Refuse an output whose suffix says another format than what is written.

    ``allowed``: the suffixes accepted (case-insensitive); ``refused``: suffixes that
    mean another kind of file (an image, a record) under a JSON or Markdown writer.
    """
    if not path or str(path) == STDOUT:
        return
    suffix = Path(path).suffix.lower()
    if allowed is not None and suffix not in tuple(allowed):
        raise ParameterError(f"{label} {path}: this writes {label_kind(label)}; give a name "
                             f"ending in {' or '.join(allowed)}")
    if suffix in tuple(refused):
        raise ParameterError(f"{label} {path}: this writes {label_kind(label)}, not a "
                             f"{suffix} file; give another name")


def label_kind(label: str) -> str:
    """What an output flag writes, in words."""
    return {"--json": "JSON", "--report": "Markdown", "--markdown": "Markdown"}.get(
        label, "a file")


# -- sizes --------------------------------------------------------------------------------


def available_memory() -> int | None:
    """Bytes of memory available now (Linux ``MemAvailable``), or None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def record_budget() -> int:
    """The most memory a record may cost [bytes] (:data:`MAX_RECORD_BYTES`, or less)."""
    avail = available_memory()
    return MAX_RECORD_BYTES if avail is None else min(MAX_RECORD_BYTES, avail // 4)


def check_size(n_samples: float, flags: str, *, bytes_per_sample: float = BYTES_PER_SAMPLE,
               what: str = "the record") -> None:
    """Refuse a record of ``n_samples`` whose estimated memory exceeds :func:`record_budget`.

    Parameters
    ----------
    n_samples : float
        Samples the run would create (``duration * fs``, or a delay buffer's length).
    flags : str
        The flags that set it, named in the message ("--duration 1e+07 s at --fs 250 Hz").
    bytes_per_sample : float
        Memory a sample costs.
    what : str
        What is created, in words.

    Raises
    ------
    ParameterError
        With the estimate, the limit and the flags.
    """
    need = float(n_samples) * bytes_per_sample
    budget = record_budget()
    if not need <= budget:  # also NaN
        raise ParameterError(
            f"{flags}: {what} would have {n_samples:.3g} samples and need about "
            f"{_bytes(need)} of memory, more than the {_bytes(budget)} allowed (a quarter of "
            "the memory available, at most 4 GiB); shorten it")


#: Seconds one population member costs per sample simulated, near idle: a population of
#: 100 over 5000 samples in 15-18 ms (README, docs/performance.md), rounded up.
SECONDS_PER_MEMBER_SAMPLE = 4e-8

#: Bytes one population member costs per sample while a population is simulated (its
#: output and the work arrays of the vector code), an upper estimate.
BYTES_PER_MEMBER_SAMPLE = 32

#: The longest global search started without complaint [s]: a day at the estimate of
#: :data:`SECONDS_PER_MEMBER_SAMPLE` (a loaded machine takes longer still).
MAX_SEARCH_SECONDS = 86400.0

#: A search estimated longer than this [s] is announced with its estimate before it starts.
LONG_SEARCH_SECONDS = 600.0


def check_search(pop: int, iters: int, n_samples: int, *, runs: int = 1,
                 flags: str = "--pop/--iters") -> None:
    """Refuse a global search whose population would not fit in memory, or which would
    run longer than :data:`MAX_SEARCH_SECONDS`, before it starts; announce one estimated
    longer than :data:`LONG_SEARCH_SECONDS` on stderr.

    Parameters
    ----------
    pop, iters : int
        Population size and iterations.
    n_samples : int
        Samples each member simulates per evaluation (the records' total).
    runs : int
        Searches run (``--starts``).
    flags : str
        The flags named in the message.

    Raises
    ------
    ParameterError
        With the estimate, the limit and the flags.
    """
    # The population's simulated outputs, and the pairwise comparison of members (up to
    # 8 parameters) in the leaders' distinctness check.
    need = float(pop) * n_samples * BYTES_PER_MEMBER_SAMPLE + 8.0 * pop * pop
    budget = record_budget()
    if need > budget:
        raise ParameterError(
            f"--pop {pop}: a population of {pop:,} members over {n_samples:,} samples needs "
            f"about {_bytes(need)} of memory, more than the {_bytes(budget)} allowed (a "
            "quarter of the memory available, at most 4 GiB); lower --pop")
    seconds = float(pop) * (iters + 1) * n_samples * runs * SECONDS_PER_MEMBER_SAMPLE
    if seconds > MAX_SEARCH_SECONDS:
        raise ParameterError(
            f"{flags}: {pop:,} members x {iters:,} iterations over {n_samples:,} samples"
            + (f" x {runs} starts" if runs > 1 else "")
            + f" would take about {seconds / 3600:,.0f} h at best, more than the "
            f"{MAX_SEARCH_SECONDS / 3600:.0f} h allowed; lower --pop or --iters")
    if seconds > LONG_SEARCH_SECONDS:
        import sys

        print(f"note: {flags}: the global search will take about {seconds / 60:,.0f} min at "
              "best (Ctrl-C stops it, writing nothing)", file=sys.stderr)


def _bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"


# -- options that would be silently ignored or replaced -----------------------------------


def check_columns(time_col: str | None, input_col: str | None, output_col: str | None) -> None:
    """Refuse one column given for two roles (``--input-col u --output-col u``), also when
    the other role takes its default column (``--input-col y`` leaves the output at its
    default ``y``: the output would be fitted as its own input)."""
    roles = (("--time-col", time_col, "t"), ("--input-col", input_col, "u"),
             ("--output-col", output_col, "y"))
    given = [(flag, col) for flag, col, _ in roles if col is not None]
    for i, (flag, col) in enumerate(given):
        for other, col2 in given[:i]:
            if col.strip() == col2.strip():
                raise ParameterError(f"{other} and {flag} both name column {col!r}: a record's "
                                     "time, input and output are three different columns")
    for flag, col in given:
        for other, col2, default in roles:
            if other != flag and col2 is None and col.strip() == default:
                raise ParameterError(
                    f"{flag} {col!r} is the default column of {other} ({default!r}): one "
                    "column would be both; a record's time, input and output are three "
                    f"different columns (give {other} too)")


def check_fix_items(items: Sequence[str] | None) -> None:
    """Refuse ``--fix NAME=A --fix NAME=B`` (the last would silently win)."""
    seen: dict[str, str] = {}
    for item in items or []:
        name, eq, value = item.partition("=")
        name = name.strip()
        if not eq or not name:
            continue  # parse_fixed names the malformed item
        if name in seen and seen[name].strip() != value.strip():
            raise ParameterError(f"--fix {name} is given twice ({name}={seen[name]} and "
                                 f"{name}={value}); give it once")
        seen[name] = value


def check_refine(text: str | None) -> None:
    """Refuse an empty ``--refine`` or an empty stage in ``a+b`` (it used to mean 'none')."""
    if text is None:
        return
    stages = text.split("+")
    if not text.strip() or any(not s.strip() for s in stages):
        raise ParameterError(f"--refine {text!r}: give ipopt, nlopt, nlopt:ALGORITHM or none "
                             "(stages joined by '+')")


def check_distinct_records(groups: Mapping[str, Sequence[str | None] | None]) -> None:
    """Refuse the same file given twice as two records (DATA twice, --validate = DATA).

    ``groups``: ``{flag: [paths]}``; built-in names ('rig', 'public', None) are skipped.
    """
    seen: list[tuple[str, Path]] = []
    for flag, names in groups.items():
        for name in names or []:
            if not name or str(name).lower() in ("rig", "public"):
                continue
            p = Path(name)
            for other_flag, q in seen:
                if _same(p, q):
                    where = (f"twice in {flag}" if other_flag == flag
                             else f"as {other_flag} and as {flag}")
                    raise ParameterError(
                        f"{name} is given {where}: the same record would count twice "
                        "(and a fit validated on its own data tells nothing); give "
                        "different records")
            seen.append((flag, p))


def check_dask_address(address: str | None) -> None:
    """Refuse a ``--dask`` value that cannot be a scheduler address, before connecting.

    An address is ``[PROTOCOL://]HOST:PORT`` (``tcp://10.0.0.5:8786``) or a scheduler
    file ending in .json.
    """
    if address is None:
        return
    text = address.strip()
    if not text:
        raise ParameterError("--dask '': give the scheduler's address, e.g. tcp://host:8786 "
                             "(or leave --dask out to run here)")
    if text.endswith(".json"):
        return
    rest = text.split("://", 1)[1] if "://" in text else text
    host, sep, port = rest.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ParameterError(f"--dask {address!r}: not a scheduler address; expected "
                             "[tcp://]HOST:PORT, e.g. tcp://10.0.0.5:8786")


def _inputs_of(args: argparse.Namespace) -> dict[str, object]:
    """Every file a command's options name as an input, by flag."""
    data = getattr(args, "data", None)
    out: dict[str, object] = {"DATA": data if isinstance(data, list) else [data]}
    for attr, flag in (("validate", "--validate"), ("fit", "FIT.json"),
                       ("effects_from", "--effects-from")):
        value = getattr(args, attr, None)
        if value:
            out[flag] = value if isinstance(value, list) else [value]
    model = getattr(args, "model", None)
    if model and ":" in model:
        out["--model"] = [model.rpartition(":")[0]]
    for flag in ("DATA", "--validate"):  # a text record's side-car is read with it
        cars = [sidecar_of(p) for p in out.get(flag) or []]  # type: ignore[attr-defined]
        cars = [c for c in cars if c is not None]
        if cars:
            out[f"{flag}'s side-car"] = cars
    return out


def sidecar_of(path: object) -> Path | None:
    """The JSON side-car a text record ``path`` is read with (``rig.csv`` -> ``rig.json``),
    if the record is a text file and the side-car exists; else None."""
    from hhra_phys.data import sidecar_path

    if not path or not isinstance(path, str | Path) or is_builtin_name(str(path)):
        return None
    p = Path(path)
    if p.suffix.lower() not in (".csv", ".tsv", ".txt"):
        return None
    side = sidecar_path(p)
    return side if side.is_file() and side != p else None


def is_builtin_name(name: str) -> bool:
    """Whether DATA ``name`` is a built-in record ('rig', 'public'), not a file."""
    return name.lower() in ("rig", "public")


def check_ranges(args: argparse.Namespace) -> None:
    """The numeric options whose range the library checks under its own (Python) names,
    checked here under the flag's name: ``--lam``, ``--margin``, ``--noise-tol``,
    ``--zeta``, ``--box``."""
    import math

    def number(flag: str, value: float | None, ok: bool, want: str) -> None:
        if value is not None and not (math.isfinite(value) and ok):
            raise ParameterError(f"{flag} must be {want}, got {value}")

    lam = getattr(args, "lam", None)
    number("--lam", lam, True, "a finite number")
    margin = getattr(args, "margin", None)
    number("--margin", margin, margin is not None and 0 <= margin < 1, "in [0, 1)")
    tol = getattr(args, "noise_tol", None)
    number("--noise-tol", tol, tol is not None and tol >= 0, "a finite number >= 0")
    zeta = getattr(args, "zeta", None)
    number("--zeta", zeta, zeta is not None and 0 < zeta <= 1, "in (0, 1]")
    box = getattr(args, "box", None)
    if box is not None:
        lo, hi = box
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ParameterError(f"--box LO HI must be finite with LO < HI, got {lo} {hi}")


def check_arguments(args: argparse.Namespace, outputs: Mapping[str, str | Path | None]) -> None:
    """The checks of this module that apply to ``args``, before any work.

    Parameters
    ----------
    args : argparse.Namespace
        A command's options; each check runs when the options it reads are there.
    outputs : mapping
        ``{flag: path}`` of every file the run writes (derived ones included).
    """
    from hhra_phys.outputs import FIGURE_SUFFIXES

    if hasattr(args, "input_col"):
        check_columns(getattr(args, "time_col", None), args.input_col, args.output_col)
    check_fix_items(getattr(args, "fix", None))
    check_refine(getattr(args, "refine", None))
    check_dask_address(getattr(args, "dask", None))
    check_ranges(args)
    data = getattr(args, "data", None)
    check_distinct_records({"DATA": data if isinstance(data, list) else [data],
                            "--validate": getattr(args, "validate", None)})
    for flag, path in outputs.items():
        if path is not None and str(path) == STDOUT and flag != "--json":
            raise ParameterError(f"{flag} -: only --json writes to stdout ('-'); give a file "
                                 "name")
    for flag in ("--json",):
        check_suffix(flag, outputs.get(flag), refused=FIGURE_SUFFIXES + DATA_SUFFIXES)
    for flag in ("--report", "--markdown"):
        check_suffix(flag, outputs.get(flag), allowed=REPORT_SUFFIXES)
    check_run_files(_inputs_of(args), outputs)


def split_value(text: str) -> float | int:
    """argparse type of ``--split``, one meaning in every command.

    A number in (0, 1] is the estimation fraction (1: all of it); an integer above 1 is
    the sample index the estimation part ends before (the public record's 512).
    """
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a fraction in (0, 1] or a sample index (an integer > 1), got {text!r}"
        ) from None
    if 0.0 < value <= 1.0:
        return value
    if value > 1.0 and value.is_integer():
        return int(value)
    raise argparse.ArgumentTypeError(
        f"expected a fraction in (0, 1] or a sample index (an integer > 1), got {text!r}")


def split_fraction(split: float | int, n_samples: Sequence[int]) -> float:
    """``--split`` as the fraction the fit takes: a sample index k of an n-sample record is
    k / n (the fit's split index ``round(fraction * n)`` is then k again).

    Raises
    ------
    ParameterError
        An index with several records (each would split elsewhere), or one that leaves an
        empty part.
    """
    if not isinstance(split, int):
        return float(split)
    if len(n_samples) != 1:
        raise ParameterError(f"--split {split}: a sample index splits one record; with "
                             f"{len(n_samples)} records give a fraction in (0, 1]")
    n = n_samples[0]
    if not 0 < split < n:
        raise ParameterError(f"--split {split}: the record has {n} samples; give an index "
                             f"between 1 and {n - 1}, or a fraction in (0, 1]")
    return split / n


# -- records and models: what the data or the model says is impossible ---------------------


def check_output_varies(data: Dataset, args: argparse.Namespace) -> None:
    """Refuse a record whose output never changes, before any fit (nothing to fit to)."""
    from hhra_phys.errors import DataError

    if data.n and float(np.ptp(data.y)) == 0.0:
        col = getattr(args, "output_col", None) or "y"
        raise DataError(f"{args.data}: the output column {col!r} is constant ({data.y[0]:g} in "
                        "every row): there is no response to fit; is --output-col the right "
                        "column?")


#: A record sampled this many times faster than the model's fastest mode is implausible:
#: 10 kHz for a 1 Hz mode. Hydraulic and mechanical records take 10 to 100 per period.
MAX_SAMPLES_PER_PERIOD = 1e4


def check_sample_rate(args: argparse.Namespace, data: Dataset, model: Any) -> None:
    """Refuse ``--time-unit`` when it makes the record absurdly fast for the model.

    The model's own time constants decide: its fastest mode (the largest eigenvalue of
    its linearisation at the nominal values, at rest) should see a few to a few hundred
    samples per period. When the rescaled rate is more than :data:`MAX_SAMPLES_PER_PERIOD`
    times that mode while the file's column, read in seconds, already gives a rate above
    it, the column was in seconds and ``--time-unit`` is wrong.
    """
    unit = getattr(args, "time_unit", None)
    if unit in (None, "s") or data.time_unit != "s" or not data.fs:
        return
    try:
        a = model.linearize(dt=float(data.dt))[0]
        fastest = float(np.max(np.abs(np.linalg.eigvals(np.asarray(a, dtype=float))))) / (
            2 * math.pi)
    except Exception:  # noqa: BLE001 - a model that cannot be linearised: no check
        return
    if not (math.isfinite(fastest) and fastest > 0):
        return
    raw = data.fs * TIME_UNITS[unit]
    if data.fs > MAX_SAMPLES_PER_PERIOD * fastest and raw >= 2 * fastest:
        from hhra_phys.errors import DataError

        raise DataError(
            f"{data.source or 'the record'}: --time-unit {unit} makes the sample rate "
            f"{data.fs:.4g} Hz, {data.fs / fastest:.3g} samples per period of the model's "
            f"fastest mode ({fastest:.3g} Hz); read in seconds the time column gives "
            f"{raw:.4g} Hz, a plausible rate: leave --time-unit out")


#: How far beyond the HHRA's plausible ranges a record is refused rather than warned
#: about: a million times (an angle span of 3.6e10 deg). Far beyond, the initial angle's
#: box loses its width in double precision and the fit cannot even start.
HOPELESS_FACTOR = 1e6


def check_hopeless_range(data: Dataset) -> None:
    """Refuse an HHRA record whose input or output is :data:`HOPELESS_FACTOR` times beyond
    its plausible range (the warning of :func:`record_for_model` is not enough there)."""
    from hhra_phys.errors import DataError
    from hhra_phys.models.hhra.defaults import PLAUSIBLE

    checks = [("input", data.u, "peak")]
    if data.output_name != "pressure":  # as prepare_record: a pressure's gain is fitted
        checks.append(("output", data.y, "span"))
    for role, values, what in checks:
        rng = PLAUSIBLE[role]
        size = float(np.max(np.abs(values))) if what == "peak" else float(np.ptp(values))
        if size > HOPELESS_FACTOR * rng.high:
            raise DataError(
                f"{data.source or data.name or 'the record'}: the {role} has a {what} of "
                f"{size:.3g} {rng.unit}, {size / rng.high:.2g} times the plausible "
                f"{rng.high:g} {rng.unit} of an HHRA: {rng.too_high} Convert the column (or "
                "give your own --model)")


def check_model_builds(model: Any, data: Dataset, what: str) -> None:
    """Build ``model``'s equations once (cheap, symbolic), so a user's part that fails
    does so before any fit starts, with the part and the file named."""
    from hhra_phys.errors import ModelError

    try:
        model.assemble(*model.symbols(), float(data.dt))
    except ModelError as exc:
        raise ModelError(f"{what}: {exc}") from None


@contextmanager
def stdout_kept_for_json(json_path: str | Path | None) -> Iterator[None]:
    """A block whose prints go to stderr when ``--json -`` reserves stdout for the JSON.

    A user's model file, effect file or plugin may print while it is imported or run; on
    stdout its lines would corrupt the JSON a pipe reads (``--json - | jq``). Outside
    ``--json -`` the block changes nothing.
    """
    import sys
    from contextlib import redirect_stdout

    if json_path is None or str(json_path) != STDOUT:
        yield
        return
    with redirect_stdout(sys.stderr):
        yield


@contextmanager
def all_or_nothing(paths: Iterable[str | Path | None]) -> Iterator[None]:
    """A block that writes several files: if it ends by Ctrl-C or an error, the files it
    created are removed again, so an interrupted run leaves none of its outputs.

    Files that existed before (replaced with ``--overwrite``) are left as they are:
    each is written atomically, so it is either the old file or the complete new one.
    """
    files = [Path(p) for p in paths if p and str(p) != STDOUT]
    new = [p for p in files if not p.exists()]
    try:
        yield
    except BaseException:
        for p in new:
            p.unlink(missing_ok=True)
        raise
