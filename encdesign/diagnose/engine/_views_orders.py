"""The shaft orders' sums the ``orders`` and ``modulated_orders`` views share (issue 43).

Both views fit ``cos, sin (m theta)``, ``m = 1..M``, to the whitened residual over the kept
rows: the ``orders`` view over the whole record, the ``modulated_orders`` view per
change-point segment of the kept rows in time order and weighted by a linear growth
(:mod:`._views_modulated`). One pass over the rows (:func:`order_scan`) gives both: per
segment ``k`` the Gram sums ``cc, cs, ss`` (3, K+1, M) and the residual's ``c r, s r``
(2, K+1, M, C), and the growth-weighted ones; the whole record's sums are their totals over
the segments. The Gram sums are geometry (kept across scans, :func:`._views_sums.geometry`),
the residual's are linear (shared within a scan, :func:`._views_sums.linear`): a scan after
the first evaluates ``cos, sin`` once for both views, and a detection bound's bisection
reads the rows once per residual.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._views_sums import fingerprint, geometry, linear

SCAN_VALUES = 1 << 18
"""Rows x orders per block of the pass (its temporaries: that times the channels)."""


@dataclasses.dataclass(frozen=True)
class OrderSums:
    """The sums of one pass (module doc): the kept rows ``kidx`` in time order, the
    segment edges ``edges`` (positions in ``kidx``) and ``tau`` (the time axis)."""

    kidx: np.ndarray
    edges: np.ndarray
    tau: np.ndarray
    S: np.ndarray  # (3, K+1, M): cc, cs, ss per segment
    Sg: np.ndarray  # (3, M): weighted by the growth g
    Sgg: np.ndarray  # (3, M): by g^2
    B: np.ndarray  # (2, K+1, M, C): c r, s r per segment
    Bg: np.ndarray  # (2, M, C): weighted by g

    @property
    def n(self) -> int:
        return int(self.kidx.size)

    def totals(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(Scc, Sss, Scs, Bc, Bs)`` over the whole record."""
        S, B = self.S.sum(1), self.B.sum(1)
        return S[0], S[2], S[1], B[0], B[1]


def time_order(prep) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(kidx, edges, seg, tau)``: the kept rows in time order (``tau``, else ``t``), the
    ``settings.modulated_orders_steps`` equal-count change-point edges among them, each
    kept row's segment and the time axis."""
    kidx = np.flatnonzero(prep.keep)
    tau = np.asarray(prep.rows["tau"] if "tau" in prep.rows else prep.rows["t"], float)
    tk = tau[kidx]
    if np.any(np.diff(tk) < 0):
        kidx = kidx[np.argsort(tk, kind="stable")]
    n = kidx.size
    K = int(min(prep.settings.modulated_orders_steps, max(n - 1, 0)))
    edges = np.unique(np.round(np.arange(1, K + 1) * n / (K + 1)).astype(int))
    edges = edges[(edges > 0) & (edges < n)]
    seg = np.searchsorted(edges, np.arange(n), side="right")
    return kidx, edges, seg, tau


def harmonics(th: np.ndarray, M: int) -> tuple[np.ndarray, np.ndarray]:
    """``cos, sin (m th)`` (M, rows) for ``m = 1..M`` (``th`` (rows,), rad), by rotation from
    ``cos, sin th`` (``e^{i m th} = e^{i (m - 1) th} e^{i th}``): two transcendentals per
    angle and six flops per order instead of ``2 M`` transcendentals of a large argument (issue
    43: the orders views' scans and the base term's factored Jacobian,
    ``kinds/multihead/_fourier.base_factors``, on every chunk of every pass). Rounding: each
    complex product adds at most ``sqrt(5) eps`` relative (Brent, Percival and Zimmermann
    2007), so order ``m`` differs from ``e^{i m th}`` of the rounded ``th`` by at most about
    ``(sqrt(5) m + 1) eps`` (``_fourier.TRIG_TABLE_ERROR * m * eps``, tested), where ``cos(m
    th)`` computed directly carries the rounding of ``m th``, about ``|m th| eps``."""
    c, s = np.empty((M, th.size)), np.empty((M, th.size))
    if M == 0:
        return c, s
    c1, s1 = np.cos(th), np.sin(th)
    c[0], s[0] = c1, s1
    tmp = np.empty(th.size)
    for k in range(1, M):
        np.multiply(c[k - 1], c1, out=c[k])
        c[k] -= np.multiply(s[k - 1], s1, out=tmp)
        np.multiply(s[k - 1], c1, out=s[k])
        s[k] += np.multiply(c[k - 1], s1, out=tmp)
    return c, s


