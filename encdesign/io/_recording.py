"""Recordings in the ``encdesign-recording/1`` format (see ``docs/recording-format.md``).

A recording is a TOML file (metadata and nominal design) plus the table it names: a CSV
(optionally ``.csv.gz``) or a Parquet file (``.parquet``, read in row groups).
:func:`load_recording` validates the whole file before returning anything: a bad file
raises :class:`~encdesign.EncdesignInputError` naming the file, the row (line, or row
group and row) or column and what was expected. :func:`write_recording` validates first
and writes atomically (temporary files renamed into place), so nothing is ever
half-written.

Kinds: ``multihead``, ``sds``, ``quadrature``, ``motion``. Each kind has a
:class:`KindSpec` in :data:`KINDS` stating its table keys, columns and extra checks.

A ``multihead`` recording with one head and a ``theta_ref`` column is one sensor read
against a reference (an optical head, a magnetic angle sensor, a resolver or a capacitive
encoder: ``[encoder] sensor``, with ``signal_periods_per_rev`` signal periods per turn).
``optical_radius_m`` is optional: it is needed only to report lengths.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import re
import tomllib
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from .._errors import EncdesignInputError, input_error
from ._parquet import PARQUET_SUFFIXES, is_parquet, read_parquet_columns, write_parquet_table
from ._paths import atomic_output
from ._sds_format import check_sds_columns
from ._table import read_columns, row_at

FORMAT = "encdesign-recording/1"
MAX_TOML_BYTES = 16 * 2**20  # a recording, design or problem TOML is metadata only
TOP_LEVEL_KEYS = {"format", "kind", "data", "description", "encoder", "motor", "provenance"}


@dataclasses.dataclass(frozen=True)
class Recording:
    """A validated recording.

    Attributes:
        kind: ``"multihead"``, ``"sds"``, ``"quadrature"`` or ``"motion"``.
        meta: the TOML content as a dict (``encoder``, ``motor``, ``description``, …), SI.
        columns: column name -> 1-D numpy array, all of one length. Numeric columns are
            float64 (``run`` and ``mark`` are int64); the ``sds`` ``sensor`` column is str.
        path: the TOML file it came from (``None`` when built in memory).
        table: the data table's file name, mapping rows to file lines
            (:class:`~encdesign.io._table.TableRef`; ``None`` when built in memory).
    """

    kind: str
    meta: dict[str, Any]
    columns: dict[str, np.ndarray]
    path: Path | None = None
    table: str | None = None

    @property
    def encoder(self) -> dict[str, Any]:
        """The ``[encoder]`` table (empty dict when absent)."""
        return dict(self.meta.get("encoder", {}))

    @property
    def n_rows(self) -> int:
        """Number of rows of the data table."""
        return len(next(iter(self.columns.values()))) if self.columns else 0

    @property
    def runs(self) -> np.ndarray:
        """Run id per row (int64; zeros when the table has no ``run`` column)."""
        if "run" in self.columns:
            return self.columns["run"]
        return np.zeros(self.n_rows, dtype=np.int64)

    @property
    def head_columns(self) -> list[str]:
        """``h0 … h{H-1}`` for a multihead recording."""
        n = len(self.encoder.get("head_angles_deg", []))
        return [f"h{k}" for k in range(n)]

    def heads(self) -> np.ndarray:
        """Multihead readings as an array ``(n_rows, H)`` in rad."""
        return np.stack([self.columns[c] for c in self.head_columns], axis=1)

    @property
    def sensor(self) -> str:
        """``[encoder] sensor`` of a multihead recording (``"optical"`` when absent)."""
        return str(self.encoder.get("sensor", "optical"))

    @property
    def signal_periods_per_rev(self) -> int | None:
        """Signal periods per turn: ``signal_periods_per_rev``, else ``grating_lines``, else
        ``None`` (unknown)."""
        enc = self.encoder
        p = enc.get("signal_periods_per_rev", enc.get("grating_lines"))
        return None if p is None else int(p)

    @property
    def radius_m(self) -> float | None:
        """``[encoder] optical_radius_m`` in m, or ``None`` (results in angles only)."""
        r = self.encoder.get("optical_radius_m")
        return None if r is None else float(r)


@dataclasses.dataclass(frozen=True)
class KindSpec:
    """What one recording kind allows.

    Attributes:
        encoder_keys: allowed keys of ``[encoder]`` -> a checker ``(where, value) -> value``.
        required_encoder: keys of ``[encoder]`` that must be present.
        motor_keys: allowed keys of ``[motor]`` -> checker.
        required_columns: columns that must be present (given the meta).
        optional_columns: columns that may be present.
        string_columns: columns kept as str.
        int_columns: columns converted to int64.
        check: extra whole-recording checks ``(where, meta, columns) -> None``.
    """

    encoder_keys: Mapping[str, Callable[[str, object], object]]
    required_encoder: tuple[str, ...] = ()
    motor_keys: Mapping[str, Callable[[str, object], object]] = dataclasses.field(
        default_factory=dict
    )
    required_columns: Callable[[dict], list[str]] = lambda meta: []
    optional_columns: Callable[[dict], list[str]] = lambda meta: []
    string_columns: tuple[str, ...] = ()
    int_columns: tuple[str, ...] = ("run",)
    check: Callable[[str, dict, dict], None] | None = None


# ----------------------------------------------------------------------------- checkers


def show(v: object) -> str:
    """``repr`` of a value for messages, NumPy scalars as plain numbers (no ``np.float64(…)``)."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, np.ndarray):
        v = v.tolist()
    return repr(v)


