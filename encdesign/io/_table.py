"""The CSV reader of recordings and imported tables: streamed, typed, with true line numbers.

:func:`read_columns` reads a CSV (optionally gzip-compressed) block by block into typed
NumPy columns, so its memory is the size of the result plus one block, whatever the
row count. It reads, or refuses in one line naming the file, the line and the column:

* a UTF-8 byte-order mark (read), CRLF line ends (read), blank lines (skipped; the line
  numbers in messages stay those of the file), trailing commas on every line (read);
* gzip data in a ``.csv`` file (read); a ``.gz`` file that is not gzip, corrupt or
  truncated gzip data (refused); binary data (a NUL byte) and text that is not UTF-8
  (refused with its line);
* an empty or repeated column name, a row with too few or too many fields, a cell that is
  not a number, an integer column (``run``, ``mark``) with a fraction or beyond int64
  (refused; integers are parsed exactly, not through float64).

The column name → file line of every row is kept in a :class:`TableRef` (a ``str``, the
file name), so whole-table checks run after reading (time order, interleaved runs) can
name the right line with :func:`row_line`.
"""

from __future__ import annotations

import csv
import gzip
import os
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from .._errors import input_error

__all__ = ["TableRef", "read_columns", "row_at", "row_line"]

_BLOCK_BYTES = 1 << 22  # 4 MiB of text per block
_GZIP_MAGIC = b"\x1f\x8b"
_EXACT_INT = 2**53  # floats at or beyond this do not hold every integer exactly
_INT64_MAX = 2**63 - 1
_INT64_MIN = -(2**63)


class TableRef(str):
    """A table's file name (``str``) that also maps row index -> line in the file.

    Rows are numbered from 0 (the first data row); the header is line 1 of a file without
    blank lines, so row ``i`` is line ``i + 2`` unless blank lines came before it.
    """

    _starts: np.ndarray
    _offsets: np.ndarray

    def __new__(cls, name: str, starts: Sequence[int] = (0,), offsets: Sequence[int] = (2,)):
        obj = super().__new__(cls, name)
        obj._starts = np.asarray(starts, dtype=np.int64)
        obj._offsets = np.asarray(offsets, dtype=np.int64)
        return obj

    def line(self, row: int) -> int:
        """The file line (1-based) of data row ``row`` (0-based)."""
        k = int(np.searchsorted(self._starts, row, side="right")) - 1
        return int(row) + int(self._offsets[max(k, 0)])

    def at(self, row: int) -> str:
        """Where data row ``row`` is, for messages: ``"line N"``."""
        return f"line {self.line(row)}"


def row_line(where: str, row: int) -> int:
    """Line of data row ``row`` in the table named ``where`` (``row + 2`` without a map)."""
    if isinstance(where, TableRef):
        return where.line(row)
    return int(row) + 2


def row_at(where: str, row: int) -> str:
    """Where data row ``row`` is in the table named ``where``, for messages: ``"line N"``
    of a CSV, ``"row group G, row R"`` of a Parquet file (``line row+2`` without a map)."""
    if isinstance(where, TableRef):
        return where.at(row)
    return f"line {int(row) + 2}"


def _open_binary(path: Path, where: str):
    with open(path, "rb") as fh:
        head = fh.read(2)
    is_gz = head == _GZIP_MAGIC
    if path.suffix.lower() == ".gz" and not is_gz:
        raise input_error(where, "named .gz but not gzip-compressed", "gzip data, or drop the .gz")
    return gzip.open(path, "rb") if is_gz else open(path, "rb")  # noqa: SIM115


def _decode(data: bytes, where: str, line0: int, first: bool) -> list[str]:
    nul = data.find(b"\x00")
    if nul >= 0:
        ln = line0 + data.count(b"\n", 0, nul)
        raise input_error(f"{where}, line {ln}", "binary data (a NUL byte)", "a UTF-8 text table")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        ln = line0 + data.count(b"\n", 0, exc.start)
        bad = data[exc.start : exc.start + 1]
        raise input_error(
            f"{where}, line {ln}", f"not UTF-8 text (byte {bad!r})", "a UTF-8 text table"
        ) from None
    if first and text.startswith("\ufeff"):
        text = text[1:]
    if "\r" in text:
        text = text.replace("\r\n", "\n")
        if text.endswith("\r"):
            text = text[:-1]
        if "\r" in text:
            ln = line0 + text.count("\n", 0, text.index("\r"))
            raise input_error(
                f"{where}, line {ln}",
                "a carriage return inside a line (old Mac line ends?)",
                "lines ending in LF or CRLF",
            )
    if text.endswith("\n"):
        text = text[:-1]
    return text.split("\n")


