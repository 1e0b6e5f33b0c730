"""Converters from the public measured data in ``shared/realdata`` to recordings.

Five sources (see ``data/real/README.md`` for the licenses, which travel with every
converted file as the recording's ``[provenance]`` table):

* NmmQuad (M. Matus, MIT): Lissajous captures of the X and Y homodyne laser
  interferometers of a SIOS NMM-1. CSV columns ``Phase (deg), Radius, Roundness deviation``;
  radius and deviation in ADC counts, rows sorted by phase (time order lost). Converted to
  kind ``quadrature`` with ``sa = r cos(phase)``, ``sb = r sin(phase)`` (ADC counts) and no
  ``t`` column.
* ODrive (gchenfc fork, MIT): a brushless motor at 0.1 rev/s under velocity control,
  without and with anti-cogging. ``.npy`` float64 ``[3, N]``: time (s), encoder position
  (counts, 8192 per turn, fractional: the controller's interpolated estimate), current
  ``Iq`` (A). Converted to kind ``motion`` with columns ``t``, ``counts``, ``current_a``.
* moteus (mjbots, Apache-2.0): a calibration sweep of the controller's on-board magnetic
  encoder against its own open-loop commanded angle, lines ``dir phase encoder``. Converted
  to a sensor-against-reference ``multihead`` recording (one head ``h0`` = the encoder,
  ``theta_ref`` = commanded mechanical angle). Read from the data: every encoder value is a
  multiple of 4 of 65536, i.e. a 14-bit sensor; the up sweep of 21.007 electrical turns
  moves the encoder 1.0002 turn, so 21 pole pairs (14 would move it 1.5 turns).
* MagAlpha (Monolithic Power Systems, MIT): a magnetic angle sensor against a reference over
  one turn, 200 rows in degrees, both angles on a 360/512 degree lattice. Converted to a
  sensor-against-reference ``multihead`` recording after putting the rows near the 0/360
  wrap in sweep order (the moved lines are listed in the provenance).
* ServoProject (A. Bäckström, CC BY 3.0 US, attribution required): a raw capture of a
  two-channel reflective optical encoder on a small DC motor, lines ``t A B position cost``.
  Converted to kind ``quadrature`` with ``t`` (s), ``sa`` = A, ``sb`` = B (ADC counts). Read
  from the data: A and B are integers (4,935-14,641 and 9,814-15,677, no clipped plateau);
  the signal phase advances one period per motor turn (monotone in the device's own
  position, 0-2047 per turn); the position and its fit cost are not carried (the format has
  no column for them, and the position comes from the device's lookup table of A and B, so
  it is not an independent reference).

Neither sensor source has time stamps: ``t`` is the sample index (1 per sample), so speeds
and delays found in them are per sample, not per second.

Motor type for the ODrive records: 7 pole pairs and 12 stator slots. Decided from the data:
the published cogging map (``odrive_cogging_map_d_16.npy``) has its largest Fourier
components at orders 7, 28, 14 (multiples of the pole-pair count: magnet asymmetry) and
36, 12, 84 (slot count multiples, and 84 = lcm(2·7, 12), the cogging order of a 12-slot,
14-pole machine); the current of both records peaks at orders 7, 14, 28, 12. This matches
the 14-pole / 12-slot outrunners ODrive sells (e.g. D5065, D6374).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._errors import input_error
from ._recording import Recording, write_recording
from ._table import read_columns, row_line

NMM_PROVENANCE = {
    "source": "github.com/matusm/NmmQuad, TestData/results/test01_XYZ_f_quad_{X,Y}_raw.csv",
    "license": "MIT License, Copyright (c) 2024 Michael Matus",
    "notes": "SIOS NMM-1 homodyne interferometer Lissajous capture; sa = r cos(phase), "
    "sb = r sin(phase) in ADC counts; rows sorted by phase, time order lost",
}
ODRIVE_PROVENANCE = {
    "source": "github.com/gchenfc/ODrive (fork of ODrive), analysis/cogging_torque/slow2/",
    "license": "MIT License, Copyright (c) 2016-2018 ODrive Robotics",
    "notes": "brushless motor at 0.1 rev/s under velocity control; position is the "
    "controller's fractional count estimate (8192 counts/rev); motor 7 pole pairs, 12 slots "
    "(from the cogging map's orders 7, 14, 28, 12, 36, 84)",
}
ODRIVE_POLE_PAIRS = 7
ODRIVE_STATOR_SLOTS = 12
ODRIVE_COUNTS_PER_REV = 8192


NMM_COLUMNS = ["Phase (deg)", "Radius", "Roundness deviation"]


def read_nmm_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read an NmmQuad ``*_raw.csv``; return ``(phase_rad, radius_counts)``.

    Read by the recordings' CSV reader (:func:`encdesign.io._table.read_columns`): a BOM,
    CRLF, blank lines, trailing commas and gzip are read; binary data, a bad cell or a
    short row is refused naming its line.

    Raises:
        EncdesignInputError: wrong header, non-numeric or non-finite values, radius <= 0.
    """
    path = Path(path)
    where = str(path)
    header, cols, ref = read_columns(path, int_columns=())
    if header != NMM_COLUMNS:
        raise input_error(where, f"header {header}", f"the NmmQuad columns {NMM_COLUMNS}")
    a = np.stack([cols[c] for c in NMM_COLUMNS], axis=1)
    if a.shape[0] < 3:
        raise input_error(where, f"{a.shape[0]} data row(s)", "at least 3 rows")
    for j, name in enumerate(NMM_COLUMNS):
        bad = np.flatnonzero(~(np.abs(a[:, j]) <= 1e100))
        if bad.size:
            i = int(bad[0])
            raise input_error(
                f"{where}, line {row_line(ref, i)}, column '{name}'",
                f"non-finite value {a[i, j].item()!r}",
                "a finite number",
            )
    if np.any(a[:, 1] <= 0):
        i = int(np.flatnonzero(a[:, 1] <= 0)[0])
        raise input_error(
            f"{where}, line {row_line(ref, i)}, column 'Radius'",
            f"radius {a[i, 1].item()!r}",
            "> 0",
        )
    return np.deg2rad(a[:, 0]), a[:, 1]


