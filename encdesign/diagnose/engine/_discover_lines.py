"""Discovery's located lines, change times and frames (issue 41; see
:mod:`encdesign.diagnose.engine._discover`): the lines each finding gives, the change time a
``step`` term uses (:func:`locate_steps`), the frames' maps onto the channels (the SDS
frames among them) and a step's report on the recording's own ``t``."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import stats

MAX_LINES = 10
"""Located lines modelled (the strongest findings first)."""

STEP_BINS = 32
"""Equal-count bins of the kept rows (in time order) whose edges are the change points a
step term scans (plus the times the finder's views located); a record with fewer rows (an
SDS record: one row per run) scans every row boundary."""

STEP_VIEWS = ("time", "order_step", "run_step")
"""Views whose located change times a step term tries."""

STEP_EXACT_ROWS = 4096
"""Records of at most this many rows locate a step with the catalog model projected out
(its Jacobian on every row, evaluated once and shared with the sums); longer records scan
the residual alone (the fit itself is always joint with the catalog model)."""


@dataclasses.dataclass(frozen=True)
class Line:
    """A located line: ``kind`` ``order`` (integer shaft order, ``value`` cycles per turn;
    0: an offset), ``frac`` (a fractional order) or ``hz`` (``value`` Hz); ``located``
    false: a drive order next to a located line (:func:`drive_neighbours`)."""

    kind: str
    value: float
    located: bool = True
    alias: bool = False  # not located: an order the located one may alias (SDS)

    def label(self) -> str:
        if self.kind == "hz":
            return f"{self.value:.4g} Hz"
        if self.kind == "order" and self.value == 0:
            return "offset (order 0)"
        return f"order {self.value:g}"


def drive_orders(meta: dict, max_order: float) -> tuple[list[int], list[int]]:
    """``(multiples, sidebands)``: the orders up to ``max_order`` tied to the drive the
    recording declares (``[motor] pole_pairs`` / ``slots``; an SDS ``[encoder]``
    ``pole_pairs`` / ``stator_coils``): multiples of the pole pairs, slots and their lcm,
    and the +-1 sidebands of the pole pairs' multiples."""
    motor, enc = meta.get("motor") or {}, meta.get("encoder") or {}
    p = int(motor.get("pole_pairs") or enc.get("pole_pairs") or 0)
    s = int(motor.get("slots") or enc.get("stator_coils") or 0)
    top = int(max_order) + 2
    mult: set[int] = set()
    side: set[int] = set()
    for base in {b for b in (p, s, p * s // math.gcd(p, s) if p and s else 0) if b > 0}:
        mult |= set(range(base, top, base))
    if p:
        side |= {k * p + e for k in range(1, top // p + 1) for e in (-1, 1)} - mult
    return sorted(o for o in mult if o <= max_order + 1), sorted(
        o for o in side if 0 < o <= max_order + 1
    )


def drive_neighbours(lines: list[Line], meta: dict, settings) -> dict[int, list[int]]:
    """Appends to ``lines`` the drive orders (:func:`drive_orders`) next to a located line
    but not located themselves (``settings.discover_drive_near`` orders of an integer line,
    ``discover_drive_near_frac`` of a fractional one), within :data:`MAX_LINES`; returns,
    per located line, the indices of the drive lines it brought."""
    top = max([ln.value for ln in lines if ln.kind in ("order", "frac")] + [0.0])
    mult, side = drive_orders(meta, top)
    have = {ln.value for ln in lines if ln.kind == "order"}
    out: dict[int, list[int]] = {}
    for i, ln in enumerate(list(lines)):
        if ln.kind == "order" and ln.value > 0:
            near = [d for d in mult if 0 < abs(d - ln.value) <= settings.discover_drive_near]
        elif ln.kind == "frac":
            lim = settings.discover_drive_near_frac
            near = [d for d in mult + side if abs(d - ln.value) <= lim]
        else:
            continue
        for d in near:
            if d in have or len(lines) >= MAX_LINES:
                continue
            have.add(d)
            lines.append(Line("order", float(d), located=False))
            out.setdefault(i, []).append(len(lines) - 1)
    return out


def _alias_share(A: np.ndarray, B: np.ndarray) -> float:
    """The largest squared canonical correlation between the column spans of ``A`` and
    ``B`` (1: a common direction)."""
    qa, qb = np.linalg.qr(A)[0], np.linalg.qr(B)[0]
    return float(np.linalg.svd(qa.T @ qb, compute_uv=False)[0] ** 2)


def alias_neighbours(lines: list[Line], prep) -> dict[int, list[int]]:
    """SDS: appends to ``lines`` the lower orders that a located integer order may be an
    alias of on the record's platform positions (one per run): those whose columns (static,
    growing linearly over the runs, or switched on at a run boundary) share at least
    ``settings.discover_alias_share`` of the located order's static columns, the largest
    first (``settings.discover_max_aliases`` per order), within :data:`MAX_LINES`; returns,
    per located line, the indices of the lines it brought. Empty on another kind.

    Only orders below the located one: a few golden-angle positions make many pairs of
    orders near-aliases, and the held-out gain of a higher alias over the true order is
    then the noise's (training seeds 7501 and 7503: order 5 read as 29 or 26); the lower
    order is the simpler reading of the same columns. A located order that is the
    alias of a higher true order stays as located."""
    sds = sds_channels(prep)
    if sds is None or not prep.settings.discover_max_aliases:  # another kind, or off
        return {}
    tau = tau_of(prep)[prep.keep]
    phi = np.asarray(prep.rows["theta"], float)[prep.keep][np.argsort(tau, kind="stable")]
    R = phi.size
    top = int(prep.ctx.n_runs) * sds[0] // 2 - 1
    mods = [np.ones(R), np.linspace(-1.0, 1.0, R)] + [
        (np.arange(R) >= b) * 1.0 for b in range(1, R)
    ]

    def cols(m: float, g: np.ndarray) -> np.ndarray:
        return np.stack([g * np.cos(m * phi), g * np.sin(m * phi)], 1)

    have = {ln.value for ln in lines if ln.kind == "order"}
    out: dict[int, list[int]] = {}
    for i, ln in enumerate(list(lines)):
        if ln.kind != "order" or ln.value <= 0 or not ln.located:
            continue
        own = cols(ln.value, mods[0])
        if R <= own.shape[1]:  # no more positions than an order's columns: all alias
            continue
        shares = []
        for m in range(1, min(top + 1, int(ln.value))):
            if m in have:
                continue
            sh = max(_alias_share(own, cols(m, g)) for g in mods)
            if sh >= prep.settings.discover_alias_share:
                shares.append((sh, m))
        for _, m in sorted(shares, reverse=True)[: prep.settings.discover_max_aliases]:
            if len(lines) >= MAX_LINES:
                break
            have.add(m)
            lines.append(Line("order", float(m), located=False, alias=True))
            out.setdefault(i, []).append(len(lines) - 1)
    return out


def lines_of(findings: Sequence[Any], signal_periods: int = 0) -> tuple[list[Line], list[int]]:
    """The located lines of ``findings`` (``_views.Finding``) and, per finding, the index of
    its first line (-1: a located structure no line models, e.g. a broad band; -2: a line
    beyond the first :data:`MAX_LINES`; -3: an SDS candidate's matched view, the pattern of
    a catalog effect, which discovery never takes)."""
    out: list[Line] = []
    first: list[int] = []

    def add(ln: Line) -> int:
        for i, o in enumerate(out):
            if o.kind == ln.kind and abs(o.value - ln.value) <= 1e-6 * max(1.0, abs(ln.value)):
                return i
        out.append(ln)
        return len(out) - 1

    for f in findings:
        w, d = f.where, f.detail
        idx = -1
        orders = [o for o in w.get("orders", []) if math.isfinite(o)]
        freqs = [h for h in w.get("frequencies_hz", []) if math.isfinite(h)]
        if f.view in ("orders", "common_orders", "modulated_orders", "common_modulated") and orders:
            idx = add(Line("order", float(round(orders[0]))))
        elif f.view == "spectrum" and (orders or freqs):
            if d.get("fixed_in") == "hz" and freqs:  # _views: "hz", "order", ...
                idx = add(Line("hz", float(np.median(freqs))))
            elif d.get("integer_order") and orders:
                m = float(round(np.median(orders)))
                idx = add(Line("order", m)) if m > 0 else -1
            elif orders:
                nu = float(np.median(orders))
                idx = add(Line("frac", round(nu, 3))) if nu > 0 else -1
        elif f.view in ("time", "drift", "direction", "speed", "run_step"):
            idx = add(Line("order", 0.0))
        elif f.view.startswith("sds_"):
            idx = -3  # a catalog candidate's matched view: its own pattern, refused by its rule
        elif f.view == "line_phase" and signal_periods > 0:
            idx = add(Line("order", float(signal_periods)))
        first.append(idx)
    return out[:MAX_LINES], [i if i < MAX_LINES else -2 for i in first]


def located_steps(findings: Sequence[Any]) -> list[tuple[float, str]]:
    """``(tau_s, view)``: the change times (on the end-to-end axis ``tau``) the finder's
    views located (:data:`STEP_VIEWS`); an SDS ``run_step`` gives its first run's index in
    ``first_run_index`` (placed on that row by :func:`locate_steps`)."""
    out = []
    for f in findings:
        d = f.detail
        if f.view not in STEP_VIEWS:
            continue
        if f.view == "run_step" and d.get("shape") == "step":
            out.append((float(d["first_run_index"]), "run_step"))
        elif f.view in ("time", "order_step") and "global_step_time_s" in d:
            if f.view == "order_step" or d.get("shape") == "step" or d.get("step_significant"):
                out.append((float(d["global_step_time_s"]), f.view))
    return out


def cells(prep) -> tuple[np.ndarray, dict]:
    """Cell index per row (-1: not kept) and the cells' run, direction and speed."""
    keep = prep.keep
    run = np.asarray(prep.run)
    if prep.ctx.kind == "sds":  # one row per run, nothing varies but the time: one cell
        run = np.zeros(prep.n, dtype=int)
    om = np.asarray(prep.rows["omega"], float) if "omega" in prep.rows else np.zeros(prep.n)
    sgn = np.where(om < 0, -1, 1)
    lsp = np.round(np.log(np.maximum(np.abs(om), 1e-12)) / 0.05).astype(np.int64)
    key = np.stack([run, sgn, lsp], 1)
    key = np.where(keep[:, None], key, np.iinfo(np.int64).min)
    uniq, inv = np.unique(key[keep], axis=0, return_inverse=True)
    cell = -np.ones(prep.n, dtype=int)
    cell[keep] = inv.ravel()
    S = len(uniq)
    speed = np.array([np.median(np.abs(om[cell == s])) for s in range(S)])
    info = {
        "run": uniq[:, 0].astype(int),
        "direction": uniq[:, 1].astype(int),
        "speed": speed,
        "rows": np.bincount(cell[keep], minlength=S),
    }
    return cell, info


def phase_basis(line: Line, th: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(rows, n_basis)`` cos/sin of the line's phase (order 0: a constant)."""
    if line.kind == "order" and line.value == 0:
        return np.ones((th.size, 1))
    ph = 2 * np.pi * line.value * t if line.kind == "hz" else line.value * th
    return np.stack([np.cos(ph), np.sin(ph)], 1)


def tau_of(prep) -> np.ndarray:
    return np.asarray(prep.rows["tau"] if "tau" in prep.rows else prep.rows["t"], float)


def sds_channels(prep) -> tuple[int, np.ndarray, bool] | None:
    """SDS: ``(M, psi_m, projected)``: the moving sensors (their run-mean channels are the
    first ``M``), their azimuths (rad), and whether terms are projected on the differences
    between them (no ``phi_ref``); ``None`` for another kind."""
    if prep.ctx.kind != "sds":
        return None
    psi = np.asarray(prep.consts["psi_m"], float).ravel()
    return psi.size, psi, float(np.asarray(prep.consts.get("proj", 0.0))) > 0


def _pinv(A: np.ndarray, raw: np.ndarray | None = None, share: float = 1e-6) -> np.ndarray:
    """Pseudo-inverse of a symmetric positive semi-definite ``A`` on its unit-diagonal
    scaled form (by ``raw``'s diagonal where given: a direction keeping less than ``share``
    of its raw norm is dropped, else less than ``1e-10`` of the largest eigenvalue)."""
    if A.size == 0:
        return np.zeros_like(A)
    d = np.sqrt(np.maximum(np.diag(A if raw is None else raw), 0.0))
    d = np.where(d > 0, d, 1.0)
    ev, V = np.linalg.eigh(A / d[:, None] / d[None, :])
    tol = share if raw is not None else 1e-10 * max(float(ev.max()), 1e-300)
    inv = np.where(ev > tol, 1.0 / np.where(ev > tol, ev, 1.0), 0.0)
    return (V * inv) @ V.T / d[:, None] / d[None, :]


def _step_columns(prep, B: np.ndarray) -> np.ndarray:
    """``(n, C, q)``: the line's basis ``B`` (n, nj) on each channel its own (SDS: the moving
    sensors' run-mean channels), whitened and projected as the data are."""
    C = prep.n_channels
    sig = np.asarray(prep.sigma, float)
    sds = sds_channels(prep)
    if sds is not None:
        Mn, _, proj = sds
        P = np.zeros((C, Mn))
        P[:Mn] = np.eye(Mn) - (1.0 / Mn if proj else 0.0)
    else:
        P = np.eye(C) - (1.0 / C if prep.kd.project else 0.0)
    W = P / sig[:, None]
    Z = B[:, None, None, :] * W[None, :, :, None]
    return Z.reshape(B.shape[0], C, -1)


def _exact_gains(Z: np.ndarray, rw: np.ndarray, J: np.ndarray, positions) -> np.ndarray:
    """Chi-square a step of the columns ``Z`` (n, C, q) from each position on takes from
    the residual ``rw`` (n, C), with ``Z`` itself (the constant line) and the catalog
    model's Jacobian ``J`` (n, C, p) projected out (Frisch-Waugh), from prefix sums."""

    def prefix(x):
        return np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(x, 0)])

    czz = prefix(np.einsum("ncq,ncr->nqr", Z, Z))
    czr = prefix(np.einsum("ncq,nc->nq", Z, rw))
    cjz = prefix(np.einsum("ncp,ncq->npq", J, Z))
    JJ = np.einsum("ncp,ncr->pr", J, J)
    Pj = _pinv(JJ)
    Jr = np.einsum("ncp,nc->p", J, rw)
    GTT, JT = czz[-1], cjz[-1]
    bT = czr[-1] - JT.T @ Pj @ Jr
    ATT = GTT - JT.T @ Pj @ JT
    ATTi = _pinv(ATT, raw=GTT)
    out = []
    for p in positions:
        GUU, JU = czz[-1] - czz[p], cjz[-1] - cjz[p]
        bU = czr[-1] - czr[p] - JU.T @ Pj @ Jr
        AUU = GUU - JU.T @ Pj @ JU
        ATU = GUU - JT.T @ Pj @ JU
        e = bU - ATU.T @ ATTi @ bT
        Sc = AUU - ATU.T @ ATTi @ ATU
        out.append(float(e @ _pinv(Sc, raw=GUU) @ e))
    return np.asarray(out)


def _switch_gains(Z: np.ndarray, rw: np.ndarray, J: np.ndarray, positions) -> np.ndarray:
    """Chi-square the columns ``Z`` (n, C, q) switched on from each position take from the
    residual ``rw`` (n, C) alone, as the library's ``step`` term is fitted (no level
    before the change), with the catalog model's Jacobian ``J`` (n, C, p) projected out
    (Frisch-Waugh), from suffix sums."""

    def prefix(x):
        return np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(x, 0)])

    czz = prefix(np.einsum("ncq,ncr->nqr", Z, Z))
    czr = prefix(np.einsum("ncq,nc->nq", Z, rw))
    cjz = prefix(np.einsum("ncp,ncq->npq", J, Z))
    Pj = _pinv(np.einsum("ncp,ncr->pr", J, J))
    Jr = np.einsum("ncp,nc->p", J, rw)
    out = []
    for p in positions:
        GUU, JU = czz[-1] - czz[p], cjz[-1] - cjz[p]
        e = czr[-1] - czr[p] - JU.T @ Pj @ Jr
        out.append(float(e @ _pinv(GUU - JU.T @ Pj @ JU, raw=GUU) @ e))
    return np.asarray(out)


def _frame_switch_gains(
    sds: tuple[int, np.ndarray, bool], Z: np.ndarray, rw, J, line: Line, positions
) -> np.ndarray:
    """SDS: per position, the largest chi-square a ``step`` term of one of the line's frames
    (:func:`_sds_frame_maps`: the platform, the azimuths, each moving sensor) takes there
    (:func:`_switch_gains` on the frame's columns: ``Z`` (n, C, M nj), each moving sensor
    its own, mapped by the frame); ``sds``: :func:`sds_channels`."""
    Mn = sds[0]
    n, C = Z.shape[:2]
    Z4 = Z.reshape(n, C, Mn, -1)
    best = np.full(len(positions), -np.inf)
    for M in _sds_frame_maps(line, C, sds).values():
        Zf = np.einsum("nckj,kjl->ncl", Z4, M[:Mn])
        best = np.maximum(best, _switch_gains(Zf, rw, J, positions))
    return best


def _residual_gains(B, r, seg_starts, positions, n) -> np.ndarray:
    """:func:`_exact_gains` without the catalog model (each channel its own, the constant
    line projected out) for a long record: sums per segment (``seg_starts``: the sorted
    change points) and rows (``positions`` not among them)."""
    seg = np.concatenate([[0], seg_starts])
    Gs = np.add.reduceat(B[:, :, None] * B[:, None, :], seg, axis=0)
    gs = np.add.reduceat(B[:, :, None] * r[:, None, :], seg, axis=0)  # (segs, nj, C)
    GT, gT = Gs.sum(0), gs.sum(0)
    GU = np.cumsum(Gs[::-1], 0)[::-1]  # from each segment's start on
    gU = np.cumsum(gs[::-1], 0)[::-1]
    GTi = np.linalg.pinv(GT)
    out = []
    for p in positions:
        i = int(np.searchsorted(seg, p, side="right")) - 1  # the segment holding row p
        nxt = int(seg[i + 1]) if i + 1 < seg.size else n
        Gp = (GU[i + 1] if i + 1 < seg.size else 0.0) + B[p:nxt].T @ B[p:nxt]
        gp = (gU[i + 1] if i + 1 < seg.size else 0.0) + B[p:nxt].T @ r[p:nxt]
        e = gp - Gp @ GTi @ gT  # (nj, C)
        Sc = Gp - Gp @ GTi @ Gp
        out.append(float(np.sum(e * (np.linalg.pinv(Sc) @ e))))
    return np.asarray(out)


def locate_steps(
    prep, resid: np.ndarray, lines: Sequence[Line], findings, J: np.ndarray | None = None
) -> list[dict | None]:
    """Per line, the change time a ``step`` term uses (``None``: no step term: a line whose
    phase is fitted per cell, or too few rows): the change point, among the
    :data:`STEP_BINS` equal-count bin edges of the kept rows and the times the finder's
    views located (:func:`located_steps`), where a step of the line's cos / sin (each
    channel its own, the constant line projected out) takes the most chi-square from the
    residual; a scanned edge is refined to the row between its neighbours. An SDS record
    (with ``J``) scans instead the ``step`` terms of the line's frames as the library fits
    them (:func:`_frame_switch_gains`: switched on from zero, one frame's columns): on 24
    golden-angle platform positions the constant line of each moving sensor, 2 columns each,
    takes most of an order switching on, and the scan above placed a platform step of 45.7
    chi-square at a change point where that term took 22.8 (session 36: the benchmark's
    ``platform_step`` 2x on 20261499, order 5 from run 9 located at run 18). Each step term
    is counted once per change point in the multiple-testing threshold
    (:func:`thresholds`), which covers the best of the frames at the best change point.
    The scan runs over all kept rows (2 at least on either side); where its best change
    point falls in the first or last ``settings.discover_step_margin`` of them, the line
    gets no step term (an end effect: a start-up or a stop the segmentation kept;
    restricting the scan instead put such a transient's change at the margin's edge, a
    change time that is nowhere in the record). With ``J`` (all rows, (n, C, p): the
    whitened Jacobian of the final catalog model, given for records of at most
    :data:`STEP_EXACT_ROWS` rows) the catalog model is projected out too, as in the fit.
    ``n_tests``: the change points tried (the term's multiple-testing count)."""
    kidx = np.flatnonzero(prep.keep)
    tau = tau_of(prep)
    order = kidx[np.argsort(tau[kidx], kind="stable")]
    n = order.size
    margin = max(2, int(prep.settings.discover_step_margin * n))
    if n < 2 * margin + 1:
        return [None] * len(lines)
    pos = set(np.unique(np.round(np.linspace(0, n, min(STEP_BINS, n) + 1)).astype(int))[1:-1])
    ts = tau[order]
    src: dict[int, str] = {}
    for v, view in located_steps(findings):
        if view == "run_step":  # the first run's row (SDS: one row per run)
            p = int(np.searchsorted(order, int(v)))
        else:
            p = int(np.searchsorted(ts, v))
        src[p] = view
        pos.add(p)
    cand = np.array(sorted(p for p in pos if 2 <= p <= n - 2), dtype=int)
    if cand.size == 0:
        return [None] * len(lines)
    sig = np.asarray(prep.sigma, float)
    th = np.asarray(prep.rows["theta"], float)[order]
    t = np.asarray(prep.rows["t"], float)[order]
    rw = np.asarray(resid, float)[order] / sig[None, :]
    Jk = J[order] if J is not None else None
    sds = sds_channels(prep)
    chans = np.arange(sds[0]) if sds else np.arange(prep.n_channels)
    out: list[dict | None] = []
    for ln in lines:
        if ln.kind != "order":
            out.append(None)
            continue
        B = phase_basis(ln, th, t)  # (n, nj)
        Z = _step_columns(prep, B) if Jk is not None else None

        def gains(ps, B=B, Z=Z, ln=ln) -> np.ndarray:
            if Z is not None and Jk is not None and sds is not None:
                return _frame_switch_gains(sds, Z, rw, Jk, ln, list(ps))
            if Z is not None and Jk is not None:
                return _exact_gains(Z, rw, Jk, ps)
            return _residual_gains(B, rw[:, chans], cand, ps, n)

        bi = int(np.argmax(gains(cand)))
        p, n_tests = int(cand[bi]), int(cand.size)
        if p not in src:  # refined to the row between the neighbouring change points
            lo = int(cand[bi - 1]) + 1 if bi > 0 else 2
            hi = int(cand[bi + 1]) if bi + 1 < cand.size else n - 1
            if hi - lo > 1:
                p = lo + int(np.argmax(gains(range(lo, hi))))
                n_tests += hi - lo - 1
        if not margin <= p <= n - margin:  # an end effect, not a change of the set-up
            out.append(None)
            continue
        out.append(
            {
                "row": int(order[p]),
                "row_before": int(order[p - 1]),
                "tau_s": float(ts[p]),
                "n_tests": n_tests,
                "located_by": src.get(p, "scan"),
            }
        )
    return out


def _rotation(m: float, a: np.ndarray) -> np.ndarray:
    """``(len(a), 2, 2)``: ``C cos(m(theta - a)) + S sin(m(theta - a))`` on the cos / sin of
    ``m theta``."""
    c, s = np.cos(m * a), np.sin(m * a)
    return np.stack([np.stack([c, -s], 1), np.stack([s, c], 1)], 1)


def _sds_frame_maps(line: Line, C: int, sds: tuple[int, np.ndarray, bool]) -> dict:
    """The SDS frames (see module) on the moving sensors' run-mean channels (the revolution
    contrasts carry no static term), projected on the differences between the moving
    sensors where the record has no ``phi_ref`` (as the data and every catalog term are)."""
    Mn, psi, proj = sds
    nj = 1 if (line.kind == "order" and line.value == 0) else 2
    eye = np.eye(nj)

    def lift(Mm: np.ndarray) -> np.ndarray:
        if proj:
            Mm = Mm - Mm.mean(0, keepdims=True)
        full = np.zeros((C, *Mm.shape[1:]))
        full[:Mn] = Mm
        return full

    out: dict[str, np.ndarray] = {}
    if not proj:
        out["platform"] = lift(np.repeat(eye[None], Mn, 0))
    if line.kind == "order" and line.value > 0 and Mn > 1:
        out["azimuth"] = lift(_rotation(line.value, -psi))  # an order of phi + psi_m
    for k in range(Mn if Mn > 1 else 0):
        Mk = np.zeros((Mn, nj, nj))
        Mk[k] = eye
        out[f"sensor m{k}"] = lift(Mk)
    return out


def frame_maps(
    line: Line, C: int, alpha: np.ndarray, sds: tuple[int, np.ndarray, bool] | None = None
) -> dict[str, np.ndarray]:
    """Per frame, ``M`` (C, nj, nj'): each channel's basis coefficients from the frame's
    parameters (``nj'``); ``sds``: the SDS frames instead (:func:`_sds_frame_maps`)."""
    if sds is not None:
        return _sds_frame_maps(line, C, sds)
    nj = 1 if (line.kind == "order" and line.value == 0) else 2
    eye = np.eye(nj)
    out: dict[str, np.ndarray] = {}
    if C > 1 or nj == 2:
        out["shaft"] = np.repeat(eye[None], C, 0)
    if line.kind == "order" and line.value > 0 and C > 1:
        out["disk"] = _rotation(line.value, np.asarray(alpha, float))
    if C > 1:
        for k in range(C):
            M = np.zeros((C, nj, nj))
            M[k] = eye
            out[f"head {k}"] = M
    return out


def hmap(layout, block: int, M: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Restriction ``(Q_line, nj' * n_free_cells)``: the frame map ``M`` on the block, per
    cell scaled by ``f`` (S,) (one shared parameter set), or ``f`` (S, G) (G groups of
    cells, each its own parameters)."""
    nb, S, C, nj = layout
    f2 = f[:, None] if f.ndim == 1 else f
    Gn = f2.shape[1]
    njp = M.shape[2]
    H = np.zeros((nb, S, C, nj, Gn, njp))
    for g in range(Gn):
        H[block, :, :, :, g, :] = f2[:, g][:, None, None, None] * M[None]
    return H.reshape(nb * S * C * nj, Gn * njp)


def step_words(prep, step: dict) -> str:
    j = step_json(prep, step)
    how = (
        f"located by the finder's {j['located_by']} view"
        if j["located_by"] != "scan"
        else f"the best of {j['n_change_points']} change points scanned"
    )
    return f" It switches on at t = {j['time_s']:.6g} s in run {j['run']} ({how})."


def step_json(prep, step: dict) -> dict:
    """A step's change time on the recording's own ``t``: between the last kept row before
    it and the first after it, with that row's run."""
    t = np.asarray(prep.rows["t"], float)
    a, b = step["row"], step["row_before"]
    return {
        "time_s": float(t[a]),
        "time_before_s": float(t[b]),
        "run": int(prep.run_ids[int(prep.run[a])]),
        "tau_s": float(step["tau_s"]),
        "located_by": step["located_by"],
        "n_change_points": int(step["n_tests"]),
    }


def thresholds(lib: Sequence[Any], alpha: float) -> np.ndarray:
    """Each term's chi-square threshold (Bonferroni over the library at ``alpha``,
    ``settings.discover_alpha``): the step terms, each counted once per change point
    scanned, share half of ``alpha`` and the others the other half (all of it when there is
    no step term)."""
    n_step = sum(tm.step["n_tests"] for tm in lib if tm.step is not None)
    n_other = sum(1 for tm in lib if tm.step is None)
    share = 0.5 if n_step and n_other else 1.0
    out = []
    for tm in lib:
        n = n_step if tm.step is not None else n_other
        q = tm.n_params
        out.append(stats.chi2.isf(alpha * share / max(n, 1), q))
    return np.asarray(out)
