"""The base term's disk error function by Horner's rule (issue 43: its value was about a
fifth of a long record's diagnosis, two sines and cosines per order and sample)."""

from __future__ import annotations

import math
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

from ...engine._views_orders import harmonics


def fourier_sum(phi, a, b):
    """``sum_{m=1..M} a_m cos(m phi) + b_m sin(m phi)`` (``phi`` any shape, rad; ``a``,
    ``b`` ``(M,)``): the real part of ``sum_m (a_m - i b_m) z^m``, ``z = exp(i phi)``, by
    Horner's rule, so one sine and one cosine per angle instead of ``M`` each. It equals
    ``physics._effects.base_error_rad`` to rounding: ``z^m`` carries ``m`` roundings of a
    product of unit numbers, where ``cos(m phi)`` carries the rounding of ``m phi``, about
    ``|m phi| eps`` (tested)."""
    zr, zi = jnp.cos(phi), jnp.sin(phi)
    pr, pi = jnp.zeros_like(phi), jnp.zeros_like(phi)
    for m in range(a.shape[0] - 1, -1, -1):
        qr, qi = pr + a[m], pi - b[m]
        pr, pi = qr * zr - qi * zi, qr * zi + qi * zr
    return pr


def fourier_columns(phi, M: int):
    """``(cos(m phi), sin(m phi))`` for ``m = 1..M``, each of shape ``phi.shape + (M,)``:
    ``exp(i m phi)`` for ``m = j B + k`` (``B = ceil(sqrt(M))``, ``k = 1..B``) as the product
    of ``exp(i j B phi)`` and ``exp(i k phi)``, so about ``2 sqrt(M)`` sines and cosines per
    angle instead of ``2 M`` (issue 43: they were most of the base term's Jacobian, which
    every pass of a trial fit evaluates). Each carries the roundings of its two factors'
    arguments and of one complex product: it equals ``cos(m phi)`` to about ``|m phi| eps``
    (tested, as :func:`fourier_sum`)."""
    B = max(1, math.isqrt(M - 1) + 1) if M > 1 else 1
    J = -(-M // B)
    k = jnp.arange(1, B + 1, dtype=phi.dtype)
    j = jnp.arange(J, dtype=phi.dtype) * B
    ph = phi[..., None]
    er, ei = jnp.cos(k * ph), jnp.sin(k * ph)
    fr, fi = jnp.cos(j * ph), jnp.sin(j * ph)
    shape = (*phi.shape, J * B)
    cr = (fr[..., :, None] * er[..., None, :] - fi[..., :, None] * ei[..., None, :]).reshape(shape)
    ci = (fr[..., :, None] * ei[..., None, :] + fi[..., :, None] * er[..., None, :]).reshape(shape)
    return cr[..., :M], ci[..., :M]


def base_value(shifted: Callable, mask) -> Callable:
    """The base candidate's ``value`` (``Candidate.value``): its ``fn`` with the disk
    error by :func:`fourier_sum`; ``shifted(p, x) -> (run one-hot, shaft angles, head
    azimuths)`` as the candidate's own, ``mask`` its live orders."""

    def value(p, x):
        oh, th, alpha = shifted(p, x)
        a, b = p["fourier_cos_rad"] * mask, p["fourier_sin_rad"] * mask
        return fourier_sum(th[:, None] - alpha[None, :], a, b) + oh @ p["offset_rad"]

    return value


TRIG_TABLE_ERROR = 4.0
"""Bound (in units of ``m * eps``) on the angle-addition table's departure from ``cos(m
theta)``, ``sin(m theta)`` of the rounded angle (``engine._views_orders.harmonics``, the
base factors' features): ``sqrt(5) + 1`` per complex product, rounded up."""


def base_factors(C: int, R: int, M: int, live: np.ndarray, placed: bool) -> Callable:
    """The base term's Jacobian as a product ``J = X W`` (``engine._normal.register_factors``): per
    row the features ``X = [run one-hot (R), cos(m theta) (M), sin(m theta) (M)]``
    (``engine._views_orders.harmonics``, theta with the runs' angle zeros), per head the weights ``W
    (F, C, k)``: ``cos(m (theta - alpha_c)) = cos(m theta) cos(m alpha_c) + sin(m theta) sin(m
    alpha_c)``, ``sin(m (theta - alpha_c)) = sin(m theta) cos(m alpha_c) - cos(m theta) sin(m
    alpha_c)``, an offset the run's one-hot, a placement's column ``-slope`` on its head (``slope =
    sum_m m (b_m cos - a_m sin)``, linear in the features too). Every head shares the row's ``F = R
    + 2 M`` features, so the fitter makes the processed (fold-sorted, projected, whitened, scaled)
    Jacobian in one matrix product (``Fitter._processed``). With ``full`` (the parameters' own
    values, nonlinear ones free too) the runs' angle zeros' columns, ``slope`` times the run's
    one-hot (not a product of the features with weights), come as ``E`` (rows, C, R - 1), after ``X
    W``'s; else ``E`` is ``None``, the nonlinear parameters held and the value that at zero linear
    parameters (0). The same columns as the candidate's ``valjac`` (its ``mask`` ``live``) to
    rounding (tested)."""
    live = np.asarray(live, float)
    m = np.arange(1, M + 1, dtype=float)
    j = np.arange(M)
    F = R + 2 * M
    Woff = np.zeros((F, C, R, C))
    for r in range(R):
        Woff[r, np.arange(C), r, np.arange(C)] = 1.0
    Woff = Woff.reshape(F, C, R * C)

    def factors(p: dict, x: dict, free: dict, rows: int, full: bool = False):
        oh = np.asarray(x["run_onehot"], float)[:rows]
        th = np.asarray(x["theta_raw"], float)[:rows]
        if R > 1:
            th = th + oh[:, 1:] @ np.asarray(p["run_angle_offset_rad"], float)
        alpha = np.asarray(x["alpha"], float)
        if C > 1 and placed:
            alpha = alpha + np.concatenate([[0.0], np.asarray(p["placement_rad"], float)])
        cm, sm = harmonics(th, M)
        X = np.empty((rows, F))
        X[:, :R] = oh
        X[:, R : R + M] = cm.T
        X[:, R + M :] = sm.T
        ang = m[:, None] * alpha[None, :]  # (M, C)
        ca, sa = np.cos(ang) * live[:, None], np.sin(ang) * live[:, None]
        Wc = np.zeros((F, C, M))
        Ws = np.zeros((F, C, M))
        Wc[R + j, :, j] = ca
        Wc[R + M + j, :, j] = sa
        Ws[R + M + j, :, j] = ca
        Ws[R + j, :, j] = -sa
        blocks = {"offset_rad": Woff, "fourier_cos_rad": Wc, "fourier_sin_rad": Ws}
        if not full:
            W = np.concatenate([blocks[k][:, :, np.asarray(free[k]).ravel()] for k in blocks], 2)
            return np.zeros((rows, C)), X, W, None
        a = np.asarray(p["fourier_cos_rad"], float)
        b = np.asarray(p["fourier_sin_rad"], float)
        lin = np.concatenate([np.asarray(p["offset_rad"], float).ravel(), a, b])
        Wall = np.concatenate([Woff, Wc, Ws], 2)
        v = X @ (Wall @ lin)  # (F, C) weights of the value
        Wsl = np.zeros((F, C))  # slope = X Wsl
        Wsl[R + j] = m[:, None] * (b[:, None] * ca + a[:, None] * sa)
        Wsl[R + M + j] = m[:, None] * (b[:, None] * sa - a[:, None] * ca)
        if C > 1 and placed:
            Wpl = np.zeros((F, C, C - 1))
            Wpl[:, np.arange(1, C), np.arange(C - 1)] = -Wsl[:, 1:]
            blocks["placement_rad"] = Wpl
        W = np.concatenate([blocks[k][:, :, np.asarray(free[k]).ravel()] for k in blocks], 2)
        E = None
        if R > 1:
            fr = np.asarray(free["run_angle_offset_rad"]).ravel()
            if fr.any():
                E = (X @ Wsl)[:, :, None] * oh[:, None, 1:][:, :, fr]
        return v, X, W, E

    return factors