def import_nmm(
    src: str | os.PathLike,
    out_toml: str | os.PathLike,
    *,
    axis: str | None = None,
    parquet: bool = False,
) -> Recording:
    """Convert an NmmQuad Lissajous capture to a ``quadrature`` recording.

    Args:
        src: the NmmQuad CSV (phase in degrees, radius and deviation in ADC counts).
        out_toml: the recording to write (its CSV goes beside it).
        axis: interferometer axis name for the description (default: from the file name).

    Returns:
        The written recording (signals ``sa``, ``sb`` in ADC counts).
    """
    phase, r = read_nmm_csv(src)
    if axis is None:
        parts = Path(src).stem.split("_")
        axis = parts[1] if len(parts) > 1 else Path(src).stem
    return write_recording(
        out_toml,
        "quadrature",
        {"sa": r * np.cos(phase), "sb": r * np.sin(phase)},
        description=f"NMM-1 {axis} interferometer Lissajous capture (ADC counts, phase-sorted)",
        provenance=NMM_PROVENANCE,
        source=str(src),
        parquet=parquet,
    )


_NPY_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


def read_odrive_npy(path: str | os.PathLike) -> np.ndarray:
    """Read an ODrive ``slow2`` record: float64 ``[3, N]`` (t s, position counts, Iq A).

    The file is memory-mapped (read only), so its size does not count against memory until
    it is converted. Refused in one line: a ``.npz`` archive, a file that is not ``.npy``
    (binary garbage, text, a pickle), a truncated array, the wrong shape or dtype,
    non-finite values, time that does not increase.
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise input_error(where, "file not found")
    if path.is_dir():
        raise input_error(where, "is a folder", "a NumPy .npy file")
    with open(path, "rb") as fh:
        magic = fh.read(6)
    if magic.startswith(_ZIP_MAGIC):
        raise input_error(
            where,
            "a .npz archive (a zip of arrays), not a .npy array",
            "a .npy file: save the [3, N] array with numpy.save",
        )
    if magic != _NPY_MAGIC:
        raise input_error(where, "not a NumPy .npy file (no .npy header)", "a .npy float array")
    try:
        a = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise input_error(
            where, f"cannot read ({_one_line(exc)})", "a complete NumPy .npy float array"
        ) from None
    if a.ndim != 2 or a.shape[0] != 3 or a.shape[1] < 3 or a.dtype.kind != "f":
        raise input_error(where, f"array {a.dtype}{list(a.shape)}", "float array of shape [3, N]")
    chunk = 1 << 20
    for s0 in range(0, a.shape[1], chunk):
        blk = np.asarray(a[:, s0 : s0 + chunk], dtype=np.float64)
        bad = np.flatnonzero(~np.all(np.abs(blk) <= 1e100, axis=0))
        if bad.size:
            raise input_error(f"{where}, sample {s0 + int(bad[0])}", "non-finite value", "finite")
    t = np.asarray(a[0], dtype=np.float64)
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise input_error(
            f"{where}, sample {k}",
            f"time goes backwards or repeats ({t[k - 1].item()!r} then {t[k].item()!r} s)",
            "strictly increasing time in row 0",
        )
    return a


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def import_odrive(
    src: str | os.PathLike,
    out_toml: str | os.PathLike,
    *,
    label: str | None = None,
    parquet: bool = False,
) -> Recording:
    """Convert an ODrive ``slow2`` record to a ``motion`` recording (counts, 8192/rev)."""
    a = read_odrive_npy(src)
    label = label or Path(src).stem
    return write_recording(
        out_toml,
        "motion",
        {"t": a[0], "counts": a[1], "current_a": a[2]},
        encoder={"counts_per_rev": ODRIVE_COUNTS_PER_REV},
        motor={"pole_pairs": ODRIVE_POLE_PAIRS, "stator_slots": ODRIVE_STATOR_SLOTS},
        description=f"ODrive brushless motor at 0.1 rev/s, velocity control ({label})",
        provenance=ODRIVE_PROVENANCE,
        source=str(src),
        parquet=parquet,
    )


REALDATA_JOBS = (
    ("nmm", "nmm_X_raw.csv", "nmm_x.toml"),
    ("nmm", "nmm_Y_raw.csv", "nmm_y.toml"),
    ("odrive", "odrive_slow2_nocomp_0.npy", "odrive_nocomp.toml"),
    ("odrive", "odrive_slow2_comp_0.npy", "odrive_comp.toml"),
    ("odrive", "odrive_slow2_nocomp_1.npy", "odrive_nocomp_1.toml"),
    ("odrive", "odrive_slow2_comp_1.npy", "odrive_comp_1.toml"),
    ("moteus", "moteus_encoder_cal.txt", "moteus_cal.toml"),
    ("magalpha", "magalpha_calibration_example.csv", "magalpha_cal.toml"),
    ("servo", "servo_optical_encoder_capture.txt", "servo_optical.toml"),
)
"""The shared recordings :func:`import_realdata_folder` converts: (source, file, output)."""


def realdata_jobs(src_dir: str | os.PathLike, out_dir: str | os.PathLike) -> list[tuple]:
    """``(source, input path, output TOML path)`` of every conversion of the folder."""
    src_dir, out_dir = Path(src_dir), Path(out_dir)
    return [(kind, src_dir / src, out_dir / dst) for kind, src, dst in REALDATA_JOBS]


def import_realdata_folder(
    src_dir: str | os.PathLike, out_dir: str | os.PathLike, *, parquet: bool = False
) -> list[Path]:
    """Convert the shared recordings found in ``src_dir`` into ``out_dir``.

    ``parquet``: write every table as Parquet instead of CSV.

    Every source is read and checked before anything is written, so a bad source leaves
    ``out_dir`` as it was.

    Returns the TOML paths written: ``nmm_x``, ``nmm_y``, ``odrive_nocomp``, ``odrive_comp``,
    ``odrive_nocomp_1``, ``odrive_comp_1``, ``moteus_cal``, ``magalpha_cal``,
    ``servo_optical``.
    """
    jobs = realdata_jobs(src_dir, out_dir)
    for kind, src, _ in jobs:  # read and check all first
        _READERS[kind](src)
    written = []
    importers = {
        "nmm": import_nmm,
        "odrive": import_odrive,
        "moteus": import_moteus,
        "magalpha": import_magalpha,
        "servo": import_servo,
    }
    for kind, src, dst in jobs:
        importers[kind](src, dst, parquet=parquet)
        written.append(dst)
    return written


# ----------------------------------------------------------------------------- sensors


MOTEUS_PROVENANCE = {
    "source": "github.com/mjbots/moteus, lib/python/moteus/test/calibrate_encoder_test.py "
    "(SOURCE_DATA)",
    "license": "Apache License 2.0, Copyright 2023 mjbots Robotic Systems, LLC",
    "notes": "calibration sweep of a moteus controller's on-board magnetic encoder against "
    "its own open-loop drive; source lines 'dir phase encoder': phase = commanded electrical "
    "angle (uint16, 65536 per electrical turn), encoder = raw reading (uint16, 65536 per "
    "mechanical turn). theta_ref = unwrapped phase / 65536 / 21 turns (21 pole pairs: the "
    "sweep of 21.0 electrical turns moves the encoder 1.000 turn); h0 = unwrapped encoder. "
    "dir 1 (phase up) then dir 2 (phase down) in one run. The source has no time stamps: "
    "t is the sample index (1 per sample, not seconds), so speeds are per sample",
}
MOTEUS_POLE_PAIRS = 21
MOTEUS_COUNTS = 65536

MAGALPHA_PROVENANCE = {
    "source": "github.com/monolithicpower/MagAlpha-Calibration-Curve-Toolbox, "
    "input-files/calibration_data_input_example.csv",
    "license": "MIT License, Copyright (c) 2017 Monolithic Power Systems",
    "notes": "a MagAlpha magnetic angle sensor against a reference angle over one turn; "
    "source columns 'Reference Angle [degree]', 'Measured Angle [degree]', both quantized to "
    "360/512 degree and printed to 6 significant digits. Rows re-ordered along the sweep of "
    "the reference (see 'reordered_rows'); both angles unwrapped to rad. The source has no "
    "time stamps: t is the sample index (1 per sample, not seconds)",
}


def _unwrap_counts(x: np.ndarray, per_turn: int) -> np.ndarray:
    """Unwrap a wrapping integer reading (``per_turn`` counts per turn) to counts."""
    d = np.diff(x)
    d = (d + per_turn // 2) % per_turn - per_turn // 2
    return x[0] + np.concatenate([[0], np.cumsum(d)])


def _text_table(
    path: str | os.PathLike,
    lines: str,
    n_cols: int,
    min_rows: int,
    cells: str,
    *,
    delimiter: str | None = None,
    skip_header: int = 0,
) -> tuple[np.ndarray, str, np.ndarray]:
    """Read a numeric text table of ``n_cols`` columns and at least ``min_rows`` rows
    (whitespace-separated with ``#`` comments, or ``delimiter``-separated after
    ``skip_header`` header lines; blank lines skipped).

    Returns:
        The table (float64), the path for messages and, per row, its FILE line number
        (1-based, counting the header, comments and blank lines), for messages.

    Raises:
        EncdesignInputError: a missing or binary file, a non-numeric cell (Python literals
            such as ``1_0`` included), the wrong column count or too few rows, naming the
            file line; the message says what was expected (``lines``: the line layout;
            ``cells``: what each column holds, e.g. "integers").
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise input_error(where, "file not found")
    if path.is_dir():
        raise input_error(where, "a folder", "a text file")
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise input_error(where, "not a UTF-8 text file", lines) from None
    if "\x00" in text:
        raise input_error(where, "binary data (NUL bytes)", lines)
    rows: list[list[float]] = []
    line_no: list[int] = []
    for k, raw in enumerate(text.replace("\r\n", "\n").replace("\r", "\n").split("\n"), 1):
        if k <= skip_header:
            continue
        body = raw if delimiter is not None else raw.split("#", 1)[0]
        if not body.strip():
            continue
        toks = [t.strip() for t in body.split(delimiter)]
        if len(toks) != n_cols:
            raise input_error(
                f"{where}, line {k}", f"wrong number of columns ({len(toks)})", f"{n_cols} {cells}"
            )
        try:
            if any("_" in t for t in toks):
                raise ValueError
            rows.append([float(t) for t in toks])
        except ValueError:
            raise input_error(
                f"{where}, line {k}", f"non-numeric value in {raw.strip()[:60]!r}", lines
            ) from None
        line_no.append(k)
    if len(rows) < min_rows:
        raise input_error(
            where, f"{len(rows)} data line(s)", f"at least {min_rows} lines of {n_cols} {cells}"
        )
    return np.asarray(rows, dtype=np.float64), where, np.asarray(line_no, dtype=np.int64)