def _text_blocks(path: Path, where: str) -> Iterator[tuple[int, list[str]]]:
    """Yield ``(line number of the first line, lines)`` blocks of the decoded file."""
    try:
        with _open_binary(path, where) as fh:
            carry = b""
            line0 = 1
            first = True
            while True:
                buf = fh.read(_BLOCK_BYTES)
                if not buf:
                    break
                buf = carry + buf
                cut = buf.rfind(b"\n")
                if cut < 0:
                    carry = buf
                    continue
                carry = buf[cut + 1 :]
                lines = _decode(buf[: cut + 1], where, line0, first)
                first = False
                yield line0, lines
                line0 += len(lines)
            if carry:
                yield line0, _decode(carry, where, line0, first)
    except (OSError, EOFError, zlib.error) as exc:
        text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        if isinstance(exc, EOFError | zlib.error | gzip.BadGzipFile):
            problem = f"corrupt or truncated gzip data ({text})"
        else:
            problem = f"cannot read ({text})"
        raise input_error(where, problem, "a UTF-8 CSV table, optionally gzip-compressed") from None


def _split(line: str, where: str, ln: int) -> list[str]:
    try:
        fields = next(csv.reader([line], strict=True))
    except csv.Error as exc:
        raise input_error(
            f"{where}, line {ln}", f"bad CSV ({exc})", "comma-separated fields"
        ) from None
    return fields


def _parse_int(where: str, name: str, ln: int, v: str) -> int:
    s = v.strip()
    try:
        x = int(s)
    except ValueError:
        try:
            f = float(s)
        except ValueError:
            raise input_error(
                f"{where}, line {ln}, column '{name}'", f"got {v!r}", "an integer"
            ) from None
        if not np.isfinite(f) or f != round(f) or abs(f) >= _EXACT_INT:
            raise input_error(
                f"{where}, line {ln}, column '{name}'",
                f"got {v!r}",
                "an integer",
            ) from None
        x = int(f)
    if not _INT64_MIN <= x <= _INT64_MAX:
        raise input_error(
            f"{where}, line {ln}, column '{name}'",
            f"integer {s} is beyond the 64-bit range",
            "an integer between -2^63 and 2^63-1",
        )
    return x


def _column(
    where: str, name: str, values: Sequence[str], lines: Sequence[int], kind: str
) -> np.ndarray:
    """Convert one column's strings of a block; ``kind`` is ``"f"``, ``"i"`` or ``"U"``."""
    if kind == "U":
        return np.asarray([v.strip() for v in values], dtype=str)
    for v, ln in zip(values, lines):  # Python reads "1_0" as 10: a number has no '_'
        if "_" in v:
            raise input_error(
                f"{where}, line {ln}, column '{name}'", f"non-numeric value {v!r}", "a number"
            )
    if kind == "i":
        try:
            return np.asarray(values, dtype=np.int64)
        except (ValueError, OverflowError):
            return np.asarray(
                [_parse_int(where, name, ln, v) for v, ln in zip(values, lines)], dtype=np.int64
            )
    try:
        return np.asarray(values, dtype=np.float64)
    except ValueError:
        for v, ln in zip(values, lines):
            try:
                float(v)
            except ValueError:
                shown = f"non-numeric value {v!r}" if v.strip() else "an empty cell"
                raise input_error(
                    f"{where}, line {ln}, column '{name}'", shown, "a number"
                ) from None
        raise


