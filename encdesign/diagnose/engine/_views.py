"""Views of a residual: where the model and the recording disagree (engine stage 3).

Each view tests the whitened residual ``r / sigma_c`` (kept rows only) with regressors of
known shape; under white noise the power they take out is chi-square with as many degrees of
freedom as regressors, and each view tests at ``alpha / n_tests`` (Bonferroni), so a record
with nothing missing gives no finding.

* ``spectrum``: per run, the periodogram in Hz of every channel (FFT on the run's kept rows,
  excluded rows set to zero), summed over channels; peaks in Hz and in shaft orders; across
  runs at different speeds a line stays fixed in Hz or in order.
* ``orders``: per channel, integer shaft orders ``1..M`` fitted over all runs (rotation
  locked, the same phase in every run): structure one channel shows and the others do not.
* ``time``: per channel and run, block means over time (a transient, a step, a drift) and
  the best single change point.
* ``drift``: per channel, the driver (``temp_c`` or time).
* ``line_phase``: per channel, harmonics 1 and 2 of the phase within one signal period.
* ``direction``: per channel, the mean difference between the two directions of rotation.
* ``speed``: per channel, a term proportional to the signed steady speed.
* ``angle_trend``: per channel, a term proportional to the shaft angle within each run.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import numpy as np
from scipy import stats

from ._located import change_chi2, change_row, interval_of, located_time
from ._timing import stage
from ._views_estimated import estimated_log10_p, estimated_threshold, pooled_noise_dof
from ._views_leakage import separate_lines
from ._views_orders import order_scan
from ._views_sums import Whitened, linear, sums_of
from ._views_time import best_step, cusum_edge, time_steps_beside_order_change
from ._workshare import deal


@dataclasses.dataclass
class Finding:
    """One located mismatch (``where``: orders, frequencies_hz, heads, runs, times_s)."""

    view: str
    where: dict[str, list]
    power: float  # whitened chi-square it carries
    dof: int
    log10_p: float
    variance_share: float = 0.0
    detail: dict[str, Any] = dataclasses.field(default_factory=dict)
    located_time: dict | None = None
    """A located change: its time on the recording's own ``t``, run and interval
    (:func:`._located.located_time`); ``None`` where the finding locates no change."""

    def to_json(self, sigma_mean: float) -> dict:
        """JSON form (rms in the unit of the residual)."""
        n = max(self.detail.get("n_values", 1), 1)
        out = {
            "view": self.view,
            "where": self.where,
            "rms": float(sigma_mean * math.sqrt(max(self.power - self.dof, 0.0) / n)),
            "variance_share": float(self.variance_share),
            "log10_p": float(self.log10_p),
            "detail": self.detail,
        }
        if self.located_time is not None:
            out["located_time"] = self.located_time
        return out


def log10_tail_p(chi2: float, dof: int) -> float:
    """log10 of the chi-square tail probability (floored at -999 where it underflows)."""
    v = float(stats.chi2.logsf(chi2, dof) / math.log(10))
    if not math.isfinite(v):
        z = (chi2 - dof) / math.sqrt(2.0 * max(dof, 1))
        v = float(stats.norm.logsf(z) / math.log(10))
    return max(v, -999.0) if math.isfinite(v) else -999.0


def chi2_threshold(alpha: float, dof: int, n_tests: int) -> float:
    return _chi2_isf(float(alpha / max(n_tests, 1)), float(dof))


@functools.lru_cache(maxsize=4096)
def _chi2_isf(p: float, dof: float) -> float:  # (the views ask for the same ones each scan)
    return float(stats.chi2.isf(p, dof))


SCAN_BLOCK = 1 << 18
"""Rows per block of the views' accumulations (temporaries bounded by the block)."""


def _blocks(n: int, size: int = SCAN_BLOCK):
    for a in range(0, n, size):
        yield a, min(n, a + size)


def _col(prep, name: str, a: int, b: int) -> np.ndarray:
    """Rows ``a:b`` of a row column (lazy columns computed for those rows only)."""
    rows = prep.rows
    return rows.column(name, a, b) if hasattr(rows, "column") else rows[name][a:b]


def _gram_power(G: np.ndarray, B: np.ndarray, n_rows: int, q: int) -> np.ndarray:
    """Power ``B_c^T G^+ B_c`` per column of ``B`` (q, C): the chi-square regressors with
    Gram matrix ``G`` (q, q) take out of each channel (its projection, as a QR would give)."""
    if n_rows <= q:
        return np.zeros(B.shape[1])
    coef = np.linalg.lstsq(G, B, rcond=None)[0]
    return np.maximum(np.sum(B * coef, axis=0), 0.0)


