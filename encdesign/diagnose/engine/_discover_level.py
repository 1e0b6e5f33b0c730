"""Discovery's thresholds at the noise level without the term being tested (issue 41,
session 23; split from :mod:`._discover` for the module size).

Where the kind's noise hook estimated a level from the data that a structure can inflate and
says what the level would be without given columns (the SDS run means:
``noise_info.level_factor``, :mod:`..kinds.sds._sds_level_out`), each library term's test
is read against the level without the term's own columns: its chi-square drop, whitened
with the record's level, is multiplied by ``(sigma / sigma')^2``, which is the same as
dividing its threshold by that factor. The term's columns are rebuilt on the kept rows from
its line's full block (:func:`._discover.accumulate`'s columns, restricted by the term's
``H``). Other kinds have no such hook: their thresholds are unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ._discover_law import Sums, Term
from ._discover_lines import Line, phase_basis, tau_of


def term_columns(prep, line: Line, sums: Sums, li: int, tm: Term) -> np.ndarray | None:
    """``(n_kept, C, q)``: the term's columns on the kept rows (unwhitened, before the
    projection on the head differences), or ``None`` where the line has more than one cell
    (not built: only SDS records, one cell, have a level hook)."""
    nb, S, C, nj = sums.layout[li]
    if S != 1:
        return None
    keep = np.asarray(prep.keep, bool)
    th = np.asarray(prep.rows["theta"], float)[keep]
    t = np.asarray(prep.rows["t"], float)[keep]
    tau = tau_of(prep)[keep]
    sc = sums.scales
    B = phase_basis(line, th, t)  # (n, nj)
    mods = []
    for name in sums.blocks:
        if name == "static":
            mods.append(np.ones(th.size))
        elif name == "growth":
            mods.append((tau - sc["tau_mid_s"]) / sc["tau_half_s"])
        elif name == "temperature":
            dr = np.asarray(prep.rows["driver"], float)[keep]
            mods.append((dr - sc["driver_mid"]) / sc["driver_half"])
        else:  # step: on from the term's own change time
            on = tau >= tm.step["tau_s"] if tm.step is not None else np.zeros(th.size, bool)
            mods.append(on.astype(float))
    F = np.zeros((th.size, C, nb * C * nj))
    for bl in range(nb):
        for c in range(C):
            for j in range(nj):
                F[:, c, (bl * C + c) * nj + j] = B[:, j] * mods[bl]
    return F @ tm.H


def level_thresholds(
    prep, lines: Sequence[Line], sums: Sums, lib: Sequence[Term], thresh: np.ndarray
) -> np.ndarray:
    """Each term's threshold over the factor of the level without its columns (module doc);
    ``thresh`` unchanged where the kind has no level hook."""
    factor = getattr(getattr(prep.ctx, "noise_info", None), "level_factor", None)
    if factor is None:
        return thresh
    M = int(np.asarray(prep.consts["psi_m"]).size)
    out = np.array(thresh, float)
    for i, tm in enumerate(lib):
        cols = term_columns(prep, lines[tm.line], sums, tm.line, tm)
        if cols is not None:
            out[i] = thresh[i] / factor(cols[:, :M])
    return out
