"""Noise of a recording per channel: second differences within motion segments (any time
grid), robust scales, and the spectral estimate of a residual."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ._protocol import Prepared
from ._views import SCAN_BLOCK


def noise_d2(r: np.ndarray, seg: np.ndarray, t: np.ndarray | None = None):
    """Second differences of ``r`` (n, C) within segments, on any time grid: each value less
    the straight line through its two neighbours, scaled so that white noise of std sigma
    gives ``6 sigma^2`` (as the plain second difference on a uniform grid). A straight line
    gives exactly zero on any grid. Returns (values (m, C), index of the centre row).

    Computed in blocks of :data:`SCAN_BLOCK` rows (temporaries bounded by the block)."""
    n, C = r.shape
    if n < 3:
        return np.zeros((0, C)), np.zeros(0, dtype=np.int64)
    ok = (seg[2:] == seg[1:-1]) & (seg[1:-1] == seg[:-2]) & (seg[1:-1] >= 0)
    centre = np.flatnonzero(ok) + 1
    out = np.empty((centre.size, C))
    pos = 0
    for a in range(1, n - 1, SCAN_BLOCK):
        b = min(n - 1, a + SCAN_BLOCK)  # centres a..b-1
        okb = ok[a - 1 : b - 1]
        m = int(okb.sum())
        if m == 0:
            continue
        rm, r0, rp = r[a - 1 : b - 1], r[a:b], r[a + 1 : b + 1]
        if t is None:
            d2 = rp - 2 * r0 + rm
        else:
            h1 = t[a:b] - t[a - 1 : b - 1]
            h2 = t[a + 1 : b + 1] - t[a:b]
            hs = np.where(h1 + h2 > 0, h1 + h2, 1.0)
            w1, w2 = h2 / hs, h1 / hs
            e = r0 - (w1[:, None] * rm + w2[:, None] * rp)
            d2 = -2.0 * e * np.sqrt(1.5 / (1.0 + w1**2 + w2**2))[:, None]
        out[pos : pos + m] = d2[okb]
        pos += m
    return out, centre


TRIM_QUANTILE = 0.99
"""Share of the smallest ``|d2|`` kept by the trimmed-RMS scale of :func:`robust_scale`."""
_TRIM_RMS = math.sqrt(
    1.0
    - 2.0
    * stats.norm.isf((1 - TRIM_QUANTILE) / 2)
    * stats.norm.pdf(stats.norm.isf((1 - TRIM_QUANTILE) / 2))
    / TRIM_QUANTILE
)
"""RMS of a unit Gaussian within its central ``TRIM_QUANTILE`` (0.962 at 99 %)."""


ROBUST_ROWS = 1 << 18
"""Rows :func:`robust_scale` reads at most."""


def robust_scale(d: np.ndarray) -> np.ndarray:
    """Robust std per column of ``d`` (m, C), centred at zero: the larger of 1.4826 MAD and
    the RMS of the central ``TRIM_QUANTILE`` of ``|d|`` (scaled to a Gaussian's std).

    The MAD alone collapses on values that sit on a lattice: the second differences of a
    quantized reading are mostly exactly 0 (then +-1 LSB), so their MAD is 0 and every step
    of the staircase would read as a glitch or a count jump. The trimmed RMS sees the
    lattice's spread, and a few glitches (under 1 % of the values) cannot inflate it; for
    Gaussian noise both read sigma. Over ``ROBUST_ROWS`` rows, from that many rows drawn at
    random (fixed seed: the scale to a few parts per thousand, memory bounded)."""
    if d.shape[0] > ROBUST_ROWS:
        d = d[np.sort(np.random.default_rng(0).integers(0, d.shape[0], ROBUST_ROWS))]
    a = np.abs(d)
    mad = 1.4826 * np.median(a, axis=0)
    if a.shape[0] < 8:
        return mad
    cut = np.quantile(a, TRIM_QUANTILE, axis=0)
    inner = np.where(a <= cut[None, :], a, 0.0)
    cnt = np.maximum(np.sum(a <= cut[None, :], axis=0), 1)
    trim = np.sqrt(np.einsum("ij,ij->j", inner, inner) / cnt) / _TRIM_RMS
    return np.maximum(mad, trim)


def noise_d1(r: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """First differences of adjacent rows of one segment, times ``sqrt(3)`` so that white
    noise of std sigma gives ``6 sigma^2`` as :func:`noise_d2` (fallback of
    :func:`noise_sigma`), ``(m, C)``."""
    ok = (seg[1:] == seg[:-1]) & (seg[:-1] >= 0)
    return (r[1:][ok] - r[:-1][ok]) * math.sqrt(3.0)


def noise_sigma(
    r: np.ndarray, seg: np.ndarray, robust: bool = False, t: np.ndarray | None = None
) -> np.ndarray:
    """Noise std per channel from second differences within segments:
    ``var(d2) = 6 sigma^2`` for white noise; structure smooth on the sampling scale adds
    ``(omega dt)^4`` of its variance only. ``robust``: from the MAD (glitch-proof).

    Where fewer than 4 rows have both neighbours in their segment (kept rows come in pairs,
    e.g. between the excluded phases of a clipped capture), first differences of adjacent
    kept rows are used instead, scaled to the same ``6 sigma^2``: smooth structure then
    adds ``(omega dt)^2`` of its variance, so the value is an upper bound. NaN only when
    no two adjacent rows are kept."""
    d2, _ = noise_d2(r, seg, t)
    if d2.shape[0] < 4:
        d2 = noise_d1(r, seg)
        if d2.shape[0] < 4:
            return np.full(r.shape[1], np.nan)
    if robust:
        med = np.median(d2, 0)
        d2 -= med[None, :]
        return robust_scale(d2) / math.sqrt(6.0)
    return np.sqrt(np.einsum("ij,ij->j", d2, d2) / d2.shape[0] / 6.0)


NOISE_BAND_KEY = "_noise_band_hz"
"""The key of a recording's ``meta`` that holds ``(passband_hz, rate_hz)`` of a record
decimated by stage 2 of a long record's reduction (issue 43, ``_decimate``)."""

NOISE_BAND_MIN_ROWS = 64
"""Segments of fewer rows add nothing to :func:`noise_band`."""


def noise_band(
    r: np.ndarray, seg: np.ndarray, f_pass: float, fs: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Noise std per channel of a record low-passed to ``f_pass`` Hz and sampled at ``fs``
    Hz with a power-complementary filter (``_decimate``: white noise stays white, and the
    band from ``f_pass`` to ``fs / 2`` holds the noise alone, where second differences would
    see the structure up to ``f_pass``, close to ``fs / 3``): the mean and (robust) the
    median over ``ln 2`` of the Hann-windowed periodogram ``|X_k|^2 / sum(w^2)`` of each
    segment's rows (``seg``; ``-1``: left out) in that band. Returns ``(sigma, sigma_robust)``
    (C,), or ``None`` where no segment of :data:`NOISE_BAND_MIN_ROWS` rows has a bin there."""
    seg = np.asarray(seg)
    cut = np.flatnonzero(np.diff(seg) != 0) + 1
    lo = np.concatenate([[0], cut])
    hi = np.concatenate([cut, [seg.size]])
    bins = []
    for a, b in zip(lo, hi):
        m = int(b - a)
        if seg[a] < 0 or m < NOISE_BAND_MIN_ROWS:
            continue
        P = _band_bins(r[a:b] - r[a:b].mean(0), np.ones(m, bool), f_pass, fs, True)
        if P.shape[0]:
            bins.append(P)
    if not bins:
        return None
    P = np.concatenate(bins, 0)
    return np.sqrt(P.mean(0)), np.sqrt(np.median(P, 0) / math.log(2.0))


def noise_method(prep: Prepared) -> str:
    """The document's ``noise.method``: how :func:`noise_spectral_dof` estimated it."""
    out = (
        "median of the base residual's periodogram per channel (white noise: ln 2 sigma^2; "
        "structure in fewer than half the bins cannot inflate it); second differences for "
        "the first weights and the glitch scan"
    )
    if NOISE_BAND_KEY in (prep.ctx.meta or {}):
        out += (
            "; decimated (reduced.decimation): Hann-windowed, on the band above the passband, "
            "which holds the noise alone, for both (second differences see the structure "
            "below it)"
        )
    return out


def _band_bins(
    x: np.ndarray, kept: np.ndarray, f_pass: float, fs: float, every_bin: bool = False
) -> np.ndarray:
    """Periodogram bins (rows: bins, columns: channels) of one run's residual ``x`` (rows
    left out zero; ``kept``) of a record decimated by stage 2 (``_decimate``), in the band
    from ``f_pass`` to ``fs / 2`` Hz that holds its white noise alone: Hann-windowed (the
    leakage of the lines below ``f_pass`` falls off as the cube of the distance, where a
    rectangular window's spreads a strong line over many of a short run's bins), scaled by
    the window's power on the kept rows (white noise: ``sigma^2`` times a unit exponential),
    every other bin (the window's neighbouring bins are correlated), or with ``every_bin``
    every bin (:func:`noise_band`)."""
    m = x.shape[0]
    w = np.hanning(m)
    norm = float(np.sum(w * w * kept))
    f = np.fft.rfftfreq(m, 1.0 / fs)
    sel = np.flatnonzero((f > f_pass) & (f < fs / 2))[:: 1 if every_bin else 2]
    if sel.size == 0 or norm <= 0:
        return np.zeros((0, x.shape[1]))
    X = np.fft.rfft(x * w[:, None], axis=0)[sel]
    return (X.real**2 + X.imag**2) / norm


def noise_spectral(prep: Prepared, resid: np.ndarray, n_params: int) -> np.ndarray:
    """Noise std per channel (:func:`noise_spectral_dof`'s ``sigma``)."""
    return noise_spectral_dof(prep, resid, n_params)[0]


MEDIAN_DOF_PER_BIN = 2.0 * math.log(2.0) ** 2
"""Effective chi-square degrees of freedom per periodogram bin of a variance estimated from
the bins' median (0.961): the sample median of ``M`` unit exponentials has variance ``1 / M``
(``1 / (4 M f^2)``, density ``f = 1/2`` at the median ``ln 2``), so the estimate
``median / ln 2`` has relative variance ``1 / (M ln^2 2)``, as ``chi2(d) / d`` has ``2 / d``."""


def noise_spectral_dof(
    prep: Prepared, resid: np.ndarray, n_params: int, own: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Noise std per channel from the median of the residual's periodogram, run by run.

    For white noise each periodogram bin ``|X_j|^2 / n`` is ``sigma^2`` times a unit
    exponential, whose median is ``ln 2``; structure in fewer than half of the bins (lines,
    a band, a slow drift, a step) cannot inflate the median much, at any frequency (second
    differences are inflated by structure near the Nyquist frequency). ``n_params``: the
    parameters fitted to ``resid``'s model, which took their share ``n_params / N`` of the
    noise's power out of the bins (on average over the bins: spread by aliased or jittered
    orders, the median is low by that share); the variance is divided by ``1 - share``, as
    the residual variance's dof (session 20, issue 44: 0.88-0.89 of ``sigma^2`` measured at a
    share of 0.11-0.12 on a few hundred jittered rows, a line the views then reported).

    Returns ``(sigma, dof)`` (C,): ``dof`` the effective degrees of freedom of each channel's
    variance estimate, :data:`MEDIAN_DOF_PER_BIN` per bin times ``1 - share`` (issue 44: a
    test that whitens by an estimated ``sigma`` is an F test, not a chi-square one;
    ``_views_estimated``). ``own``: the kind's second estimate (C,), where it has one: the
    smaller of the two per channel, whose ``dof`` is then taken as unlimited (unknown)."""
    C = resid.shape[1]
    bins = [[] for _ in range(C)]
    band = (prep.ctx.meta or {}).get(NOISE_BAND_KEY)
    for r in range(prep.ctx.n_runs):
        rows = np.flatnonzero(prep.run == r)
        kr = prep.keep[rows]
        nk = int(kr.sum())
        if nk < 16:
            continue
        x = np.where(kr[:, None], resid[rows], 0.0)
        x = x - np.where(kr[:, None], x.sum(0) / nk, 0.0)
        if band is not None:
            P = _band_bins(x, kr, band[0], band[1])
        else:
            P = np.abs(np.fft.rfft(x, axis=0)) ** 2 / nk
            P = P[1 : (x.shape[0] - 1) // 2 + 1]
        for k in range(C):
            bins[k].append(P[:, k])
    out = np.full(C, np.nan)
    n_dof = np.full(C, np.inf)
    eff = (C - 1) / C if prep.kd.project and C > 1 else 1.0
    share = n_params / prep.n_values if prep.n_values > 0 else 0.0
    # a decimated record's band above its passband: the fitted terms lie below it
    dof = 1.0 - share if 0 <= share < 1 and band is None else 1.0
    for k in range(C):
        if bins[k]:
            allb = np.concatenate(bins[k])
            if allb.size >= 8:
                out[k] = math.sqrt(np.median(allb) / math.log(2.0) / eff / dof)
                n_dof[k] = MEDIAN_DOF_PER_BIN * allb.size * dof
    if own is not None:
        own = np.asarray(own, float)
        n_dof = np.where(own < out, np.inf, n_dof)
        out = np.fmin(out, own)
    return out, n_dof
