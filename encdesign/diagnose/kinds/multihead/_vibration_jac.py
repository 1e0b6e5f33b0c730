"""The multihead ``vibration`` term's value and Jacobian written by hand (issue 43: its
forward-mode Jacobian carried one tangent per run and head amplitude through the term, on
every pass of its trial fit over the rows; ``Candidate.valjac``, tested against
``jax.jacfwd``)."""

from __future__ import annotations

import jax.numpy as jnp

from ....physics import _effects as fx


def vibration_valjac(p, x):
    """``(value (n, C), {parameter: d value / d parameter})`` of ``_vb_fn``: the value
    ``A cos(w) + B sin(w)``, ``w = 2 pi f t``, ``A``, ``B`` the run's amplitudes per head."""
    oh = x["run_onehot"]
    C = x["reading"].shape[1]
    R = oh.shape[1]
    t = x["t"]
    A = oh @ p["cos_rad"].reshape(R, C)
    B = oh @ p["sin_rad"].reshape(R, C)
    v = fx.vibration_rad(t, p["frequency_hz"], A, B)
    w = 2.0 * jnp.pi * p["frequency_hz"] * t[:, None]
    cw, sw = jnp.cos(w), jnp.sin(w)
    at = oh[:, None, :, None] * jnp.eye(C, dtype=t.dtype)[None, :, None, :]  # (n, C, R, C)
    dw = 2.0 * jnp.pi * t[:, None]
    return v, {
        "frequency_hz": (B * cw - A * sw) * dw,
        "cos_rad": at * cw[:, :, None, None],
        "sin_rad": at * sw[:, :, None, None],
        "locked_margin": jnp.zeros_like(v),
    }
