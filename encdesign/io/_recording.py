"""Recordings in the ``encdesign-recording/1`` format (see ``docs/recording-format.md``).

A recording is a TOML file (metadata and nominal design) plus the CSV table it names
(optionally ``.csv.gz``). :func:`load_recording` validates the whole file before returning
anything: a bad file raises :class:`~encdesign.EncdesignInputError` naming the file, the
row or column and what was expected. :func:`write_recording` validates first and writes
atomically (temporary files renamed into place), so nothing is ever half-written.

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
import gzip
import io
import math
import os
import re
import tempfile
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from .._errors import input_error
from ._sds_format import check_sds_columns

FORMAT = "encdesign-recording/1"
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
    """

    kind: str
    meta: dict[str, Any]
    columns: dict[str, np.ndarray]
    path: Path | None = None

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

    encoder_keys: Mapping[str, Callable[[str, Any], Any]]
    required_encoder: tuple[str, ...] = ()
    motor_keys: Mapping[str, Callable[[str, Any], Any]] = dataclasses.field(default_factory=dict)
    required_columns: Callable[[dict], list[str]] = lambda meta: []
    optional_columns: Callable[[dict], list[str]] = lambda meta: []
    string_columns: tuple[str, ...] = ()
    int_columns: tuple[str, ...] = ("run",)
    check: Callable[[str, dict, dict], None] | None = None


# ----------------------------------------------------------------------------- checkers


