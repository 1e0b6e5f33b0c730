"""An order of the platform angle common to the moving sensors that switches or grows over the
runs (SDS, issue 41, session 26).

The ``common_orders`` view (:func:`view_common_orders`) fits each order ``n`` of
the platform angle φ with one amplitude and phase on every moving sensor over the whole
record, and the ``modulated_orders`` view scans growths and switches per sensor only. A
pattern common to the moving sensors that switches on from one run on (a platform gear or a
reference that is disturbed, re-seated or starts to rub) keeps about half its power in the
static fit and is charged, per sensor, for ``max_order x M`` shapes of which it fills none.
This view fits, per order ``n = 1..(R - 1) // 2`` (the ``common_orders`` view's range), the
cos / sin of ``n φ`` on every moving sensor's run mean times one amplitude *shape* over the
kept runs in time order:

* ``growth``: linear from 0 at the first kept run to 1 at the last; ``decay``: ``1 -`` that;
* ``switch_on`` at boundary ``j``: 0 before the ``j``-th kept run, 1 from it; ``switch_off``:
  ``1 -`` that; at every one of the ``R - 1`` boundaries between kept runs (one row per run:
  nothing between two runs to locate).

Each shape is 2 regressors, made orthogonal to the base model's whitened Jacobian (a part the
base takes is no evidence), a chi-square of 2 dof under white noise at the run-mean level the
record is whitened with. The family-wise false-alarm rate ``settings.modulated_orders_alpha``
(the ``modulated_orders`` view's) is split in halves between the two families, each
Bonferroni over its own library: ``2 (R - 1) // 2`` growths, ``2 (R - 1) (R - 1) // 2``
switches (24 runs: 22 and 506 shapes, thresholds 21.4 and 27.8 against the per-sensor
view's 25.9 and 30.1 over 210 and 1680). An order is reported only where its best shape is
the stronger evidence than its static fit, each charged for its own tests (``common_orders``
reports a static order with its static chi-square). Nothing without ``phi_ref``: a pattern
common to the moving sensors is taken by the per-run offsets there.

The finding (view ``common_modulated``) is an order line for discovery
(:func:`..engine._discover_lines.lines_of`), whose ``platform`` frame and ``step`` /
``growth`` modulations then model it with their own held-out gain and threshold.
"""

from __future__ import annotations

import numpy as np

from ...engine._protocol import Prepared
from ...engine._views import Finding
from ...engine._views import chi2_threshold as _thr
from ...engine._views import log10_tail_p as _logp
from ...engine._views import make_where as _where
from ...engine._views_modulated import _basis, _power2
from ...engine._views_orders import time_order
from ._sds_level_out import common_shapes_scale
from ._sds_noise import common_order_power, noise_info

VIEW = "common_modulated"