def read_moteus_cal(path: str | os.PathLike) -> np.ndarray:
    """Read a moteus ``dir phase encoder`` sweep; return int64 ``(n, 3)``.

    Raises:
        EncdesignInputError: not three integer columns, ``dir`` not 1 or 2, ``phase`` or
            ``encoder`` outside ``0 … 65535``, fewer than 3 rows.
    """
    a, where, line = _text_table(path, "lines 'dir phase encoder'", 3, 3, "integers")
    return _moteus_ints(a, where, line)


def _moteus_ints(a: np.ndarray, where: str, line: np.ndarray) -> np.ndarray:
    """Check the moteus columns (integers in range, before any cast) and cast to int64."""
    for j, name, lo, hi in ((0, "dir", 1, 2), (1, "phase", 0, 65535), (2, "encoder", 0, 65535)):
        x = a[:, j]
        bad = np.flatnonzero(~(np.isfinite(x) & (x == np.round(x))))
        if bad.size:
            raise input_error(
                f"{where}, line {int(line[bad[0]])}, column '{name}'",
                f"got {x[bad[0]].item()!r}",
                "integers",
            )
        bad = np.flatnonzero((x < lo) | (x > hi))
        if bad.size:
            raise input_error(
                f"{where}, line {int(line[bad[0]])}, column '{name}'",
                f"got {x[bad[0]].item():g}",
                f"{lo} … {hi}",
            )
    return a.astype(np.int64)


