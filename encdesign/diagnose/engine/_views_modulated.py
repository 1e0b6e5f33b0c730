"""A view of integer shaft orders whose amplitude changes over the record (engine stage 3).

The ``orders`` view (:func:`._views.view_orders`) fits each order with one amplitude and
phase over the whole record. An order whose amplitude grows linearly in time keeps only
3/4 of its power in that fit, one that switches on half-way through 1/2, so a structure
the record holds clearly can stay below the static scan's threshold (issue 41: a slow
growth or a switching order on an SDS sensor, the truth's model 34-37 chi-square against a
locating threshold of 25-26). This view fits, per order ``m`` and channel, the cos / sin of
``m theta`` times one amplitude *shape* over the kept rows in time order (the end-to-end
axis ``tau``):

* ``growth``: linear from 0 at the first kept row to 1 at the last; ``decay``: ``1 -`` that;
* ``switch_on`` at change point ``k``: 0 before, 1 from it; ``switch_off``: 1 before, 0 from
  it; the change points are ``settings.modulated_orders_steps`` equal-count edges of the
  kept rows (a change between two edges keeps most of its power at the nearer one).

Each shape is 2 regressors (chi-square with 2 dof under white noise); the view's own
family-wise false-alarm rate ``settings.modulated_orders_alpha`` (beside the static scan's)
is split in halves between the two families, each tested at its half over its count of
tests (Bonferroni over orders x channels x shapes: 2 shapes of growth, ``2 K`` switches), so
a growth is not charged for the many change points of the switches. An order is reported only
where the static fit at the ``orders`` view's own threshold shows nothing (that view
reports it), so a record the static scan already reads is read as before; on an SDS record
(``beside_static``) also where its shape is the stronger evidence than its static fit, each
charged for its own tests: on a few platform positions a switching order's near-aliases
are reported here with its whole chi-square while its own order, which the static scan
reads, is reported with a part of it, and ranked below them it fell off the findings the
diagnosis keeps (issue 41, session 21). The sums are accumulated in blocks of rows (per
change-point segment), so nothing per row is held.
"""

from __future__ import annotations

import numpy as np

from ._views import Finding, chi2_threshold, log10_tail_p, make_where
from ._views_orders import order_scan, time_order

BLOCK_VALUES = 1 << 16
"""Rows x orders per block of the accumulation (its temporaries: that times the channels)."""