def _pass(prep, rw, name: str, kidx, M: int, seg, K: int, ch, geom: bool) -> list[np.ndarray]:
    """The sums of one pass over the rows ``kidx`` (module doc); the Gram sums (zeros
    unless ``geom``) then the residual's."""
    n, C = kidx.size, ch.size
    S, Sg, Sgg = np.zeros((3, K + 1, M)), np.zeros((3, M)), np.zeros((3, M))
    B, Bg = np.zeros((2, K + 1, M, C)), np.zeros((2, M, C))
    g_all = np.arange(n) / max(n - 1, 1)
    step = max(1, SCAN_VALUES // max(M, 1))
    for a in range(0, n, step):
        b = min(n, a + step)
        rows = kidx[a:b]
        c, s = harmonics(np.asarray(prep.rows.take(name, rows), float), M)  # (M, rows)
        r = np.asarray(rw[rows], float)[:, ch]
        g = g_all[a:b]
        sb = seg[a:b]
        st = np.flatnonzero(np.r_[True, sb[1:] != sb[:-1]])
        pieces = [(int(sb[j0]), j0, j1) for j0, j1 in zip(st, np.r_[st[1:], b - a])]
        for k, j0, j1 in pieces:
            B[0, k] += c[:, j0:j1] @ r[j0:j1]
            B[1, k] += s[:, j0:j1] @ r[j0:j1]
        gr = g[:, None] * r
        Bg[0] += c @ gr
        Bg[1] += s @ gr
        if geom:
            for i, pr in enumerate((c * c, c * s, s * s)):
                for k, j0, j1 in pieces:
                    S[i, k] += pr[:, j0:j1].sum(1)
                Sg[i] += pr @ g
                Sgg[i] += pr @ (g * g)
    return [S, Sg, Sgg, B, Bg]


def order_scan(prep, rw, max_order: int, channels) -> OrderSums:
    """The sums of orders ``1..max_order`` on ``channels`` of the whitened residual ``rw``
    (rows indexable by an index array; ``theta_eff`` where the rows have it, else
    ``theta``): geometry kept across scans, the residual's shared within one."""
    name = "theta_eff" if "theta_eff" in prep.rows else "theta"
    kidx, edges, seg, tau = time_order(prep)
    K = int(edges.size)
    M = int(max_order)
    ch = np.asarray(channels, int)
    th = np.asarray(prep.rows.take(name, kidx), float) if kidx.size else np.zeros(0)
    gkey = ("order_scan", name, int(max_order), fingerprint(kidx, th, edges))
    del th
    first: list = []

    def geo():
        first.append(_pass(prep, rw, name, kidx, M, seg, K, ch, True))
        return first[0][:3]

    S, Sg, Sgg = geometry(prep, gkey, geo)

    def lin():
        got = first[0] if first else _pass(prep, rw, name, kidx, M, seg, K, ch, False)
        return got[3:]

    B, Bg = linear(prep, (*gkey, tuple(ch.tolist())), lin)
    return OrderSums(kidx, edges, tau, S, Sg, Sgg, B, Bg)


__all__ = ["OrderSums", "harmonics", "order_scan", "time_order"]