def import_moteus(
    src: str | os.PathLike,
    out_toml: str | os.PathLike,
    *,
    pole_pairs: int = MOTEUS_POLE_PAIRS,
    parquet: bool = False,
) -> Recording:
    """Convert a moteus encoder-calibration sweep to a sensor-against-reference recording.

    ``theta_ref`` is the commanded mechanical angle (unwrapped electrical phase divided by
    the pole pairs), ``h0`` the magnetic encoder's unwrapped reading, both in rad; one run
    (the sweep up then down), ``t`` the sample index. The electrical phase steps are checked
    to be below half an electrical turn (else the unwrapping would be ambiguous).
    """
    raw, where, line = _text_table(src, "lines 'dir phase encoder'", 3, 3, "integers")
    a = _moteus_ints(raw, where, line)
    dp = (np.diff(a[:, 1]) + 32768) % 65536 - 32768
    if np.any(np.abs(dp) >= 16384):
        i = int(np.flatnonzero(np.abs(dp) >= 16384)[0]) + 1
        raise input_error(
            f"{where}, line {int(line[i])}",
            "phase step of a quarter electrical turn or more from the line before",
            "a sweep",
        )
    phase = _unwrap_counts(a[:, 1], 65536).astype(np.float64)
    enc = _unwrap_counts(a[:, 2], MOTEUS_COUNTS).astype(np.float64)
    theta_ref = 2 * np.pi * phase / 65536 / pole_pairs
    h0 = 2 * np.pi * enc / MOTEUS_COUNTS
    up = int(np.sum(a[:, 0] == 1))
    prov = dict(MOTEUS_PROVENANCE)
    prov["directions"] = f"rows 0-{up - 1}: dir 1 (up); rows {up}-{len(a) - 1}: dir 2 (down)"
    return write_recording(
        out_toml,
        "multihead",
        {"t": np.arange(len(a), dtype=np.float64), "theta_ref": theta_ref, "h0": h0},
        encoder={"head_angles_deg": [0.0], "sensor": "magnetic", "signal_periods_per_rev": 1},
        description="moteus on-board magnetic encoder against its open-loop commanded angle "
        f"({pole_pairs} pole pairs), one turn up and one down",
        provenance=prov,
        parquet=parquet,
    )


