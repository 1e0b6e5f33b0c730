"""Converters from the public measured data in ``shared/realdata`` to recordings.

Two sources (see ``data/real/README.md`` for the licenses, which travel with every
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
    src: str | os.PathLike, out_toml: str | os.PathLike, *, axis: str | None = None
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
    src: str | os.PathLike, out_toml: str | os.PathLike, *, label: str | None = None
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
    )


REALDATA_JOBS = (
    ("nmm", "nmm_X_raw.csv", "nmm_x.toml"),
    ("nmm", "nmm_Y_raw.csv", "nmm_y.toml"),
    ("odrive", "odrive_slow2_nocomp_0.npy", "odrive_nocomp.toml"),
    ("odrive", "odrive_slow2_comp_0.npy", "odrive_comp.toml"),
)
"""The shared recordings :func:`import_realdata_folder` converts: (source, file, output)."""


def realdata_jobs(src_dir: str | os.PathLike, out_dir: str | os.PathLike) -> list[tuple]:
    """``(source, input path, output TOML path)`` of every conversion of the folder."""
    src_dir, out_dir = Path(src_dir), Path(out_dir)
    return [(kind, src_dir / src, out_dir / dst) for kind, src, dst in REALDATA_JOBS]


def import_realdata_folder(src_dir: str | os.PathLike, out_dir: str | os.PathLike) -> list[Path]:
    """Convert all four shared recordings found in ``src_dir`` into ``out_dir``.

    Every source is read and checked before anything is written, so a bad source leaves
    ``out_dir`` as it was.

    Returns the TOML paths written: ``nmm_x``, ``nmm_y``, ``odrive_nocomp``, ``odrive_comp``.
    """
    jobs = realdata_jobs(src_dir, out_dir)
    for kind, src, _ in jobs:  # read and check all first
        read_nmm_csv(src) if kind == "nmm" else read_odrive_npy(src)
    written = []
    for kind, src, dst in jobs:
        (import_nmm if kind == "nmm" else import_odrive)(src, dst)
        written.append(dst)
    return written
