"""Parquet data tables of recordings: read row group by row group, typed, checked.

A recording's ``data`` may name a Parquet file (``.parquet``, or any file that starts
with Parquet's ``PAR1`` magic) instead of a CSV. :func:`read_parquet_columns` reads it
one row group at a time into the same typed NumPy columns as the CSV reader, so its
memory is the result plus one row group. It refuses, in one line naming the file, the
row group and the column:

* a file that is not Parquet, or is truncated (no footer), or whose row group cannot be
  decoded (corrupt pages);
* an empty or repeated column name, a nested column (list, struct, map);
* a column of the wrong type: a number column (``t``, heads, …) that is not an integer
  or floating type, a string column (``sds`` ``sensor``) that is not a string type;
* a null cell; an integer column (``run``, ``mark``) holding a fraction, a non-finite
  value or an unsigned value beyond int64.

Rows are located by :class:`ParquetRef` (a ``str``, the file name): row ``i`` of the
table is ``row group g, row r`` (both counted from 0, as ``pyarrow`` numbers them), so
the whole-table checks after reading (non-finite values, time order) name it exactly.

:func:`write_parquet_table` writes typed columns (float64, int64, string) in row groups
of :data:`ROW_GROUP_ROWS` rows to an open binary file.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from .._errors import input_error
from ._table import TableRef

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = [
    "PARQUET_SUFFIXES",
    "ParquetRef",
    "is_parquet",
    "read_parquet_columns",
    "write_parquet_table",
]

PARQUET_MAGIC = b"PAR1"
PARQUET_SUFFIXES = (".parquet", ".pq")
ROW_GROUP_ROWS = 1 << 20
"""Rows per row group written (about 8 MiB per float64 column)."""
_EXACT_INT = 2**53


class ParquetRef(TableRef):
    """A Parquet table's file name (``str``) that maps row index -> (row group, row)."""

    _group_starts: np.ndarray

    def __new__(cls, name: str, group_starts: Sequence[int] = (0,)):
        obj = super().__new__(cls, name)
        obj._group_starts = np.asarray(group_starts, dtype=np.int64)
        return obj

    def group_row(self, row: int) -> tuple[int, int]:
        """``(row group, row within the group)`` of table row ``row`` (all from 0)."""
        g = max(int(np.searchsorted(self._group_starts, row, side="right")) - 1, 0)
        return g, int(row) - int(self._group_starts[g])

    def line(self, row: int) -> int:
        """Table row ``row`` counted from 1 (a Parquet file has no text lines)."""
        return int(row) + 1

    def at(self, row: int) -> str:
        g, r = self.group_row(row)
        return f"row group {g}, row {r}"


def is_parquet(path: str | os.PathLike) -> bool:
    """A ``.parquet``/``.pq`` name, or a file that starts with the Parquet magic bytes."""
    path = Path(path)
    if path.suffix.lower() in PARQUET_SUFFIXES:
        return True
    try:
        with open(path, "rb") as fh:
            return fh.read(4) == PARQUET_MAGIC
    except OSError:
        return False


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _check_type(where: str, name: str, typ: Any, kind: str) -> None:
    import pyarrow as pa

    t = pa.types
    if kind == "U":
        ok = t.is_string(typ) or t.is_large_string(typ) or t.is_dictionary(typ)
        expected = "a string column"
    else:
        ok = t.is_integer(typ) or t.is_floating(typ)
        expected = "a number column (floating or integer type)"
    if not ok:
        raise input_error(f"{where}, column '{name}'", f"Parquet type {typ}", expected)