def common_max_order(R: int) -> int:
    """Highest common order scanned on ``R`` runs: ``(R - 1) // 2`` (the ``common_orders``
    view's)."""
    return int(max(1, (R - 1) // 2))


def shapes(n: int) -> tuple[np.ndarray, list[tuple[str, int | None]]]:
    """``(S, n)`` amplitude shapes over ``n`` kept runs in time order (growth, decay, then
    switch on / off at each boundary ``j = 1..n-1``) and their ``(name, boundary)``."""
    j = np.arange(n)
    g = j / max(n - 1, 1)
    rows = [g, 1.0 - g]
    names: list[tuple[str, int | None]] = [("growth", None), ("decay", None)]
    for b in range(1, n):
        on = (j >= b).astype(float)
        rows += [on, 1.0 - on]
        names += [("switch_on", b), ("switch_off", b)]
    return np.stack(rows), names


def powers(
    r: np.ndarray,
    phi: np.ndarray,
    sig: np.ndarray,
    W: np.ndarray,
    orders: np.ndarray,
    Q: np.ndarray | None = None,
) -> np.ndarray:
    """``(S, L)``: chi-square (2 dof) of cos / sin ``n φ`` times each shape of ``W`` (S, n)
    on every one of the first ``M`` channels of the whitened residual ``r`` (n, C) (rows:
    the kept runs in time order), per order of ``orders`` (L,); the regressors whitened by
    those channels' levels ``sig`` (M,) (rad), made orthogonal to ``Q`` (n, C, p) where
    given, else each channel's mean taken out (its constant)."""
    n, C = r.shape
    M = sig.size
    ang = np.outer(phi, orders)  # (n, L)
    cs = np.stack([np.cos(ang), np.sin(ang)], -1)  # (n, L, 2)
    X = W.T[:, :, None, None] * cs[:, None]  # (n, S, L, 2)
    S, L = W.shape[0], orders.size
    A = np.zeros((n, C, S * L * 2))
    A[:, :M] = X.reshape(n, 1, -1) / sig[None, :, None]
    A = A.reshape(n * C, -1)
    y = np.asarray(r, float).ravel()
    if Q is not None:
        Qf = Q.reshape(n * C, -1)
        A = A - Qf @ (Qf.T @ A)
        y = y - Qf @ (Qf.T @ y)
    else:
        Am = A.reshape(n, C, -1)
        A = (Am - Am.mean(0, keepdims=True)).reshape(n * C, -1)
    P = A.reshape(n * C, S * L, 2)
    G = np.einsum("kgi,kgj->gij", P, P)  # (S L, 2, 2)
    b = np.einsum("k,kgi->gi", y, P)
    return _power2(G[:, None], b[:, :, None])[:, 0].reshape(S, L)


def view_common_modulated(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """The view (module doc) on the whitened residual ``rw`` of an SDS record (rows: runs;
    the first ``M`` channels the moving sensors' run means). ``scan_order`` is not used:
    the common orders a record of ``R`` runs resolves are ``1..(R - 1) // 2``."""
    del scan_order
    M = int(np.asarray(prep.consts["psi_m"]).size)
    if float(prep.consts["proj"]) > 0 or "phi" not in prep.rows:
        return []
    kidx, _, _, tau = time_order(prep)
    n = kidx.size
    if n < 4:
        return []
    L = common_max_order(n)
    orders = np.arange(1, L + 1, dtype=float)
    phi = np.asarray(prep.rows["phi"], float)[kidx]
    r = np.asarray(rw, float)[kidx]
    basis = _basis(prep, kidx, rw)
    Q = None if basis is None else basis[0]
    W, names = shapes(n)
    sig = np.asarray(prep.sigma, float)[:M]
    W1 = np.concatenate([np.ones((1, n)), W])
    alpha = prep.settings.modulated_orders_alpha
    n_tests = [2 * L, 2 * (n - 1) * L]
    thr = [_thr(alpha / 2, 2, nt) for nt in n_tests]
    fam = np.array([0 if b is None else 1 for _, b in names])
    # each test's false-alarm probability: the static fit's (``common_orders``), the families'
    p = np.concatenate([[prep.settings.alpha / L], alpha / 2 / np.asarray(n_tests)[fam]])
    pw = powers(r, phi, sig, W1, orders, Q)
    pw = pw * common_view_scale(prep, W1, kidx, orders, p)  # the level (session 42)
    static, pw = pw[0], pw[1:]
    T = np.asarray(thr)[fam]
    out = []
    for i in range(L):
        margin = pw[:, i] - T
        j = int(np.argmax(margin))
        if margin[j] <= 0:
            continue
        nt = n_tests[fam[j]]
        mine = _logp(float(pw[j, i]), 2) + np.log10(nt)
        if mine >= _logp(float(static[i]), 2) + np.log10(L):  # the static fit says it better
            continue
        shape, b = names[j]
        detail = {
            "integer_order": True,
            "modulation": shape,
            "n_values": int(n * M),
            "n_tests": int(nt),
            "threshold_chi2": float(T[j]),
            "static_power": float(static[i]),
            "common_to_moving_sensors": True,
        }
        times: list[float] = []
        if b is not None:  # between the last run before the boundary and the first after
            r0, r1 = int(kidx[b - 1]), int(kidx[b])
            detail["global_step_time_s"] = float(0.5 * (tau[r0] + tau[r1]))
            times = [float(prep.rows["t"][r0]), float(prep.rows["t"][r1])]
        out.append(
            Finding(
                VIEW,
                _where(
                    orders=[float(orders[i])],
                    heads=list(range(M)),
                    runs=prep.run_ids.tolist(),
                    times_s=times,
                ),
                float(pw[j, i]),
                2,
                _logp(float(pw[j, i]), 2),
                detail=detail,
            )
        )
    return out


def common_view_scale(
    prep: Prepared, shapes: np.ndarray, kidx: np.ndarray, orders: np.ndarray, p: np.ndarray
) -> float | np.ndarray:
    """The factor on the common views' chi-squares (``common_orders``, ``common_modulated``):
    ``SDSNoiseInfo.common_scale`` (at most 1: the clock's rounding constant within a run that
    the whitening level does not hold, :func:`_common_scale`) where it is below 1 or
    ``FinderSettings.sds_level_per_component`` is below 2; else ``(S, L)`` per amplitude shape
    (``shapes`` (S, n) over the kept rows ``kidx`` in the view's order) and order of ``orders``
    the run-mean level without the tested columns, per component
    (:func:`._sds_level_out.common_shapes_scale`, session 42), as the one-sensor views read
    theirs, widened at each shape's false-alarm probability ``p`` (S,: its family's threshold's,
    per test), and at least 1: a common test is never read above the whitening level, as
    before (where the common component's own level is not lower, the widening at the
    view's small ``p`` would otherwise raise it)."""
    info = noise_info(prep.ctx)
    lv = info.level_factor
    if prep.settings.sds_level_per_component < 2 or lv is None or info.common_scale < 1:
        return info.common_scale
    keep = np.asarray(prep.keep, bool)
    W = np.zeros((shapes.shape[0], keep.size))
    W[:, np.asarray(kidx, int)] = shapes
    phi = np.asarray(prep.rows["phi"], float)[keep]
    p = np.asarray(p, float)
    out = np.ones((shapes.shape[0], np.size(orders)))
    for q in np.unique(p):  # one call per family
        rows = np.flatnonzero(p == q)
        out[rows] = common_shapes_scale(lv, phi, W[rows][:, keep], np.asarray(orders, float), q)
    return np.maximum(out, 1.0)  # never below the whitening level's reading (before 42)


def view_common_orders(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """Orders in φ common to every moving sensor (platform gear, axial runout, a reference
    error), 2 dof each, Bonferroni over the orders, each read at :func:`common_view_scale`;
    nothing without ``phi_ref``."""
    M = prep.consts["psi_m"].size
    if float(prep.consts["proj"]) > 0:
        return []
    pw = common_order_power(prep, rw[:, :M])
    kidx = np.flatnonzero(np.asarray(prep.keep, bool))
    p = np.array([prep.settings.alpha / pw.size])  # the Bonferroni threshold's
    f = common_view_scale(prep, np.ones((1, kidx.size)), kidx, np.arange(1.0, pw.size + 1), p)
    pw = pw * (np.asarray(f)[0] if np.ndim(f) else f)
    thr = _thr(prep.settings.alpha, 2, pw.size)
    out = []
    for i in np.flatnonzero(pw > thr):
        out.append(
            Finding(
                "common_orders",
                _where(orders=[float(i + 1)], heads=list(range(M)), runs=prep.run_ids.tolist()),
                float(pw[i]),
                2,
                _logp(float(pw[i]), 2),
                detail={"n_values": int(rw.shape[0] * M), "common_to_moving_sensors": True},
            )
        )
    return out