def order_sums(prep, theta_name: str, resids, orders) -> tuple:
    """Sums over the kept rows, in blocks, for integer shaft orders ``m``: ``(N, Scc, Sss,
    Scs, [(Bc, Bs) per residual])`` with ``c = cos(m theta)``, ``s = sin(m theta)``,
    ``Scc = sum c^2`` (M,), ``Bc = sum c r`` (M, C). Memory: one block of rows."""
    m = np.asarray(orders, float)
    M = m.size
    keep = prep.keep
    n = keep.size
    Scc, Sss, Scs = np.zeros(M), np.zeros(M), np.zeros(M)
    Bs = [(np.zeros((M, r.shape[1])), np.zeros((M, r.shape[1]))) for r in resids]
    N = 0
    step = max(1024, SCAN_BLOCK // max(M, 1))
    for a, b in _blocks(n, step):
        kb = keep[a:b]
        if not kb.any():
            continue
        th = _col(prep, theta_name, a, b)[kb]
        ang = th[:, None] * m[None, :]
        c, s_ = np.cos(ang), np.sin(ang)
        del ang
        N += th.size
        Scc += np.einsum("ij,ij->j", c, c)
        Sss += np.einsum("ij,ij->j", s_, s_)
        Scs += np.einsum("ij,ij->j", c, s_)
        for (bc, bs), r in zip(Bs, resids):
            rb = r[a:b][kb]
            bc += c.T @ rb
            bs += s_.T @ rb
    return N, Scc, Sss, Scs, Bs


def _heads(
    prep, W: np.ndarray, ch: list[int], order: float | None = None
) -> tuple[list[int], str | None]:
    """Heads that carry a structure, from its whitened coefficients ``W`` (values x channels;
    complex: Fourier coefficients, real: block means).

    Each channel is seen through what the base model cannot take: without a reference the
    heads' mean is removed (``P``), and at an integer order ``m <= M`` the base model's disk
    error takes the pattern ``b_k = exp(-i m alpha_k)`` (one disk seen by every head). A
    structure on head ``k`` alone therefore shows on every head as ``u_k``, ``e_k`` less those
    parts. Each one-head pattern is fitted; the structure is reported on head ``k`` only when
    ``u_k`` leaves no significant power (chi-square at ``FinderSettings.alpha``, or
    ``heads_left_share`` of a strong structure's power) and fits significantly
    better than every other head's pattern. When the patterns cannot be told apart (too few
    heads for what the base takes) or none fits, the structure is reported on ``ch`` (the
    channels where it is significant) with a note saying so."""
    W = np.asarray(W)
    if W.ndim == 1:
        W = W[None, :]
    C = W.shape[1]
    if C < 2:
        return ch, None
    names = prep.kd.channel_names
    proj = bool(prep.kd.project)
    M = int(prep.ctx.max_order) if hasattr(prep, "ctx") else 0
    base = (
        order is not None
        and np.iscomplexobj(W)
        and abs(order - round(order)) < 1e-9
        and 1 <= round(order) <= M
    )
    B = []
    if proj:
        B.append(np.ones(C, complex) / math.sqrt(C))
    if base:
        alpha = np.asarray(prep.consts["alpha"], float)
        B.append(np.exp(-1j * round(order) * alpha))
    if B:
        Qb, _ = np.linalg.qr(np.stack(B, 1))
    else:
        Qb = np.zeros((C, 0), complex)
    free = C - Qb.shape[1]  # complex (or real) dimensions the base model leaves
    if not B:
        return ch, None
    what = " and ".join(
        (["the heads' mean (no reference)"] if proj else [])
        + ([f"the base model's disk error at order {round(order)}"] if base else [])
    )
    if free < 2:
        return sorted(set(ch) | set(range(C))) if proj else ch, (
            f"confounded: with {C} heads, {what} leave too little to tell which head carries it"
        )
    res = []
    for k in range(C):
        u = np.zeros(C, complex)
        u[k] = 1.0
        u = u - Qb @ (Qb.conj().T @ u)
        nu = np.linalg.norm(u)
        u = u / nu if nu > 0 else u
        res.append(float(np.sum(np.abs(W) ** 2) - np.sum(np.abs(W @ u.conj()) ** 2)))
    order_k = np.argsort(res)
    k1, k2 = int(order_k[0]), int(order_k[1])
    f = 2 if np.iscomplexobj(W) else 1
    rows = W.shape[0]
    tot = float(np.sum(np.abs(W) ** 2))
    # what the pattern leaves: noise, or at most heads_left_share of the power (a strong
    # structure is not seen through exactly equal heads: sensitivities, placements, per-head
    # noise weights)
    left_ok = res[k1] <= max(
        chi2_threshold(prep.settings.alpha, f * rows * (free - 1), 1),
        prep.settings.heads_left_share * tot,
    )
    if left_ok and res[k2] - res[k1] > chi2_threshold(prep.settings.alpha, f * rows, 1):
        return [k1], f"on {names[k1]} alone (the other heads show it through {what})"
    return ch, f"on several heads, or not told apart from {what}"


def _carrying(prep, pw: np.ndarray, thr: float) -> list[int]:
    """The channels that carry a structure: power above the test threshold ``thr`` and at
    least ``settings.channel_power_share`` of the strongest channel's."""
    top = prep.settings.channel_power_share * pw.max()
    return [k for k in range(pw.size) if pw[k] > thr and pw[k] >= top]


def view_orders(prep, rw, max_order: int, channels=None, scale=None) -> list[Finding]:
    """Integer shaft orders per channel, rotation locked over all runs (least squares of
    cos / sin of each order, from sums accumulated in blocks of rows). Only ``channels``
    (default all) are scanned and counted in the threshold's tests; the others show 0.
    ``scale`` (max_order, C): a factor per order and channel on the chi-square (SDS: the
    level without the tested columns, :mod:`..kinds.sds._sds_level_out`)."""
    C = rw.shape[1]
    ch_in = list(range(C)) if channels is None else list(channels)
    out = []
    thr = chi2_threshold(prep.settings.alpha, 2, max_order * len(ch_in))
    orders = np.arange(1, max_order + 1)
    sums = order_scan(prep, rw, max_order, ch_in)
    N = sums.n
    Scc, Sss, Scs, Bc_in, Bs_in = sums.totals()
    Bc, Bs = np.zeros((orders.size, C)), np.zeros((orders.size, C))
    Bc[:, ch_in], Bs[:, ch_in] = Bc_in, Bs_in
    for i, m in enumerate(orders):
        G = np.array([[Scc[i], Scs[i]], [Scs[i], Sss[i]]])
        B = np.stack([Bc[i], Bs[i]])  # (2, C)
        if N <= 2:
            continue
        coef = np.linalg.lstsq(G, B, rcond=None)[0]  # (2, C): the cos / sin amplitudes
        pw = np.maximum(np.sum(B * coef, axis=0), 0.0) * (1.0 if scale is None else scale[i])
        if pw.max() > thr:
            ch = _carrying(prep, pw, thr)
            Z = coef * math.sqrt(0.5 * N)
            heads, note = _heads(prep, Z[0] - 1j * Z[1], ch, order=float(m))
            detail = {
                "integer_order": True,
                "n_values": int(N),
                "power_per_channel": pw.tolist(),
            }
            if note:
                detail["heads_note"] = note
            out.append(
                Finding(
                    "orders",
                    make_where(orders=[float(m)], heads=heads, runs=prep.run_ids.tolist()),
                    float(pw[ch].sum()),
                    2 * len(ch),
                    log10_tail_p(float(pw.max()), 2),
                    detail=detail,
                )
            )
    return out


def view_spectrum(prep, rw) -> list[Finding]:
    """Periodogram per run (channels summed), peaks in Hz and shaft order."""
    keep = prep.keep
    C = rw.shape[1]
    dof_ch = C - 1 if prep.kd.project and C > 1 else C
    peaks = []
    # the runs and bins tested (the threshold) first, then one run's transform at a time
    runs = []
    for r, (a, b) in _run_slices(prep):
        nk = int(keep[a:b].sum())
        if b - a >= prep.settings.spectrum_min_rows and nk >= prep.settings.spectrum_min_rows:
            runs.append((r, a, b, nk))
    out: list[Finding] = []
    if not runs:
        return out
    n_tests, d_est = sum((b - a) // 2 + 1 for _, a, b, _ in runs), pooled_noise_dof(prep)
    thr = estimated_threshold(prep.settings.alpha, 2 * dof_ch, n_tests, d_est)  # issue 44: F
    per_run = []
    for r, a, b, nk in runs:
        t = _col(prep, "t", a, b)
        dt = float(np.median(np.diff(t)))
        kr = keep[a:b]
        X = _run_rfft(prep, rw, kr, a, b)
        P = 2.0 * np.abs(X) ** 2 / nk  # ~ chi2(2) per channel
        P[0] = 0.0
        if (b - a) % 2 == 0:
            P[-1] = 0.0
        Ps = P.sum(1)  # each line's power: three bins (leakage), tested on the centre
        idx = np.flatnonzero((Ps > thr) & (Ps >= np.roll(Ps, 1)) & (Ps >= np.roll(Ps, -1)))
        lines = separate_lines(rw, (a, b), kr, X, Ps, idx, thr, prep.settings)
        f = np.fft.rfftfreq(b - a, dt)
        # revolutions per second from the steady speeds (a record that turns back and
        # forth has no net advance)
        om = _col(prep, "omega", a, b)[kr]
        frev = float(np.median(np.abs(om))) / (2 * np.pi)
        # a run turning backwards sees exp(+i m alpha_k) at positive frequencies
        if np.median(om) < 0:
            X = np.conj(X)  # (a copy: the transform is shared with the band view)
        per_run.append((r, frev))
        for i in lines:
            lo, hi = max(i - 1, 1), min(i + 2, Ps.size)
            band = P[lo:hi].sum(0)
            # parabolic interpolation of the frequency
            if 0 < i < Ps.size - 1:
                pl, pc, pr = Ps[i - 1], Ps[i], Ps[i + 1]
                den = pl - 2 * pc + pr
                di = 0.5 * (pl - pr) / den if den != 0 else 0.0
            else:
                di = 0.0
            fr = float(f[1] * (i + di)) if f.size > 1 else 0.0
            peaks.append(
                dict(
                    run=r,
                    f_hz=fr,
                    order=fr / frev if frev > 0 else float("nan"),
                    power=float(band.sum()),
                    band=band,
                    z=X[lo:hi] * math.sqrt(2.0 / nk),
                    bin_hz=float(f[1]),
                    bin_order=float(f[1] / frev) if frev > 0 else float("nan"),
                    nk=nk,
                    logp=estimated_log10_p(Ps[i], 2 * dof_ch, d_est, log10_tail_p),
                )
            )
    # group peaks across runs: fixed in Hz or in order
    used = [False] * len(peaks)
    peaks.sort(key=lambda p: -p["power"])
    speeds = dict(per_run)
    s = prep.settings
    multi_speed = len(per_run) > 1 and (
        max(speeds.values()) > s.spectrum_speed_ratio * max(min(speeds.values()), 1e-12)
    )
    for i, p in enumerate(peaks):
        if used[i]:
            continue
        grp_hz = [
            j
            for j, q in enumerate(peaks)
            if not used[j]
            and abs(q["f_hz"] - p["f_hz"]) <= s.peak_match_bins * max(p["bin_hz"], q["bin_hz"])
        ]
        grp_ord = [
            j
            for j, q in enumerate(peaks)
            if not used[j]
            and abs(q["order"] - p["order"])
            <= s.peak_match_bins * max(p["bin_order"], q["bin_order"])
        ]
        runs_hz = {peaks[j]["run"] for j in grp_hz}
        runs_ord = {peaks[j]["run"] for j in grp_ord}
        if not multi_speed or len(runs_hz) == len(runs_ord):
            fixed = (
                "single_run"
                if len(runs_ord) == 1 and len(per_run) > 1 and multi_speed
                else ("undetermined")
            )
            grp = grp_ord if len(grp_ord) >= len(grp_hz) else grp_hz
        elif len(runs_hz) > len(runs_ord):
            fixed, grp = "hz", grp_hz
        else:
            fixed, grp = "order", grp_ord
        for j in grp:
            used[j] = True
        sel = [peaks[j] for j in grp]
        band = np.sum([q["band"] for q in sel], 0)
        orders = [q["order"] for q in sel]
        integer = (
            all(
                abs(o - round(o)) <= max(s.integer_order_bins * q["bin_order"], s.integer_order_tol)
                for o, q in zip(orders, sel)
                if np.isfinite(o)
            )
            and all(round(o) >= 1 for o in orders if np.isfinite(o))
            and any(np.isfinite(o) for o in orders)
        )
        thr_ch = estimated_threshold(s.alpha, 2, n_tests, pooled_noise_dof(prep, True))
        ch = [
            k
            for k in range(C)
            if band[k] > s.head_chi2_share * thr_ch and band[k] >= s.head_power_share * band.max()
        ]
        zs = np.concatenate([q["z"] for q in sel], 0)
        ints = {round(o) for o in orders if np.isfinite(o)}
        o0 = ints.pop() if integer and len(ints) == 1 else None  # one integer order
        ch, note = _heads(prep, zs, ch, order=float(round(o0)) if o0 is not None else None)
        out.append(
            Finding(
                "spectrum",
                make_where(
                    orders=[float(o) for o in orders],
                    frequencies_hz=[float(q["f_hz"]) for q in sel],
                    heads=ch or [int(np.argmax(band))],
                    runs=[int(prep.run_ids[q["run"]]) for q in sel],
                ),
                float(band.sum()),
                2 * 3 * C * len(sel),
                float(min(q["logp"] for q in sel)),
                detail={
                    "fixed_in": fixed,
                    "integer_order": bool(integer),
                    "n_values": int(sum(q["nk"] for q in sel)),
                    **({"heads_note": note} if note else {}),
                },
            )
        )
    return out[: s.spectrum_findings_max]


def run_spans(run: np.ndarray) -> list[tuple[int, tuple[int, int]]]:
    """``(run index, (start, stop))`` of each stretch of rows with one run index (prepared
    rows are sorted run by run, so one stretch per run)."""
    run = np.asarray(run)
    cut = np.flatnonzero(np.diff(run)) + 1
    edges = [0, *cut.tolist(), run.size]
    return [(int(run[a]), (a, b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def _run_slices(prep):
    """:func:`run_spans` of a prepared record."""
    return run_spans(prep.run)


def _run_rfft(prep, rw, kr: np.ndarray, a: int, b: int) -> np.ndarray:
    """The transform of rows ``a:b`` (a run; excluded rows zero), kept for the sizes of a
    reused scan (:meth:`._views_sums.ViewSums.linear`; read only)."""
    return linear(
        prep,
        ("rfft", a, b),
        lambda: [np.fft.rfft(np.where(kr[:, None], rw[a:b], 0.0), axis=0)],
        large=True,
    )[0]


def view_band(prep, rw, n_bands: int = 16) -> list[Finding]:
    """Broadband excess: periodogram power per run, channel and frequency band (1/16 of the
    band to Nyquist), for structure spread over many bins (a chirp, a wideband noise)."""
    keep = prep.keep
    C = rw.shape[1]
    found: list[Finding] = []

    def bands(m: int) -> list[tuple[int, int]]:
        n_bins = m // 2 + 1
        edges = np.linspace(1, n_bins - 1, n_bands + 1).astype(int)
        return [(lo, hi) for lo, hi in zip(edges[:-1], edges[1:]) if hi - lo >= 4]

    runs = []
    for r, (a, b) in _run_slices(prep):
        nk = int(keep[a:b].sum())
        if nk >= prep.settings.band_min_rows:
            runs.append((r, a, b, nk))
    n_tests = sum(len(bands(b - a)) for _, a, b, _ in runs) * C
    if not n_tests:
        return found
    for r, a, b, nk in runs:  # one run's transform at a time
        kr = keep[a:b]
        m = b - a
        Xf = _run_rfft(prep, rw, kr, a, b)
        P = 2.0 * np.abs(Xf) ** 2 / nk
        dt = float(np.median(np.diff(_col(prep, "t", a, b))))
        f = np.fft.rfftfreq(m, dt)
        for lo, hi in bands(m):
            pw = P[lo:hi].sum(0) * (nk / m)
            dof = 2 * (hi - lo)
            thr = chi2_threshold(prep.settings.alpha, dof, n_tests)
            share = prep.settings.head_power_share
            ch = [k for k in range(C) if pw[k] > thr and pw[k] - dof >= share * (pw.max() - dof)]
            if not ch:
                continue
            Xb = Xf[lo:hi] * math.sqrt(2.0 / m)
            heads, note = _heads(prep, Xb, ch)
            found.append(
                Finding(
                    "band",
                    make_where(
                        frequencies_hz=[float(f[lo]), float(f[hi - 1])],
                        heads=heads,
                        runs=[int(prep.run_ids[r])],
                    ),
                    float(pw[ch].sum()),
                    dof * len(ch),
                    log10_tail_p(float(pw[ch].max()), dof),
                    detail={"n_values": int(nk), **({"heads_note": note} if note else {})},
                )
            )
    return found


def view_time(prep, rw) -> list[Finding]:
    """Block means over time per channel and run; and the best change point."""
    keep = prep.keep
    C = rw.shape[1]
    out = []
    blocks_all = []
    for r in range(prep.ctx.n_runs):
        rows = np.flatnonzero((prep.run == r) & keep)
        nb = int(min(32, max(2, rows.size // 32)))
        if rows.size < 2 * nb:
            continue
        parts = np.array_split(rows, nb)
        means = np.stack([rw[p].sum(0) / math.sqrt(p.size) for p in parts])  # ~N(0,1) each
        blocks_all.append((r, parts, means))
    n_tests = max(1, len(blocks_all) * C)
    c_change = change_chi2(prep.settings.change_time_level)
    for r, parts, means in blocks_all:
        nb = len(parts)
        chi = np.sum(means**2, 0) - np.sum(means, 0) ** 2 / nb  # less the run constant
        thr = chi2_threshold(prep.settings.alpha, nb - 1, n_tests)
        # beside it the best single step (issue 44 C, session 25, ._views_time)
        thr1 = chi2_threshold(prep.settings.time_step_alpha, 1, n_tests * (nb - 1))
        rest = chi2_threshold(prep.settings.alpha, max(nb - 2, 1), n_tests)
        shr = prep.settings.step_shape_share  # main's step: block test and share (._views_time)
        for k in range(C):
            jb, step_pw = jb1, pw1 = best_step(means[:, k])
            if chi[k] <= thr and pw1 <= thr1:
                continue
            b = int(np.argmax(np.abs(means[:, k] - means[:, k].mean())))  # the farthest block
            t0 = float(prep.rows["t"][parts[b][0]])
            t1 = float(prep.rows["t"][parts[b][-1]])
            # or what the best step leaves is within chance; else the CUSUM's edge (._views_time)
            is_step = step_pw > prep.settings.step_shape_share * chi[k] or chi[k] - step_pw <= rest
            jb, step_pw = (jb, step_pw) if is_step else cusum_edge(means[:, k])
            # the step's row: the single change point of largest likelihood near the block
            # edge (CUSUM of the run's rows, white noise: S_i^2 n / (i (n - i)))
            rows_r = np.concatenate(parts)
            i_step, stat = change_row(rw[rows_r, k], parts, jb)
            tstep = float(prep.rows["t"][rows_r[i_step]])
            detail = {
                "shape": "step" if is_step else "transient_or_drift",
                "step_time_s": tstep,
                "global_step_time_s": float(prep.rows.take("tau", rows_r[i_step])),
                "block_s": float(t1 - t0),
                # the best single step alone is significant (a dented step: a transient)
                "step_significant": bool(step_pw > chi2_threshold(prep.settings.alpha, 1, n_tests)),
                "n_values": int(sum(p.size for p in parts)),
                "block_test": bool(chi[k] > thr),  # found by it (else the best step's)
                "by_best_step": bool(is_step and not (chi[k] > thr and step_pw > shr * chi[k])),
            }
            # where the step is: between the last row before it and the first row after it
            detail["step_times_s"] = [float(prep.rows["t"][rows_r[max(i_step - 1, 0)]]), tstep]
            if is_step:
                t0, t1 = detail["step_times_s"]
            located = None
            if is_step:
                # a step's profile of chi-square over its row (CUSUM); a transient or drift
                # is no step, and that interval would not describe it (issue 44 C)
                cand = np.arange(1, rows_r.size)
                _, lo, hi = interval_of(cand, -stat, c_change, best=i_step)
                located = located_time(prep, rows_r, i_step, lo, hi)
            pw, dof = (float(chi[k]), nb - 1) if chi[k] > thr else (pw1, 1)  # its test's
            out.append(
                Finding(
                    "time",
                    make_where(heads=[k], runs=[int(prep.run_ids[r])], times_s=[t0, t1]),
                    pw,
                    dof,
                    log10_tail_p(pw, dof),
                    detail=detail,
                    located_time=located,
                )
            )
    # merge channels that share a run and a time (report a structure on several heads once)
    merged: list[Finding] = []
    for f in sorted(out, key=lambda f: -f.power):
        for g in merged:
            if (
                g.where["runs"] == f.where["runs"]
                and abs(g.detail["step_time_s"] - f.detail["step_time_s"])
                < 1e-9
                + prep.settings.time_merge_blocks * g.detail["block_s"]
                + prep.settings.time_merge_s
            ):
                if f.power >= prep.settings.head_power_share * g.power:
                    g.where["heads"] = sorted(set(g.where["heads"]) | set(f.where["heads"]))
                g.power += f.power
                g.dof += f.dof
                break
        else:
            merged.append(f)
    # which heads: without a reference, one head's step shows on all of them
    zrun = {r: means - means.mean(0) for r, _, means in blocks_all}
    for g in merged:
        r = int(np.flatnonzero(prep.run_ids == g.where["runs"][0])[0])
        heads, note = _heads(prep, zrun[r], g.where["heads"])
        g.where["heads"] = heads
        if note:
            g.detail["heads_note"] = note
    return merged


def _regress_view(prep, rw, name: str, cols: list, extra: dict | None = None):
    """Least squares of the whitened residual on ``cols`` (names of row columns, or arrays),
    less a constant per run (the base model has one): sums accumulated run by run in blocks
    (two passes: run means, then centred products), so nothing per row is held."""
    keep = prep.keep
    C = rw.shape[1]
    q = len(cols)

    def X_of(a: int, b: int) -> np.ndarray:
        return np.stack(
            [(_col(prep, c, a, b) if isinstance(c, str) else np.asarray(c)[a:b]) for c in cols],
            1,
        )

    G = np.zeros((q, q))
    B = np.zeros((q, C))
    xmax = 0.0
    n_kept = 0
    for _, (a0, b0) in _run_slices(prep):
        nk = int(keep[a0:b0].sum())
        if nk == 0:
            continue
        sx, sr = np.zeros(q), np.zeros(C)
        for a, b in _blocks(b0 - a0):
            kb = keep[a0 + a : a0 + b]
            sx += X_of(a0 + a, a0 + b)[kb].sum(0)
            sr += rw[a0 + a : a0 + b][kb].sum(0)
        mx, mr = sx / nk, sr / nk
        for a, b in _blocks(b0 - a0):
            kb = keep[a0 + a : a0 + b]
            X = X_of(a0 + a, a0 + b)[kb]
            if X.size:
                xmax = max(xmax, float(np.abs(X).max()))
            Xc = X - mx
            G += Xc.T @ Xc
            B += Xc.T @ (rw[a0 + a : a0 + b][kb] - mr)
        n_kept += nk
    # nothing left after the run constants (e.g. one speed per run)
    if np.trace(G) <= (1e-12 * (xmax + 1e-300)) ** 2 * max(n_kept, 1):
        return []
    pw = _gram_power(G, B, n_kept, q)
    thr = chi2_threshold(prep.settings.alpha, q, C)
    if pw.max() <= thr:
        return []
    ch = _carrying(prep, pw, thr)
    return [
        Finding(
            name,
            make_where(heads=ch, runs=prep.run_ids.tolist()),
            float(pw[ch].sum()),
            q * len(ch),
            log10_tail_p(float(pw.max()), q),
            detail={"n_values": int(n_kept), **(extra or {})},
        )
    ]


def view_drift(prep, rw):
    """Correlation with the driver (temperature or time)."""
    return _regress_view(prep, rw, "drift", ["driver"], {"driver": prep.ctx.driver_name})


def view_line_phase(prep, rw):
    """Harmonics 1 and 2 of the phase within a signal period, per channel."""
    if prep.ctx.signal_periods <= 0:
        return []
    out = []
    keep = prep.keep
    C = rw.shape[1]
    thr = chi2_threshold(prep.settings.alpha, 4, C)
    G = np.zeros((C, 4, 4))
    B = np.zeros((C, 4))
    n_kept = 0
    for a, b in _blocks(keep.size):
        kb = keep[a:b]
        if not kb.any():
            continue
        psi = np.asarray(_col(prep, "psi", a, b))[kb]
        r = rw[a:b][kb]
        n_kept += int(kb.sum())
        for k in range(C):
            ph = psi[:, k]
            X = np.stack([np.cos(ph), np.sin(ph), np.cos(2 * ph), np.sin(2 * ph)], 1)
            G[k] += X.T @ X
            B[k] += X.T @ r[:, k]
    pw = np.array([_gram_power(G[k], B[k][:, None], n_kept, 4)[0] for k in range(C)])
    # read on a lattice as coarse as the signal period (2 pi / q = L or 2 L counts per turn)
    # the phases sit on a few points: the view would see the staircase, not the signal phase
    lam = np.array([np.linalg.eigvalsh(G[k] / max(n_kept, 1))[0] for k in range(C)])
    pw = np.where(lam < prep.settings.interp_spread_min, 0.0, pw)
    if pw.max() > thr:
        ch = _carrying(prep, pw, thr)
        L = prep.ctx.signal_periods
        out.append(
            Finding(
                "line_phase",
                make_where(orders=[float(L), float(2 * L)], heads=ch, runs=prep.run_ids.tolist()),
                float(pw[ch].sum()),
                4 * len(ch),
                log10_tail_p(float(pw.max()), 4),
                detail={"n_values": int(keep.sum())},
            )
        )
    return out


def view_direction(prep, rw):
    """Mean difference between the directions of rotation."""
    d = prep.rows["direction"][prep.keep]
    if np.all(d == d[0]):
        return []
    del d
    return _regress_view(prep, rw, "direction", ["direction"])


def view_speed(prep, rw):
    """A term proportional to the signed steady speed (needs two speeds or directions)."""
    w = prep.rows["omega"][prep.keep]
    if np.ptp(w) <= prep.settings.one_speed_spread * np.max(np.abs(w)):
        return []
    del w
    return _regress_view(prep, rw, "speed", ["omega"])


def view_angle_trend(prep, rw):
    """A term growing linearly with the shaft angle within each run."""
    return _regress_view(prep, rw, "angle_trend", ["theta"])


VIEWS = {
    "spectrum": lambda prep, rw, M: view_spectrum(prep, rw),
    "orders": lambda prep, rw, M: view_orders(prep, rw, M),
    "time": lambda prep, rw, M: view_time(prep, rw),
    "band": lambda prep, rw, M: view_band(prep, rw),
    "drift": lambda prep, rw, M: view_drift(prep, rw),
    "line_phase": lambda prep, rw, M: view_line_phase(prep, rw),
    "direction": lambda prep, rw, M: view_direction(prep, rw),
    "speed": lambda prep, rw, M: view_speed(prep, rw),
    "angle_trend": lambda prep, rw, M: view_angle_trend(prep, rw),
}


def locate(
    prep, resid: np.ndarray, views: tuple, scan_order: int, scale: float = 1.0, reuse=False
) -> list[Finding]:
    """Run ``views`` on the residual ``scale * resid``; findings strongest first, with
    variance shares. The views share their sums within the scan, and with ``reuse`` across
    the scans of one ``resid`` object at several sizes (:mod:`._views_sums`)."""
    with stage("views"), sums_of(prep).scanning(resid, scale, reuse):
        return _locate(prep, resid, views, scan_order, scale)


def _locate(prep, resid: np.ndarray, views: tuple, scan_order: int, scale: float) -> list[Finding]:
    rw = Whitened(resid, prep.sigma, scale)
    tot = float(sum(np.sum(rw[a:b][prep.keep[a:b]] ** 2) for a, b in _blocks(rw.shape[0])))
    out: list[Finding] = []

    def scans(mine: list) -> list[list[Finding]]:  # this process's views (_workshare.deal)
        got, rw_array = [], None
        for v in mine:
            if isinstance(v, str) or getattr(v, "rows", False):  # rows only (KindView.rows)
                got.append((VIEWS[v] if isinstance(v, str) else v)(prep, rw, scan_order))
            else:  # a kind's own view: a callable ``view(prep, rw, scan_order)`` on an array
                rw_array = np.asarray(rw) if rw_array is None else rw_array
                got.append(v(prep, rw_array, scan_order))
        return got

    for found in deal(list(views), scans):
        out += found
    out = time_steps_beside_order_change(out, prep.settings)
    # a spectrum line at an integer order takes its heads from the rotation-locked fit of
    # that order (the orders view), which sees every run at once
    by_order = {
        round(f.where["orders"][0]): f for f in out if f.view == "orders" and f.where["orders"]
    }
    for f in out:
        if f.view == "spectrum" and f.detail.get("integer_order") and f.where["orders"]:
            ints = {round(o) for o in f.where["orders"] if math.isfinite(o)}
            g = by_order.get(ints.pop()) if len(ints) == 1 else None
            if g is not None:
                f.where["heads"] = list(g.where["heads"])
                if "heads_note" in g.detail:
                    f.detail["heads_note"] = g.detail["heads_note"]
    for f in out:
        f.variance_share = float(max(f.power - f.dof, 0.0) / max(tot, 1e-300))
    out.sort(key=lambda f: f.log10_p)
    return out


def make_where(**kw) -> dict[str, list]:
    base = {"orders": [], "frequencies_hz": [], "heads": [], "runs": [], "times_s": []}
    for k, v in kw.items():
        base[k] = [x.item() if hasattr(x, "item") else x for x in v]
    return base