def finite_number(where: str, v: object) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise input_error(where, f"got {show(v)}", "a finite number")
    return float(v)


def number_in(lower: float, upper: float, units: str = "", *, lower_open: bool = True):
    """A checker for a finite number in ``(lower, upper]`` (``[lower, upper]`` when not
    ``lower_open``); ``units`` only for the message."""
    u = f" {units}" if units else ""
    if lower == 0.0 and lower_open:
        rng = f"a positive number <= {upper:g}{u}"
    else:
        rng = f"{lower:g} {'<' if lower_open else '<='} value <= {upper:g}{u}"

    def check(where: str, v: object) -> float:
        x = finite_number(where, v)
        if x < lower or (lower_open and x == lower) or x > upper:
            raise input_error(where, f"got {show(v)}", rng)
        return x

    return check


def positive_number(where: str, v: object) -> float:
    x = finite_number(where, v)
    if x <= 0:
        raise input_error(where, f"got {v!r}", "a positive number")
    return x


def positive_int(where: str, v: object) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
        raise input_error(where, f"got {v!r}", "a positive integer")
    return int(v)


def _nonneg_int(where: str, v: object) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise input_error(where, f"got {v!r}", "a non-negative integer")
    return int(v)


def int_in(lower: int, upper: int):
    """A checker for an integer in ``[lower, upper]`` (bools refused)."""

    def check(where: str, v: object) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or not lower <= v <= upper:
            raise input_error(where, f"got {show(v)[:40]}", f"an integer {lower} … {upper}")
        return int(v)

    return check


def _angle_list(where: str, v: object) -> list[float]:
    if not isinstance(v, list) or len(v) == 0 or len(v) > 1000:
        raise input_error(where, f"got {show(v)[:80]}", "a list of 1 … 1000 angles in degrees")
    return [_ANGLE_DEG(f"{where}[{i}]", x) for i, x in enumerate(v)]


def _string(where: str, v: object) -> str:
    if not isinstance(v, str):
        raise input_error(where, f"got {v!r}", "a string")
    return v


SENSORS = ("optical", "magnetic", "resolver", "capacitive")
"""Values of ``[encoder] sensor`` (multihead kind)."""


def _sensor(where: str, v: object) -> str:
    if not isinstance(v, str) or v not in SENSORS:
        raise input_error(where, f"got {v!r}", f"one of {', '.join(repr(s) for s in SENSORS)}")
    return v


def _table(where: str, v: object) -> dict:
    if not isinstance(v, dict):
        raise input_error(where, f"got {v!r}", "a table")
    return v


