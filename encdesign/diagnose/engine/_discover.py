"""Discovery after the catalog: model located structure no catalog effect explains (issue 41).

For each located line (an integer or fractional shaft order, a fixed frequency in Hz, order 0
for offsets that drift, step or follow the direction), candidate terms are built from a
generic library organised by **frame** and **modulation**:

* frames: ``disk`` (the order seen by every head with the phase ``m psi_k`` of its azimuth),
  ``shaft`` (one phase on every head: a motion of the shaft or of the reference),
  ``head <k>`` (one head only), ``hz`` (a fixed frequency: its own phase in every cell);
  on an SDS record (rows: runs, one platform angle each; only the moving sensors' run-mean
  channels carry a term) ``platform`` (an order of the platform angle, one phase on every
  moving sensor; not identifiable without ``phi_ref``), ``azimuth`` (an order of
  ``phi + psi_m``: every moving sensor with the phase ``m psi_m`` of its azimuth) and
  ``sensor m<k>`` (one moving sensor only: an error in the frame of that sensor);
* modulations (per *cell*: rows of one run, one direction and one steady speed):
  ``static``, ``speed`` (amplitude ``(|omega| / omega_0)^beta``, the exponent fitted with a
  standard error), ``direction`` (opposite sign in the two directions), ``forward`` /
  ``reverse`` (one direction only), ``cell <i>`` (one run only), ``per_cell`` (each run its
  own amplitude and phase), ``ringing`` (a fixed-Hz line only: each run its own amplitude
  and phase and their own linear change within the run), ``ringdown`` (a fixed-Hz line
  only: each run its own amplitude and phase times ``exp(-t_in_run / T)``, one decay time
  ``T`` shared by the runs, fitted with a standard error, at the mode's own frequency
  within a bin of the located one: a mode rung at the start of every run and decaying at its
  own ``Q = pi f T``; :mod:`._discover_ring`), ``growth`` (amplitude linear in the time
  across runs, with its own level where the catalog model leaves it:
  :mod:`._discover_growth`),
  ``temperature`` (linear in ``temp_c``), ``step`` (the amplitude switches on at one change
  time: the best of the times the finder's views located (``time``, ``order_step``,
  ``run_step``) and :data:`STEP_BINS` change points over the kept rows, scanned per line on
  the residual; the scan is counted in the multiple-testing threshold).

Every term is a linear (``speed``: nonlinear in ``beta`` only; ``ringdown``: in ``T`` and its
frequency, fitted before the sums) restriction of one *full*
block per line: cos/sin of the line's phase, per cell and channel, times the within-cell
modulations (1, time, temperature). One pass over the rows accumulates per held-out fold the
Gram matrix of those columns, their products with the whitened residual and with the
Jacobian of the final catalog model; the columns are then made orthogonal to that Jacobian
(Frisch-Waugh: a discovered term is fitted jointly with the catalog model, never taking what
it already explains), and every term's fit, held-out gain and inclusion are computed from
those sums without another pass.

Selection is **orthogonal forward regression**: at each step the term with the largest
in-sample chi-square drop less its multiple-testing threshold
``chi2.isf(settings.discover_alpha / N, q)``
(``N`` terms in the library, ``q`` parameters: Bonferroni, which also prefers the smaller of
two nested terms; where the library holds step terms, half of ``alpha`` goes to them, each
counted once per change point scanned, and half to the others) enters when that margin is
positive and its K-fold held-out gain (fitted without each fold, scored on it) is positive.
The same selection repeated without each fold in turn gives each term's inclusion
probability; a term enters only when it is at least ``settings.discover_inclusion_min``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ._discover_export import discovered_candidate, nonlinear_start
from ._discover_growth import best_at_place, growth_term, same_place
from ._discover_law import (
    Sums,
    Term,
    _embed,
    _fit_beta,
    _gain,
    _heldout,
    _psolve,
    _same_span,
    _scatter_se,
    _sibling,
    _tie_pick,
    one_structure,
    taken_by,
)
from ._discover_level import level_thresholds
from ._discover_lines import (
    MAX_LINES,
    STEP_EXACT_ROWS,
    Line,
    alias_neighbours,
    cells,
    drive_neighbours,
    frame_maps,
    hmap,
    lines_of,
    locate_steps,
    phase_basis,
    sds_channels,
    step_json,
    step_words,
    tau_of,
    thresholds,
)
from ._discover_ring import locate_ringdowns, ring_columns, ring_json, run_starts
from ._discover_words import reading
from ._fit import make_term
from ._settings import FinderSettings

MAX_TERMS = 4
"""Terms the forward selection may add over all lines."""

_NOT_LOCATED = (
    "the drive order next to a located line.",
    "an order the located line may be an alias of on the record's platform positions.",
)
MAX_CELLS = 12
"""Cells (run x direction x speed) beyond which the cell modulations are left out."""


# ----------------------------------------------------------------------------- sums


def _jac_chunk(prep, fitter, terms: Sequence[Any], a: int, b: int, x: dict) -> np.ndarray:
    """The final catalog model's Jacobian on rows ``a:b`` (rows, C, p), projected like the
    data and whitened."""
    Js = [fitter.eval_term(tm, a, b, x, jac=True)[1] for tm in terms]
    J = np.concatenate(Js, axis=2) if Js else np.zeros((b - a, prep.n_channels, 0))
    if prep.kd.project:
        J = J - J.mean(1, keepdims=True)
    return J / np.asarray(prep.sigma, float)[None, :, None]


def _jacobian(prep, fitter, terms: Sequence[Any]) -> np.ndarray:
    """:func:`_jac_chunk` on every row (n, C, p)."""
    parts = [_jac_chunk(prep, fitter, terms, a, b, x) for a, b, x in fitter.chunks()]
    return np.concatenate(parts, 0)


def accumulate(
    prep,
    fitter,
    terms: Sequence[Any],
    resid: np.ndarray,
    lines: Sequence[Line],
    cell,
    cinfo,
    steps: Sequence[dict | None] | None = None,
    jac: np.ndarray | None = None,
    rings: Sequence[dict | None] | None = None,
) -> Sums:
    """One pass over the rows: the per-fold sums of every line's full block (see module);
    ``steps``: per line its change time (:func:`locate_steps`), the ``step`` block;
    ``jac``: the catalog model's whitened Jacobian on every row (:func:`_jacobian`), else
    evaluated per chunk; ``rings``: per line its ring-down (:func:`locate_ringdowns`), the
    ``ringdown`` block."""
    K = prep.settings.n_folds
    C = prep.n_channels
    S = len(cinfo["speed"])
    sig = np.asarray(prep.sigma, float)
    has_temp = prep.ctx.driver_name != "time" and "driver" in prep.rows
    steps = list(steps) if steps is not None else [None] * len(lines)
    has_step = any(st is not None for st in steps)
    rings = list(rings) if rings is not None else [None] * len(lines)
    has_ring = any(rg is not None for rg in rings)
    blocks = (
        ["static", "growth"]
        + (["temperature"] if has_temp else [])
        + (["step"] if has_step else [])
        + (["ringdown"] if has_ring else [])
    )
    starts = run_starts(prep) if has_ring else np.zeros(0)
    nb = len(blocks)
    layout, slices, q0 = [], [], 0
    for ln in lines:
        nj = 1 if (ln.kind == "order" and ln.value == 0) else 2
        layout.append((nb, S, C, nj))
        size = nb * S * C * nj
        slices.append(slice(q0, q0 + size))
        q0 += size
    Q = q0
    U = sum(nb * lay[3] for lay in layout)  # compact columns (before cell x channel)
    tau_all = tau_of(prep)
    kept_tau = tau_all[prep.keep]
    tmid = float(np.mean(kept_tau)) if kept_tau.size else 0.0
    tsc = float(np.ptp(kept_tau)) / 2 or 1.0
    dmid, dsc = 0.0, 1.0
    if has_temp:
        dr = np.asarray(prep.rows["driver"], float)[prep.keep]
        dmid, dsc = float(np.mean(dr)), float(np.ptp(dr)) / 2 or 1.0
    scales = {"tau_mid_s": tmid, "tau_half_s": tsc, "driver_mid": dmid, "driver_half": dsc}
    G = np.zeros((K, S, U, U))
    XR = np.zeros((K, S, U, C))
    p = None
    JX = JJ = Jr = None
    rr = np.zeros(K)
    for a, b, x in fitter.chunks():
        kb = prep.keep[a:b]
        if not kb.any():
            continue
        J = (jac[a:b] if jac is not None else _jac_chunk(prep, fitter, terms, a, b, x))[kb]
        if p is None:
            p = J.shape[2]
            JX = np.zeros((K, p, S, U, C))
            JJ = np.zeros((K, p, p))
            Jr = np.zeros((K, p))
        th = np.asarray(x["theta"][: b - a], float)[kb]
        t = np.asarray(x["t"][: b - a], float)[kb]
        tau = t
        if "tau" in x:
            tau = np.asarray(x["tau"][: b - a], float)[kb]
        mods = [np.ones(th.size), (tau - tmid) / tsc]
        if has_temp:
            mods.append((np.asarray(x["driver"][: b - a], float)[kb] - dmid) / dsc)
        cols = []
        ru = np.asarray(prep.run[a:b])[kb] if has_ring else np.zeros(0, int)
        for ln, stp, rg in zip(lines, steps, rings):
            B = phase_basis(ln, th, t)
            for m in mods:
                cols.append(B * m[:, None])
            if has_step:
                on = tau >= stp["tau_s"] if stp is not None else np.zeros(th.size, bool)
                cols.append(B * on[:, None])
            if has_ring:
                cols.append(ring_columns(B, th, t, tau, ru, starts, rg))
        Xc = np.concatenate(cols, 1)  # (rows, U)
        rw = (resid[a:b] / sig[None, :])[kb]
        fo = prep.fold[a:b][kb]
        ce = cell[a:b][kb]
        for k in range(K):
            mk = fo == k
            if not mk.any():
                continue
            rr[k] += float(np.sum(rw[mk] ** 2))
            Jk = J[mk]
            JJ[k] += np.einsum("ncp,ncq->pq", Jk, Jk)
            Jr[k] += np.einsum("ncp,nc->p", Jk, rw[mk])
            for s in np.unique(ce[mk]):
                ms = mk & (ce == s)
                Xs = Xc[ms]
                G[k, s] += Xs.T @ Xs
                XR[k, s] += Xs.T @ rw[ms]
                JX[k, :, s] += np.einsum("ncp,nu->puc", J[ms], Xs)
    if p is None:
        raise ValueError("discovery: no kept rows")
    # full columns: (line, block, cell, channel, basis); compact u: (line, block, basis)
    A = np.zeros((K, Q, Q))
    bvec = np.zeros((K, Q))
    JXf = np.zeros((K, p, Q))
    comp = []  # per full column: (u, s, c)
    u0 = 0
    for nb_, S_, C_, nj in layout:
        for bl in range(nb_):
            for s in range(S_):
                for c in range(C_):
                    for j in range(nj):
                        comp.append((u0 + bl * nj + j, s, c))
        u0 += nb_ * nj
    comp_a = np.asarray(comp)
    uu, ss, cc = comp_a[:, 0], comp_a[:, 1], comp_a[:, 2]
    w = 1.0 / sig
    same_s = ss[:, None] == ss[None, :]
    # a column on channel c is projected as the data are, before whitening (no reference:
    # less the head mean; ``P``), then whitened: on channel c'' it is P[c'', c] x / sigma_c''.
    # Its Gram is x x' (P W^2 P)[c, c'], its products with the (already projected and
    # whitened) residual and Jacobian sum w P over the channels. Projecting after whitening
    # instead (W P W) leaves a term common to all heads a small norm where the heads' noise
    # levels differ (it has none) and fitted it at a non-physical size.
    P = np.eye(C) - (1.0 / C if prep.kd.project else 0.0)
    PW2P = P @ np.diag(w**2) @ P
    wP = w[:, None] * P  # (c'', c): w_c'' P[c'', c]
    for k in range(K):
        Gk = G[k][ss[:, None], uu[:, None], uu[None, :]]  # (Q, Q) on the same cell
        A[k] = np.where(same_s, Gk * PW2P[cc[:, None], cc[None, :]], 0.0)
        XRp = np.einsum("suc,cd->sud", XR[k], wP)
        bvec[k] = XRp[ss, uu, cc]
        JXp = np.einsum("psuc,cd->psud", JX[k], wP)
        JXf[k] = JXp[:, ss, uu, cc]
    # Frisch-Waugh: columns orthogonal to the catalog model's Jacobian (all folds' sums)
    JJt, JXt = JJ.sum(0), JXf.sum(0)
    P = _psolve(JJt, JXt)
    raw = A.copy()
    for k in range(K):
        A[k] = A[k] - JXf[k].T @ P - P.T @ JXf[k] + P.T @ JJ[k] @ P
        bvec[k] = bvec[k] - P.T @ Jr[k]
    return Sums(
        A=A, b=bvec, rr=rr, raw=raw, slices=slices, scales=scales, layout=layout, blocks=blocks
    )


# ----------------------------------------------------------------------------- library


def library(
    lines: Sequence[Line],
    sums: Sums,
    cinfo: dict,
    C: int,
    alpha,
    settings: FinderSettings,
    sds: tuple[int, np.ndarray, bool] | None = None,
    steps: Sequence[dict | None] | None = None,
    rings: Sequence[dict | None] | None = None,
) -> list[Term]:
    """Every (line, frame, modulation) term the record can test."""
    S = len(cinfo["speed"])
    sp, dr = cinfo["speed"], cinfo["direction"]
    steps = list(steps) if steps is not None else [None] * len(lines)
    out: list[Term] = []
    for li, ln in enumerate(lines):
        lay = sums.layout[li]
        per_cell_phase = ln.kind in ("hz", "frac")
        for fr, M in frame_maps(ln, C, alpha, sds).items():
            name = "hz" if ln.kind == "hz" and fr == "shaft" else fr
            if per_cell_phase:
                if S <= MAX_CELLS:
                    eye = np.eye(S)
                    out.append(Term(li, name, "per_cell", hmap(lay, 0, M, eye)))
                    if ln.kind == "hz":  # a mode's amplitude changing within every run
                        H = np.concatenate([hmap(lay, 0, M, eye), hmap(lay, 1, M, eye)], 1)
                        out.append(Term(li, name, "ringing", H))
                    if rings is not None and rings[li] is not None:  # rung, decaying
                        H = hmap(lay, sums.blocks.index("ringdown"), M, eye)
                        out.append(Term(li, name, "ringdown", H, decay=rings[li]))
                continue
            one = np.ones(S)
            out.append(Term(li, name, "static", hmap(lay, 0, M, one)))
            if S > 1 and np.ptp(np.log(np.maximum(sp, 1e-12))) > math.log(
                settings.discover_speed_ratio
            ):
                H0 = hmap(lay, 0, M, one)
                out.append(Term(li, name, "speed", H0, beta=0.0, H0=H0))
            if (dr > 0).any() and (dr < 0).any():
                out.append(Term(li, name, "direction", hmap(lay, 0, M, dr.astype(float))))
                out.append(Term(li, name, "forward", hmap(lay, 0, M, (dr > 0).astype(float))))
                out.append(Term(li, name, "reverse", hmap(lay, 0, M, (dr < 0).astype(float))))
            if 1 < S <= MAX_CELLS:
                for s in range(S):
                    out.append(
                        Term(li, name, f"cell {s}", hmap(lay, 0, M, (np.arange(S) == s) * 1.0))
                    )
                out.append(Term(li, name, "per_cell", hmap(lay, 0, M, np.eye(S))))
            out.append(growth_term(sums, li, name, M, level=sds is not None))
            if "temperature" in sums.blocks:
                out.append(Term(li, name, "temperature", hmap(lay, 2, M, one)))
            if steps[li] is not None:
                bl = sums.blocks.index("step")
                out.append(Term(li, name, "step", hmap(lay, bl, M, one), step=steps[li]))
    return out


# ----------------------------------------------------------------------------- fits


def _single_heldout(sums: Sums, tm: Term, folds) -> float:
    """Held-out gain of one term alone (on its line's columns only)."""
    sl = sums.slices[tm.line]
    return _heldout(sums.A[:, sl, sl], sums.b[:, sl], tm.H, folds, sums.raw[:, sl, sl])


def _forward(
    A: np.ndarray, b: np.ndarray, lib: Sequence[Term], sums: Sums, folds, thresh, me: float
) -> list[int]:
    """Orthogonal forward regression over the folds ``folds``: indices of the terms taken
    (each step: the largest chi-square drop beyond its threshold, given those taken, by the
    Schur complement, less ``me`` of it per parameter (``settings.discover_model_error``);
    taken when its K-fold held-out gain is positive)."""
    folds = list(folds)
    At, bt, Rt = A[folds].sum(0), b[folds].sum(0), sums.raw[folds].sum(0)
    D, e, Dr = [], [], []
    for tm in lib:
        sl = sums.slices[tm.line]
        D.append(tm.H.T @ At[sl, sl] @ tm.H)
        Dr.append(tm.H.T @ Rt[sl, sl] @ tm.H)
        e.append(tm.H.T @ bt[sl])
    chosen: list[int] = []
    Hc = np.zeros((At.shape[0], 0))
    ho_c = 0.0
    for _ in range(MAX_TERMS):
        AHc = At @ Hc
        Gc = Hc.T @ AHc
        Gr = Hc.T @ Rt @ Hc
        gc = Hc.T @ bt
        u = _psolve(Gc, gc, raw=Gr) if Hc.shape[1] else np.zeros(0)
        best, best_m = -1, 0.0
        for i, tm in enumerate(lib):
            if i in chosen:
                continue
            sl = sums.slices[tm.line]
            if Hc.shape[1]:
                X = tm.H.T @ AHc[sl]  # (q, qc)
                W = _psolve(Gc, X.T, raw=Gr)  # (qc, q)
                Dt = D[i] - X @ W
                et = e[i] - X @ u
            else:
                Dt, et = D[i], e[i]
            gi = _gain(Dt, et, Dr[i])
            q = tm.n_params
            if gi <= thresh[i]:
                continue
            m = gi * (1.0 - me * q) - thresh[i]
            if m > best_m:
                best, best_m = i, m
        if best < 0:
            break
        Hj = np.concatenate([Hc, _embed(sums, [lib[best]])], 1)
        if len(folds) > 1:
            ho = _heldout(A, b, Hj, folds, sums.raw)
            if ho <= ho_c:
                break
            ho_c = ho
        chosen.append(best)
        Hc = Hj
    return chosen


# ----------------------------------------------------------------------------- entry


@dataclasses.dataclass
class State:
    """What discovery built for one record: the located lines, each finding's line, the
    cells, the per-fold sums, the library (speed exponents fitted) and its thresholds;
    ``drive``: per located line, the drive orders next to it brought in as lines."""

    lines: list[Line]
    first: list[int]
    cinfo: dict
    sums: Sums
    lib: list[Term]
    thresh: np.ndarray
    infl: float
    signal_periods: int
    settings: FinderSettings
    drive: dict[int, list[int]] = dataclasses.field(default_factory=dict)


def build(prep, fitter, terms: Sequence[Any], resid: np.ndarray, findings) -> State | None:
    """The discovery state of a record (``None``: discovery does not apply: nothing
    located, no shaft (platform) angle and time, no line to model)."""
    if not findings or not {"theta", "t"} <= set(prep.rows):
        return None
    L = int(getattr(prep.ctx, "signal_periods", 0) or 0)
    lines, first = lines_of(findings, L)
    if not lines:
        return None
    near = drive_neighbours(lines, dict(prep.ctx.meta), prep.settings)
    for li, extra in alias_neighbours(lines, prep).items():
        near.setdefault(li, []).extend(extra)
    cell, cinfo = cells(prep)
    C = prep.n_channels
    alpha = np.asarray(getattr(prep.kd, "alpha", np.zeros(C)), float)
    if alpha.size != C:
        alpha = np.zeros(C)
    sds = sds_channels(prep)
    jac = _jacobian(prep, fitter, terms) if prep.n <= STEP_EXACT_ROWS else None
    steps = locate_steps(prep, resid, lines, findings, jac)
    S = len(cinfo["speed"])
    rings: list[dict | None] = [None] * len(lines)
    if sds is None and S <= MAX_CELLS and any(ln.kind == "hz" for ln in lines):
        tj = terms if jac is not None else []  # longer records: the residual alone

        def sums_at(li: int, ring: dict) -> Sums:
            ln = [lines[li]]
            return accumulate(prep, fitter, tj, resid, ln, cell, cinfo, None, jac, [ring])

        rings = locate_ringdowns(prep, lines, S, lambda ln: frame_maps(ln, C, alpha), sums_at)
    sums = accumulate(prep, fitter, terms, resid, lines, cell, cinfo, steps, jac, rings)
    infl = float(sums.rr.sum()) / max(prep.n_values, 1.0)
    lib = library(lines, sums, cinfo, C, alpha, prep.settings, sds, steps, rings)
    for tm in lib:
        if tm.modulation == "speed":
            _fit_beta(tm, sums.layout[tm.line], sums.slices[tm.line], sums, cinfo["speed"], infl)
            _scatter_se(tm, lib, sums)
    th = level_thresholds(prep, lines, sums, lib, thresholds(lib, prep.settings.discover_alpha))
    return State(lines, first, cinfo, sums, lib, th, infl, L, prep.settings, near)


def discover(
    prep,
    fitter,
    terms: Sequence[Any],
    resid: np.ndarray,
    findings: Sequence[Any],
) -> list[dict | None]:
    """Discovery after the catalog: one ``model`` object per finding (``None`` for every
    finding where discovery does not apply: see :func:`build`).

    ``terms``: the final catalog model's terms (the discovered ones are fitted jointly with
    it); ``resid``: its residual (n, C); ``findings``: what the views still locate
    (``_views.Finding``)."""
    st = build(prep, fitter, terms, resid, findings)
    if st is None:
        if findings:
            return [_none("no line, order or time structure to model (a broad band)")] * len(
                findings
            )
        return [None] * len(findings)
    kept, incl = select_terms(st)
    if kept and spanned_share(st, kept) >= st.settings.discover_refit_share:
        # the catalog model refitted with the terms kept, and the selection again
        cat, resid2 = _refit(prep, fitter, terms, st, kept, incl)
        st2 = build(prep, fitter, cat, resid2, findings)
        if st2 is not None:  # taken where its model gains more (held out)
            k2, i2 = select_terms(st2)
            if _whole_gain(st2, k2) > _whole_gain(st, kept):
                st, kept, incl = st2, k2, i2
    gains = _gains(st, kept)
    terms_json = [_term_json(prep, st, kept, i, incl, gains) for i in kept]
    near: dict[int, list[dict]] = {}  # per line: the best other terms (computed once)
    return [_model_json(st, kept, terms_json, fi, near) for fi in range(len(findings))]


def spanned_share(st: State, kept: list[int]) -> float:
    """The share of the kept terms' fitted signal (jointly, all folds) that the catalog
    model's Jacobian spans: the chi-square of its projection on the Jacobian (the raw Gram
    less the projected one) over its raw chi-square (0: orthogonal, the catalog model cannot
    have moved to take any of it; 1: the catalog spans it all). Read from the sums, no pass
    over the rows."""
    H = _embed(st.sums, [st.lib[j] for j in kept])
    At = H.T @ st.sums.A.sum(0) @ H
    Rt = H.T @ st.sums.raw.sum(0) @ H
    g = _psolve(At, H.T @ st.sums.b.sum(0), raw=Rt)
    raw = float(g @ Rt @ g)
    return float(g @ (Rt - At) @ g) / raw if raw > 0 else 0.0


def _whole_gain(st: State, kept: list[int]) -> float:
    """Held-out gain (chi-square, K folds) of the kept terms together."""
    if not kept:
        return 0.0
    folds = list(range(st.sums.A.shape[0]))
    H = _embed(st.sums, [st.lib[j] for j in kept])
    return _heldout(st.sums.A, st.sums.b, H, folds, st.sums.raw)


def _refit(
    prep, fitter, terms: Sequence[Any], st: State, kept: list[int], incl: np.ndarray
) -> tuple[list[Any], np.ndarray]:
    """The final catalog model fitted jointly (nonlinear, the engine's fitter) with the
    kept terms as candidates (:func:`discovered_candidate`), and the residual of its catalog
    part: ``(catalog terms, residual)``. The projection of the sums is the linearised joint
    fit at the catalog's optimum without the terms; a nonlinear catalog parameter can have
    moved far from where it belongs to absorb part of the structure (a head placement or a
    run's angle offset of up to ``pi / m`` turns the disk's order ``m`` into another phase),
    and the structure's own law is then measured on what is left. Refitted jointly, it
    moves back. :func:`discover` takes the second selection where its model's held-out gain
    is the larger (a catalog parameter that the terms make degenerate, e.g. one sensor's own
    error function at the order of a speed law, can land anywhere in the joint fit)."""
    gains = _gains(st, kept)
    new = []
    for i in kept:
        spec = _term_json(prep, st, kept, i, incl, gains)
        new.append(make_term(discovered_candidate(spec), prep, nonlinear_start(spec) or None))
    res = fitter.fit([*terms, *new])
    cat = res.terms[: len(terms)]
    return cat, fitter.residual(cat)


def select_terms(st: State) -> tuple[list[int], np.ndarray]:
    """Forward selection on all folds (of the terms at a chosen term's line and frame, the
    held-out gain picks the modulation: :func:`best_at_place`), and each term's inclusion
    probability over the selections repeated without each fold (a repeat that takes a term
    of the same span, :func:`_same_span`, of the same line and frame, or of the same frame at
    a line the record cannot tell apart from it, :func:`one_structure`, includes it); the
    terms kept (chosen on all folds and included at least ``settings.discover_inclusion_min``)."""
    sums, lib = st.sums, st.lib
    K = sums.A.shape[0]
    folds = list(range(K))
    me = st.settings.discover_model_error
    chosen = _forward(sums.A, sums.b, lib, sums, folds, st.thresh, me)
    # of terms the record cannot tell apart, the first of the library the catalog does not
    # mostly span (not rounding's pick)
    chosen = [_tie_pick(sums, lib, i, st.settings.discover_own_share_min) for i in chosen]
    if len(st.cinfo["speed"]) == 1:  # one cell (SDS): static, growth, step; no per-run terms
        chosen = best_at_place(sums, lib, chosen, st.thresh, me)
    incl = np.zeros(len(lib))
    for k in folds:
        rest = [f for f in folds if f != k]
        got = _forward(sums.A, sums.b, lib, sums, rest, st.thresh, me)
        same = {
            i
            for i in chosen
            if any(
                _same_span(sums, lib[i], lib[j])
                or same_place(lib[i], lib[j])
                or one_structure(sums, lib, st.thresh, i, j)
                for j in got
            )
        }
        for i in set(got) | same:
            incl[i] += 1.0 / K
    return [i for i in chosen if incl[i] >= st.settings.discover_inclusion_min], incl


def _gains(st: State, kept: list[int]) -> dict[str, dict]:
    """Held-out gains (chi-square) of the kept terms (in forward order): ``entry`` (over the
    terms taken before it: they sum to the model's), ``drop_one`` (the loss when only it is
    removed: 0 where another kept term spans it), ``line`` (when a line's terms are removed)."""
    sums, lib = st.sums, st.lib
    folds = list(range(sums.A.shape[0]))

    def ho(idx: list[int]) -> float:
        H = _embed(sums, [lib[j] for j in idx]) if idx else None
        return _heldout(sums.A, sums.b, H, folds, sums.raw) if H is not None else 0.0

    whole = ho(kept)
    entry, prev = {}, 0.0
    for n, i in enumerate(kept):
        cur = ho(kept[: n + 1])
        entry[i], prev = cur - prev, cur
    drop = {i: whole - ho([j for j in kept if j != i]) for i in kept}
    line = {
        li: whole - ho([j for j in kept if lib[j].line != li]) for li in {lib[i].line for i in kept}
    }
    return {"entry": entry, "drop_one": drop, "line": line}


def _term_json(
    prep, st: State, kept: list[int], i: int, incl: np.ndarray, gains: dict[str, dict]
) -> dict:
    """One kept term's JSON entry (parameters fitted with the others; held-out gains as
    :func:`_gains` defines them)."""
    sums, lib, cinfo = st.sums, st.lib, st.cinfo
    At, bt = sums.A.sum(0), sums.b.sum(0)
    Hk = _embed(sums, [lib[j] for j in kept])
    G = Hk.T @ At @ Hk
    Gr = Hk.T @ sums.raw.sum(0) @ Hk
    coef = _psolve(G, Hk.T @ bt, raw=Gr)
    cov = _psolve(G, np.eye(Hk.shape[1]), raw=Gr) * max(st.infl, 1.0)
    q0 = sum(lib[j].H.shape[1] for j in kept[: kept.index(i)])
    tm = lib[i]
    q = tm.H.shape[1]
    c, cv = coef[q0 : q0 + q], cov[q0 : q0 + q, q0 : q0 + q]
    ln = st.lines[tm.line]
    st_sds = sds_channels(prep)
    nj = 1 if (ln.kind == "order" and ln.value == 0) else 2
    pairs = c.reshape(-1, nj)
    amp = float(np.sqrt(np.mean(np.sum(pairs**2, 1))))
    amp_se = float(np.sqrt(max(np.trace(cv), 0.0) / max(pairs.shape[0], 1)))
    runs_id = [int(prep.run_ids[r]) if r < len(prep.run_ids) else r for r in cinfo["run"]]
    if prep.ctx.kind == "sds" or tm.step is not None:  # the runs of the rows (from the step)
        on = prep.keep & (tau_of(prep) >= (tm.step["tau_s"] if tm.step else -np.inf))
        runs_id = [int(prep.run_ids[r]) for r in np.unique(np.asarray(prep.run)[on])]
    runs = sorted(set(runs_id))
    if tm.modulation.startswith("cell "):
        runs = [runs_id[int(tm.modulation.split()[1])]]
    dirs = sorted({int(d) for d in cinfo["direction"]})
    if tm.modulation in ("forward", "reverse"):
        dirs = [1 if tm.modulation == "forward" else -1]
    names = list(prep.kd.channel_names)
    heads = names
    if tm.frame.startswith("head "):
        heads = [names[int(tm.frame.split()[1])]]
    elif tm.frame.startswith("sensor "):
        heads = [tm.frame.split()[1]]
    elif prep.ctx.kind == "sds":  # the moving sensors' run-mean channels
        heads = [c for c in names if "." not in c]
    scaling = None
    ring = ring_json(prep, tm)
    law = tm if tm.beta is not None else None
    if tm.modulation == "per_cell":  # the best law across the runs, described, not chosen
        law = _sibling(tm, lib, "speed")
    if law is not None:
        scaling = {
            "law": "amplitude ~ (speed / geometric-mean speed)^beta"
            + ("" if law is tm else " (fitted to describe the runs' own amplitudes)"),
            "beta": law.beta,
            "beta_se": law.beta_se,
            "speeds_rad_s": [float(v) for v in cinfo["speed"]],
        }
    return {
        "line": ln.label(),
        "located": ln.located,
        "line_kind": ln.kind,
        "value": float(ln.value),
        "frame": tm.frame,
        "modulation": tm.modulation,
        "heads": heads,
        "runs": runs,
        "directions": ["positive" if d > 0 else "negative" for d in dirs],
        "scaling": scaling,
        "params": {
            "coefficients": [float(v) for v in c],
            "coefficients_se": [math.sqrt(max(float(v), 0.0)) for v in np.diag(cv)],
            "amplitude": amp,
            "amplitude_se": amp_se,
            "unit": prep.kd.unit,
            **ring[0],
        },
        **({"step": step_json(prep, tm.step)} if tm.step is not None else {}),
        "heldout_gain_chi2": float(gains["entry"][i]),
        "heldout_gain_drop_one_chi2": float(gains["drop_one"][i]),
        "heldout_gain_line_chi2": float(gains["line"][tm.line]),
        "inclusion_probability": float(incl[i]),
        "reading": reading(
            ln, tm, dict(prep.ctx.meta), st.signal_periods, cinfo, len(names), prep.settings
        )
        + (step_words(prep, tm.step) if tm.step is not None else "")
        + ("" if ln.located else " Not located itself: " + _NOT_LOCATED[ln.alias]),
        "export": {
            **sums.scales,
            "kind": prep.ctx.kind,
            "n_runs": int(prep.ctx.n_runs),
            "run_index": int(cinfo["run"][int(tm.modulation.split()[1])])
            if tm.modulation.startswith("cell ")
            else None,
            "speed_ref_rad_s": float(np.exp(np.mean(np.log(np.maximum(cinfo["speed"], 1e-12))))),
            **({"step_tau_s": tm.step["tau_s"]} if tm.step is not None else {}),
            **({"growth_level": True} if tm.level else {}),
            **ring[1],
            **({"n_moving": int(st_sds[0]), "projected": bool(st_sds[2])} if st_sds else {}),
        },
    }


def _model_json(st: State, kept: list[int], terms_json: list[dict], fi: int, near) -> dict:
    """The ``model`` object of finding ``fi``."""
    li = st.first[fi]
    N = len(st.lib)
    if li == -2:
        return _none(f"beyond the first {MAX_LINES} located lines discovery models")
    if li == -3:
        return _none(
            "the matched view of a catalog candidate: its own pattern, which the catalog "
            "refused by its rule; discovery never takes a catalog effect's structure"
        )
    if li < 0:
        return _none("no line, order or time structure to model (a broad band)")
    own = {li, *st.drive.get(li, [])}  # its line and the drive orders next to it
    mine = [t for t, i in zip(terms_json, kept) if st.lib[i].line in own]
    if not mine:
        return _none(
            f"no term of the library ({N} terms: frames x modulations) passes the "
            f"multiple-testing threshold with a positive held-out gain at "
            f"{st.lines[li].label()}" + taken_by(st.sums, st.lib, st.lines, st.thresh, kept, li),
            library_size=N,
        )
    K = st.sums.A.shape[0]
    frames = sorted({t["frame"] for t in mine})
    return {
        "outside_catalog": True,
        "frame": frames[0] if len(frames) == 1 else ", ".join(frames),
        "terms": mine,
        "scaling": next((t["scaling"] for t in mine if t["scaling"]), None),
        "heldout_gain_chi2": mine[0]["heldout_gain_line_chi2"],
        "inclusion": {
            f"{t['frame']} / {t['modulation']}": t["inclusion_probability"] for t in mine
        },
        "library_size": N,
        "selection": "orthogonal forward regression; Bonferroni threshold "
        f"chi2.isf({st.settings.discover_alpha} / {N}, q); K-fold held-out gain > 0; "
        f"inclusion over {K} leave-one-fold-out repeats >= "
        f"{st.settings.discover_inclusion_min}",
        "alternatives": near.setdefault(li, _nearest(st.lib, kept, li, st.sums, list(range(K)))),
        "reading": " ".join(t["reading"] for t in mine),
    }


def _nearest(lib, kept, li, sums, folds) -> list[dict]:
    """The best other frames at the same line (held-out gain each alone): why the chosen
    frame, not these."""
    out = []
    best: dict[str, float] = {}
    for i, tm in enumerate(lib):
        if tm.line != li or i in kept:
            continue
        g = _single_heldout(sums, tm, folds)
        k = f"{tm.frame} / {tm.modulation}"
        if g > best.get(k, -np.inf):
            best[k] = g
    for k, g in sorted(best.items(), key=lambda kv: -kv[1])[:3]:
        out.append({"term": k, "heldout_gain_chi2": float(g)})
    return out


def _none(reason: str, **kw) -> dict:
    return {"outside_catalog": True, "frame": None, "terms": [], "reason": reason, **kw}