def read_magalpha_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read the MagAlpha toolbox CSV; return ``(reference_deg, measured_deg)``."""
    ref, mea, _ = _read_magalpha(path)
    return ref, mea


def _read_magalpha(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(reference_deg, measured_deg, file line of each row)``."""
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise input_error(where, "file not found")
    with open(path, encoding="utf-8") as fh:
        header = [h.strip() for h in fh.readline().split(",")]
    expected = ["Reference Angle [degree]", "Measured Angle [degree]"]
    if header != expected:
        raise input_error(where, f"header {header}", f"the MagAlpha toolbox columns {expected}")
    a, _, line = _text_table(
        path, "two numeric columns", 2, 8, "numbers", delimiter=",", skip_header=1
    )
    bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
    if bad.size:
        raise input_error(f"{where}, line {int(line[bad[0]])}", "non-finite value", "finite")
    bad = np.flatnonzero(np.any(np.abs(a) > 720.0, axis=1))
    if bad.size:
        raise input_error(
            f"{where}, line {int(line[bad[0]])}",
            f"angle {a[bad[0]].tolist()} deg",
            "angles of one turn in degrees (|angle| <= 720)",
        )
    return a[:, 0], a[:, 1], line


def import_magalpha(
    src: str | os.PathLike, out_toml: str | os.PathLike, *, parquet: bool = False
) -> Recording:
    """Convert the MagAlpha calibration example to a sensor-against-reference recording.

    The rows are one sweep of the reference over a turn, a few of them out of order near
    the 0/360 degree wrap; they are put in sweep order (sorted by the reference angle
    counted from the first row along the sweep direction) and the rows moved are listed in
    ``[provenance] reordered_rows``. Both angles are then unwrapped (rad).

    Raises:
        EncdesignInputError: bad table, or the measured angle does not follow the sweep
            (a step of half a turn or more after re-ordering).
    """
    ref_deg, mea_deg, line = _read_magalpha(src)
    where = str(src)
    step = (np.diff(ref_deg) + 180.0) % 360.0 - 180.0
    sense = 1.0 if np.median(step) >= 0 else -1.0
    key = np.mod(sense * (ref_deg - ref_deg[0]), 360.0)
    order = np.argsort(key, kind="stable")
    moved = order[np.flatnonzero(order != np.arange(order.size))]
    ref = np.unwrap(np.deg2rad(ref_deg[order]))
    mea = np.unwrap(np.deg2rad(mea_deg[order]))
    dm = np.diff(mea) * sense
    if np.any(dm <= -np.pi / 2):
        i = int(line[order[int(np.flatnonzero(dm <= -np.pi / 2)[0]) + 1]])
        raise input_error(f"{where}, line {i}", "the measured angle runs against the sweep")
    prov = dict(MAGALPHA_PROVENANCE)
    prov["reordered_rows"] = [int(line[i]) for i in moved]  # file line numbers (header = 1)
    return write_recording(
        out_toml,
        "multihead",
        {"t": np.arange(ref.size, dtype=np.float64), "theta_ref": ref, "h0": mea},
        encoder={"head_angles_deg": [0.0], "sensor": "magnetic", "signal_periods_per_rev": 1},
        description="MagAlpha magnetic angle sensor against a reference angle, one turn",
        provenance=prov,
        parquet=parquet,
    )


