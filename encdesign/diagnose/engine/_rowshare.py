"""Row passes split over processes: the chunks in fixed groups, the groups' sums gathered.

A pass that accumulates sums over the rows (the fit's per-fold normal equations, the
column statistics of :meth:`Fitter.column_chi2`) cuts its chunks into at most
:data:`ROW_GROUPS` contiguous groups. Each process sums the chunks of its share of the
groups (:func:`~encdesign._distributed.split_range`), group by group; the groups' sums
are gathered on every process (one all-gather through ``jax.distributed``) and added in
group order. The grouping does not depend on the number of processes, so one process and
N give the same sums to the last bit, and every process continues with the same numbers.

Inside :func:`alone` (a stage split over processes by work items, :mod:`._workshare`) a
process sums every group itself, in the same order, and gathers nothing: the same sums
again, while the other processes work on other items.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

import jax
import numpy as np

from ..._distributed import allgather_rows, split_range

ROW_GROUPS = 16
"""Most groups a pass's chunks are cut into: the unit of work split over processes (more
processes than groups leave some idle) and the number of partial sums held at once."""


_ALONE: list[bool] = []
"""One entry per :func:`alone` block entered (module state: one diagnosis per process)."""


@contextmanager
def alone() -> Iterator[None]:
    """Row passes made inside sum all of the groups on this process and gather nothing."""
    _ALONE.append(True)
    try:
        yield
    finally:
        _ALONE.pop()


def is_alone() -> bool:
    """Whether this process works alone now (inside :func:`alone`)."""
    return bool(_ALONE)


def _parts() -> tuple[int, int]:
    """``(process count, this process's index)`` of the row passes (one alone)."""
    return (1, 0) if _ALONE else (jax.process_count(), jax.process_index())


def row_groups(n_chunks: int) -> list[tuple[int, int]]:
    """Chunk index ranges ``[lo, hi)`` of the groups of a pass over ``n_chunks`` chunks."""
    g = max(1, min(int(n_chunks), ROW_GROUPS))
    return [(j * n_chunks // g, (j + 1) * n_chunks // g) for j in range(g)]


def my_groups(n_groups: int) -> range:
    """The groups this process sums (a contiguous share; all of them on one process)."""
    lo, hi = split_range(n_groups, *_parts())
    return range(lo, hi)


def gathered_groups(parts: Sequence[np.ndarray], n_groups: int, size: int) -> np.ndarray:
    """``(n_groups, size)``: the flat per-group values ``parts`` of every process (this
    process's groups, in order, each of ``size`` values), in group order on every process."""
    rows = np.stack(parts) if len(parts) else np.zeros((0, size))
    return rows if _ALONE else allgather_rows(rows, n_groups)


def reduce_groups(parts: Sequence[np.ndarray], n_groups: int, size: int) -> np.ndarray:
    """Sum over all groups of the flat per-group sums ``parts`` (this process's groups, in
    order, each of ``size`` values), the same on every process and for any process count."""
    every = gathered_groups(parts, n_groups, size)
    total = np.zeros(size)
    for r in every:  # group order, one addition at a time: the same on one process
        total += r
    return total


def summed_items(n_items: int, zeros: Sequence[np.ndarray], add: Callable) -> list[np.ndarray]:
    """Sums over ``n_items`` work items (blocks of rows in a fixed order, whatever the
    number of processes) of arrays shaped as ``zeros``: ``add(sums, i)`` adds item ``i`` to
    ``sums`` in place. The items are cut into groups as a pass's chunks are
    (:func:`row_groups`), this process sums its groups' items and the groups' sums are
    reduced as :func:`reduce_groups` reduces them (the same on every process and for any
    process count)."""
    groups = row_groups(n_items)
    parts = []
    for grp in my_groups(len(groups)):
        sums = [np.zeros_like(z) for z in zeros]
        for i in range(*groups[grp]):
            add(sums, i)
        parts.append(np.concatenate([v.ravel() for v in sums]) if sums else np.zeros(0))
    total = reduce_groups(parts, len(groups), sum(int(z.size) for z in zeros))
    return unflatten(total, [z.shape for z in zeros])


def summed(fitter, zeros: Sequence[np.ndarray], add: Callable) -> list[np.ndarray]:
    """Sums over the rows of arrays shaped as ``zeros``: ``add(sums, a, b, x)`` adds chunk
    ``a:b`` (``x``: its row columns) to ``sums`` in place, for the chunks of ``fitter`` in
    the groups of this process; the groups' sums are reduced as :func:`reduce_groups`
    reduces them (the same on every process and for any process count)."""
    groups = row_groups(fitter.n_chunks())
    parts = []
    for grp in my_groups(len(groups)):
        sums = [np.zeros_like(z) for z in zeros]
        for a, b, x in fitter.chunks(*groups[grp]):
            add(sums, a, b, x)
        parts.append(np.concatenate([v.ravel() for v in sums]) if sums else np.zeros(0))
    total = reduce_groups(parts, len(groups), sum(int(z.size) for z in zeros))
    return unflatten(total, [z.shape for z in zeros])


def unflatten(flat: np.ndarray, shapes: Sequence[tuple[int, ...]]) -> list[np.ndarray]:
    """``flat`` cut into arrays of ``shapes`` (the inverse of concatenating their ravels)."""
    out, at = [], 0
    for s in shapes:
        k = int(np.prod(s, dtype=np.int64))
        out.append(flat[at : at + k].reshape(s).copy())
        at += k
    return out