_ANGLE_DEG = number_in(-360.0, 360.0, "deg", lower_open=False)
_RADIUS_M = number_in(0.0, 10.0, "m")

# Largest magnitude of a cell, by column: beyond it a value cannot be physical (a time of
# 1e12 s is 30,000 years; an unwrapped angle of 1e12 rad is 1.6e11 turns) and sums of
# squares of the rest stay finite. Columns of any unit (quadrature signals) get 1e100.
COLUMN_LIMITS: dict[str, tuple[float, str]] = {
    "t": (1e12, "s"),
    "theta": (1e12, "rad"),
    "theta_ref": (1e12, "rad"),
    "phi_ref": (1e12, "rad"),
    "counts": (1e18, "counts"),
    "current_a": (1e6, "A"),
    "temp_c": (1e4, "degC"),
}
_HEAD_LIMIT = (1e12, "rad")
_ANY_UNIT_LIMIT = (1e100, "")


def _column_limit(name: str) -> tuple[float, str]:
    if name in COLUMN_LIMITS:
        return COLUMN_LIMITS[name]
    if re.fullmatch(r"h\d+", name):
        return _HEAD_LIMIT
    return _ANY_UNIT_LIMIT


# ----------------------------------------------------------------------------- kinds


def _multihead_required(meta: dict) -> list[str]:
    n = len(meta.get("encoder", {}).get("head_angles_deg", []))
    return ["t"] + [f"h{k}" for k in range(n)]


def _multihead_meta_check(where: str, meta: dict) -> None:
    enc = meta["encoder"]
    n = len(enc["head_angles_deg"])
    ref = enc.get("reference_head")
    if ref is not None and ref >= n:
        raise input_error(
            f"{where}: [encoder].reference_head",
            f"got {ref}",
            f"an index < {n} (number of head_angles_deg)",
        )


def _multihead_check(where: str, meta: dict, cols: dict) -> None:
    enc = meta["encoder"]
    n = len(enc["head_angles_deg"])
    if n == 1 and "theta_ref" not in cols:
        raise input_error(
            where,
            "one head needs a theta_ref column (head_angles_deg lists 1 head)",
            "a theta_ref column (one sensor against a reference) or at least two heads",
        )
    extra = sorted(c for c in cols if re.fullmatch(r"h\d+", c) and int(c[1:]) >= n)
    if extra:
        raise input_error(
            where,
            f"head column(s) {', '.join(extra)} but head_angles_deg lists {n} heads",
            f"columns h0 … h{n - 1}, one per entry of head_angles_deg",
        )
    _check_time_increasing(where, cols, "t")


def _check_time_increasing(where: str, cols: dict, tcol: str) -> None:
    """Time strictly increasing within each run (vectorised: one stable sort by run)."""
    if tcol not in cols:
        return
    t = cols[tcol]
    if len(t) < 2:
        return
    run = cols.get("run")
    if run is None or bool(np.all(run[1:] >= run[:-1])):
        order = None
        same = np.ones(len(t) - 1, bool) if run is None else run[1:] == run[:-1]
        bad = np.flatnonzero(same & (np.diff(t) <= 0))
    else:
        order = np.argsort(run, kind="stable")
        rs = run[order]
        bad = np.flatnonzero((rs[1:] == rs[:-1]) & (np.diff(t[order]) <= 0))
    if bad.size:
        a, b = int(bad[0]), int(bad[0]) + 1
        if order is not None:
            a, b = int(order[a]), int(order[b])
        r = 0 if run is None else int(run[b])
        raise input_error(
            f"{where}, {row_at(where, b)}, column '{tcol}'",
            f"time goes backwards or repeats ({show(t[a])} at {row_at(where, a)}, "
            f"then {show(t[b])}) within run {r}",
            "strictly increasing time within each run",
        )