def _power2(G: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Chi-square two regressors with Gram ``G`` (..., C or 1, 2, 2) take out of ``B``
    (..., 2, C) (their projection; 0 where the Gram matrix is singular)."""
    g00, g01, g11 = G[..., 0, 0], G[..., 0, 1], G[..., 1, 1]
    det = g00 * g11 - g01 * g01
    ok = det > 1e-9 * np.maximum(g00 + g11, 1e-300) ** 2
    b0, b1 = B[..., 0, :], B[..., 1, :]
    q = (b0 * b0 * g11 - 2 * b0 * b1 * g01 + b1 * b1 * g00) / np.where(ok, det, 1.0)
    return np.where(ok, np.maximum(q, 0.0), 0.0)


def _projected(G: np.ndarray, B: np.ndarray, V, u) -> tuple[np.ndarray, np.ndarray]:
    """Gram (..., C, 2, 2) and sums (..., 2, C) of the regressors made orthogonal to the base
    model's whitened Jacobian (orthonormal basis ``Q``): ``V`` (2, ..., C, p) are the
    regressors' sums with ``Q``, ``u`` (p,) the residual's (0 up to the fit's convergence).
    Without a basis (``V`` None) the raw Gram, shared by the channels."""
    if V is None:
        return G[..., None, :, :], B
    corr = np.einsum("i...p,j...p->...ij", V, V)
    return G[..., None, :, :] - corr, B - np.einsum("i...cp,p->...ic", V, u)


def _gram(cc, cs, ss) -> np.ndarray:
    return np.stack([np.stack([cc, cs], -1), np.stack([cs, ss], -1)], -2)


def _sums(prep, rw, name: str, idx, m, seg, K: int, ch, Q=None):
    """Sums over the kept rows ``idx`` (time order) of ``c = cos(m theta)``, ``s``: per
    change-point segment (``seg``: each row's, 0..K) ``cc, cs, ss`` (K+1, M) and ``c r``,
    ``s r`` (K+1, M, C) on the channels ``ch``; weighted by the growth ``g`` (0..1 over the
    rows) and ``g^2``. With ``Q`` (rows of ``idx``, channels ``ch``, p: the base's whitened
    basis) also ``c Q``, ``s Q`` per segment (2, K+1, M, C, p) and weighted by ``g``."""
    n, M, C = idx.size, m.size, ch.size
    S = np.zeros((3, K + 1, M))
    Bs = np.zeros((2, K + 1, M, C))
    Sg, Sgg = np.zeros((3, M)), np.zeros((3, M))
    Bg = np.zeros((2, M, C))
    p = 0 if Q is None else Q.shape[2]
    Vs, Vg = np.zeros((2, K + 1, M, C, p)), np.zeros((2, M, C, p))
    g_all = np.arange(n) / max(n - 1, 1)
    step = max(1, BLOCK_VALUES // (M * max(1, C * p)))
    for a in range(0, n, step):
        b = min(n, a + step)
        rows = idx[a:b]
        th = np.asarray(prep.rows.take(name, rows), float)
        ang = th[:, None] * m[None, :]
        c, s = np.cos(ang), np.sin(ang)
        del ang
        r = np.asarray(rw[rows], float)[:, ch]
        g = g_all[a:b]
        prods = (c * c, c * s, s * s)
        sb = seg[a:b]
        st = np.flatnonzero(np.r_[True, sb[1:] != sb[:-1]])
        for i, pr in enumerate(prods):
            S[i, sb[st]] += np.add.reduceat(pr, st, axis=0)
            Sg[i] += g @ pr
            Sgg[i] += (g * g) @ pr
        for i, x in enumerate((c, s)):
            xr = x[:, :, None] * r[:, None, :]  # (rows, M, C)
            Bs[i, sb[st]] += np.add.reduceat(xr, st, axis=0)
            Bg[i] += np.einsum("n,nmc->mc", g, xr)
            if p:
                xq = x[:, :, None, None] * Q[a:b][:, None]  # (rows, M, C, p)
                Vs[i, sb[st]] += np.add.reduceat(xq, st, axis=0)
                Vg[i] += np.einsum("n,nmcp->mcp", g, xq)
    return S, Bs, Sg, Sgg, Bg, (Vs, Vg) if p else None


def base_jacobian(prep, fitter, terms) -> np.ndarray | None:
    """The Jacobian of ``terms`` on every row (n, C, p), projected like the data, not
    whitened (:attr:`Prepared.base_jacobian`), for a record of one row per run (the SDS run
    means; else ``None``: on a 3000-row multihead record its evaluation and the view's sums
    with it took the diagnosis from 3.1 to 5.8 s CPU, session 18)."""
    if prep.n > len(prep.run_ids) or not terms:
        return None
    return np.concatenate([fitter.jacobian(terms, a, b, x)[1] for a, b, x in fitter.chunks()], 0)


def _basis(prep, kidx, rw) -> tuple[np.ndarray, np.ndarray] | None:
    """The base model's whitened Jacobian on the kept rows ``kidx``: an orthonormal basis
    (rows, C, r) of its span over rows x channels, and the residual's sums with it (r,)."""
    J = getattr(prep, "base_jacobian", None)
    if J is None or J.shape[0] != rw.shape[0] or J.shape[1] != rw.shape[1]:
        return None
    Jw = J[kidx] / np.asarray(prep.sigma, float)[None, :, None]
    U, sv, _ = np.linalg.svd(Jw.reshape(-1, J.shape[2]), full_matrices=False)
    U = U[:, sv > sv.max(initial=0.0) * 1e-9 * np.sqrt(U.shape[0])]
    if U.shape[1] == 0:
        return None
    Q = U.reshape(kidx.size, J.shape[1], -1)
    return Q, np.einsum("ncp,nc->p", Q, np.asarray(rw[kidx], float))


def scan_modulated(
    prep,
    rw,
    max_order: int,
    channels: list[int],
    n_channels_static: int,
    beside_static: bool = False,
    scale=None,
) -> list[Finding]:
    """The view on ``channels`` of the whitened residual ``rw`` (rows indexable by an index
    array), orders ``1..max_order``; the static fit skips an order it finds at
    ``chi2_threshold(alpha, 2, max_order * n_channels_static)`` (the ``orders`` view's).

    ``beside_static`` (SDS, few platform positions): such an order is reported too where
    its best shape is the stronger evidence, each family's tail probability times its own
    count of tests (the static scan's ``max_order * n_channels_static``): the ``orders``
    view reports the order with its static chi-square only, while a switching order's
    near-aliases on the positions, which the static scan misses, come here with the
    step's whole chi-square and so outrank it (training seed 20261359: a step at order 7
    of one SDS sensor, static 33 and switched 71 chi-square, came 24th of the located
    structures, after its aliases 28, 14, 6, 20 at 60-63; the diagnosis keeps 12). A
    static order does not pass this: with raw regressors a switch or a growth keeps at most
    ``(K-1)/K`` or 3/4 of its chi-square, and it is charged for more tests.

    ``scale``: ``scale(kidx, edges) -> (per shape (2 + 2K, max_order, C), static
    (max_order, C))``, factors on the chi-squares in the order of the shapes (growth,
    decay, then switch on / off per edge) and on the static fit's (SDS: the level without
    the tested columns, :mod:`..kinds.sds._sds_level_out`); ``None``: 1."""
    s = prep.settings
    if max_order < 1 or not channels or int(prep.keep.sum()) < 4:  # 2 rows either side
        return []
    kidx, edges, seg, tau = time_order(prep)
    n = kidx.size
    K = edges.size
    name = "theta_eff" if "theta_eff" in prep.rows else "theta"
    m = np.arange(1, max_order + 1, dtype=float)
    ch = np.asarray(channels, int)
    basis = _basis(prep, kidx, rw)
    Q, u = (None, None) if basis is None else (basis[0][:, ch], basis[1])
    if Q is None:  # the sums the orders view shares (issue 43: one pass for both)
        sums = order_scan(prep, rw, max_order, ch)
        S, Bs, Sg, Sgg, Bg, V = sums.S, sums.B, sums.Sg, sums.Sgg, sums.Bg, None
    else:
        S, Bs, Sg, Sgg, Bg, V = _sums(prep, rw, name, kidx, m, seg, K, ch, Q)
    # totals, prefix (before each edge) and suffix (from each edge) sums
    tot_S, tot_B = S.sum(1), Bs.sum(1)  # (3, M), (2, M, C)
    on_S, on_B = np.cumsum(S[:, ::-1], 1)[:, ::-1][:, 1:], np.cumsum(Bs[:, ::-1], 1)[:, ::-1][:, 1:]
    off_S, off_B = tot_S[:, None] - on_S, tot_B[:, None] - on_B  # (3, K, M), (2, K, M, C)
    G_tot = _gram(*tot_S)  # (M, 2, 2)
    static = _power2(G_tot[:, None], np.moveaxis(tot_B, 0, -2))  # (M, C)
    # shapes: growth g, decay 1 - g, switch on / off at each edge; with the base's basis
    # each shape's regressors are made orthogonal to the base model first (the residual
    # is: a part the base takes is no evidence, and the chi-square is then exactly 2 dof)
    dec_S = tot_S - 2 * Sg + Sgg
    dec_B = tot_B - Bg
    if V is None:
        v_g = v_d = v_on = v_off = None
    else:
        Vs, v_g = V
        v_tot = Vs.sum(1)
        v_on = np.cumsum(Vs[:, ::-1], 1)[:, ::-1][:, 1:]
        v_d, v_off = v_tot - v_g, v_tot[:, None] - v_on

    def power(Sx, Bx, Vx):
        return _power2(*_projected(_gram(*Sx), np.moveaxis(Bx, 0, -2), Vx, u))

    shapes = [("growth", None, power(Sgg, Bg, v_g)), ("decay", None, power(dec_S, dec_B, v_d))]
    pw_on = power(on_S, on_B, v_on)  # (K, M, C)
    pw_off = power(off_S, off_B, v_off)
    for k in range(K):
        shapes.append(("switch_on", k, pw_on[k]))
        shapes.append(("switch_off", k, pw_off[k]))
    # half the false-alarm rate to each family (growth and decay; the switches)
    n_tests = [max_order * ch.size * 2, max_order * ch.size * 2 * K]
    thr = [chi2_threshold(s.modulated_orders_alpha / 2, 2, nt) for nt in n_tests]
    thr_static = chi2_threshold(s.alpha, 2, max_order * n_channels_static)
    P = np.stack([p for _, _, p in shapes])  # (shapes, M, C)
    if scale is not None:
        f_shape, f_static = scale(kidx, edges)
        P = P * f_shape[:, :, ch]
        static = static * f_static[:, ch]
    T = np.array([thr[0] if k is None else thr[1] for _, k, _ in shapes])
    out = []
    n_static = max_order * n_channels_static
    for i in range(m.size):
        margin = P[:, i] - T[:, None]  # (shapes, C): past each family's threshold
        j = int(np.argmax(margin.max(1)))
        if margin[j].max() <= 0:
            continue
        if static[i].max() > thr_static:  # the orders view reports this order
            if not beside_static:
                continue
            nt = n_tests[0 if shapes[j][1] is None else 1]
            mine = log10_tail_p(float(P[j, i].max()), 2) + np.log10(nt)
            if mine >= log10_tail_p(float(static[i].max()), 2) + np.log10(n_static):
                continue
        pw = P[j, i]
        carry = [k for k in range(ch.size) if margin[j, k] > 0]
        shape, k, _ = shapes[j]
        detail = {
            "integer_order": True,
            "modulation": shape,
            "n_values": int(n),
            "n_tests": int(n_tests[0 if k is None else 1]),
            "threshold_chi2": float(T[j]),
            "power_per_channel": pw.tolist(),
            "static_power_per_channel": static[i].tolist(),
        }
        times: list[float] = []
        if k is not None:  # the change: between the last row before the edge and the first after
            r0, r1 = int(kidx[edges[k] - 1]), int(kidx[edges[k]])
            detail["global_step_time_s"] = float(0.5 * (tau[r0] + tau[r1]))
            times = [float(prep.rows["t"][r0]), float(prep.rows["t"][r1])]
        out.append(
            Finding(
                "modulated_orders",
                make_where(
                    orders=[float(m[i])],
                    heads=[int(ch[k]) for k in carry],
                    runs=prep.run_ids.tolist(),
                    times_s=times,
                ),
                float(pw[carry].sum()),
                2 * len(carry),
                log10_tail_p(float(pw.max()), 2),
                detail=detail,
            )
        )
    return out


def view_modulated_orders(prep, rw, scan_order: int) -> list[Finding]:
    """The view on every channel, orders up to the scan order (a kind's ``KindView``)."""
    C = rw.shape[1]
    return scan_modulated(prep, rw, scan_order, list(range(C)), C)
