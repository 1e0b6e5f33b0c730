"""The multihead ``beam_tilt_axial`` term's model: its head-specific projection, its value and
its value and Jacobian written by hand (issue 43).

Per runout order ``m`` (:data:`._runout.RUNOUT_ORDERS`) the fitted head coefficients ``w_k =
c_k - i s_k`` (rad) lose their part in the base model's span at that order, ``z = P_m w`` with
``P_m = I - Q^T conj(Q)`` (:func:`_bt_basis`), and the term is ``e_k(theta) = sum_m on_m [Re
z_k cos(m theta) - Im z_k sin(m theta)]``. ``P_m`` depends on the head angles alone, so it is
formed once per evaluation as two real ``(C, C)`` matrices, all orders at once
(:func:`bt_projectors`): with ``Pr + i Pi = P_m``, ``Re z = Pr c + Pi s`` and ``Im z = Pi c -
Pr s``, and the term is linear in ``c`` and ``s`` with the Jacobian columns
``d e_k / d c_l = on_m (Pr_kl cos m theta - Pi_kl sin m theta)`` and ``d e_k / d s_l = on_m
(Pi_kl cos m theta + Pr_kl sin m theta)``.

Why by hand: the complex form (a basis, an inner product and a product per order, each
order apart) compiled to the largest program of a diagnosis; its ``jax.jacfwd`` (24 forward
tangents through every complex step) took about 0.6 s of XLA compilation on every process of
a split diagnosis, and its value about 0.2 s (``docs/scale.md``). The real form below
computes the same numbers to rounding (tested against the complex form, its Jacobian
against ``jax.jacfwd`` and finite differences: ``tests/test_beam_tilt.py``).
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

from ._runout import RUNOUT_ORDERS

SPAN_MIN = 1e-6
"""At a multiple of the head symmetry the head pattern ``u_k = exp(-i m alpha_k)`` is the
common mode itself: its part outside the common mode (norm below ``SPAN_MIN * sqrt(C)``) is
then not a second direction of the base model's span."""


def _bt_basis(alpha, m: float, project: bool):
    """Orthonormal head vectors (complex, (q, C)) of what the base model spans at order ``m``:
    the disk error every head sees phase-shifted by its azimuth, ``u_k = exp(-i m alpha_k)``,
    and without theta_ref also the common mode (the head mean is projected out)."""
    C = alpha.shape[0]
    u = jnp.exp(-1j * m * alpha)
    if not project:
        return (u / jnp.sqrt(C))[None, :]
    q1 = jnp.ones(C, complex) / jnp.sqrt(C)
    v = u - q1 * jnp.vdot(q1, u)
    nv = jnp.sqrt(jnp.sum(jnp.abs(v) ** 2))
    # at a multiple of the head symmetry u is the common mode itself: one vector only
    q2 = jnp.where(nv > SPAN_MIN * jnp.sqrt(C), v / jnp.maximum(nv, 1e-300), 0.0)
    return jnp.stack([q1, q2])


def _bt_head_specific(alpha, coefs, project: bool):
    """Per runout order: the complex head coefficients ``z_k = c_k - i s_k`` less their part
    in the base model's span (what the disk error, or the head mean, would take)."""
    out = []
    for j, m in enumerate(RUNOUT_ORDERS):
        c, s_ = coefs[j]
        w = c - 1j * s_
        Q = _bt_basis(alpha, m, project)
        out.append(w - Q.T @ (jnp.conj(Q) @ w))
    return out


def bt_projectors(alpha, project: bool, xp=np):
    """``(Pr, Pi)``, each ``(orders, C, C)``: the real and imaginary parts of ``P_m = I -
    Q^T conj(Q)`` (:func:`_bt_basis`) at every runout order, in real arithmetic (``xp``:
    NumPy, or ``jax.numpy`` inside a traced function). The head pattern ``u_k = exp(-i m
    alpha_k) = cos(m alpha_k) - i sin(m alpha_k)``; its span's projector is ``u u^H / |u|^2``
    (``|u|^2 = C``), and without theta_ref the common mode's ``1 / C`` plus that of ``v = u -
    mean(u)`` where it is not zero (:data:`SPAN_MIN`)."""
    C = alpha.shape[0]
    ma = xp.asarray(RUNOUT_ORDERS)[:, None] * alpha[None, :]  # (orders, C)
    ur, ui = xp.cos(ma), -xp.sin(ma)
    if project:
        ur = ur - xp.mean(ur, axis=1, keepdims=True)
        ui = ui - xp.mean(ui, axis=1, keepdims=True)
        n2 = xp.sum(ur * ur + ui * ui, axis=1)[:, None, None]
        span = n2 > (SPAN_MIN * SPAN_MIN) * C
        scale = xp.where(span, 1.0 / xp.where(span, n2, 1.0), 0.0)
        common = 1.0 / C
    else:
        scale = 1.0 / C
        common = 0.0
    # u_k conj(u_l) = (ur_k ur_l + ui_k ui_l) + i (ui_k ur_l - ur_k ui_l)
    re = ur[:, :, None] * ur[:, None, :] + ui[:, :, None] * ui[:, None, :]
    im = ui[:, :, None] * ur[:, None, :] - ur[:, :, None] * ui[:, None, :]
    return xp.eye(C)[None] - common - scale * re, -scale * im