def check_runs_contiguous(rec: Recording) -> None:
    """Refuse a recording whose runs' rows are interleaved (run 0, then 1, then 0 again).

    Raises:
        EncdesignInputError: naming the table and the line where a run resumes.
    """
    run = rec.runs
    if run.size < 2:
        return
    change = np.flatnonzero(run[1:] != run[:-1]) + 1
    starts = run[np.concatenate([[0], change])]
    _, first = np.unique(starts, return_index=True)
    if first.size == starts.size:
        return
    seen: set[int] = set()
    for k, r in enumerate(starts.tolist()):
        if r in seen:
            i = int(np.concatenate([[0], change])[k])
            where = rec.table or str(rec.path or "<recording>")
            raise input_error(
                f"{where}, {row_at(where, i)}, column 'run'",
                f"rows of the runs are interleaved: run {r} resumes here after other runs",
                "each run's rows together, in time order",
            )
        seen.add(r)


def _sds_required(meta: dict) -> list[str]:
    return ["sensor", "mark", "t"]


def _sds_check(where: str, meta: dict, cols: dict) -> None:
    check_sds_columns(where, meta, cols)
    for extra in _EXTRA_CHECKS.get("sds", []):
        extra(where, meta, cols)


def _quadrature_check(where: str, meta: dict, cols: dict) -> None:
    _check_time_increasing(where, cols, "t")
    for extra in _EXTRA_CHECKS.get("quadrature", []):
        extra(where, meta, cols)


def _motion_required(meta: dict) -> list[str]:
    enc = meta.get("encoder", {})
    return ["t", "counts" if "counts_per_rev" in enc else "theta"]


def _motion_check(where: str, meta: dict, cols: dict) -> None:
    _check_time_increasing(where, cols, "t")
    for extra in _EXTRA_CHECKS.get("motion", []):
        extra(where, meta, cols)


_EXTRA_CHECKS: dict[str, list[Callable[[str, dict, dict], None]]] = {}


def register_check(kind: str, check: Callable[[str, dict, dict], None]) -> None:
    """Add an extra validation ``check(where, meta, columns)`` for ``kind`` (idempotent)."""
    lst = _EXTRA_CHECKS.setdefault(kind, [])
    if check not in lst:
        lst.append(check)


KINDS: dict[str, KindSpec] = {
    "multihead": KindSpec(
        encoder_keys={
            "optical_radius_m": _RADIUS_M,
            "head_angles_deg": _angle_list,
            "reference_head": int_in(0, 999),
            "grating_lines": int_in(1, 10**9),
            "sensor": _sensor,
            "signal_periods_per_rev": int_in(1, 10**9),
        },
        required_encoder=("head_angles_deg",),
        required_columns=_multihead_required,
        optional_columns=lambda meta: ["run", "theta_ref", "temp_c"],
        check=_multihead_check,
    ),
    "sds": KindSpec(
        encoder_keys={
            "marks_per_rev": int_in(1, 10**8),
            "fixed_sensor_angles_deg": _angle_list,
            "moving_sensor_angles_deg": _angle_list,
            "pole_pairs": int_in(1, 1000),
            "stator_coils": int_in(1, 10_000),
            "commutation_states": int_in(1, 1000),
            "clock_hz": number_in(0.0, 1e15, "Hz"),
            # extension of the spec: the read radius turns fitted angles into lengths
            "optical_radius_m": _RADIUS_M,
        },
        required_encoder=("marks_per_rev", "fixed_sensor_angles_deg", "moving_sensor_angles_deg"),
        required_columns=_sds_required,
        optional_columns=lambda meta: ["run", "phi_ref", "temp_c"],
        string_columns=("sensor",),
        int_columns=("run", "mark"),
        check=_sds_check,
    ),
    "quadrature": KindSpec(
        encoder_keys={"signal_period_m": number_in(0.0, 1.0, "m")},
        required_columns=lambda meta: ["sa", "sb"],
        optional_columns=lambda meta: ["t", "run"],
        check=_quadrature_check,
    ),
    "motion": KindSpec(
        encoder_keys={"counts_per_rev": int_in(1, 2**48)},
        motor_keys={
            "pole_pairs": int_in(1, 1000),
            "stator_slots": int_in(1, 10_000),
            "commutation_states": int_in(1, 1000),
        },
        required_columns=_motion_required,
        optional_columns=lambda meta: ["current_a", "run"],
        check=_motion_check,
    ),
}


