"""Stages split over processes by work items (issue 43): a selection round's trial fits,
the detection bounds' probes and the views of a residual, each process its share, the
results gathered.

Row passes (:mod:`._rowshare`) split the rows of every fit over the processes; what is left
of the trial fits and of the bounds (the residuals, the views that scan them, the starts,
the probes' own refits and bisections) runs whole on every process. These items are
independent of each other, so :func:`deal` hands them out instead: each process works on its
share of the items alone (every row pass of its items sums all rows on that process,
:func:`._rowshare.alone`, in the same groups and order as a split pass: the same sums), and
the results are gathered through ``jax.distributed`` in the items' order, so every process
continues with the results one process computes, to the last bit.

An item's work must not leave state behind that a later stage reads (a fitter's caches
differ between processes afterwards, and a pass one process makes from its cache another
would make over the rows, with a collective the first never joins):
:func:`._dealt_fits.private` gives the work a fitter of its own, its caches copied from the
shared one, and :func:`._dealt_fits.pack_fit` readies a fit to travel.
"""

from __future__ import annotations

import pickle
from collections.abc import Callable, Sequence
from typing import TypeVar

import jax

from ..._distributed import allgather_bytes
from ._rowshare import alone, is_alone

_T = TypeVar("_T")
_R = TypeVar("_R")


def shares(weights: Sequence[float], n_processes: int) -> list[list[int]]:
    """The items (indices, ascending) of each process: the heaviest item first to the least
    loaded process (ties: the lower index), the same on every process."""
    load = [0.0] * n_processes
    out: list[list[int]] = [[] for _ in range(n_processes)]
    for i in sorted(range(len(weights)), key=lambda j: (-float(weights[j]), j)):
        p = min(range(n_processes), key=lambda q: (load[q], q))
        out[p].append(i)
        load[p] += float(weights[i])
    return [sorted(o) for o in out]


def deal(
    items: Sequence[_T],
    work: Callable[[list[_T]], list[_R]],
    weight: Callable[[_T], float] | None = None,
) -> list[_R]:
    """``work(items)`` (one result per item, in order), each process working on its share
    of the items (:func:`shares` by ``weight``, 1 each by default) alone and the results
    gathered (picklable). An exception on any process is raised on every process (the first
    in process order; its message when it does not pickle). Fewer items than processes
    (one on two: a round with one candidate) are not dealt: every process then works on all
    of them, each row pass split over the processes as everywhere else; nor are items met
    inside a share of items (a process alone works on all of them)."""
    items = list(items)
    n = jax.process_count()
    if len(items) < n or is_alone():  # too few to deal (all of them on every process, row
        return list(work(items))  # passes split), or inside a share of items dealt already
    mine = shares([1.0 if weight is None else weight(x) for x in items], n)[jax.process_index()]
    try:
        with alone():
            got = list(work([items[i] for i in mine]))
        if len(got) != len(mine):
            raise ValueError(f"deal: {len(got)} results for {len(mine)} items")
        msg = pickle.dumps((None, list(zip(mine, got))), protocol=pickle.HIGHEST_PROTOCOL)
    except Exception as exc:  # every process must reach the gather, or the others wait
        try:
            msg = pickle.dumps((exc, None), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:
            msg = pickle.dumps((RuntimeError(repr(exc)), None))
    out: list = [None] * len(items)
    errors = []
    for blob in allgather_bytes(msg):
        err, pairs = pickle.loads(blob)
        if err is not None:
            errors.append(err)
            continue
        for i, r in pairs:
            out[i] = r
    if errors:
        raise errors[0]
    return out


__all__ = ["deal", "shares"]
