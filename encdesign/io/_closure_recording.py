"""Recordings of kind ``closure``: a dual-closure polygon test (``docs/recording-format.md``).

An N-sided polygon sits on the instrument; at each *setting* its face 0 is set down at a
different position of the instrument and the platform is turned so that faces
``0, 1, …, N−1`` and then face 0 again are nulled on an autocollimator. Each row is one
null: columns ``setting`` (integer id), ``face`` (``0 … N−1``), ``reading`` (the
instrument's reading, rad), optional ``autocollimator`` (the autocollimator's residual
reading at the null, rad, subtracted from ``reading``) and ``t`` (s). The rows of one
setting are consecutive and in measurement order. ``[encoder] faces = N``.

Importing this module registers the kind in :data:`encdesign.io._recording.KINDS`; its
check refuses, naming the file and line: a face index outside ``0 … N−1``, a setting with
faces missing or out of sequence, a setting that does not return to face 0, a setting
split into several blocks (non-finite readings are refused by the table reader).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._errors import input_error
from ._recording import KINDS, KindSpec, Recording, positive_int, write_recording
from ._table import row_line

__all__ = ["closure_arrays", "write_closure_recording"]


def _closure_check(where: str, meta: dict, cols: dict) -> None:
    n = int(meta["encoder"]["faces"])
    setting = cols["setting"]
    face = cols["face"]
    bad = np.flatnonzero((face < 0) | (face >= n))
    if bad.size:
        i = int(bad[0])
        raise input_error(
            f"{where}, line {row_line(where, i)}, column 'face'",
            f"unknown face index {int(face[i])}",
            f"0 … {n - 1} ([encoder] faces = {n})",
        )
    change = np.flatnonzero(np.diff(setting) != 0) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [setting.size]])
    seen: set[int] = set()
    expected = list(range(n)) + [0]
    for a, b in zip(starts, ends):
        s = int(setting[a])
        if s in seen:
            raise input_error(
                f"{where}, line {row_line(where, a)}, column 'setting'",
                f"setting {s} appears in more than one block of rows",
                "the rows of one setting consecutive",
            )
        seen.add(s)
        got = [int(x) for x in face[a:b]]
        if got == expected:
            continue
        if got[0] != 0:
            raise input_error(
                f"{where}, line {row_line(where, a)}",
                f"setting {s} starts at face {got[0]}",
                "each setting to start at face 0",
            )
        missing = sorted(set(range(n)) - set(got))
        if missing:
            raise input_error(
                f"{where}, lines {row_line(where, a)}–{row_line(where, b - 1)}",
                f"setting {s} is missing face(s) {missing}",
                f"faces 0 … {n - 1} in sequence, then face 0 again",
            )
        if got[:n] == list(range(n)):
            after = "nothing" if len(got) == n else f"face {got[n]}"
            if len(got) == n or got[n] != 0:
                raise input_error(
                    f"{where}, line {row_line(where, a + n - 1)}",
                    f"setting {s} does not return to face 0 after face {n - 1} ({after})",
                    "a last reading of face 0 (the closure)",
                )
            raise input_error(
                f"{where}, line {row_line(where, a + n + 1)}",
                f"setting {s} has {len(got) - n - 1} row(s) after its return to face 0",
                f"{n + 1} rows per setting",
            )
        idx = next(i for i, (g, e) in enumerate(zip(got, expected)) if g != e)
        raise input_error(
            f"{where}, line {row_line(where, a + idx)}, column 'face'",
            f"setting {s}: face {got[idx]} where face {expected[idx]} was expected",
            f"faces 0 … {n - 1} in sequence, then face 0 again",
        )


KINDS.setdefault(
    "closure",
    KindSpec(
        encoder_keys={"faces": positive_int},
        required_encoder=("faces",),
        required_columns=lambda meta: ["setting", "face", "reading"],
        optional_columns=lambda meta: ["autocollimator", "t"],
        int_columns=("setting", "face"),
        check=_closure_check,
    ),
)


def closure_arrays(rec: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ``closure`` recording as arrays for the solver.

    Returns:
        ``(readings_rad, setting_positions, setting_ids)``: readings ``(S, N + 1)`` (minus
        the autocollimator residual when given) in the order of the file, the face-0
        position of each setting ``round(reading / (2π/N)) mod N``, and the ids.

    Raises:
        EncdesignInputError: not a closure recording.
    """
    where = str(rec.path) if rec.path is not None else "closure recording"
    if rec.kind != "closure":
        raise input_error(where, f"kind {rec.kind!r}", "a recording of kind 'closure'")
    n = int(rec.encoder["faces"])
    r = np.asarray(rec.columns["reading"], dtype=float)
    if "autocollimator" in rec.columns:
        r = r - rec.columns["autocollimator"]
    s_count = r.size // (n + 1)
    readings = r.reshape(s_count, n + 1)
    ids = rec.columns["setting"].reshape(s_count, n + 1)[:, 0]
    step = 2 * math.pi / n
    pos = np.mod(np.round(readings[:, 0] / step).astype(np.int64), n)
    return readings, pos, ids


def write_closure_recording(
    path: str | os.PathLike,
    readings_rad: np.ndarray,
    *,
    setting_ids: Sequence[int] | None = None,
    autocollimator_rad: np.ndarray | None = None,
    description: str | None = None,
    provenance: dict[str, Any] | None = None,
) -> Recording:
    """Write a ``closure`` recording from readings ``(S, N + 1)`` (faces 0 … N−1, 0), rad."""
    r = np.asarray(readings_rad, dtype=float)
    if r.ndim != 2 or r.shape[1] < 3:
        raise input_error("write_closure_recording readings_rad", f"shape {r.shape}", "(S, N+1)")
    s_count, n1 = r.shape
    n = n1 - 1
    ids = np.arange(s_count) if setting_ids is None else np.asarray(setting_ids)
    faces = np.tile(np.append(np.arange(n), 0), s_count)
    cols: dict[str, Any] = {
        "setting": np.repeat(ids, n1),
        "face": faces,
        "reading": r.reshape(-1),
    }
    if autocollimator_rad is not None:
        cols["autocollimator"] = np.asarray(autocollimator_rad, dtype=float).reshape(-1)
    return write_recording(
        path,
        "closure",
        cols,
        encoder={"faces": n},
        description=description,
        provenance=provenance,
    )