# ----------------------------------------------------------------------------- meta


def validate_meta(meta: dict, where: str) -> dict:
    """Check the TOML part of a recording; return a normalised copy. Raises on any error."""
    if not isinstance(meta, dict):
        raise input_error(where, "not a TOML table")
    unknown = sorted(set(meta) - TOP_LEVEL_KEYS)
    if unknown:
        raise input_error(
            where, f"unknown key(s) {', '.join(unknown)}", f"only {sorted(TOP_LEVEL_KEYS)}"
        )
    fmt = meta.get("format")
    if fmt != FORMAT:
        raise input_error(f"{where}: format", f"got {fmt!r}", repr(FORMAT))
    kind = meta.get("kind")
    if not isinstance(kind, str) or kind not in KINDS:
        raise input_error(f"{where}: kind", f"got {kind!r}", f"one of {sorted(KINDS)}")
    spec = KINDS[kind]
    out = dict(meta)
    if "data" in meta:
        _string(f"{where}: data", meta["data"])
    if "description" in meta:
        _string(f"{where}: description", meta["description"])
    if "provenance" in meta:
        _table(f"{where}: [provenance]", meta["provenance"])
    for table, allowed, required in (
        ("encoder", spec.encoder_keys, spec.required_encoder),
        ("motor", spec.motor_keys, ()),
    ):
        if table not in meta:
            if required:
                raise input_error(where, f"missing table [{table}]", f"keys {list(required)}")
            continue
        tab = _table(f"{where}: [{table}]", meta[table])
        unknown = sorted(set(tab) - set(allowed))
        if unknown:
            raise input_error(
                f"{where}: [{table}]",
                f"unknown key(s) {', '.join(unknown)} for kind '{kind}'",
                f"only {sorted(allowed)}",
            )
        for key in required:
            if key not in tab:
                raise input_error(f"{where}: [{table}]", f"missing key '{key}'")
        out[table] = {k: allowed[k](f"{where}: [{table}].{k}", v) for k, v in tab.items()}
    if kind == "multihead":
        _multihead_meta_check(where, out)
    return out


# ----------------------------------------------------------------------------- table


def _names(cols: list[str]) -> str:
    """Column names for messages: plain, quoted when empty or padded (so they show)."""
    return ", ".join(c if c and c.strip() == c and "," not in c else repr(c) for c in cols)


def _bad_cell(where: str, name: str, i: int, problem: str, expected: str):
    return input_error(f"{where}, {row_at(where, i)}, column '{name}'", problem, expected)


def _convert(
    where: str, name: str, values: Iterable[object], kind: str, spec: KindSpec
) -> np.ndarray:
    """Column ``values`` (strings or numbers) -> a typed, checked array."""
    if name in spec.string_columns:
        arr = np.asarray(values)
        if arr.dtype.kind != "U":
            arr = np.asarray([str(v) for v in values], dtype=str)
        return np.char.strip(arr)
    if isinstance(values, np.ndarray) and values.dtype.kind in "fiu":
        return _convert_array(where, name, values, spec)
    vals = [str(v) for v in values]
    try:
        arr = np.asarray(vals, dtype=np.float64)
    except ValueError:
        for i, v in enumerate(vals):
            try:
                float(v)
            except ValueError:
                raise _bad_cell(where, name, i, f"non-numeric value {v!r}", "a number") from None
        raise
    return _convert_array(where, name, arr, spec)


