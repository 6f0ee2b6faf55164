"""Reading and writing the small CSV tables of a project folder (DESIGN section 10).

Input rules, shared by every input file:

* UTF-8 (a leading byte-order mark is accepted); the first row that is not a comment is the header;
* a line whose first non-blank character is ``#`` is a comment; blank lines are skipped;
* surrounding whitespace of header names and of values is stripped;
* every row must have as many fields as the header; the table remembers which columns the caller
  asked for (:meth:`CsvTable.unused_columns`: the reader turns the others into a Note, never
  ignoring a column silently);
* every row keeps its physical, 1-based line number, so that an error names file, line and reason.

Only regular files are read (:func:`read_input_bytes`): a folder, a FIFO, a device or a socket in
place of an input file is an InputError, found by ``os.stat`` before anything is opened, so a
reader never blocks; a link whose target is missing is an error, never "absent"
(:func:`input_present`).

Errors are :class:`striptri.errors.InputError`. Nothing here prints or writes except ``write_csv``.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import stat
from collections.abc import Iterator, Mapping, Sequence
from itertools import repeat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

try:
    import fastnumbers as _fastnumbers
except ImportError:
    _fastnumbers = None

from striptri.errors import InputError

_BOM = b"\xef\xbb\xbf"


@dataclass(frozen=True)
class CsvTable:
    """One parsed CSV file: header names, the string values of each column and the line numbers of
    the rows.

    header: stripped column names. columns: one list of stripped strings per header name, each with
    one value per data row. lines: physical 1-based line number of the first line of each row.
    header_line: that of the header row (None for an empty file). ``rows`` gives the same values
    row by row.
    """

    path: Path
    header: tuple[str, ...]
    header_line: int | None
    columns: tuple[list[str], ...]
    lines: list[int]
    # the columns a reader asked for (require, strings, floats, ...): the others are unused
    used: set = field(default_factory=set, compare=False, repr=False)

    def __len__(self) -> int:
        return len(self.lines)

    @property
    def rows(self) -> list[tuple[str, ...]]:
        """One tuple of stripped strings per data row, aligned with header."""
        return list(zip(*self.columns)) if self.columns else [() for _ in self.lines]

    def has(self, name: str) -> bool:
        """True when the header has a column called ``name``."""
        return name in self.header

    def error(self, row: int, reason: str) -> InputError:
        """An InputError for data row ``row`` (0-based index into rows), naming its physical line."""
        return InputError(self.path, self.lines[int(row)], reason)

    def text(self, row: int, name: str) -> str:
        """The text of column ``name`` in data row ``row`` as the file has it ('' when the column is absent)."""
        return self.columns[self.header.index(name)][int(row)] if name in self.header else ""

    def unused_columns(self) -> list[str]:
        """Header names no reader asked for, in header order."""
        return [name for name in self.header if name not in self.used]

    def require(self, *names: str) -> None:
        """Raise InputError(path, header line, "missing column ...") unless every name is in the header.
        An empty file (no header row at all) is said to be empty."""
        self.used.update(names)
        for name in names:
            if self.header_line is None:
                raise InputError(self.path, None, f"the file is empty (no header row; expected the columns "
                                                  f"{', '.join(names)})")
            if name not in self.header:
                have = ", ".join(self.header) if self.header else "nothing"
                raise InputError(self.path, self.header_line or 1, f"missing column '{name}' (header has: {have})")

    def strings(self, name: str, allow_empty: bool = False) -> list[str]:
        """Values of a required column as strings; an empty value is an error unless allow_empty."""
        self.require(name)
        values = list(self.columns[self.header.index(name)])
        if not allow_empty and not all(values):
            raise self.error(values.index(""), f"column '{name}' is empty")
        return values

    def id_indices(self, names: Sequence[str], index_of: Mapping[str, int], known_in: str) -> dict[str, np.ndarray]:
        """Columns of ids turned into indices: name -> (rows,) int64 through ``index_of``; an id it
        does not hold is an error naming the line ("unknown NAME 'ID' (not in KNOWN_IN)")."""
        out = {}
        for name in names:
            out[name] = np.zeros(len(self), dtype=np.int64)
            for i, key in enumerate(self.strings(name)):
                if key not in index_of:
                    raise self.error(i, f"unknown {name} '{key}' (not in {known_in})")
                out[name][i] = index_of[key]
        return out

    def optional_strings(self, name: str, default: str = "") -> list[str]:
        """Values of an optional column; ``default`` for every row when the column is absent."""
        self.used.add(name)
        if name not in self.header:
            return [default] * len(self)
        return list(self.columns[self.header.index(name)])

    def floats(self, name: str) -> np.ndarray:
        """A required column of finite numbers -> (n,) float array. Empty, non-numeric, nan, inf: error."""
        self.require(name)
        out = self.optional_floats(name)
        empty = np.flatnonzero(np.isnan(out))
        if len(empty):
            raise self.error(empty[0], f"column '{name}' is empty (a number is required)")
        return out

    def optional_floats(self, name: str, keywords: Mapping[str, float] | None = None) -> np.ndarray:
        """An optional column of finite numbers -> (n,) float array; empty field or absent column -> nan.

        keywords: words accepted in place of a number (case-insensitive), e.g. {"free": inf}.
        Non-numeric text, and the literals nan and inf, are rejected with an InputError naming the
        line, the column and the bad value.

        The column is converted in one pass of ``float`` (the same parser, so the same numbers); a
        column with a keyword or a value it refuses is gone through value by value, which finds
        the first problem and says what it is.
        """
        words = {k.lower(): v for k, v in (keywords or {}).items()}
        values = self.optional_strings(name)
        if not words:
            out = _finite_floats(values)
            if out is not None:
                return out
        out = np.full(len(values), np.nan)
        for i, text in enumerate(values):
            if text == "":
                continue
            if text.lower() in words:
                out[i] = words[text.lower()]
                continue
            out[i] = _parse_finite(text, lambda reason, i=i: self.error(i, f"column '{name}': {reason}"))
        return out


def _finite_floats(values: list[str]) -> np.ndarray | None:
    """float of every value, '' -> nan, as an (n,) array; None when a value is not a finite number
    (the caller then finds and names it)."""
    n = len(values)
    if not any(values):
        return np.full(n, np.nan)
    if (out := _compiled_floats(values)) is not None:
        return out
    try:
        if n > 1000 and len(set(values[:1000])) <= 16:  # a column of a few values (sigmas): each parsed once
            number = {v: float(v or "nan") for v in set(values)}
            out = np.fromiter(map(number.__getitem__, values), dtype=np.float64, count=n)
        else:
            texts = values if all(values) else [v or "nan" for v in values]
            out = np.fromiter(map(float, texts), dtype=np.float64, count=n)
    except ValueError:
        return None
    bad = np.flatnonzero(~np.isfinite(out))
    if len(bad) and any(values[i] for i in bad.tolist()):  # a nan or inf in the file, not an empty field
        return None
    return out


FAST_FLOATS_MIN = 1000  # shorter columns: the call's set-up is about what it saves


def _compiled_floats(values: list[str]) -> np.ndarray | None:
    """float of every value by fastnumbers (compiled, correctly rounded: float's doubles, 5x quicker), or None
    for float's path: not installed, few values, an empty one, one refused ("1_0") or not finite ("nan(123)")."""
    if _fastnumbers is None or len(values) < FAST_FLOATS_MIN or not all(values):
        return None
    try:
        out = _fastnumbers.try_array(values, dtype=np.float64)
    except (ValueError, OverflowError, TypeError):
        return None
    return out if np.isfinite(out).all() else None


def _parse_finite(text: str, fail) -> float:
    """float(text) if it is a finite number, else raise fail(reason)."""
    try:
        value = float(text)
    except ValueError:
        raise fail(f"'{text}' is not a number") from None
    if not math.isfinite(value):
        raise fail(f"'{text}' is not a finite number")
    return value


def _kind_of(mode: int) -> str:
    """Words for a file type that is not a regular file."""
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "not a regular file"


def _missing(path: Path) -> InputError:
    """The InputError for a path os.stat cannot find: a link to nothing, or nothing."""
    if os.path.islink(path):
        try:
            target = os.readlink(path)
        except OSError:  # pragma: no cover - the link vanished meanwhile
            target = "?"
        return InputError(path, None, f"is a link to '{target}', which does not exist")
    return InputError(path, None, "file not found")


def input_present(path: str | Path) -> bool:
    """Whether an optional input file is there: False when nothing at all has that name; True when
    something does (the reader then reads it, and refuses a folder or a FIFO). A link whose target is
    missing is an InputError naming it: it is never taken for "absent"."""
    path = Path(path)
    try:
        os.lstat(path)
    except FileNotFoundError:
        return False
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    try:
        os.stat(path)
    except FileNotFoundError:
        raise _missing(path) from None
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    return True


def read_input_bytes(path: Path, folder_reason: str = "is a folder, not a file") -> bytes:
    """The bytes of an input file. A missing path, a link to nothing, a folder (folder_reason), a
    FIFO, a device, a socket or an unreadable file -> InputError(path, None, ...). The type is
    checked with os.stat before opening, and the file is opened without blocking and checked again
    (os.fstat), so a FIFO never makes a reader wait."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise _missing(path) from None
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(path, None, folder_reason)
    if not stat.S_ISREG(st.st_mode):
        raise InputError(path, None, f"is {_kind_of(st.st_mode)}, not a regular file; striptri reads input "
                                     "only from regular files")
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    with os.fdopen(fd, "rb") as handle:
        mode = os.fstat(handle.fileno()).st_mode
        if not stat.S_ISREG(mode):  # replaced between stat and open
            raise InputError(path, None, f"is {_kind_of(mode)}, not a regular file; striptri reads input "
                                         "only from regular files")
        try:
            return handle.read()
        except OSError as exc:
            raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None


def read_csv(path: str | Path) -> CsvTable:
    """Read one CSV table (rules in the module docstring). Missing file -> InputError(path, None, ...)."""
    path = Path(path)
    return parse_csv(path, read_input_bytes(path))


def parse_csv(path: str | Path, content: str | bytes) -> CsvTable:
    """Parse the content of one CSV table (bytes as in a file, or text); path only names it in
    messages. Same rules and errors as read_csv."""
    path = Path(path)
    return _parse(path, decode_text(path, content))


def decode_text(path: str | Path, content: str | bytes) -> str:
    """The text of an input file: UTF-8 with an optional byte-order mark (also on text already
    decoded); undecodable bytes -> InputError naming the line they are on."""
    if isinstance(content, str):
        return content[1:] if content.startswith("\ufeff") else content
    raw = content[len(_BOM):] if content.startswith(_BOM) else content
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        bad = raw[exc.start : exc.end].hex(" ")
        raise InputError(path, line, f"not valid UTF-8 text (bytes {bad}); save the file as UTF-8") from None


def _parse(path: Path, text: str) -> CsvTable:
    """Split text into header and rows, skipping comments and blank lines, keeping line numbers.

    Text without quotes (and without NUL characters or huge fields, which csv.reader refuses) is
    split with str methods over whole columns; anything else goes through csv.reader line by line.
    Both give the same table and the same errors."""
    if '"' in text or "\0" in text:
        return _parse_with_csv(path, text)
    lf = text.replace("\r\n", "\n").replace("\r", "\n")
    physical = lf.split("\n")
    spaced = _may_have_space(text)
    if spaced or "#" in lf or "\n\n" in lf or lf.startswith("\n"):
        kept = [i for i, line in enumerate(physical) if (stripped := line.strip()) and stripped[0] != "#"]
    else:  # no comment, no blank line: every line is a row, but for the empty one after a final line break
        kept = range(len(physical) - (physical[-1] == ""))
    if not kept:
        return CsvTable(path=path, header=(), header_line=None, columns=(), lines=[])
    if max(map(len, physical)) > csv.field_size_limit():
        return _parse_with_csv(path, text)
    header = tuple(f.strip() for f in physical[kept[0]].split(","))
    header_line = kept[0] + 1
    _check_header(path, header, header_line)
    data = physical[kept[0] + 1: kept[-1] + 1] if isinstance(kept, range) else [physical[i] for i in kept[1:]]
    k = len(header)
    commas = np.fromiter(map(str.count, data, repeat(",")), dtype=np.int64, count=len(data))
    wrong = np.flatnonzero(commas != k - 1)
    if len(wrong):
        i = int(wrong[0])
        raise InputError(path, kept[1 + i] + 1, f"row has {int(commas[i]) + 1} fields, the header has {k}")
    n_rows, joined = len(data), ",".join(data)
    del data, physical  # the lines' strings freed before the cells are made: the parse's peak, 20 MB at 5,000 photos
    cells = joined.split(",") if n_rows else []
    if spaced:  # some field may have surrounding white space
        columns = tuple(list(map(str.strip, cells[j::k])) for j in range(k))
    else:
        columns = tuple(cells[j::k] for j in range(k))
    lines = list(range(kept[0] + 2, kept[-1] + 2)) if isinstance(kept, range) else (
        (np.asarray(kept[1:], dtype=np.int64) + 1).tolist())
    return CsvTable(path=path, header=header, header_line=header_line, columns=columns, lines=lines)


_SPACE = re.compile(r"[^\S\r\n]")  # white space within a line
_ASCII_SPACE = (" ", "\t", "\v", "\f", "\x1c", "\x1d", "\x1e", "\x1f")  # what str.strip removes, in ASCII


def _may_have_space(text: str) -> bool:
    """Whether text holds a character str.strip removes, other than line breaks (substring tests for
    ASCII text, a regular expression otherwise)."""
    if text.isascii():
        return any(c in text for c in _ASCII_SPACE)
    return _SPACE.search(text) is not None


def _parse_with_csv(path: Path, text: str) -> CsvTable:
    """_parse by csv.reader (quoted fields, and the text csv.reader refuses, named in its error)."""
    consumed: list[int] = []
    reader = csv.reader(_data_lines(text, consumed), skipinitialspace=True)
    header: tuple[str, ...] = ()
    header_line: int | None = None
    rows: list[tuple[str, ...]] = []
    lines: list[int] = []
    while True:
        start = len(consumed)
        try:
            fields = next(reader)
        except StopIteration:
            break
        except csv.Error as exc:
            line = consumed[start] if start < len(consumed) else (consumed[-1] if consumed else None)
            raise InputError(path, line, f"malformed CSV: {exc}") from None
        line = consumed[start]
        fields = tuple(f.strip() for f in fields)
        if header_line is None:
            header, header_line = fields, line
            _check_header(path, header, line)
            continue
        if len(fields) != len(header):
            raise InputError(path, line, f"row has {len(fields)} fields, the header has {len(header)}")
        rows.append(fields)
        lines.append(line)
    columns = tuple(list(c) for c in zip(*rows)) if rows else tuple([] for _ in header)
    return CsvTable(path=path, header=header, header_line=header_line, columns=columns, lines=lines)


def _data_lines(text: str, consumed: list[int]) -> Iterator[str]:
    """Yield the physical lines that are not comments or blank, appending each one's number to consumed."""
    for number, line in enumerate(io.StringIO(text, newline=""), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        consumed.append(number)
        yield line


def _check_header(path: Path, header: tuple[str, ...], line: int) -> None:
    """Header names must be non-empty and distinct."""
    seen: set[str] = set()
    for name in header:
        if name == "":
            raise InputError(path, line, "the header has an empty column name")
        if name in seen:
            raise InputError(path, line, f"the header names column '{name}' twice")
        seen.add(name)


def format_csv(columns: Mapping[str, Sequence]) -> str:
    """CSV text of equal-length columns, header first.

    Floats are written with repr (shortest text that reads back to the same float), nan as an empty
    field; ints and strings as they are; None as an empty field. Lines end in ``\\n``. Fields are
    quoted as :func:`csv.writer` quotes them (a comma, a quote or a line break).

    Column by column, not cell by cell: a float column is formatted in one call (``orjson``'s
    shortest round-trip formatting where it gives exactly Python's repr, :func:`_float_cells`), an
    int column by ``str`` over ``tolist()``, a string column is checked for characters that need
    quoting in one search; only unusual cells (non-finite numbers, values Python writes with an
    exponent, strings to quote, mixed object columns) take the per-cell path. FORMAT_ROWS rows at a
    time: the cells of one slice are joined into its text before the next slice is formatted.
    """
    names = list(columns)
    lengths = {len(columns[n]) for n in names}
    if len(lengths) > 1:
        raise ValueError(f"columns of unequal length: { {n: len(columns[n]) for n in names} }")
    n_rows = lengths.pop() if lengths else 0
    header = list(_string_cells(names))
    if len(names) == 1 and header[0] == "":
        header[0] = '""'  # csv.writer writes a row of one empty field as ""
    if n_rows == 0:
        return ",".join(header) + "\n"
    pieces = []
    for a in range(0, n_rows, FORMAT_ROWS):  # the cells of a slice of rows at a time (format_csv's doc)
        cells = [_column_cells(columns[n][a: a + FORMAT_ROWS]) for n in names]
        if len(names) == 1:
            cells[0] = ['""' if c == "" else c for c in cells[0]]
        pieces.append("\n".join(map(",".join, zip(*cells))))
        del cells
    return ",".join(header) + "\n" + "\n".join(pieces) + "\n"


# rows formatted at once by format_csv: a cell is a Python string of about 60 bytes, so the cells of
# a whole table of 600,000 residuals and 12 columns took 500 MB beside the text (and, freed, left
# the allocator's pages resident); a slice of rows at a time holds 50 MB at most
FORMAT_ROWS = 65536


# characters after which a field is handed to csv.writer itself to be quoted exactly as it quotes
# (a superset: Python 3.11 quotes , " and \n; later versions also \r)
_QUOTE_CANDIDATE = re.compile('[,"\r\n]')
_FLOAT_TYPES = (float, np.float64)


def _column_cells(values) -> list[str]:
    """The field texts of one column (format_csv's rules), quoted where csv.writer would quote."""
    if isinstance(values, np.ndarray) and values.ndim == 1:
        kind = values.dtype.kind
        if kind == "f":
            return _float_cells(values)
        if kind in "iu":
            return list(map(str, values.tolist()))
        if kind == "b":
            return np.where(values, "true", "false").tolist()
        if kind == "U":
            return _string_cells(values.tolist())
        values = values.tolist() if kind == "O" else list(values)
    else:
        values = list(values)
    types = set(map(type, values))
    if types <= {str}:
        return _string_cells(values)
    if types <= set(_FLOAT_TYPES):
        return _float_cells(np.array(values, dtype=np.float64))
    if types <= {int}:
        return list(map(str, values))
    return _string_cells([_format_value(v) for v in values])


def _string_cells(values: list[str]) -> list[str]:
    """Strings as fields: as they are, but those with a quoting candidate written by csv.writer."""
    if not _QUOTE_CANDIDATE.search("".join(values)):
        return values
    return [_csv_field(v) if _QUOTE_CANDIDATE.search(v) else v for v in values]


def _csv_field(text: str) -> str:
    """One non-empty field exactly as csv.writer (QUOTE_MINIMAL) writes it."""
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow([text, ""])
    return buffer.getvalue()[:-2]  # without the empty second field's comma and the line end


def _float_cells(values: np.ndarray) -> list[str]:
    """repr of each value ('' for nan), the same text as ``repr(float(v))``, for a whole column.

    With orjson (optional): one call formats the column with the shortest digits that read back to
    the same double (Ryu), which are the digits of Python's repr (David Gay's shortest mode; both
    pick the shortest string, and of those the closest to the double). orjson's text is taken where
    it is Python's too: a finite value Python writes without exponent (0 or 1e-4 <= |x| < 1e16), and
    a token without an exponent and with a decimal point. Every other value (nan, inf, tiny and huge
    numbers) goes through repr. The equality is checked once on difficult values before orjson is
    trusted (:func:`_orjson_agrees`) and by tests/test_io.py on random bit patterns.
    """
    x = np.ascontiguousarray(values, dtype=np.float64)
    n = len(x)
    if n >= _ORJSON_MIN and _orjson_usable():
        dumped = _orjson.dumps(x, option=_orjson.OPT_SERIALIZE_NUMPY)
        cells = dumped[1:-1].decode("ascii").split(",")
        take = _orjson_tokens_taken(x, np.frombuffer(dumped, dtype=np.uint8))
        redo = np.flatnonzero(~take)
    else:
        cells = list(map(float.__repr__, x.tolist()))
        redo = np.flatnonzero(~np.isfinite(x))
    xs = x[redo].tolist()
    for i, value in zip(redo.tolist(), xs):
        cells[i] = "" if value != value else repr(value)
    return cells


_ORJSON_MIN = 64  # shorter columns: repr is as quick as the call
_orjson = None
_orjson_state: bool | None = None  # None: not tried yet


def _orjson_usable() -> bool:
    """Whether orjson is installed and its shortest formatting is Python's repr on difficult values."""
    global _orjson, _orjson_state
    if _orjson_state is None:
        try:
            import orjson
        except ImportError:
            _orjson_state = False
        else:
            _orjson = orjson
            _orjson_state = _orjson_agrees()
    return _orjson_state


def _orjson_agrees() -> bool:
    """orjson's tokens taken by _orjson_tokens_taken equal repr on values near every switch of the
    format (powers of ten, 1e-4, 1e16, integers beyond 2**53, subnormals, 0.1-like decimals)."""
    pow10 = 10.0 ** np.arange(-8, 20)
    x = np.concatenate([pow10, np.nextafter(pow10, 0), np.nextafter(pow10, np.inf), 1 / 3 * pow10,
                        [0.0, -0.0, 0.1, 0.2, 0.3, 2.5, 100.0, 123.456, 9007199254740993.0, 9999999999999998.0,
                         5e-324, 2.2250738585072014e-308, 1.7976931348623157e308, -1.5, 1e-4 + 1e-20]])
    x = np.concatenate([x, -x])
    dumped = _orjson.dumps(x, option=_orjson.OPT_SERIALIZE_NUMPY)
    tokens = dumped[1:-1].decode("ascii").split(",")
    take = _orjson_tokens_taken(x, np.frombuffer(dumped, dtype=np.uint8))
    return len(tokens) == len(x) and all(t == repr(v) for t, v, k in zip(tokens, x.tolist(), take) if k)


def _orjson_tokens_taken(x: np.ndarray, dumped: np.ndarray) -> np.ndarray:
    """(n,) bool: orjson's token for x[i] is Python's repr (see _float_cells). dumped: the bytes of
    orjson.dumps(x) ('[t0,t1,...]') as uint8."""
    n = len(x)
    body = dumped[1:-1]
    commas = np.flatnonzero(body == ord(","))  # token i ends before commas[i]
    has_exponent = np.zeros(n, dtype=bool)
    has_exponent[np.searchsorted(commas, np.flatnonzero((body == ord("e")) | (body == ord("E"))))] = True
    has_point = np.zeros(n, dtype=bool)
    has_point[np.searchsorted(commas, np.flatnonzero(body == ord(".")))] = True
    a = np.abs(x)
    with np.errstate(invalid="ignore"):
        positional = (a == 0) | ((a >= 1e-4) & (a < 1e16))
    return positional & has_point & ~has_exponent


def _format_value(value) -> str:
    """One cell: float -> repr ('' for nan), bool -> 'true'/'false', int/str as is, None -> ''."""
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return "" if math.isnan(value) else repr(value)
    return str(value)


def write_csv(path: str | Path, columns: Mapping[str, Sequence]) -> None:
    """Write format_csv(columns) to path (UTF-8). For whole output folders use write_output_folder."""
    Path(path).write_bytes(format_csv(columns).encode("utf-8"))
