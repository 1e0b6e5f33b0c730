"""Whole-record evaluation of a jitted row function in bucketed lengths.

A kind's start or applies code that evaluates a term function on every kept row would, run
eagerly, compile one small XLA program per operation for each new record length (some
0.05-0.3 s of CPU each, dozens per diagnosis). :func:`eval_rows` evaluates one jitted
function instead, on rows padded to a few lengths (:func:`encdesign._distributed.bucket`,
at most :data:`CHUNK_ROWS` rows a call): records of about the same length share a program.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import numpy as np

from ..._distributed import bucket
from ._constants import CHUNK_ROWS


def eval_rows(fn: Callable, p: dict, x: dict, consts: dict | None = None):
    """``fn(p, x | consts)`` (a ``jax.jit``-ed function of parameters and row columns, its
    outputs a pytree of arrays with one row per input row) on all rows of ``x``, as NumPy
    arrays: in calls of at most :data:`CHUNK_ROWS` rows, the last rows repeated up to a
    bucketed length (their values dropped). Every column of ``x`` has the rows along its
    first axis; ``consts`` (not per row) go to every call whole."""
    x = {k: np.asarray(v) for k, v in x.items()}
    n = len(next(iter(x.values())))
    size = bucket(n) if n <= CHUNK_ROWS else CHUNK_ROWS
    parts = []
    for a in range(0, n, size):
        b = min(n, a + size)
        pad = size - (b - a)
        xc = {
            k: np.concatenate([v[a:b], np.repeat(v[b - 1 : b], pad, axis=0)]) if pad else v[a:b]
            for k, v in x.items()
        }
        out = fn(p, {**xc, **(consts or {})})
        parts.append(jax.tree.map(lambda v, m=b - a: np.asarray(v)[:m], out))
    if len(parts) == 1:
        return parts[0]
    return jax.tree.map(lambda *vs: np.concatenate(vs, axis=0), *parts)