# ----------------------------------------------------------------------------- servo


SERVO_PROVENANCE = {
    "source": "github.com/adamb314/ServoProject, Python/tests/dataFiles/optEncTestData.txt",
    "license": "CC BY 3.0 US, Adam Bäckström (ServoProject); attribution required",
    "notes": "raw capture of a two-channel reflective optical encoder on a small DC motor. "
    "Source lines 't A B position cost' (whitespace separated): t in s (4.2 ms steps, "
    "25 bursts: a 0.115 s pause after the first line, then 23 pauses of 1.1-1.2 s and one "
    "of 7.8 s), A and B the two channels' raw ADC values "
    "(integers 4,935-14,641 and 9,814-15,677: below 16,384, no clipped plateau), the "
    "device's own position estimate (integers 0-2047 per motor turn, from its lookup table of "
    "A, B: not an independent reference) and that estimate's fit cost (integers 0-84). "
    "sa = A, sb = B (ADC counts); position and cost are not carried (the quadrature format "
    "has no column for them). The signal phase atan2(B - centre, A - centre) advances one "
    "period per motor turn (monotone in the device's position); ~14 samples per period at "
    "~17 turns/s, the direction reversing every few seconds",
}
SERVO_COLUMNS = ("t", "A", "B", "position", "cost")


