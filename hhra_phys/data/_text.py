"""Reading text records: the encoding of the bytes and the delimiter of the fields.

Measured records come from loggers and spreadsheets on every platform: UTF-8 with or without
an Excel byte-order mark, UTF-16 from "Unicode text" exports, Latin-1/Windows-1252 from
older German or French tools (``Winkel [°]``), and ``,``, ``;``, tab or blank-separated
columns. This module decides both from the bytes, or raises a :class:`DataFormatError`
naming the file, so a loader never fails with a ``UnicodeDecodeError`` traceback.
"""

from __future__ import annotations

import codecs
from collections.abc import Sequence

from hhra_phys.data.errors import DataFormatError

#: Delimiters tried by :func:`detect_delimiter`, in order of preference on a tie.
CANDIDATES: tuple[str, ...] = (",", ";", "\t")
#: The name of the fifth choice: split on runs of blanks and tabs (``str.split()``).
WHITESPACE = "whitespace"
_NAMES = {",": ",", ";": ";", "\t": "tab", " ": "space", WHITESPACE: WHITESPACE}
_SAMPLE_LINES = 20  # lines looked at to detect the delimiter: enough for a header + data
_BOMS = (
    # UTF-32 first: its little-endian mark starts with the UTF-16 one.
    (codecs.BOM_UTF32_LE, "utf-32"),
    (codecs.BOM_UTF32_BE, "utf-32"),
    (codecs.BOM_UTF8, "utf-8-sig"),
    (codecs.BOM_UTF16_LE, "utf-16"),
    (codecs.BOM_UTF16_BE, "utf-16"),
)


def decode(data: bytes, source: str, encoding: str | None = None) -> tuple[str, str]:
    """``(text, encoding)`` of the bytes of a text file.

    Parameters
    ----------
    data : bytes
        The whole file.
    source : str
        File name for messages.
    encoding : str, optional
        Use this codec; ``None`` detects: a byte-order mark (UTF-8, UTF-16, UTF-32), else
        UTF-8, else Windows-1252, else Latin-1 (which decodes any bytes, so binary files
        are recognised first by their NUL and control bytes).

    Raises
    ------
    DataFormatError
        Binary content, or bytes the given ``encoding`` cannot decode.
    """
    if encoding is not None:
        return _decode_as(data, source, encoding)
    marked = _decode_marked(data, source)
    if marked is not None:
        return marked
    _refuse_binary(data, source)
    for codec in ("utf-8", "cp1252"):
        try:
            return data.decode(codec), codec
        except UnicodeDecodeError:
            continue
    return data.decode("latin-1"), "latin-1"


def _decode_as(data: bytes, source: str, encoding: str) -> tuple[str, str]:
    """``(text, encoding)`` with the codec the user named; an error names the file."""
    try:
        return data.decode(encoding), encoding
    except LookupError:
        raise DataFormatError(f"{source}: unknown encoding {encoding!r}") from None
    except UnicodeDecodeError as exc:
        raise DataFormatError(
            f"{source}: not valid {encoding} text (byte {exc.start}: {exc.reason}); "
            "leave encoding=None to detect it"
        ) from None


def _decode_marked(data: bytes, source: str) -> tuple[str, str] | None:
    """``(text, encoding)`` by the byte-order mark the bytes start with; ``None`` without one."""
    for bom, codec in _BOMS:
        if data.startswith(bom):
            try:
                return data.decode(codec), codec
            except UnicodeDecodeError as exc:
                raise DataFormatError(
                    f"{source}: starts with a {codec.upper()} byte-order mark but is not valid "
                    f"{codec.upper()} text (byte {exc.start}: {exc.reason})"
                ) from None
    return None


def _refuse_binary(data: bytes, source: str) -> None:
    """Refuse binary content (checked before Latin-1, which would decode any bytes)."""
    if _looks_binary(data):
        hint = ""
        if data[1::2].count(0) > len(data) // 4 or data[0::2].count(0) > len(data) // 4:
            hint = "; if it is UTF-16 text, save it with a byte-order mark (BOM)"
        raise DataFormatError(
            f"{source}: binary or undecodable content (NUL or control bytes), not a text "
            f"record{hint}"
        )


