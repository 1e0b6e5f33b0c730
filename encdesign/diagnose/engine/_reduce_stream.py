"""Issue 43: a long Parquet record reduced to block means as it is read, one row group at a
time (:mod:`._reduce` holds the rule; the whole table is never in memory), its row groups
split over the processes of a distributed run.

Each process takes a contiguous share of the row groups (:func:`~encdesign._distributed.
split_range`; all of them on one process) and makes two passes over its share only:

1. ``t`` and the shaft's columns (``theta_ref``, or the heads): each row group's median time
   step and fastest shaft step (:func:`._reduce.step_stats`). The groups' values are gathered
   in group order, so every process finds the same sampling interval and shaft rate, which
   set the block ``B`` (:func:`._reduce.plan_for`).
2. Every column of a group, checked as :func:`~encdesign.io.load_recording` would (the
   message names the file, the row group and the column), replaced by its block means. The
   blocks lie on the record's fixed grid of ``B`` rows, so a process knows its blocks without
   knowing where the stretch it starts in began; a block is kept when no row but its first
   starts a stretch (:func:`._reduce.stretch_starts`: a row's flag depends on it and the two
   rows before it). The rows of the block still open at a group's end, and the two rows
   before the next group, are carried into it.

The one block that straddles the start of a process's share, and the flags of the share's
first two rows, need the rows before the share: each process also keeps its share's first
and last ``B + 2`` rows, these edges are gathered (one small collective), and the process
that holds a straddling block's last row computes it from the same rows in the same way as
one process would. The reduced rows of all processes are then gathered in process order
(column by column, :data:`~encdesign._distributed.GATHER_ROWS` rows per process at a time),
so every process continues with the same reduced record, bit
for bit the record one process reduces (the block means are computed by
:func:`._reduce.block_means`, whose result for a block does not depend on its neighbours).
A bad row group on any process stops every process with its message. Memory per process:
one row group, its share of the reduced rows, then the whole reduced record.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import jax
import numpy as np

from ..._distributed import allgather_concat, allgather_objects, split_range
from ..._errors import EncdesignInputError
from ...io._parquet import _to_numpy, is_parquet
from ...io._recording import KINDS as SPECS
from ...io._recording import Recording, read_toml, validate_columns, validate_meta
from ._reduce import (
    REDUCIBLE_KINDS,
    block_means,
    full_blocks,
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
    grown: bool = False,
) -> tuple[Recording, dict] | None:
    """The reduced recording of the TOML file ``path`` and its ``reduced`` entry, read row
    group by row group; ``None`` when the record is not a Parquet table to reduce (then it is
    loaded whole, and any error in it is raised there). ``order_of(kind)``: the base's start
    order and whether it grows (:func:`._reduce.scan_orders_reached`); ``grown``: the block
    planned for every order the base can grow to (:func:`._reduce.plan_for`, a restart). The
    entry keeps the file's path (``_source``, removed before the document) for a restart."""
    import pyarrow as pa

    got = _read_reduced(path, settings, order_of, grown)
    # the row groups' buffers are freed, but pyarrow's pool keeps their pages (about 0.1 GB
    # for 2^20-row groups, held through the whole diagnosis): back to the system once the
    # reading is done and its file closed (issue 43, peak memory)
    pa.default_memory_pool().release_unused()
    return got