def read_servo_capture(path: str | os.PathLike) -> np.ndarray:
    """Read a ServoProject optical-encoder capture: float64 ``(n, 5)`` (t s, A, B, position,
    cost; see :data:`SERVO_PROVENANCE`).

    Raises:
        EncdesignInputError: not 5 numeric columns, non-finite values, A or B not integers
            in ``0 … 65535``, ``t`` not increasing, fewer than 32 rows.
    """
    a, where, line = _text_table(path, "lines 't A B position cost'", 5, 32, "numbers")
    bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
    if bad.size:
        raise input_error(f"{where}, line {int(line[bad[0]])}", "non-finite value", "finite")
    for j in (1, 2):
        x = a[:, j]
        bad = np.flatnonzero((x != np.round(x)) | (x < 0) | (x > 65535))
        if bad.size:
            raise input_error(
                f"{where}, line {int(line[bad[0]])}, column '{SERVO_COLUMNS[j]}'",
                f"got {x[bad[0]].item()!r}",
                "an ADC count (integer 0 … 65535)",
            )
    bad = np.flatnonzero(np.diff(a[:, 0]) <= 0)
    if bad.size:
        raise input_error(
            f"{where}, line {int(line[bad[0] + 1])}, column 't'", "time not increasing"
        )
    return a


def import_servo(
    src: str | os.PathLike, out_toml: str | os.PathLike, *, parquet: bool = False
) -> Recording:
    """Convert a ServoProject optical-encoder capture to a ``quadrature`` recording
    (``t`` s, ``sa`` = channel A, ``sb`` = channel B in ADC counts; one run: the pauses
    between bursts are gaps the diagnosis reports)."""
    a = read_servo_capture(src)
    return write_recording(
        out_toml,
        "quadrature",
        {"t": a[:, 0], "sa": a[:, 1], "sb": a[:, 2]},
        description="ServoProject: raw two-channel optical encoder on a DC motor (ADC counts), "
        "one signal period per motor turn, bursts in both directions",
        provenance=SERVO_PROVENANCE,
        parquet=parquet,
    )


_READERS = {
    "servo": read_servo_capture,
    "nmm": read_nmm_csv,
    "odrive": read_odrive_npy,
    "moteus": read_moteus_cal,
    "magalpha": read_magalpha_csv,
}
"""Source kind -> the reader that checks a file without writing anything."""