def validate_columns(where: str, kind: str, meta: dict, columns: Mapping[str, Any]) -> dict:
    """Check a data table against its kind; return the converted columns. Raises on error."""
    spec = KINDS[kind]
    required = spec.required_columns(meta)
    allowed = set(required) | set(spec.optional_columns(meta))
    names = list(columns)
    missing = [c for c in required if c not in columns]
    if missing:
        raise input_error(
            where,
            f"missing column(s) {_names(missing)}",
            f"columns {required} at least (header has {names})",
        )
    unknown = [c for c in names if c not in allowed]
    if unknown:
        raise input_error(
            where,
            f"unknown column(s) {_names(unknown)} for kind '{kind}'",
            f"only {sorted(allowed)}",
        )
    lengths = {len(v) for v in columns.values()}
    if len(lengths) > 1:
        raise input_error(where, f"columns of unequal length {sorted(lengths)}")
    if lengths == {0}:
        raise input_error(where, "the data table has no rows", "at least one row")
    out: dict[str, np.ndarray] = {}
    for name in names:
        out[name] = _convert(where, name, columns[name], kind, spec)
    if spec.check is not None:
        spec.check(where, meta, out)
    return out


def _convert_array(where: str, name: str, vals: np.ndarray, spec: KindSpec) -> np.ndarray:
    if name in spec.int_columns:
        if vals.dtype.kind in "iu":
            if vals.dtype.kind == "u" and vals.size and int(vals.max()) > 2**63 - 1:
                i = int(np.argmax(vals))
                raise _bad_cell(where, name, i, f"got {show(vals[i])}", "an integer < 2^63")
            return np.asarray(vals, dtype=np.int64)
        arr = np.asarray(vals, dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(arr) | (arr != np.round(arr)) | (np.abs(arr) >= 2**53))
        if bad.size:
            i = int(bad[0])
            raise _bad_cell(where, name, i, f"got {show(arr[i])}", "an integer below 2^53")
        return arr.astype(np.int64)
    arr = np.asarray(vals, dtype=np.float64)
    limit, units = _column_limit(name)
    with np.errstate(invalid="ignore"):
        bad = np.flatnonzero(~(np.abs(arr) <= limit))
    if bad.size:
        i = int(bad[0])
        u = f" {units}" if units else ""
        if not np.isfinite(arr[i]):
            raise _bad_cell(where, name, i, f"non-finite value {show(arr[i])}", "a finite number")
        raise _bad_cell(where, name, i, f"got {show(arr[i])}", f"|value| <= {limit:g}{u}")
    return arr


