"""Stage 1 of the engine, **prepare**: motion segments, noise, glitches, count jumps, folds."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.signal
from scipy import stats

from ..._errors import input_error
from ._candidates import Context
from ._noise import NOISE_BAND_KEY, noise_band, noise_d2, noise_sigma, robust_scale
from ._nuisances import LATE_STAMPS_REASON, angle_steps, late_stamp_rows
from ._protocol import KeptRows, KindData, Prepared, RowColumns, steady_tolerance
from ._settings import DEFAULT_SETTINGS, FinderSettings
from ._views import SCAN_BLOCK, run_spans


def _smooth_speed(shaft: np.ndarray, t: np.ndarray, win: int) -> np.ndarray:
    """Speed (rad/s): the least-squares slope of the angle over ``win`` rows centred on each
    row, as ``sum_k k theta_(i+k) / sum_k k t_(i+k)`` (k = -h..h; exact for a steady turn on
    any time grid, and it averages a quantized angle's rounding over the whole window rather
    than reading it at two ends). The run's ends are padded with their first / last row, which
    keeps the ratio exact there too."""
    n = shaft.size
    if n < 3:
        return np.zeros(n)
    h = max(1, win // 2)
    k = np.arange(h, -h - 1, -1, dtype=float)  # reversed: convolution is a correlation
    # subtract the mean line first (precision on long records)
    w0 = (shaft[-1] - shaft[0]) / (t[-1] - t[0]) if t[-1] != t[0] else 0.0
    tc = t - t[0]
    y = shaft - shaft[0] - w0 * tc
    yp = np.concatenate([np.full(h, y[0]), y, np.full(h, y[-1])])
    tp = np.concatenate([np.full(h, tc[0]), tc, np.full(h, tc[-1])])
    num = scipy.signal.oaconvolve(yp, k, mode="valid")
    den = scipy.signal.oaconvolve(tp, k, mode="valid")
    out = np.zeros(n)
    ok = den > 0
    out[ok] = num[ok] / den[ok] + w0
    return out


def _runs_of(mask: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous ``True`` stretches as (start, stop) index pairs."""
    if mask.size == 0:
        return []
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def speed_window_rows(shaft: np.ndarray, t: np.ndarray, tolerance: float, window: float) -> int:
    """Rows over which the speed is measured when judging steadiness.

    At least ``window`` of the run (and 5 rows), and long enough that the shaft angle's own
    sample-to-sample scatter cannot move the speed estimate out of the ``tolerance``: the
    window slope (:func:`_smooth_speed`, ``w = 2 h + 1`` rows) of an angle with per-sample
    scatter ``s`` (rad) has a speed error ``s / (dt sqrt(S))``, ``S = h (h + 1) (2 h + 1) / 3``,
    held to ``tolerance / 3`` of the typical speed. The scatter is read from second
    differences (``s^2 = mean(d2^2) / 6`` over the smallest 95 %, so a reversal or a glitch
    does not count): a reference quantized to a step ``q`` scatters by about ``q / sqrt(12)``
    plus any sampling jitter, so a coarse reference gets a wider window instead of being read
    as unsteady. Capped at a quarter of the run (and 2001 rows).
    """
    n = shaft.size
    win = max(5, int(window * n))
    if n >= 16:
        a2 = np.sort(np.abs(np.diff(shaft, 2)))
        # mean square of the smallest 95 % (a reversal or a glitch does not count; a MAD
        # would read 0 on a quantized ramp whose second differences are mostly 0 and +-q)
        s = math.sqrt(float(np.mean(a2[: max(1, int(0.95 * a2.size))] ** 2)) / 6.0)
        dt = np.diff(t)
        dt_med = float(np.median(dt)) if dt.size else 0.0
        step = float(np.median(np.abs(np.diff(shaft))))  # typical angle advance per row
        if s > 0 and step > 0 and dt_med > 0:
            need_s = (3.0 * s / (tolerance * step)) ** 2  # S = sum k^2 needed
            h = 1
            while h * (h + 1) * (2 * h + 1) / 3.0 < need_s and h < n:
                h += 1
            win = max(win, 2 * h + 1)
        win = min(win, max(5, n // 4))
    return int(min(win, 2001))


def find_motion_segments(
    shaft: np.ndarray,
    t: np.ndarray,
    tolerance: float,
    window: float,
    settings: FinderSettings = DEFAULT_SETTINGS,
) -> tuple[np.ndarray, list[dict]]:
    """Steady segments of one run.

    A sample is steady when the shaft turns in the direction of a long piece of the run at a
    speed within ``tolerance`` (relative) of that piece's median speed. Pieces are maximal
    stretches of one direction; a piece shorter than ``settings.segment_min_share`` of the
    run (and ``segment_min_rows``) is a return move, a reversal or a start-up, and samples
    slower than ``dwell_speed_share`` of the median speed are dwells. Each excluded stretch
    is widened by the speed window or ``settling_share`` of the run (settling). A piece
    turning against the run's longest piece is kept from ``reversal_piece_share`` of the run
    on (and ``segment_min_rows``) when it follows a long piece of the main direction: a short
    move back after a stop is where a direction offset shows. Before the first long main
    piece such a piece is a return move into the start position and needs
    ``segment_min_share`` like a start-up.

    Returns:
        ``(segment id per sample (-1 excluded), [excluded stretches {start, stop, reason}])``.
    """
    n = shaft.size
    win = speed_window_rows(shaft, t, tolerance, window)
    w = _smooth_speed(shaft, t, win)
    seg = -np.ones(n, dtype=int)
    out: list[dict] = []
    if n < 8:
        return np.zeros(n, dtype=int), out
    sgn = np.sign(w)
    st = settings
    big = np.abs(w) > st.dwell_speed_share * np.median(np.abs(w))
    min_len = max(st.segment_min_rows, int(st.segment_min_share * n))
    pieces = {s: _runs_of(big & (sgn == s)) for s in (1, -1)}
    main = max((1, -1), key=lambda s: max((b - a for a, b in pieces[s]), default=0))
    back_len = min(min_len, max(st.segment_min_rows, int(st.reversal_piece_share * n)))
    # a move back is one that follows motion in the main direction (forward, stop, back):
    # a piece against it before the run's first long main piece is a return move into the
    # start position (a positioning move, then the run) and needs min_len like a start-up
    first_main = min((a for a, b in pieces[main] if b - a >= min_len), default=n)
    sid = 0
    for s in (1, -1):
        for a, b in pieces[s]:
            short_ok = s != main and a > first_main
            if b - a < (back_len if short_ok else min_len):
                continue
            med = np.median(w[a:b])
            ok = np.abs(w[a:b] - med) <= tolerance * abs(med)
            # a piece starts and ends where the speed first / last comes within
            # ramp_edge_tolerance of its steady speed (a ramp is not steady even where it is
            # inside a loose tolerance)
            near = np.flatnonzero(np.abs(w[a:b] - med) <= st.ramp_edge_tolerance * abs(med))
            # (a stretch shorter than the speed window is not resolved as a ramp: at a run's
            # end the window is one-sided and the estimate there leans on the last rows)
            if near.size:
                if near[0] >= win // 2 or a > 0:
                    ok[: near[0]] = False
                if (b - a) - 1 - near[-1] >= win // 2 or b < n:
                    ok[near[-1] + 1 :] = False
            for c, d in _runs_of(ok):
                if d - c >= min(min_len, st.segment_steady_rows):
                    seg[a + c : a + d] = sid
                    sid += 1
    # widen the exclusions (settling after a move)
    bad = seg < 0
    if bad.any() and not bad.all():
        widened = bad.copy()
        h = max(win, int(st.settling_share * n))
        for a, b in _runs_of(bad):
            widened[max(0, a - h) : min(n, b + h)] = True
        seg[widened & ~bad] = -1
    for a, b in _runs_of(seg < 0):
        piece = w[a:b]
        steady = np.median(np.abs(w[seg >= 0])) if (seg >= 0).any() else 0.0
        if np.median(np.abs(piece)) < st.dwell_speed_share * steady:
            reason = "dwell (shaft nearly at rest)"
        elif (
            (seg[:a] >= 0).any()
            and (seg[b:] >= 0).any()
            and np.any(np.sign(piece) != np.sign(np.median(w[seg >= 0])))
        ):
            reason = "reversal or return move (direction changes)"
        elif a == 0 and steady and np.median(piece) * np.median(w[seg >= 0]) < 0:
            reason = "return move into the start position (opposite direction)"
        elif a == 0:
            reason = "start-up (speed far from the steady speed)"
        elif np.any(np.sign(piece) != np.sign(np.median(w[seg >= 0]) if steady else 1)):
            reason = "return move (opposite direction)"
        else:
            reason = "speed far from the segment's steady speed"
        out.append(dict(start=a, stop=b, reason=reason))
    return seg, out


def find_glitches(
    r: np.ndarray,
    seg: np.ndarray,
    project: bool,
    t: np.ndarray | None = None,
    settings: FinderSettings = DEFAULT_SETTINGS,
) -> tuple[list[tuple[int, int]], list[tuple[int, int, float]]]:
    """Single-sample glitches and count jumps in ``r`` (n, C).

    On the second differences (any grid, :func:`noise_d2`), a glitch of size g at row i
    gives ``(-1, 2, -1) g`` at rows ``i-1, i, i+1``; a step between rows i-1 and i gives
    ``(s, -s)`` at ``i-1, i``. Outliers beyond the Gaussian quantile at ``1e-4 / n`` (MAD
    scale) are classified by that pattern (neighbour ratios: ``settings.glitch_neighbour_*``
    and ``jump_neighbour_*``); a clean record has none.

    Returns:
        ``([(row, channel)] glitches, [(row of the first new value, channel, size)] jumps)``;
        channel -1 when the projection cannot tell which channel (two channels, no reference).
    """
    n, C = r.shape
    d2, centre = noise_d2(r, seg, t)
    out_g: list[tuple[int, int]] = []
    out_j: list[tuple[int, int, float]] = []
    if d2.shape[0] < 8:
        return out_g, out_j
    s = robust_scale(d2)  # not the bare MAD: it collapses on a quantized reading
    s = np.where(s > 0, s, np.inf)
    thr = stats.norm.isf(1e-4 / max(n, 1) / 2)
    hit = np.zeros(d2.shape[0], bool)
    for a in range(0, d2.shape[0], SCAN_BLOCK):
        hit[a : a + SCAN_BLOCK] = np.any(np.abs(d2[a : a + SCAN_BLOCK]) > thr * s, 1)
    hit_idx = np.flatnonzero(hit)
    del hit
    # the centres near a hit (row -> index into d2), and their z values
    near = np.unique(np.concatenate([hit_idx + d for d in (-2, -1, 0, 1, 2)]))
    near = near[(near >= 0) & (near < d2.shape[0])]
    pos = {int(centre[i]): int(i) for i in near}
    z = {int(i): d2[i] / s for i in near}
    hit_rows = sorted({int(centre[i]) for i in hit_idx})
    lo_g, hi_g = settings.glitch_neighbour_min, settings.glitch_neighbour_max
    lo_j, hi_j = settings.jump_neighbour_min, settings.jump_neighbour_max
    done: set[int] = set()
    for row in hit_rows:
        if row in done:
            continue
        i = pos[row]
        k = int(np.argmax(np.abs(z[i])))
        # the strongest centre in the neighbourhood
        cands = [pos[q] for q in (row - 1, row, row + 1) if q in pos]
        i = max(cands, key=lambda j: abs(z[j][k]))
        row = int(centre[i])
        zi = z[i][k]
        zl = z[pos[row - 1]][k] if row - 1 in pos else 0.0
        zr = z[pos[row + 1]][k] if row + 1 in pos else 0.0
        kk = -1 if (project and C == 2) else k
        if (
            np.sign(zl) == -np.sign(zi)
            and np.sign(zr) == -np.sign(zi)
            and lo_g < abs(zl / zi) < hi_g
            and lo_g < abs(zr / zi) < hi_g
        ):
            out_g.append((row, kk))
            done |= {row - 1, row, row + 1}
            continue
        # step: the neighbour of opposite sign and similar size
        for nb, zn in ((row + 1, zr), (row - 1, zl)):
            if np.sign(zn) == -np.sign(zi) and lo_j < abs(zn / zi) < hi_j:
                first = max(row, nb)
                size = float(-d2[i, k] / 2.0 * (1 if first == row + 1 else -1))
                # the step size: jump of the level between the two rows
                a, b = first - 1, first
                size = float(r[b, k] - r[a, k])
                out_j.append((first, kk, size))
                done |= {row - 1, row, row + 1, nb}
                break
        else:
            out_g.append((row, kk))
            done |= {row}
    return out_g, out_j


def _fold_blocks(prep_keep: np.ndarray, run: np.ndarray, k: int, seed: int = 0):
    """K folds of contiguous blocks of kept rows, blocks assigned at random (balanced) per run:
    random assignment cannot alias with any periodic structure."""
    fold = -np.ones(run.size, dtype=np.int8)
    rng = np.random.default_rng(seed)
    block_rows = []
    for r in np.unique(run):
        rows = np.flatnonzero((run == r) & prep_keep)
        if rows.size == 0:
            continue
        nb = max(k, min(64, rows.size // 16))
        nb = max(k, nb - nb % k)
        edges = np.linspace(0, rows.size, nb + 1).astype(int)
        assign = np.tile(np.arange(k), nb // k)
        rng.shuffle(assign)
        for b in range(nb):
            fold[rows[edges[b] : edges[b + 1]]] = assign[b]
        block_rows.append(int(np.median(np.diff(edges))))
    design = {
        "k": k,
        "scheme": "contiguous blocks of kept rows within each run, assigned to folds at random "
        "(balanced, seed 0); each fold is predicted by the model fitted on the other K-1",
        "block_rows_median": int(np.median(block_rows)) if block_rows else 0,
        "seed": seed,
    }
    return fold, design


def _runs_in_order(kd: KindData):
    """Run index 0..R-1 in file order per row (4 bytes a row) and the rows sorted run by run
    in time (most records already are: then nothing is copied). Returns ``(kd, run,
    run_ids in file order, sort)`` (``sort``: prepared row -> file row, or ``None``)."""
    run_ids, first, inv = np.unique(kd.run, return_index=True, return_inverse=True)
    order_runs = run_ids[np.argsort(first)]
    # run index 0..R-1 in file order, 4 bytes a row
    rank = np.empty(run_ids.size, dtype=np.int32)
    rank[np.argsort(first)] = np.arange(run_ids.size, dtype=np.int32)
    run = rank[inv.reshape(-1)]
    del inv
    # rows sorted run by run in time (most records already are: then nothing is copied)
    in_order = bool(np.all(np.diff(run) >= 0)) and all(
        np.all(np.diff(kd.t[a:b]) >= 0) for _, (a, b) in run_spans(run)
    )
    sort = None if in_order else np.lexsort((kd.t, run))  # prepared row -> file row
    if sort is not None:
        kd = dataclasses.replace(
            kd,
            y=kd.y[sort],
            shaft=kd.shaft[sort],
            t=kd.t[sort],
            run=kd.run[sort],
            reading=(kd.reading if kd.reading is not None else np.stack(kd.reading_cols, 1))[sort],
            reading_cols=(),
            theta_ref=None if kd.theta_ref is None else kd.theta_ref[sort],
            temp=None if kd.temp is None else kd.temp[sort],
            segments=None if kd.segments is None else kd.segments[sort],
            masked=tuple((m[sort], why) for m, why in kd.masked),
        )
        run = run[sort]
    return kd, run, order_runs, sort


def _segments(kd: KindData, run: np.ndarray, order_runs: np.ndarray, settings: FinderSettings):
    """Gaps in ``t`` and the steady segments of each run; the late stamps after a gap are
    excluded with their own reason (:func:`._nuisances.late_stamp_rows`). Returns ``(seg,
    excluded, gaps, revolutions per run, speed per segment)``."""
    n = kd.y.shape[0]
    R = order_runs.size
    t = kd.t
    # gaps and segments
    seg = -np.ones(n, dtype=np.int32)
    excluded: list[dict] = []
    gaps: list[dict] = []
    nseg = 0
    revs = np.zeros(R)
    seg_speed: list[float] = []
    for r in range(R):
        rows = np.flatnonzero(run == r)
        tr = t[rows]
        dt = np.diff(tr)
        med = np.median(dt) if dt.size else 1.0
        cuts = np.flatnonzero(dt > settings.gap_factor * med) + 1
        for c in cuts:
            gaps.append(
                dict(run=int(order_runs[r]), t_s=float(tr[c - 1]), duration_s=float(dt[c - 1]))
            )
        bounds = [0, *cuts.tolist(), rows.size]
        gap0 = len(gaps) - cuts.size
        for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
            sub = rows[a:b]
            if a > 0:  # after a logger gap: buffered samples stamped late on arrival
                k = late_stamp_rows(np.diff(tr[a:b]), float(med), settings.late_stamp_ratio)
                if k:
                    gaps[gap0 + i - 1]["late_rows"] = k
                    excluded.append(
                        dict(
                            run=int(order_runs[r]),
                            t_start_s=float(t[sub[0]]),
                            t_end_s=float(t[sub[k - 1]]),
                            n_rows=k,
                            reason=LATE_STAMPS_REASON,
                        )
                    )
                    sub = sub[k:]
            if sub.size < 8:
                excluded.append(
                    dict(
                        run=int(order_runs[r]),
                        t_start_s=float(t[sub[0]]),
                        t_end_s=float(t[sub[-1]]),
                        n_rows=int(sub.size),
                        reason="too few rows between gaps",
                    )
                )
                continue
            if kd.segments is not None:  # given by the kind (no motion to segment)
                s_id = np.asarray(kd.segments[sub], dtype=int)
                s_id = np.unique(s_id, return_inverse=True)[1].reshape(s_id.shape)
                bad = []
            else:
                s_id, bad = find_motion_segments(
                    kd.shaft[sub],
                    t[sub],
                    steady_tolerance(kd, settings),
                    kd.speed_window,
                    settings,
                )
            for sid in np.unique(s_id[s_id >= 0]):
                m = sub[s_id == sid]
                seg[m] = nseg
                w = np.polyfit(t[m] - t[m].mean(), kd.shaft[m], 1)[0] if m.size > 2 else 0.0
                seg_speed.append(float(w))
                revs[r] += abs(kd.shaft[m[-1]] - kd.shaft[m[0]]) / (2 * np.pi)
                nseg += 1
            for e in bad:
                ss = sub[e["start"] : e["stop"]]
                excluded.append(
                    dict(
                        run=int(order_runs[r]),
                        t_start_s=float(t[ss[0]]),
                        t_end_s=float(t[ss[-1]]),
                        n_rows=int(ss.size),
                        reason=e["reason"],
                    )
                )
    return seg, excluded, gaps, revs, seg_speed


def _mask_rows(kd: KindData, seg, run, order_runs, excluded) -> np.ndarray:
    """Rows the kind leaves out (``kd.masked``) leave ``seg`` (in place); returns the steady
    segments of the motion before the masks (their speeds give omega and the direction)."""
    t = kd.t
    seg_motion = seg.copy() if kd.masked else seg
    for mask, why in kd.masked:  # rows the kind leaves out (e.g. clipped signals)
        mask = np.asarray(mask, bool) & (seg >= 0)
        if mask.any():
            idx = np.flatnonzero(mask)
            excluded.append(
                dict(
                    run=int(order_runs[run[idx[0]]]),
                    t_start_s=float(t[idx[0]]),
                    t_end_s=float(t[idx[-1]]),
                    n_rows=int(idx.size),
                    reason=why,
                    stretches=len(_runs_of(mask)),
                )
            )
            seg[mask] = -1
    return seg_motion


def _glitches_and_noise(kd: KindData, seg, keep, run, order_runs, sort, settings, band=None):
    """Glitches and count jumps on a first detrended residual (``keep`` updated in place),
    and the noise per channel (robust first). Returns ``(kd, glitches, count_jumps, seg_eff,
    sigma)``."""
    where, t = kd.where, kd.t
    # noise (robust first), glitches and count jumps on a first detrended residual
    # kd.y is the kind's own array (never the user's columns) and is not modified: no copy
    y = kd.y - kd.y.mean(1, keepdims=True) if kd.project else kd.y
    if y is not kd.y:  # one (n, C) array held, not two
        kd = dataclasses.replace(kd, y=y)
    glitches_raw, jumps_raw = find_glitches(_detrend(y, seg), seg, kd.project, t, settings)
    glitches, count_jumps = [], []
    for i, k in glitches_raw:
        keep[i] = False
        glitches.append(
            dict(
                run=int(order_runs[run[i]]),
                t_s=float(t[i]),
                row=int(i if sort is None else sort[i]),
                channel=None if k < 0 else kd.channel_names[k],
            )
        )
    for i, k, size in jumps_raw:
        count_jumps.append(
            dict(
                run=int(order_runs[run[i]]),
                t_s=float(t[i]),
                row=int(i if sort is None else sort[i]),
                channel=None if k < 0 else kd.channel_names[k],
                channel_index=k,
                size=size,
                index=i,
                note="a step of one channel's reading (missed or extra counts); modelled as "
                "a constant change from then on"
                + ("; two channels without a reference: which one cannot be told" if k < 0 else ""),
            )
        )
    seg_eff = seg if np.array_equal(keep, seg >= 0) else np.where(keep, seg, -1).astype(np.int32)
    seg_noise = seg_eff.copy() if jumps_raw else seg_eff
    for i, _, _ in jumps_raw:  # the step itself is not noise
        seg_noise[max(i - 1, 0) : i + 1] = -1
    yd = _detrend(y, seg_eff)
    # a decimated record (issue 43, stage 2: ``band``) holds only noise above its passband
    got = None if band is None else noise_band(yd, seg_noise, band[0], band[1])
    if got is not None:
        sigma, sigma_r = got
    else:
        sigma = noise_sigma(yd, seg_noise, robust=False, t=t)
        sigma_r = noise_sigma(yd, seg_noise, robust=True, t=t)
    del yd
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, sigma_r)
    if not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
        raise input_error(where, "the noise cannot be estimated", "readings that vary")
    return kd, glitches, count_jumps, seg_eff, sigma


def _row_columns(kd: KindData, run, R: int, seg_motion, seg_speed, keep):
    """The row columns: the recording's own arrays, or lazy (computed per chunk from them).
    Returns ``(rows, driver_name)``."""
    n, C = kd.y.shape
    t = kd.t
    t0_run = np.zeros(R)
    off_run = np.zeros(R)
    off = 0.0
    for r, (a, b) in run_spans(run):
        tr = t[a:b]
        dtm = float(np.median(np.diff(tr))) if b - a > 1 else 1.0
        t0_run[r] = tr[0]
        off_run[r] = off
        off = tr[-1] - tr[0] + off + dtm

    def tau_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Time across the runs, each run after the previous one (s)."""
        ru = run[lo:hi]
        return t[lo:hi] - t0_run[ru] + off_run[ru]

    speeds = np.asarray([*seg_speed, 0.0])  # index -1: no steady segment

    def omega_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Steady speed of the row's segment (rad/s; 0 outside segments)."""
        return speeds[seg_motion[lo:hi]]

    def direction_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        return np.where(omega_rows(lo, hi) >= 0, 1.0, -1.0)

    theta = kd.theta_ref if kd.theta_ref is not None else kd.shaft
    if kd.temp is not None and np.ptp(kd.temp[keep]) > 0:
        temp, t_mean = kd.temp, float(kd.temp[keep].mean())
        driver_name = "temp_c"

        def driver_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
            return temp[lo:hi] - t_mean
    else:
        tau_mean = float(np.mean(tau_rows()[keep]))
        driver_name = "time"

        def driver_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
            return tau_rows(lo, hi) - tau_mean

    L = kd.signal_periods

    def reading_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Each channel's reading (rad)."""
        if kd.reading is not None:
            return kd.reading[lo:hi]
        return np.stack([c[lo:hi] for c in kd.reading_cols], 1)

    def psi_rows(lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Signal phase of each channel's reading (rad); zero without signal periods."""
        if L > 0:
            return np.mod(L * reading_rows(lo, hi), 2 * np.pi)
        m = (hi if hi is not None else n) - lo
        return np.broadcast_to(0.0, (max(m, 0), C))

    stored = dict(
        t=t,
        theta=theta,
        # no reference: zero (a read-only broadcast, no memory)
        theta_ref=kd.theta_ref if kd.theta_ref is not None else np.broadcast_to(0.0, (n,)),
    )
    lazy = dict(
        tau=tau_rows,
        omega=omega_rows,
        direction=direction_rows,
        driver=driver_rows,
        psi=psi_rows,
        reading=reading_rows,
    )
    if kd.reading is not None:
        stored["reading"] = kd.reading
        del lazy["reading"]
    return RowColumns(stored, run, R, lazy), driver_name


def prepare(kd: KindData, meta: dict, settings: FinderSettings = DEFAULT_SETTINGS) -> Prepared:
    """Stage 1: nuisances, noise, folds (see module doc). Raises EncdesignInputError."""
    n, C = kd.y.shape
    where = kd.where
    if n < settings.diagnose_min_rows:
        raise input_error(
            where, f"only {n} rows", f"at least {settings.diagnose_min_rows} rows to diagnose"
        )
    if not np.all(np.isfinite(kd.y)):
        raise input_error(where, "non-finite readings", "finite values")
    kd, run, order_runs, sort = _runs_in_order(kd)
    R = order_runs.size
    t = kd.t
    seg, excluded, gaps, revs, seg_speed = _segments(kd, run, order_runs, settings)
    seg_motion = _mask_rows(kd, seg, run, order_runs, excluded)
    keep = seg >= 0
    if keep.sum() < settings.diagnose_min_rows:
        raise input_error(
            where,
            f"no steady segment of at least {settings.diagnose_min_rows} rows",
            "a shaft turning steadily",
        )
    kd, glitches, count_jumps, seg_eff, sigma = _glitches_and_noise(
        kd, seg, keep, run, order_runs, sort, settings, meta.get(NOISE_BAND_KEY)
    )
    ang = kd.theta_ref if kd.theta_ref is not None else kd.shaft  # recurring: of the angle
    steps_of_angle, count_jumps = angle_steps(count_jumps, ang, settings)
    y = kd.y
    fold, design = _fold_blocks(keep, run, settings.n_folds)
    fold[~keep] = -1
    rows, driver_name = _row_columns(kd, run, R, seg_motion, seg_speed, keep)
    L = kd.signal_periods
    dt_med = float(np.median(np.diff(t))) if n > 1 else 1.0
    consts = dict(
        step_width_s=np.asarray(0.5 * abs(dt_med) if dt_med > 0 else 1e-3),
        alpha=np.asarray(kd.alpha, float),
        radius_m=np.asarray(kd.radius_m if kd.radius_m else 1.0, float),
        signal_periods=np.asarray(float(L)),
        n_runs=np.asarray(float(R)),
        **kd.constants,
    )
    krows = KeptRows(rows, keep)
    ctx = Context(
        kind=meta.get("kind", ""),
        n_channels=C,
        n_runs=R,
        has_ref=kd.theta_ref is not None,
        sensor=kd.sensor,
        signal_periods=L,
        radius_m=kd.radius_m,
        rows=krows,
        consts=consts,
        noise=sigma,
        revolutions=revs,
        meta=meta,
        settings=settings,
        driver_name=driver_name,
        data=kd,
    )
    return Prepared(
        kd=kd,
        ctx=ctx,
        y=y,
        rows=rows,
        consts=consts,
        keep=keep,
        fold=fold,
        seg=seg_eff,
        sigma=sigma,
        excluded=excluded,
        glitches=glitches,
        count_jumps=count_jumps,
        angle_steps=steps_of_angle,
        gaps=gaps,
        fold_design=design,
        run_ids=order_runs,
        run=run,
        settings=settings,
        part_turn_span=part_turn_span(np.asarray(kd.shaft, float), keep, run),
    )


def part_turn_span(shaft: np.ndarray, keep: np.ndarray, run: np.ndarray) -> float | None:
    """The widest shaft-angle span (rad) of a run's kept rows where every run covers less than
    one turn (the base's orders are then not separable: their held-out error measures that
    ill-conditioning, not their fit; issue 44), else ``None`` (``Prepared.part_turn_span``).
    A run's span is its kept angles' range plus its median step between neighbouring rows:
    N rows evenly spaced over a whole turn have a range of only ``2 pi (N - 1) / N``, and
    they cover the turn (session 20: a 200-row turn of ``magalpha_cal`` counted as part of
    one)."""
    widest = 0.0
    for _, (a, b) in run_spans(run):
        th = shaft[a:b][keep[a:b]]
        if th.size:
            widest = max(widest, float(np.ptp(th)) + _median_step(th))
    return widest if widest < 2 * np.pi else None


def _median_step(th: np.ndarray) -> float:
    """The median step (rad) between neighbouring rows' angles ``th`` that differ; 0.0
    where none do."""
    steps = np.abs(np.diff(th))
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else 0.0


def folds_see_each_others_arcs(
    shaft: np.ndarray, keep: np.ndarray, run: np.ndarray, fold: np.ndarray
) -> bool:
    """Whether, in every run, the rows each held-out fold leaves out lie on shaft angles the
    other folds see: the median distance (rad) from a held-out row's angle to the nearest
    angle of the same run's other folds is at most the run's median step between neighbouring
    rows (a pass forward and back over the arc; on a single pass the blocks' own arcs are seen
    by no other fold). Where they do not, held-out error on part of a turn measures how the
    orders extrapolate over a held-out block's arc, not their need (issue 44, session 20)."""
    for _, (a, b) in run_spans(run):
        k = keep[a:b] & (fold[a:b] >= 0)
        th, fo = shaft[a:b][k], fold[a:b][k]
        step = _median_step(th)
        if not step:  # (no two rows at different angles)
            continue
        dist = []
        for f in np.unique(fo):
            other = np.sort(th[fo != f])
            if other.size == 0:
                return False
            x = th[fo == f]
            j = np.clip(np.searchsorted(other, x), 1, max(other.size - 1, 1))
            lo, hi = other[j - 1], other[np.minimum(j, other.size - 1)]
            dist.append(np.minimum(np.abs(x - lo), np.abs(x - hi)))
        if float(np.median(np.concatenate(dist))) > step:
            return False
    return True


def _detrend(y: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """``y`` less a per-segment quadratic in the row's rank within its segment, mapped to
    [-1, 1] (for the noise and glitch scans only). Normal equations accumulated in blocks:
    the temporaries are bounded by :data:`SCAN_BLOCK` rows, not by the segment."""
    out = np.zeros_like(y)
    ids = np.flatnonzero(seg >= 0)
    if ids.size == 0:
        return out
    order = ids[np.argsort(seg[ids], kind="stable")]  # rows grouped by segment, in order
    del ids
    sv = seg[order]
    cut = np.flatnonzero(np.diff(sv)) + 1
    edges = [0, *cut.tolist(), order.size]
    for lo, hi in zip(edges[:-1], edges[1:]):
        cnt = hi - lo
        den = max(cnt - 1, 1)

        def design(a: int, b: int, lo=lo, den=den, cnt=cnt) -> np.ndarray:
            x = (
                -1.0 + 2.0 * (np.arange(a - lo, b - lo, dtype=float) / den)
                if cnt > 1
                else np.full(b - a, -1.0)
            )
            return np.stack([np.ones_like(x), x, x**2], 1)

        G = np.zeros((3, 3))
        h = np.zeros((3, y.shape[1]))
        for a in range(lo, hi, SCAN_BLOCK):
            b = min(hi, a + SCAN_BLOCK)
            X = design(a, b)
            yb = y[order[a:b]]
            G += X.T @ X
            h += X.T @ yb
        coef = np.linalg.lstsq(G, h, rcond=None)[0]
        for a in range(lo, hi, SCAN_BLOCK):
            b = min(hi, a + SCAN_BLOCK)
            rows = order[a:b]
            out[rows] = y[rows] - design(a, b) @ coef
    return out
