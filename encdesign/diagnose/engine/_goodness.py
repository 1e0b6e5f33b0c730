"""Stage 2 of the engine, **fit**: the goodness of fit of a residual against the noise level
(split from :mod:`._fit`)."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ._constants import MEDIAN_VAR
from ._protocol import Prepared
from ._views import SCAN_BLOCK


def _row_chi2(resid: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """``sum_c (resid / sigma_c)^2`` per row (n,), in blocks (no (n, C) temporary)."""
    out = np.empty(resid.shape[0])
    w = 1.0 / np.asarray(sigma, float) ** 2
    for a in range(0, resid.shape[0], SCAN_BLOCK):
        r = resid[a : a + SCAN_BLOCK]
        out[a : a + SCAN_BLOCK] = (r * r) @ w
    return out


def goodness_of_fit(prep: Prepared, resid: np.ndarray, n_params: int) -> dict:
    """Variance-ratio test of the residual against the noise level.

    ``z = log(s_r^2) / sqrt(v / N)`` with ``s_r^2`` the residual variance per fitted value
    (dof-corrected) whitened by the noise per channel (the periodogram-median estimate,
    :func:`noise_spectral`, which structure in fewer than half the frequency bins cannot
    inflate), and ``v = 2 + 2 MEDIAN_VAR`` (residual and noise estimate treated as
    independent: conservative). Under white noise ``z ~ N(0, 1)``; structure the model misses
    raises ``s_r^2``. Applied to the whole record and to each time block of each run
    (Bonferroni); ``p`` is the smaller of the two (times 2).
    """
    keep = prep.keep
    q = _row_chi2(resid, prep.sigma)  # whitened chi-square per row (n,)
    C = prep.n_channels
    eff = (C - 1) / C if prep.kd.project and C > 1 else 1.0
    N = float(keep.sum() * C * eff)
    v = 2.0 + 2.0 * MEDIAN_VAR / eff
    sr = float(np.sum(q, where=keep)) / max(N - n_params, 1.0)
    z = math.log(sr) / math.sqrt(v / max(N, 1.0))
    p_global = float(stats.norm.sf(z))
    blocks = []
    for r in range(prep.ctx.n_runs):
        rows = np.flatnonzero((prep.run == r) & keep)
        nb = int(min(16, max(1, rows.size // 64)))
        for part in np.array_split(rows, nb):
            if part.size < 16:
                continue
            Nb = part.size * C * eff
            srb = float(np.sum(q[part])) / max(Nb * (1 - n_params / max(N, 1)), 1.0)
            zb = math.log(max(srb, 1e-300)) / math.sqrt(2.0 / Nb + (v - 2.0) / N)
            blocks.append(
                (
                    float(stats.norm.sf(zb)),
                    zb,
                    int(prep.run_ids[r]),
                    float(prep.rows["t"][part[0]]),
                    float(prep.rows["t"][part[-1]]),
                )
            )
    nbk = max(len(blocks), 1)
    worst = min(blocks, default=(1.0, 0.0, 0, 0.0, 0.0))
    p_block = min(1.0, worst[0] * nbk)
    p = min(1.0, 2 * min(p_global, p_block))
    return {
        "test": "variance ratio of the whitened residual to the noise (median of the "
        "periodogram per channel); log ratio ~ N(0, v/N) under white noise, whole record and "
        "per time block (16 per run, Bonferroni)",
        "statistic_z": z,
        "variance_ratio": sr,
        "p_value": p,
        "p_value_whole": p_global,
        "p_value_blocks": p_block,
        "worst_block": {
            "run": worst[2],
            "t_start_s": worst[3],
            "t_end_s": worst[4],
            "z": worst[1],
        },
        "n_values": N,
        "n_params": n_params,
        "alpha": prep.settings.alpha,
        "passes": bool(p >= prep.settings.alpha),
    }


__all__ = ["goodness_of_fit"]
