"""Shared tools of the finders for real-data kinds: Fourier order scans, held-out splits,
forward selection of catalog effects by held-out error and BIC.

Everything here is plain NumPy on already-fitted residuals (the nonlinear fits live with
each kind's finder). Orders are cycles per revolution (motion) or per signal period
(quadrature).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np


def fourier_columns(x_rad: np.ndarray, orders: Sequence[int]) -> np.ndarray:
    """Columns ``cos(m x), sin(m x)`` for each order ``m`` (shape ``(n, 2·len(orders))``)."""
    orders = np.asarray(list(orders), dtype=float)
    if orders.size == 0:
        return np.zeros((len(x_rad), 0))
    mx = np.outer(x_rad, orders)
    out = np.empty((len(x_rad), 2 * orders.size))
    out[:, 0::2] = np.cos(mx)
    out[:, 1::2] = np.sin(mx)
    return out


@dataclasses.dataclass(frozen=True)
class OrderScan:
    """Least-squares amplitude of each order in a residual, with a calibrated test.

    Attributes:
        orders: the orders scanned.
        amplitude: Fourier amplitude per order (units of the residual).
        snr: amplitude² over its noise expectation (χ²₂/2 under white noise: mean 1).
        local_ratio: amplitude² over the median amplitude² of the neighbouring orders
            (robust against coloured noise on real data).
        significant: orders passing both tests (family-wise false-alarm ``alpha``).
    """

    orders: np.ndarray
    amplitude: np.ndarray
    snr: np.ndarray
    local_ratio: np.ndarray
    significant: np.ndarray


def order_scan(
    x_rad: np.ndarray,
    resid: np.ndarray,
    orders: Sequence[int],
    *,
    alpha: float = 1e-3,
    local_factor: float = 8.0,
    window: int = 10,
) -> OrderScan:
    """Scan ``resid`` (sampled at angles ``x_rad``, any spacing) for Fourier orders.

    All orders are fitted jointly by least squares (so uneven sampling is handled). The
    noise variance is the residual variance after that joint fit. An order is significant
    when its power exceeds the white-noise threshold at family-wise false-alarm ``alpha``
    (Bonferroni over the orders: ``snr > ln(N/alpha)``) *and* stands ``local_factor``
    above the median power of its ``window`` neighbours on each side.
    """
    orders = np.asarray(list(orders), dtype=int)
    X = fourier_columns(x_rad, orders)
    X1 = np.column_stack([np.ones(len(x_rad)), X])
    coef, *_ = np.linalg.lstsq(X1, resid, rcond=None)
    rest = resid - X1 @ coef
    dof = max(len(resid) - X1.shape[1], 1)
    sigma2 = float(rest @ rest) / dof
    c, s = coef[1::2], coef[2::2]
    amp2 = c**2 + s**2
    # variance of each coefficient for near-orthogonal columns: 2 sigma² / n
    expected = 2.0 * sigma2 / len(resid) * 2.0
    snr = amp2 / max(expected, 1e-300)
    local = np.empty_like(amp2)
    for i in range(amp2.size):
        lo, hi = max(0, i - window), min(amp2.size, i + window + 1)
        neigh = np.delete(amp2[lo:hi], i - lo)
        local[i] = amp2[i] / max(float(np.median(neigh)) if neigh.size else 0.0, 1e-300)
    thresh = math.log(max(orders.size, 1) / alpha)
    sig = (snr > thresh) & (local > local_factor)
    return OrderScan(orders, np.sqrt(amp2), snr, local, orders[sig])


def sector_split(x_rad: np.ndarray, n_sectors: int = 40, every: int = 5, offset: int = 2):
    """Held-out mask by interleaved angular sectors: sector ``i`` is held out when
    ``i % every == offset``. Returns ``(train_mask, heldout_mask)``."""
    frac = np.mod(x_rad, 2 * np.pi) / (2 * np.pi)
    sector = np.minimum((frac * n_sectors).astype(int), n_sectors - 1)
    held = (sector % every) == offset
    return ~held, held


def rms(x: np.ndarray) -> float:
    """Root mean square (same units as ``x``)."""
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def bic(resid_train: np.ndarray, n_params: int) -> float:
    """Bayesian information criterion of a Gaussian least-squares fit."""
    n = resid_train.size
    return float(
        n * math.log(max(float(resid_train @ resid_train) / n, 1e-300)) + n_params * math.log(n)
    )


@dataclasses.dataclass
class Step:
    """One accepted candidate in a forward selection."""

    name: str
    fit: dict
    rms_after: float
    heldout_rms_after: float
    bic: float
    heldout_gain: float


def forward_select(
    fit_fn: Callable[[tuple[str, ...]], dict],
    candidates: Sequence[str],
    *,
    min_heldout_gain: float = 0.2,
) -> tuple[dict, list[Step], list[dict]]:
    """Greedy forward selection of catalog effects.

    ``fit_fn(names)`` fits the base model plus the named effects on the training part and
    returns a dict with at least ``rms``, ``heldout_rms``, ``bic``. At each step every
    remaining candidate is tried; the one with the lowest held-out RMS is accepted when it
    lowers the BIC and cuts the held-out RMS by at least ``min_heldout_gain`` (relative).

    Returns ``(base_fit, accepted_steps, rejected)`` where ``rejected`` lists each
    candidate never accepted with the numbers of its last try and the reason.
    """
    base = fit_fn(())
    current, accepted = base, []
    remaining = list(candidates)
    last_try: dict[str, dict] = {}
    while remaining:
        tries = {c: fit_fn(tuple(s.name for s in accepted) + (c,)) for c in remaining}
        last_try.update(tries)
        best = min(tries, key=lambda c: tries[c]["heldout_rms"])
        f = tries[best]
        gain = 1.0 - f["heldout_rms"] / current["heldout_rms"]
        if f["bic"] < current["bic"] and gain >= min_heldout_gain:
            accepted.append(Step(best, f, f["rms"], f["heldout_rms"], f["bic"], gain))
            current = f
            remaining.remove(best)
        else:
            break
    rejected = []
    ref = current
    for c in remaining:
        f = last_try[c]
        gain = 1.0 - f["heldout_rms"] / ref["heldout_rms"] if c in last_try else 0.0
        why = []
        if f["bic"] >= ref["bic"]:
            why.append("no BIC improvement")
        if gain < min_heldout_gain:
            why.append(
                f"held-out RMS changes by {-100 * gain + 0.0:+.1f} % "
                f"(needs -{100 * min_heldout_gain:.0f} %)"
            )
        rejected.append(
            {"name": c, "heldout_rms": f["heldout_rms"], "reason": "; ".join(why) or "not best"}
        )
    return base, accepted, rejected