def _finite_number(where: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise input_error(where, f"got {v!r}", "a finite number")
    return float(v)


def _positive_number(where: str, v: Any) -> float:
    x = _finite_number(where, v)
    if x <= 0:
        raise input_error(where, f"got {v!r}", "a positive number")
    return x


def _positive_int(where: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
        raise input_error(where, f"got {v!r}", "a positive integer")
    return int(v)


def _nonneg_int(where: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise input_error(where, f"got {v!r}", "a non-negative integer")
    return int(v)


def _angle_list(where: str, v: Any) -> list[float]:
    if not isinstance(v, list) or len(v) == 0:
        raise input_error(where, f"got {v!r}", "a non-empty list of angles in degrees")
    return [_finite_number(f"{where}[{i}]", x) for i, x in enumerate(v)]


def _string(where: str, v: Any) -> str:
    if not isinstance(v, str):
        raise input_error(where, f"got {v!r}", "a string")
    return v


SENSORS = ("optical", "magnetic", "resolver", "capacitive")
"""Values of ``[encoder] sensor`` (multihead kind)."""


def _sensor(where: str, v: Any) -> str:
    if not isinstance(v, str) or v not in SENSORS:
        raise input_error(where, f"got {v!r}", f"one of {', '.join(repr(s) for s in SENSORS)}")
    return v


def _table(where: str, v: Any) -> dict:
    if not isinstance(v, dict):
        raise input_error(where, f"got {v!r}", "a table")
    return v


# ----------------------------------------------------------------------------- kinds


def _multihead_required(meta: dict) -> list[str]:
    n = len(meta.get("encoder", {}).get("head_angles_deg", []))
    return ["t"] + [f"h{k}" for k in range(n)]


def _multihead_check(where: str, meta: dict, cols: dict) -> None:
    enc = meta["encoder"]
    n = len(enc["head_angles_deg"])
    if n == 1 and "theta_ref" not in cols:
        raise input_error(
            where,
            "one head needs a theta_ref column (head_angles_deg lists 1 head)",
            "a theta_ref column (one sensor against a reference) or at least two heads",
        )
    ref = enc.get("reference_head")
    if ref is not None and ref >= n:
        raise input_error(
            f"{where}: [encoder].reference_head",
            f"got {ref}",
            f"an index < {n} (number of head_angles_deg)",
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
    if tcol not in cols:
        return
    t = cols[tcol]
    run = cols.get("run", np.zeros(len(t), dtype=np.int64))
    for r in np.unique(run):
        idx = np.flatnonzero(run == r)
        dt = np.diff(t[idx])
        bad = np.flatnonzero(dt <= 0)
        if bad.size:
            row = int(idx[bad[0] + 1]) + 2  # header is line 1
            raise input_error(
                f"{where}, line {row}, column '{tcol}'",
                f"time goes backwards or repeats ({t[idx[bad[0]]]!r} then "
                f"{t[idx[bad[0] + 1]]!r}) within run {int(r)}",
                "strictly increasing time within each run",
            )


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
            "optical_radius_m": _positive_number,
            "head_angles_deg": _angle_list,
            "reference_head": _nonneg_int,
            "grating_lines": _positive_int,
            "sensor": _sensor,
            "signal_periods_per_rev": _positive_int,
        },
        required_encoder=("head_angles_deg",),
        required_columns=_multihead_required,
        optional_columns=lambda meta: ["run", "theta_ref", "temp_c"],
        check=_multihead_check,
    ),
    "sds": KindSpec(
        encoder_keys={
            "marks_per_rev": _positive_int,
            "fixed_sensor_angles_deg": _angle_list,
            "moving_sensor_angles_deg": _angle_list,
            "pole_pairs": _positive_int,
            "stator_coils": _positive_int,
            "commutation_states": _positive_int,
            "clock_hz": _positive_number,
            # extension of the spec: the read radius turns fitted angles into lengths
            "optical_radius_m": _positive_number,
        },
        required_encoder=("marks_per_rev", "fixed_sensor_angles_deg", "moving_sensor_angles_deg"),
        required_columns=_sds_required,
        optional_columns=lambda meta: ["run", "phi_ref", "temp_c"],
        string_columns=("sensor",),
        int_columns=("run", "mark"),
        check=_sds_check,
    ),
    "quadrature": KindSpec(
        encoder_keys={"signal_period_m": _positive_number},
        required_columns=lambda meta: ["sa", "sb"],
        optional_columns=lambda meta: ["t", "run"],
        check=_quadrature_check,
    ),
    "motion": KindSpec(
        encoder_keys={"counts_per_rev": _positive_int},
        motor_keys={
            "pole_pairs": _positive_int,
            "stator_slots": _positive_int,
            "commutation_states": _positive_int,
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
    if kind not in KINDS:
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
    return out


# ----------------------------------------------------------------------------- table


def _open_text(path: Path):
    if path.suffix == ".gz":
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8", newline="")
    return open(path, encoding="utf-8", newline="")


def _convert(where: str, name: str, values: list[str], kind: str, spec: KindSpec) -> np.ndarray:
    if name in spec.string_columns:
        arr = np.asarray([v.strip() for v in values], dtype=str)
        return arr
    try:
        arr = np.asarray(values, dtype=np.float64)
    except ValueError:
        for i, v in enumerate(values):
            try:
                float(v)
            except ValueError:
                raise input_error(
                    f"{where}, line {i + 2}, column '{name}'", f"got {v!r}", "a number"
                ) from None
        raise
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        raise input_error(
            f"{where}, line {i + 2}, column '{name}'", f"got {values[i]!r}", "a finite number"
        )
    if name in spec.int_columns:
        if np.any(arr != np.round(arr)):
            i = int(np.flatnonzero(arr != np.round(arr))[0])
            raise input_error(
                f"{where}, line {i + 2}, column '{name}'", f"got {values[i]!r}", "an integer"
            )
        arr = arr.astype(np.int64)
    return arr


def validate_columns(where: str, kind: str, meta: dict, columns: Mapping[str, Any]) -> dict:
    """Check a data table against its kind; return the converted columns. Raises on error."""
    spec = KINDS[kind]
    required = spec.required_columns(meta)
    allowed = set(required) | set(spec.optional_columns(meta))
    names = list(columns)
    missing = [c for c in required if c not in columns]
    if missing:
        raise input_error(
            where, f"missing column(s) {', '.join(missing)}", f"columns {required} at least"
        )
    unknown = [c for c in names if c not in allowed]
    if unknown:
        raise input_error(
            where, f"unknown column(s) {', '.join(unknown)} for kind '{kind}'", f"{sorted(allowed)}"
        )
    lengths = {len(v) for v in columns.values()}
    if len(lengths) > 1:
        raise input_error(where, f"columns of unequal length {sorted(lengths)}")
    if lengths == {0}:
        raise input_error(where, "the data table has no rows", "at least one row")
    out: dict[str, np.ndarray] = {}
    for name in names:
        vals = columns[name]
        if (
            isinstance(vals, np.ndarray)
            and vals.dtype.kind in "fiu"
            and name not in (spec.string_columns)
        ):
            out[name] = _convert_array(where, name, vals, spec)
        else:
            out[name] = _convert(where, name, [str(v) for v in vals], kind, spec)
    if spec.check is not None:
        spec.check(where, meta, out)
    return out


def _convert_array(where: str, name: str, vals: np.ndarray, spec: KindSpec) -> np.ndarray:
    arr = np.asarray(vals, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        raise input_error(f"{where}, line {i + 2}, column '{name}'", f"got {arr[i]!r}", "finite")
    if name in spec.int_columns:
        if np.any(arr != np.round(arr)):
            i = int(np.flatnonzero(arr != np.round(arr))[0])
            raise input_error(
                f"{where}, line {i + 2}, column '{name}'", f"got {arr[i]!r}", "an integer"
            )
        return arr.astype(np.int64)
    return arr


def read_table(path: Path) -> dict[str, list[str]]:
    """Read a CSV (or .csv.gz) file into column name -> list of str. Raises on bad shape."""
    where = str(path)
    if not path.exists():
        raise input_error(where, "data file not found")
    try:
        with _open_text(path) as fh:
            reader = csv.reader(fh)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise input_error(where, "empty file", "a header row") from None
            if len(set(header)) != len(header):
                raise input_error(where, f"duplicate column names in header {header}")
            rows = []
            for i, row in enumerate(reader):
                if not row:
                    continue
                if len(row) != len(header):
                    raise input_error(
                        f"{where}, line {i + 2}",
                        f"{len(row)} fields",
                        f"{len(header)} fields as in the header",
                    )
                rows.append(row)
    except (OSError, UnicodeDecodeError, csv.Error, EOFError) as exc:
        raise input_error(where, f"cannot read ({exc})", "a UTF-8 CSV file") from None
    cols = list(zip(*rows)) if rows else [() for _ in header]
    return {h: list(c) for h, c in zip(header, cols)}


def read_toml(path: str | os.PathLike) -> dict[str, Any]:
    """Read a TOML file (recording, design or problem) into a dict; never modifies it.

    Raises:
        EncdesignInputError: the file is missing, unreadable or not valid TOML.
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise input_error(where, "file not found")
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise input_error(where, f"not valid TOML ({exc})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise input_error(where, f"cannot read ({exc})") from None


def load_recording(path: str | os.PathLike) -> Recording:
    """Load and validate a recording from its TOML file.

    Args:
        path: the ``NAME.toml`` file; its ``data`` key names the CSV relative to it.

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
        raise input_error(where, "missing key 'data'", "the name of the CSV data table")
    data_path = (path.parent / meta["data"]).resolve()
    table = read_table(data_path)
    columns = validate_columns(str(data_path), meta["kind"], meta, table)
    return Recording(kind=meta["kind"], meta=meta, columns=columns, path=path)


def _fmt(x: Any) -> str:
    if isinstance(x, float | np.floating):
        return repr(float(x))
    return str(x)


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
) -> Recording:
    """Validate and write a recording (``path`` = the TOML file; the CSV goes beside it).

    Args:
        path: output TOML path.
        kind: recording kind.
        columns: column name -> 1-D array-like (SI units, see the format).
        encoder, motor, description, provenance: TOML content.
        data_name: file name of the data table (default ``<stem>.csv[.gz]``).
        compress: gzip the table.

    Returns:
        The :class:`Recording` as it would be loaded back.

    Both files are written to temporary names and renamed into place only after the
    whole recording validated and was written, so a failure leaves nothing half-written.
    """
    path = Path(path)
    meta: dict[str, Any] = {"format": FORMAT, "kind": kind}
    if data_name is None:
        data_name = path.stem + (".csv.gz" if compress else ".csv")
    meta["data"] = data_name
    if description is not None:
        meta["description"] = description
    for name, tab in (("encoder", encoder), ("motor", motor), ("provenance", provenance)):
        if tab is not None:
            meta[name] = {
                k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in tab.items()
            }
    meta = validate_meta(meta, str(path))
    cols = {k: np.asarray(v) for k, v in columns.items()}
    conv = validate_columns(str(path.parent / data_name), kind, meta, cols)
    path.parent.mkdir(parents=True, exist_ok=True)
    data_path = path.parent / data_name
    names = list(conv)
    tmp_files = []
    try:
        fd, tmp_data = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".csv")
        os.close(fd)
        tmp_files.append(tmp_data)
        opener = gzip.open if data_name.endswith(".gz") else open
        with opener(tmp_data, "wt", encoding="utf-8", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(names)
            str_cols = [[_fmt(x) for x in conv[n].tolist()] for n in names]
            w.writerows(zip(*str_cols))
        fd, tmp_toml = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".toml")
        os.close(fd)
        tmp_files.append(tmp_toml)
        with open(tmp_toml, "wb") as fh:
            tomli_w.dump(meta, fh)
        umask = os.umask(0)
        os.umask(umask)
        for tmp in tmp_files:
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp_data, data_path)
        os.replace(tmp_toml, path)
    finally:
        for f in tmp_files:
            if os.path.exists(f):
                os.remove(f)
    return Recording(kind=kind, meta=meta, columns=conv, path=path)
