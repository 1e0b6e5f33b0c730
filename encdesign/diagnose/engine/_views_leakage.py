"""The ``spectrum`` view's peaks without the leakage of stronger lines (issue 43, session 27).

A run's periodogram is the transform of its rows as they are (a rectangular window): a line
of frequency ``f`` that is not a whole number of cycles over the run, ``(k + delta) / T``
with ``0 < |delta| <= 1/2``, leaks into every bin, the ``d``-th bin from its centre bin
getting ``sin^2(pi delta) / (pi^2 (d - delta)^2)`` of the line's power. For a line far above
the noise that skirt rises over the view's threshold for many bins, and the noise makes
local maxima in it: lines that are not in the data. (The benchmark's 31 Hz vibration on
the 10^7-row record reduced in blocks of 12 rows: one run of 208,332 block means spans
1549.99 cycles, ``delta = -0.0099``, chi-square 4.5e7 at the line and 4.4e3 / d^2 beside
it: two extra lines at 30.809 and 31.155 Hz, chi-square 219 and 255 on 24 dof. The runs of
208,333 block means, ``delta = -0.0025``, leak 16 times less and showed none.)

:func:`separate_lines` takes the peaks strongest first and keeps a weaker one only where
it stays above the threshold once the leakage of every stronger line kept is taken out of
its bin: each such line is fitted to the run's kept rows (a sinusoid of its own frequency,
amplitude and phase per channel, least squares, the frequency refined within half a bin of
its peak), and its exact transform (the same rows, the same window, its image at ``-f``
included) is subtracted. The leakage left is that of the fitted frequency's error: about
``P (eps / d)^2`` at ``d`` bins for a line of power ``P`` whose frequency is off by ``eps``
bins (``eps`` about ``1 / sqrt(P)`` in chi-square units: under one unit of chi-square for
any line). A stronger line's fit is skipped where its leakage cannot matter: for
``|delta| <= 1/2`` the centre bin holds at least ``4 / pi^2`` of the line's power, so the
leakage at ``d`` bins is at most ``P_c / (4 (d - 1/2)^2)`` of the centre bin's ``P_c``, and a
peak whose power stays above the threshold after the largest such leakage is taken off its
amplitude (triangle inequality over the channels) is kept as it is. The peaks kept are
reported with their own transform (unchanged numbers).
"""

from __future__ import annotations

import math

import numpy as np

from ._settings import FinderSettings

_GOLDEN_STEPS = 40
"""Golden-section steps of the frequency refinement within the peak's bin (``0.618^40``:
a bracket of 4e-9 bins; the flat maximum limits the frequency to about 1e-7 bins in
float64, far below the error the noise leaves)."""


def _explained(x: np.ndarray, n: np.ndarray, w: float) -> tuple[float, np.ndarray]:
    """Sum over channels of the squares a sinusoid of ``w`` rad per row explains in ``x``
    (kept rows ``n``, ``(len(n), C)``), and its coefficients ``(2, C)`` (cos, sin)."""
    c, s = np.cos(w * n), np.sin(w * n)
    G = np.array([[c @ c, c @ s], [c @ s, s @ s]])
    rhs = np.stack([c @ x, s @ x])
    coef = np.linalg.solve(G, rhs)
    return float(np.sum(coef * rhs)), coef


def fit_line(x: np.ndarray, n: np.ndarray, m: int, k: int) -> np.ndarray:
    """The sinusoid fitted to ``x`` (the kept rows' values, ``(len(n), C)``, at rows ``n``
    of ``m``) whose frequency lies within half a bin of bin ``k`` of the ``m``-row
    transform (least squares; the frequency by golden section): its values ``x``-shaped."""
    step = 2.0 * math.pi / m
    lo, hi = (k - 0.5) * step, (k + 0.5) * step
    g = (math.sqrt(5.0) - 1.0) / 2.0
    u, v = hi - g * (hi - lo), lo + g * (hi - lo)
    fu, fv = _explained(x, n, u)[0], _explained(x, n, v)[0]
    for _ in range(_GOLDEN_STEPS):
        if fu >= fv:
            hi, v, fv = v, u, fu
            u = hi - g * (hi - lo)
            fu = _explained(x, n, u)[0]
        else:
            lo, u, fu = u, v, fv
            v = lo + g * (hi - lo)
            fv = _explained(x, n, v)[0]
    w = 0.5 * (lo + hi)
    coef = _explained(x, n, w)[1]
    return np.outer(np.cos(w * n), coef[0]) + np.outer(np.sin(w * n), coef[1])


def separate_lines(
    rw,
    span: tuple[int, int],
    kept: np.ndarray,
    X: np.ndarray,
    Ps: np.ndarray,
    idx: np.ndarray,
    thr: float,
    settings: FinderSettings,
) -> np.ndarray:
    """The peaks ``idx`` (bins of the run's transform ``X``, ``(bins, C)``, of the whitened
    residual's rows ``rw[a:b]`` for ``span = (a, b)``, those ``kept`` only; ``Ps``: the
    channel-summed periodogram ``2 |X|^2 / nk``, ``nk`` rows kept) that are lines of their
    own, strongest first, at most ``settings.spectrum_peaks_per_run``: a weaker peak is kept
    only where
    its power with the leakage of the stronger peaks kept taken out stays above ``thr``
    (the module's docstring states the bound)."""
    most, nk = settings.spectrum_peaks_per_run, int(kept.sum())
    order = idx[np.argsort(-Ps[idx])]
    out: list[int] = [int(i) for i in order[:1]]  # the strongest is a line
    leaks: list[np.ndarray] = []  # the transforms of out's first lines, fitted in turn
    x, n, m = None, np.zeros(0, dtype=int), 0  # the run's kept rows, read when first needed
    for i in order[1:]:
        if len(out) >= most:
            break
        i = int(i)
        # the largest leakage the kept lines can put into bin i (channel-summed power)
        worst = sum(Ps[p] / (4.0 * (abs(i - p) - 0.5) ** 2) for p in out)
        if math.sqrt(Ps[i]) - math.sqrt(worst) > math.sqrt(thr):
            out.append(i)
            continue
        if x is None:
            r = rw[span[0] : span[1]]
            m, n = r.shape[0], np.flatnonzero(kept)
            x = r[n]
        while len(leaks) < len(out):
            # each line fitted to the rows less the stronger lines already fitted
            line = fit_line(x, n, m, out[len(leaks)])
            x = x - line
            full = np.zeros((m, X.shape[1]))
            full[n] = line
            leaks.append(np.fft.rfft(full, axis=0))
        leak = np.sum([q[i] for q in leaks], 0)
        cleaned = 2.0 * float(np.sum(np.abs(X[i] - leak) ** 2)) / nk  # (as Ps)
        if cleaned > thr:
            out.append(i)
    return np.asarray(out, dtype=idx.dtype)


__all__ = ["fit_line", "separate_lines"]