def read_toml(path: str | os.PathLike) -> dict[str, Any]:
    """Read a TOML file (recording, design or problem) into a dict; never modifies it.

    Raises:
        EncdesignInputError: the file is missing, unreadable or not valid TOML.
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise input_error(where, "file not found")
    if path.is_dir():
        raise input_error(where, "is a folder", "a TOML file")
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_TOML_BYTES + 1)
    except OSError as exc:
        raise input_error(where, f"cannot read ({exc.strerror or exc})") from None
    if len(data) > MAX_TOML_BYTES:
        raise input_error(where, f"larger than {MAX_TOML_BYTES} bytes", "a small TOML file")
    if b"\x00" in data:
        line = data.count(b"\n", 0, data.index(b"\x00")) + 1
        raise input_error(f"{where}, line {line}", "binary data (a NUL byte)", "a TOML text file")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise input_error(f"{where}, line {line}", "not UTF-8 text", "a UTF-8 TOML file") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise input_error(where, f"not valid TOML ({exc})") from None
    except RecursionError:
        raise input_error(where, "not valid TOML (nested too deeply)") from None


def load_recording(path: str | os.PathLike) -> Recording:
    """Load and validate a recording from its TOML file.

    Args:
        path: the ``NAME.toml`` file; its ``data`` key names the table relative to it: a
            CSV (``.csv``, ``.csv.gz``) or a Parquet file (``.parquet``, read in row groups).

    Returns:
        The validated :class:`Recording`.

    Raises:
        EncdesignInputError: the file breaks the format; the message names the file, the
            row or column, and what was expected. Nothing is returned half-loaded.
    """
    path = Path(path)
    where = str(path)
    meta = validate_meta(read_toml(path), where)
    if "data" not in meta:
        raise input_error(where, "missing key 'data'", "the name of the data table")
    if not meta["data"].strip():
        raise input_error(f"{where}: data", "is empty", "the name of the data table")
    data_path = path.parent / meta["data"]
    spec = KINDS[meta["kind"]]
    reader = read_parquet_columns if is_parquet(data_path) else read_columns
    _, table, ref = reader(
        data_path, string_columns=spec.string_columns, int_columns=spec.int_columns
    )
    columns = validate_columns(ref, meta["kind"], meta, table)
    return Recording(kind=meta["kind"], meta=meta, columns=columns, path=path, table=ref)


WRITE_CHUNK_ROWS = 65_536  # rows formatted at a time: memory stays bounded by the chunk


def _format_column(a: np.ndarray) -> list[str]:
    """Cells of one column chunk: floats as the shortest repr that reads back exactly."""
    if a.dtype.kind == "f":
        return list(map(repr, a.tolist()))
    return list(map(str, a.tolist()))


def write_recording(
    path: str | os.PathLike,
    kind: str,
    columns: Mapping[str, Any],
    *,
    encoder: Mapping[str, Any] | None = None,
    motor: Mapping[str, Any] | None = None,
    description: str | None = None,
    provenance: Mapping[str, Any] | None = None,
    data_name: str | None = None,
    compress: bool = False,
    parquet: bool = False,
    source: str | None = None,
) -> Recording:
    """Validate and write a recording (``path`` = the TOML file; the table goes beside it).

    Args:
        path: output TOML path.
        kind: recording kind.
        columns: column name -> 1-D array-like (SI units, see the format).
        encoder, motor, description, provenance: TOML content.
        data_name: file name of the data table (default ``<stem>.csv[.gz]``, or
            ``<stem>.parquet`` with ``parquet``); a name ending in ``.parquet`` or ``.pq``
            writes Parquet.
        compress: gzip the table (CSV only).
        parquet: write the table as Parquet (float64, int64 and string columns, in row
            groups of 2^20 rows) instead of CSV.
        source: the input the columns were made from (a design, an imported file): a
            validation error then names it instead of the output file.

    Returns:
        The :class:`Recording` as it would be loaded back.

    Both files are written to temporary names and renamed into place only after the
    whole recording validated and was written, so a failure leaves nothing half-written.
    """
    path = Path(path)
    meta: dict[str, Any] = {"format": FORMAT, "kind": kind}
    if data_name is None:
        data_name = path.stem + (".parquet" if parquet else ".csv.gz" if compress else ".csv")
    as_parquet = parquet or Path(data_name).suffix.lower() in PARQUET_SUFFIXES
    if as_parquet and compress:
        raise input_error(
            str(path.parent / data_name),
            "gzip compression asked of a Parquet table",
            "gzip for a CSV table only (Parquet compresses its own pages)",
        )
    meta["data"] = data_name
    if description is not None:
        meta["description"] = description
    for name, tab in (("encoder", encoder), ("motor", motor), ("provenance", provenance)):
        if tab is not None:
            meta[name] = {
                k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in tab.items()
            }
    try:
        meta = validate_meta(meta, str(path))
        cols = {k: np.asarray(v) for k, v in columns.items()}
        conv = validate_columns(str(path.parent / data_name), kind, meta, cols)
    except EncdesignInputError as exc:
        if source is None:
            raise
        raise input_error(source, f"gives an invalid {kind} recording: {exc}") from None
    data_path = path.parent / data_name
    names = list(conv)
    # the table first, then the TOML that names it: each renamed into place when whole
    with atomic_output(path, "wb") as toml_fh:
        if as_parquet:
            with atomic_output(data_path, "wb") as fh:
                write_parquet_table(fh, conv)
        else:
            gz = data_name.endswith(".gz")
            with atomic_output(data_path, "w", newline="", compress=gz) as fh:
                w = csv.writer(fh, lineterminator="\n")
                w.writerow(names)
                n = len(conv[names[0]])
                for a in range(0, n, WRITE_CHUNK_ROWS):
                    b = min(n, a + WRITE_CHUNK_ROWS)
                    w.writerows(zip(*[_format_column(conv[c][a:b]) for c in names]))
        tomli_w.dump(meta, toml_fh)
    return Recording(kind=kind, meta=meta, columns=conv, path=path)
