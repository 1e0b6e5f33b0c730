"""Each candidate's home process (issue 43): where its programs are compiled and run.

On several processes a candidate's trial fit, its term RMS (:mod:`._select`) and its
detection bounds' probes (:mod:`._bounds`) run on one process, the candidate's *home*, and
their results are gathered (:func:`._workshare.deal` with ``home``): its programs (its
Jacobian, its value, its linear part) are compiled there only. Compiling them was most of
the candidates stage on every process (about 1.2 s of XLA compilation at 10^7 rows,
session 34), and dealing the trial fits alone moved that compilation into the later stages
on the other processes. What still needs a candidate's programs on every process is what
the selection does with the candidate it names (its refit, its residual and the rules on
it), and the rules that compare two candidates' fits (``tie_gap``), met only when two
candidates come close.

The homes are dealt by the size of each candidate's Jacobian program (the equations of its
traced ``jaxpr``, sub-programs included: what XLA compiles), the largest first to the least
loaded process (:func:`._workshare.shares`), over the candidates that apply to the record,
the same on every process and in every stage. One process is every candidate's home.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.extend.core as jcore
import numpy as np

from ._candidates import Candidate
from ._fit import valjac_fn
from ._protocol import Prepared
from ._workshare import shares


def _eqns(jaxpr: jcore.Jaxpr) -> int:
    """Equations of ``jaxpr``, those of its sub-programs included."""
    return len(jaxpr.eqns) + sum(_eqns(sub) for sub in jcore.subjaxprs(jaxpr))


@functools.lru_cache(maxsize=256)
def _program_size(cand: Candidate, params: tuple, rows: tuple) -> int:
    """Equations of the traced Jacobian program of ``cand`` (:func:`._fit.valjac_fn`) at
    the parameter shapes ``params`` and row-column shapes ``rows`` (``(name, shape,
    dtype)`` each)."""
    p = {k: jax.ShapeDtypeStruct(s, np.float64) for k, s in params}
    x = {k: jax.ShapeDtypeStruct(s, np.dtype(d)) for k, s, d in rows}
    return _eqns(jax.make_jaxpr(valjac_fn(cand))(p, x).jaxpr)


def program_size(cand: Candidate, prep: Prepared, chunk: int) -> int:
    """The size of ``cand``'s Jacobian program on chunks of ``chunk`` rows of ``prep`` (its
    weight in the deal of homes)."""
    C, R = prep.n_channels, prep.ctx.n_runs
    params = tuple(sorted(cand.shapes(C, R).items()))
    rows = []
    for k in prep.rows.names():
        col = np.asarray(prep.rows.column(k, 0, 1))
        rows.append((k, (chunk, *col.shape[1:]), col.dtype.str))
    for k, v in prep.consts.items():
        if isinstance(v, np.ndarray):
            rows.append((k, v.shape, v.dtype.str))
    return _program_size(cand, params, tuple(sorted(rows)))


def homes(prep: Prepared, chunk: int, candidates: Sequence[Candidate]) -> dict[str, int]:
    """Candidate name -> its home process (module doc); every one 0 on one process."""
    n = jax.process_count()
    if n == 1:
        return {c.name: 0 for c in candidates}
    weights = [float(program_size(c, prep, chunk)) for c in candidates]
    out: dict[str, int] = {}
    for p, mine in enumerate(shares(weights, n)):
        out.update({candidates[i].name: p for i in mine})
    return out


__all__ = ["homes", "program_size"]