def _looks_binary(data: bytes) -> bool:
    """NUL bytes, or more than 5 % control bytes other than tab, CR, LF, FF: not text."""
    if b"\x00" in data:
        return True
    sample = data[:65536]
    if not sample:
        return False
    controls = sum(1 for b in sample if b < 32 and b not in (9, 10, 12, 13))
    return controls > 0.05 * len(sample)


def split_fields(line: str, delimiter: str) -> list[str]:
    """The fields of one line with the ``csv`` dialect rules (quotes), or on blanks."""
    import csv

    if delimiter == WHITESPACE:
        return line.split()
    return next(csv.reader([line], delimiter=delimiter), [])


def detect_delimiter(lines: Sequence[str]) -> str:
    """The delimiter of a header and its first data lines.

    The candidate that splits every line into the same number of fields, more than one,
    wins (ties: the most fields, then the order of :data:`CANDIDATES`); failing that,
    blanks (:data:`WHITESPACE`) when they split the header; else ``","`` (one column).
    Consistency matters more than counts so that ``1,5;2,5`` (decimal commas) is read as
    ';'-delimited.
    """
    sample = [ln for ln in lines[:_SAMPLE_LINES] if ln.strip()]
    if not sample:
        return ","
    best: tuple[int, int] | None = None
    choice = None
    for rank, cand in enumerate(CANDIDATES):
        counts = {len(_safe_split(ln, cand)) for ln in sample}
        if len(counts) == 1 and (n := counts.pop()) > 1:
            score = (n, -rank)
            if best is None or score > best:
                best, choice = score, cand
    if choice is not None:
        return choice
    if len({len(ln.split()) for ln in sample}) == 1 and len(sample[0].split()) > 1:
        return WHITESPACE
    # Inconsistent everywhere: the candidate that splits the header most, so the
    # ragged-row message names the likely delimiter.
    header = sample[0]
    counts = [(len(_safe_split(header, c)), -i, c) for i, c in enumerate(CANDIDATES)]
    n, _, cand = max(counts)
    return cand if n > 1 else (WHITESPACE if len(header.split()) > 1 else ",")


def _safe_split(line: str, delimiter: str) -> list[str]:
    try:
        return split_fields(line, delimiter)
    except Exception:  # csv.Error on odd quoting: this candidate does not fit
        return [line]


#: Separators some exports use that detection does not try, but a hint names.
HINT_ONLY = ("|", ":")


def delimiter_hint(header: str, used: str) -> str:
    """``"; the header looks ';'-delimited: pass --delimiter ';' ..."`` or ``""``.

    Given when the header, split with ``used``, lacks a column the caller asked for, and
    another delimiter would split it into several fields.
    """
    if len(_safe_split(header, used)) > 1:
        # The header did split: the names differ, not the separator ('Zeit [s];Strom [mA]'
        # has blanks inside its names, so a blank would split it more, wrongly).
        return ""
    # Detection only tries the common separators; a hint may also name rarer ones.
    for cand in (*CANDIDATES, *HINT_ONLY, WHITESPACE):
        if cand == used:
            continue
        fields = _safe_split(header, cand) if cand != WHITESPACE else header.split()
        if len(fields) > 1 and len(fields) > len(_safe_split(header, used)):
            name = display(cand)
            return (
                f"; the header looks {name!r}-delimited: pass --delimiter {name!r} "
                f"(Python: delimiter={cand!r})"
            )
    return ""


def display(delimiter: str) -> str:
    """How messages and the CLI name a delimiter (``"tab"`` for ``"\\t"``)."""
    return _NAMES.get(delimiter, delimiter)


def parse_delimiter(text: str | None) -> str | None:
    """The delimiter a user typed: ``,`` ``;`` ``tab`` ``\\t`` ``space`` ``whitespace`` ``auto``.

    Returns ``None`` for ``auto`` (detect) and :data:`WHITESPACE` for ``whitespace``.

    Raises
    ------
    ValueError
        For anything else (more than one character and not a known name).
    """
    if text is None:
        return None
    word = text.strip().lower() if text.strip() else text
    named = {"auto": None, "tab": "\t", "\\t": "\t", "space": " ", "whitespace": WHITESPACE,
             "comma": ",", "semicolon": ";"}
    if word in named:
        return named[word]
    if len(text) == 1 and text not in "\"\r\n":
        return text
    raise ValueError(
        f"delimiter {text!r}: use one character (',', ';', '|'), 'tab', 'whitespace' or 'auto'"
    )