def read_columns(
    path: str | os.PathLike,
    *,
    string_columns: Sequence[str] = (),
    int_columns: Sequence[str] = ("run",),
    where: str | None = None,
) -> tuple[list[str], dict[str, np.ndarray], TableRef]:
    """Read a CSV table into typed columns, block by block.

    Args:
        path: the ``.csv`` or ``.csv.gz`` file.
        string_columns: columns kept as ``str``.
        int_columns: columns parsed as exact int64.
        where: name used in messages (default: the path).

    Returns:
        ``(header, columns, ref)``: the column names in file order, name -> 1-D array
        (float64, int64 or str) and the :class:`TableRef` mapping rows to file lines.

    Raises:
        EncdesignInputError: the file is missing, unreadable or malformed; the message
            names the file, line and column.
    """
    path = Path(path)
    where = str(path) if where is None else where
    if not path.exists():
        raise input_error(where, "data file not found")
    if path.is_dir():
        raise input_error(where, "is a folder", "a CSV file")
    header: list[str] | None = None
    n_trailing = 0
    kinds: list[str] = []
    chunks: dict[str, list[np.ndarray]] = {}
    starts: list[int] = []
    offsets: list[int] = []
    n_rows = 0
    for line0, lines in _text_blocks(path, where):
        keep = [k for k, s in enumerate(lines) if s.strip()]
        if header is None:
            if not keep:
                continue
            k0 = keep.pop(0)
            raw = _split(lines[k0], where, line0 + k0)
            names = [h.strip() for h in raw]
            while names and names[-1] == "" and len(names) > 1:
                names.pop()
                n_trailing += 1
            for j, h in enumerate(names):
                if h == "":
                    raise input_error(
                        f"{where}, line {line0 + k0}",
                        f"column {j + 1} of the header has an empty name",
                        "a name for every column",
                    )
            dup = sorted({h for h in names if names.count(h) > 1})
            if dup:
                raise input_error(
                    f"{where}, line {line0 + k0}",
                    f"repeated column name(s) {', '.join(repr(d) for d in dup)}",
                    "distinct column names",
                )
            header = names
            kinds = [
                "U" if h in string_columns else "i" if h in int_columns else "f" for h in header
            ]
            chunks = {h: [] for h in header}
        if not keep:
            continue
        file_lines = [line0 + k for k in keep]
        # row -> line map: record where (line - row) changes
        off = np.asarray(file_lines, dtype=np.int64) - (n_rows + np.arange(len(keep)))
        change = np.flatnonzero(np.diff(off)) + 1
        for c in [0, *change.tolist()]:
            if not offsets or offsets[-1] != int(off[c]):
                starts.append(n_rows + c)
                offsets.append(int(off[c]))
        data = [lines[k] for k in keep]
        _parse_block(where, header, kinds, n_trailing, data, file_lines, chunks)
        n_rows += len(keep)
    if header is None:
        raise input_error(where, "empty file", "a header row")
    cols: dict[str, np.ndarray] = {}
    for h, kind in zip(header, kinds):
        parts = chunks.pop(h)
        if parts:
            cols[h] = parts[0] if len(parts) == 1 else np.concatenate(parts)
        else:
            cols[h] = np.zeros(0, dtype={"U": str, "i": np.int64, "f": np.float64}[kind])
        del parts
    ref = TableRef(where, starts or [0], offsets or [2])
    return header, cols, ref


def _parse_block(
    where: str,
    header: list[str],
    kinds: list[str],
    n_trailing: int,
    data: list[str],
    lines: list[int],
    chunks: dict[str, list[np.ndarray]],
) -> None:
    n = len(header)
    if n_trailing == 0 and "U" not in kinds:
        try:
            a = np.loadtxt(
                data, delimiter=",", dtype=np.float64, ndmin=2, quotechar='"', comments=None
            )
        except ValueError:
            a = None
        if a is not None and a.shape == (len(data), n):
            ok = True
            ints = {}
            for j, kind in enumerate(kinds):
                if kind == "i":
                    col = a[:, j]
                    fin = np.isfinite(col)
                    if (
                        np.any(np.abs(col[fin]) >= _EXACT_INT)
                        or np.any(col[fin] != np.round(col[fin]))
                        or not np.all(fin)
                    ):
                        ok = False
                        break
                    ints[j] = col.astype(np.int64)
            if ok:
                for j, h in enumerate(header):
                    chunks[h].append(ints[j] if j in ints else np.ascontiguousarray(a[:, j]))
                return
    # slow path: exact per-cell parsing with the line and column of any error
    rows = []
    for s, ln in zip(data, lines):
        f = _split(s, where, ln)
        if len(f) != n:
            extra = f[n:]
            if not (n < len(f) <= n + n_trailing and all(not x.strip() for x in extra)):
                raise input_error(
                    f"{where}, line {ln}",
                    f"{len(f)} fields",
                    f"{n} fields as in the header",
                )
            f = f[:n]
        rows.append(f)
    cols = list(zip(*rows))
    for j, (h, kind) in enumerate(zip(header, kinds)):
        chunks[h].append(_column(where, h, cols[j], lines, kind))