def _to_numpy(where: str, g: int, name: str, col: Any, kind: str) -> np.ndarray:
    """One column of one row group -> a typed array (float64, int64 or str)."""
    import pyarrow as pa

    if col.null_count:
        i = int(np.flatnonzero(np.asarray(col.is_null()))[0])
        raise input_error(
            f"{where}, row group {g}, row {i}, column '{name}'",
            "an empty (null) cell",
            "a string" if kind == "U" else "a number",
        )
    if kind == "U":
        if pa.types.is_dictionary(col.type):
            col = col.cast(pa.string())
        return np.asarray(col.to_numpy(zero_copy_only=False), dtype=str)
    a = col.to_numpy()
    if kind == "f":
        return np.asarray(a, dtype=np.float64)
    if a.dtype.kind in "iu":
        if a.dtype.kind == "u" and a.size and int(a.max()) > 2**63 - 1:
            i = int(np.argmax(a))
            raise input_error(
                f"{where}, row group {g}, row {i}, column '{name}'",
                f"got {int(a[i])}",
                "an integer < 2^63",
            )
        return a.astype(np.int64)
    f = np.asarray(a, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = np.flatnonzero(~np.isfinite(f) | (f != np.round(f)) | (np.abs(f) >= _EXACT_INT))
    if bad.size:
        i = int(bad[0])
        raise input_error(
            f"{where}, row group {g}, row {i}, column '{name}'",
            f"got {f[i].item()!r}",
            "an integer below 2^53",
        )
    return f.astype(np.int64)


def read_parquet_columns(
    path: str | os.PathLike,
    *,
    string_columns: Sequence[str] = (),
    int_columns: Sequence[str] = ("run",),
    where: str | None = None,
) -> tuple[list[str], dict[str, np.ndarray], ParquetRef]:
    """Read a Parquet table into typed columns, one row group at a time.

    Args:
        path: the Parquet file.
        string_columns: columns kept as ``str``.
        int_columns: columns converted to exact int64.
        where: name used in messages (default: the path).

    Returns:
        ``(header, columns, ref)`` as :func:`~encdesign.io._table.read_columns`, with a
        :class:`ParquetRef` that maps rows to row groups.

    Raises:
        EncdesignInputError: the file is missing, not Parquet, truncated or corrupt, or a
            column has the wrong type or a bad cell; the message names the file, the row
            group and the column.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    where = str(path) if where is None else where
    if not path.exists():
        raise input_error(where, "data file not found")
    if path.is_dir():
        raise input_error(where, "is a folder", "a Parquet file")
    try:
        pf = pq.ParquetFile(path)
        schema = pf.schema_arrow
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise input_error(
            where,
            f"not a readable Parquet file, truncated or corrupt ({_one_line(exc)})",
            "a whole Parquet file (or a CSV table)",
        ) from None
    names = list(schema.names)
    for j, h in enumerate(names):
        if not h.strip():
            raise input_error(where, f"column {j + 1} has an empty name", "a name for every column")
    dup = sorted({h for h in names if names.count(h) > 1})
    if dup:
        raise input_error(
            where, f"repeated column name(s) {', '.join(repr(d) for d in dup)}", "distinct names"
        )
    kinds = ["U" if h in string_columns else "i" if h in int_columns else "f" for h in names]
    for h, kind in zip(names, kinds):
        _check_type(where, h, schema.field(h).type, kind)
    chunks: dict[str, list[np.ndarray]] = {h: [] for h in names}
    starts: list[int] = []
    n_rows = 0
    for g in range(pf.num_row_groups):
        try:
            tab = pf.read_row_group(g)
        except (pa.ArrowException, OSError, ValueError) as exc:
            raise input_error(
                f"{where}, row group {g}",
                f"cannot be decoded, truncated or corrupt ({_one_line(exc)})",
                "a whole Parquet file",
            ) from None
        starts.append(n_rows)
        for h, kind in zip(names, kinds):
            col = tab.column(h)
            col = col.combine_chunks() if col.num_chunks != 1 else col.chunk(0)
            chunks[h].append(_to_numpy(where, g, h, col, kind))
        n_rows += tab.num_rows
        del tab
    cols: dict[str, np.ndarray] = {}
    for h, kind in zip(names, kinds):
        parts = chunks.pop(h)
        if len(parts) == 1:
            cols[h] = parts[0]
        elif parts:
            cols[h] = np.concatenate(parts)
        else:
            cols[h] = np.zeros(0, dtype={"U": str, "i": np.int64, "f": np.float64}[kind])
        del parts
    return names, cols, ParquetRef(where, starts or [0])


def write_options(schema: pa.Schema) -> dict[str, dict[str, str] | list[str]]:
    """``pyarrow.parquet.ParquetWriter`` options for a table of ``schema`` (a
    ``pyarrow.Schema``): float64 columns plain and uncompressed, the others dictionary-encoded
    where it pays and ``snappy``-compressed (Parquet's defaults).

    Measured on the benchmark's record (issue 43; 2^20 rows a row group): a float64 reading
    does not compress (``snappy``: 8.66 MB a column, as much as the raw values; ``t`` 7.0
    MB), but decoding it took twice the CPU (a row group of 7 columns 33 ms against 15 ms),
    and with two processes decoding at once four times (66-84 ms against 16-27 ms)."""
    import pyarrow as pa

    names = list(schema.names)
    floats = {c for c in names if pa.types.is_floating(schema.field(c).type)}
    return dict(
        compression={c: "none" if c in floats else "snappy" for c in names},
        use_dictionary=[c for c in names if c not in floats],
    )


def write_parquet_table(
    fh: IO[bytes], columns: dict[str, np.ndarray], *, row_group_rows: int | None = None
) -> None:
    """Write typed columns to the open binary file ``fh`` as Parquet, in row groups.

    float columns are written as float64, integer ones as int64, str ones as string
    (:func:`write_options`: the float columns plain and uncompressed); ``row_group_rows``
    rows per row group (default :data:`ROW_GROUP_ROWS`).
    """
    row_group_rows = ROW_GROUP_ROWS if row_group_rows is None else int(row_group_rows)
    import pyarrow as pa
    import pyarrow.parquet as pq

    def arrow_type(a: np.ndarray):
        if a.dtype.kind == "U":
            return pa.string()
        if a.dtype.kind in "iu":
            return pa.int64()
        return pa.float64()

    names = list(columns)
    schema = pa.schema([(c, arrow_type(columns[c])) for c in names])
    n = len(columns[names[0]]) if names else 0
    with pq.ParquetWriter(fh, schema, **write_options(schema)) as w:
        for a in range(0, max(n, 1), row_group_rows):
            b = min(n, a + row_group_rows)
            arrays = [pa.array(columns[c][a:b], type=schema.field(c).type) for c in names]
            w.write_table(pa.Table.from_arrays(arrays, schema=schema))