def _read_reduced(
    path: str | os.PathLike,
    settings: FinderSettings,
    order_of: Callable[[str], tuple[int, bool]],
    grown: bool = False,
) -> tuple[Recording, dict] | None:
    """:func:`stream_reduce`'s reading and reduction."""
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
    offsets = np.concatenate(
        [[0], np.cumsum([pf.metadata.row_group(g).num_rows for g in range(G)])]
    )
    g0, g1 = split_range(G, jax.process_count(), jax.process_index())
    shaft_cols = ["theta_ref"] if "theta_ref" in names else heads

    def steps() -> tuple[float, float]:
        def mine() -> list[list[float]]:
            out = []
            for g in range(g0, g1):
                part = read(g, ["t", *shaft_cols])
                out.append(list(step_stats(part["t"], shaft_of(part, heads))))
            return out

        stats = [r for share in _agreed(mine) for r in share]  # group order
        dt = float(np.nanmedian([d for d, _ in stats]))
        rates = [r for _, r in stats if np.isfinite(r)]
        return dt, (float(np.max(rates)) / dt / (2 * math.pi) if rates else 0.0)

    order0, grows = order_of(kind)
    info = plan_for(kind, pf.metadata.num_rows, order0, grows, settings, steps, grown)
    if not info["applied"]:
        return None
    B, dt = int(info["block_rows"]), float(info["dt_s"])
    angles = [*heads, "theta_ref"] if "theta_ref" in names else heads

    def flags(cols: dict[str, np.ndarray]) -> np.ndarray:
        return stretch_starts(cols, angles, shaft_of(cols, heads), dt)

    def group(g: int) -> dict[str, np.ndarray]:
        return validate_columns(f"{dwhere}, row group {g}", kind, meta, read(g, names))

    types = {h: np.int64 if h in spec.int_columns else np.float64 for h in names}
    share = _Share(types, B, int(offsets[g0]), int(offsets[g1]))
    edges = _agreed(lambda: share.run(group, range(g0, g1), offsets, flags))
    share.finish(edges[: jax.process_index()], flags)
    counts = allgather_objects([[share.n_blocks, share.n_starts]])
    out = {h: allgather_concat(share.take(h), [c for c, _ in counts]) for h in names}
    n_blocks = sum(c for c, _ in counts)
    info.update(
        reduced_rows=int(n_blocks),
        rows_left_out=int(pf.metadata.num_rows - n_blocks * B),
        stretches=int(sum(s for _, s in counts)),
        streamed_row_groups=G,
    )
    meta = signal_period_tests(meta, info)
    info["_source"] = str(path)
    return Recording(kind, meta, out, path=path), info


_T = TypeVar("_T")


def _agreed(work: Callable[[], _T]) -> list[_T]:
    """Every process's ``work()`` (JSON-able), in process order; when it raised an input error
    on any process, every process raises the first one's message (so none waits forever)."""
    try:
        got, err = work(), None
    except EncdesignInputError as exc:
        if jax.process_count() == 1:
            raise
        got, err = None, str(exc)
    every = allgather_objects([[err, got]])
    errs = [e for e, _ in every if e is not None]
    if errs:
        raise EncdesignInputError(errs[0])
    return [g for _, g in every]


Columns = dict[str, np.ndarray]