def _weights(Pr, Pi, on, c, s):
    """The term's weights on its features ``[cos m theta (orders), sin m theta (orders)]``
    (:func:`bt_factors`), NumPy: per parameter (``cos1_rad, sin1_rad, ...``, then
    ``orders_on``) ``(F, C, size)``."""
    K, C = Pr.shape[0], Pr.shape[1]
    out = {}
    for j in range(K):
        wc, ws = np.zeros((2 * K, C, C)), np.zeros((2 * K, C, C))
        wc[j], wc[K + j] = Pr[j] * on[j], -Pi[j] * on[j]  # d e / d c_j
        ws[j], ws[K + j] = Pi[j] * on[j], Pr[j] * on[j]  # d e / d s_j
        out[f"cos{j + 1}_rad"], out[f"sin{j + 1}_rad"] = wc, ws
    re = np.einsum("mkl,ml->mk", Pr, c) + np.einsum("mkl,ml->mk", Pi, s)  # Re z (orders, C)
    im = np.einsum("mkl,ml->mk", Pi, c) - np.einsum("mkl,ml->mk", Pr, s)  # Im z
    wo = np.zeros((2 * K, C, K))
    wo[np.arange(K), :, np.arange(K)] = re
    wo[K + np.arange(K), :, np.arange(K)] = -im
    out["orders_on"] = wo
    return out


def bt_factors(project: bool) -> Callable:
    """The term's Jacobian as a product ``J = X W`` (``engine._normal.register_factors``):
    per row the features ``X = [cos(m theta), sin(m theta)]`` over the runout orders, per head
    the weights ``W`` (:func:`_weights`, from :func:`bt_projectors` of the head angles).
    Without ``full``: over the free linear parameters, the value at zero linear parameters
    (0); with ``full``: over every free scalar, the value at ``p``. ``E`` is always ``None``
    (every column is a product of the features). The same columns as ``jax.jacfwd`` of the
    candidate's ``fn`` to rounding (tested)."""
    K = len(RUNOUT_ORDERS)
    m = np.asarray(RUNOUT_ORDERS)
    names = [f"{a}{j + 1}_rad" for j in range(K) for a in ("cos", "sin")]

    def factors(p: dict, x: dict, free: dict, rows: int, full: bool = False):
        th = np.asarray(x["theta"], float)[:rows]
        alpha = np.asarray(x["alpha"], float)
        arg = th[:, None] * m[None, :]
        X = np.concatenate([np.cos(arg), np.sin(arg)], axis=1)  # (rows, 2 K)
        Pr, Pi = bt_projectors(alpha, project)
        on = np.asarray(p["orders_on"], float)
        c = np.stack([np.asarray(p[f"cos{j + 1}_rad"], float) for j in range(K)])
        s = np.stack([np.asarray(p[f"sin{j + 1}_rad"], float) for j in range(K)])
        blocks = _weights(Pr, Pi, on, c, s)
        used = names + (["orders_on"] if full else [])
        W = np.concatenate([blocks[k][:, :, np.asarray(free[k]).ravel()] for k in used], 2)
        if not full:
            return np.zeros((rows, alpha.size)), X, W, None
        lin = np.concatenate([np.asarray(p[k], float).ravel() for k in names])
        Wall = np.concatenate([blocks[k] for k in names], 2)
        return X @ (Wall @ lin), X, W, None

    return factors


def bt_valjac(project: bool) -> Callable:
    """``valjac(p, x) -> (value (n, C), {parameter: (n, C, *shape)})`` of the term in JAX
    (``Candidate.valjac``): its value in the real form (module doc) and its Jacobian,
    ``orders_on``'s column per order the order's unmasked part."""
    K = len(RUNOUT_ORDERS)

    def valjac(p, x):
        arg = x["theta"][:, None] * jnp.asarray(RUNOUT_ORDERS)[None, :]
        cs, sn = jnp.cos(arg), jnp.sin(arg)
        c = jnp.stack([p[f"cos{j + 1}_rad"] for j in range(K)])
        s = jnp.stack([p[f"sin{j + 1}_rad"] for j in range(K)])
        Pr, Pi = bt_projectors(x["alpha"], project, jnp)
        re = jnp.sum(Pr * c[:, None, :] + Pi * s[:, None, :], axis=2)  # Re z (orders, C)
        im = jnp.sum(Pi * c[:, None, :] - Pr * s[:, None, :], axis=2)  # Im z
        on = p["orders_on"]
        J = {}
        for j in range(K):
            cj, sj = cs[:, j, None, None], sn[:, j, None, None]
            ar, ai = Pr[j] * on[j], Pi[j] * on[j]
            J[f"cos{j + 1}_rad"] = cj * ar[None] - sj * ai[None]
            J[f"sin{j + 1}_rad"] = cj * ai[None] + sj * ar[None]
        J["orders_on"] = cs[:, None, :] * re.T[None] - sn[:, None, :] * im.T[None]
        v = jnp.sum(J["orders_on"] * on[None, None, :], axis=2)
        return v, J

    return valjac
