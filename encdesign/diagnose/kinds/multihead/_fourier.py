"""The base term's disk error function by Horner's rule (issue 43: its value was about a
fifth of a long record's diagnosis, two sines and cosines per order and sample)."""

from __future__ import annotations

import math
from collections.abc import Callable

import jax.numpy as jnp


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