class _Share:
    """One process's share of the rows, ``[lo, hi)``, reduced to the means of the grid
    blocks whose last row is in it (:func:`stream_reduce`, pass 2); ``types``: the columns
    and their dtypes."""

    def __init__(self, types: dict[str, type], B: int, lo: int, hi: int):
        self.names, self.B, self.lo, self.hi = list(types), B, lo, hi
        self.n_starts = 0  # rows of the share that start a stretch
        # slot 0: the block that straddles lo (finish); allocated once (pages never
        # written are never resident)
        self.out = {h: np.empty(max(hi - lo, 0) // B + 2, t) for h, t in types.items()}
        self.at = 1
        self.head: Columns = {}  # the share's first B + 2 rows
        self.edge: Columns = {}  # and its last B + 2 rows

    def _put(self, cols: Columns, full: np.ndarray, at: int) -> None:
        for h in self.names:
            v = block_means(cols[h], self.B, full, h == "run")
            self.out[h][at : at + v.size] = v

    def run(
        self,
        group: Callable[[int], Columns],
        groups: range,
        offsets: np.ndarray,
        flags: Callable[[Columns], np.ndarray],
    ) -> dict[str, list]:
        """Pass 2 over the share's row groups (``group(g)``: its checked columns;
        ``flags(cols)``: the stretch starts of consecutive rows): the blocks that lie wholly
        after the share's first row; returns the share's last ``B + 2`` rows (its edge)."""
        B, lo, keep = self.B, self.lo, self.B + 2
        k = lo // B + 1  # the next block to close (block lo // B: finish)
        tail: Columns | None = None
        base = lo  # the row of the record that the tail's (else the group's) first row is
        for g in groups:
            part = group(g)
            gs, ge = int(offsets[g]), int(offsets[g + 1])
            for h in self.names:
                v = part[h][-keep:]
                if v.size < keep and h in self.edge:
                    v = np.concatenate([self.edge[h], v])[-keep:]
                self.edge[h] = v.copy()
                if gs - lo < keep:
                    old = self.head.get(h, part[h][:0])
                    self.head[h] = np.concatenate([old, part[h][: keep - old.size]])
            # the rows [base, ge) are the tail (rows carried from the group before, at most
            # B + 1) and then the group, never copied whole: ``rows`` joins a range across
            # the two, and a row's flag depends only on it and the two rows before it
            T = 0 if tail is None else gs - base
            rows = _Joined(tail, part, T)
            st = rows.flags(flags)  # exact from row lo + 2 on (two rows before each)
            first = max(gs, lo + 2)
            if first < ge:
                self.n_starts += int(st[first - base :].sum())
            k_end = ge // B  # blocks k < k_end end in rows read so far
            if k_end > k:
                a, b = k * B - base, k_end * B - base
                full = full_blocks(st[a:b], B)
                # a block that starts in the tail on its own, the others views of the group
                m = B if a < T else b - a
                self._put(rows.take(self.names, a, a + m), full[: m // B], self.at)
                self.at += int(full[: m // B].sum())
                if m < b - a:
                    self._put(rows.take(self.names, a + m, b), full[m // B :], self.at)
                    self.at += int(full[m // B :].sum())
                k = k_end
            # the open block and the row before it (its second row's flag needs two rows
            # before it), and the group's last two rows (the next group's first rows' flags)
            cut = max(base, min(k * B - 1, ge - 2))
            tail = {h: v.copy() for h, v in rows.take(self.names, cut - base, ge - base).items()}
            base = cut
            del part, rows, st
        return {h: v.tolist() for h, v in self.edge.items()}

    def finish(self, before: list[dict[str, list]], flags: Callable[[Columns], np.ndarray]) -> None:
        """The block that straddles the share's first row (when its last row is in the
        share) and the flags of the share's first two rows, from ``before``: the edges of
        the processes before this one, in order."""
        B, lo, hi = self.B, self.lo, self.hi
        kd, kept = lo // B, False
        if hi > lo:
            w0 = max(0, kd * B - 2)  # the rows from two before the block on
            w = {}
            for h in self.names:
                mine = self.head[h]
                prev = [np.asarray(e[h], mine.dtype) for e in before if e]
                prev = np.concatenate(prev) if prev else mine[:0]
                w[h] = np.concatenate([prev[prev.size - (lo - w0) :], mine])
            st = flags(w)  # exact from row w0 + 2 on, and from the record's first row
            self.n_starts += int(st[lo - w0 : min(lo + 2, hi) - w0].sum())
            if (kd + 1) * B <= hi:  # its last row is in the share
                a = kd * B - w0
                full = full_blocks(st[a : a + B], B)
                self._put({h: w[h][a : a + B] for h in self.names}, full, 0)
                kept = bool(full[0])
        if not kept:
            self.out = {h: v[1:] for h, v in self.out.items()}
            self.at -= 1

    @property
    def n_blocks(self) -> int:
        return self.at

    def take(self, h: str) -> np.ndarray:
        """The share's block means of column ``h`` (released from the share)."""
        return self.out.pop(h)[: self.at]


class _Joined:
    """Rows ``tail`` then ``part`` (``T`` rows of ``tail``; ``tail`` ``None`` when ``T`` is
    0) seen as one table without joining the columns: :meth:`take` gives views of ``part``
    where a range lies in it and joins only a range that crosses from ``tail`` into it."""

    def __init__(self, tail: Columns | None, part: Columns, T: int):
        self.tail, self.part, self.T = tail, part, T

    def take(self, names: list[str], a: int, b: int) -> Columns:
        """Rows ``[a, b)`` of every column ``names``."""
        T, tail, part = self.T, self.tail, self.part
        if a >= T or tail is None:
            return {h: part[h][a - T : b - T] for h in names}
        if b <= T:
            return {h: tail[h][a:b] for h in names}
        return {h: np.concatenate([tail[h][a:], part[h][: b - T]]) for h in names}

    def flags(self, flags: Callable[[Columns], np.ndarray]) -> np.ndarray:
        """``flags`` of all the rows, as on the joined table: the group's own from its third
        row on, the tail's and the group's first two from the tail and those two rows (a
        row's flag depends on it and the two rows before it)."""
        T, part = self.T, self.part
        n = len(next(iter(part.values())))
        if self.tail is None or T == 0:
            return flags(part)
        if n < 2:
            names = list(part)
            return flags(self.take(names, 0, T + n))
        edge = flags(self.take(list(part), 0, T + 2))
        own = flags(part)
        return np.concatenate([edge, own[2:]])
