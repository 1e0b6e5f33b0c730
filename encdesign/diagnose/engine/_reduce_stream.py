"""Issue 43: a long Parquet record reduced to block means as it is read, one row group at a
time (:mod:`._reduce` holds the rule; the whole table is never in memory).

Two passes over the row groups: the first reads ``t`` and the shaft's columns (``theta_ref``,
or the heads) for the sampling interval and the fastest shaft rate, which set the block
(:func:`._reduce.plan_for`); the second reads every column of a group, checks it as
:func:`~encdesign.io.load_recording` would (the message names the file, the row group and the
column), and replaces it by its block means. The rows of a stretch that continues into the
next group (fewer than ``B`` after its last whole block) are carried over, so the blocks are
those of the in-memory reduction (:func:`._reduce.reduce_recording`) except that a reversal
exactly at a row-group boundary is not seen.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ...io._parquet import _to_numpy, is_parquet
from ...io._recording import KINDS as SPECS
from ...io._recording import Recording, read_toml, validate_columns, validate_meta
from ._reduce import (
    REDUCIBLE_KINDS,
    plan_for,
    shaft_of,
    signal_period_tests,
    step_stats,
    stretch_starts,
)
from ._settings import FinderSettings


def stream_reduce(
    path: str | os.PathLike,
    settings: FinderSettings,
    order_of: Callable[[str], tuple[int, bool]],
) -> tuple[Recording, dict] | None:
    """The reduced recording of the TOML file ``path`` and its ``reduced`` entry, read row
    group by row group; ``None`` when the record is not a Parquet table to reduce (then it is
    loaded whole, and any error in it is raised there). ``order_of(kind)``: the base's start
    order and whether it grows (:func:`._reduce.scan_orders_reached`)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    where = str(path)
    meta = validate_meta(read_toml(path), where)
    kind = meta["kind"]
    if kind not in REDUCIBLE_KINDS or not str(meta.get("data", "")).strip():
        return None
    data = path.parent / meta["data"]
    if not (data.is_file() and is_parquet(data)):
        return None
    try:
        pf = pq.ParquetFile(data)
    except (pa.ArrowException, OSError, ValueError):
        return None
    spec = SPECS[kind]
    names = list(pf.schema_arrow.names)
    heads = [f"h{k}" for k in range(len(meta.get("encoder", {}).get("head_angles_deg", [])))]
    if "t" not in names or not set(heads) <= set(names):
        return None
    dwhere = str(data)

    def read(g: int, cols: list[str]) -> dict[str, np.ndarray]:
        try:
            tab = pf.read_row_group(g, columns=cols)
        except (pa.ArrowException, OSError, ValueError) as exc:
            from ..._errors import input_error

            raise input_error(
                f"{dwhere}, row group {g}",
                f"cannot be decoded, truncated or corrupt ({exc})",
                "a whole Parquet file",
            ) from None
        out = {}
        for h in cols:
            c = tab.column(h)
            c = c.combine_chunks() if c.num_chunks != 1 else c.chunk(0)
            typ = "U" if h in spec.string_columns else "i" if h in spec.int_columns else "f"
            out[h] = _to_numpy(dwhere, g, h, c, typ)
        return out

    G = pf.num_row_groups
    shaft_cols = ["theta_ref"] if "theta_ref" in names else heads

    def steps() -> tuple[float, float]:
        stats = []
        for g in range(G):
            part = read(g, ["t", *shaft_cols])
            stats.append(step_stats(part["t"], shaft_of(part, heads)))
        dt = float(np.nanmedian([d for d, _ in stats]))
        rates = [r for _, r in stats if np.isfinite(r)]
        return dt, (float(np.max(rates)) / dt / (2 * math.pi) if rates else 0.0)

    order0, grows = order_of(kind)
    info = plan_for(kind, pf.metadata.num_rows, order0, grows, settings, steps)
    if not info["applied"]:
        return None
    B, dt = int(info["block_rows"]), float(info["dt_s"])
    angles = [*heads, "theta_ref"] if "theta_ref" in names else heads
    # the reduced columns allocated once (at most N // B blocks; pages never written are
    # never resident): pieces kept per group would interleave with each group's temporaries
    # and fragment the heap, so the peak grew with the rows (2.2 GB at 10^8 rows)
    n_max = int(pf.metadata.num_rows) // B
    out: dict[str, np.ndarray] = {}
    at = 0
    carry: dict[str, np.ndarray] | None = None
    left = stretches = 0
    for g in range(G):
        cols = validate_columns(f"{dwhere}, row group {g}", kind, meta, read(g, names))
        if carry is not None:
            cols = {h: np.concatenate([carry[h], cols[h]]) for h in names}
        m = len(cols["t"])
        st = stretch_starts(cols, angles, shaft_of(cols, heads), dt)
        stretches += int(st.sum()) - (carry is not None)
        idx = np.flatnonzero(st)
        ends = np.append(idx[1:], m)
        full = (ends - idx) // B
        carry = None
        if g < G - 1:  # the last stretch may go on in the next group
            cut = int(idx[-1] + full[-1] * B)
            carry = {h: cols[h][cut:].copy() for h in names}
            ends[-1] = cut
        left += int(np.sum(ends - idx - full * B))
        sel = [np.arange(i, i + k * B) for i, k in zip(idx, full) if k]
        rows = np.concatenate(sel) if sel else np.zeros(0, np.int64)
        k = rows.size // B
        for h in names:
            v = cols[h][rows]
            if h not in out:
                out[h] = np.empty(n_max, v.dtype)
            out[h][at : at + k] = v[::B] if h == "run" else v.reshape(-1, B).mean(1)
        at += k
        del cols
    out = {h: out[h][:at] if h in out else np.zeros(0) for h in names}
    info.update(
        reduced_rows=int(at),
        rows_left_out=left,
        stretches=stretches,
        streamed_row_groups=G,
    )
    meta = signal_period_tests(meta, info)
    return Recording(kind, meta, out, path=path), info
