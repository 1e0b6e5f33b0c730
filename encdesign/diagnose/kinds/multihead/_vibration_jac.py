"""Value and Jacobian written by hand (``Candidate.valjac``, each tested against
``jax.jacfwd``) of the multihead terms a selection round fits nonlinearly, pass after pass
over the rows (issue 43: forward mode carries one tangent per parameter through the
whole term): ``vibration`` (one tangent per run and head amplitude), ``bearing_wobble``
and ``eccentricity_shift``."""

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
        "staircase_margin": jnp.zeros_like(v),
    }


def bearing_wobble_valjac(p, x):
    """``(value, Jacobian)`` of ``_wb_fn``: ``[A sin(a) + B cos(a)] / R``, ``a = nu theta -
    alpha_k``, ``A``, ``B`` the run's runout components (m), ``R`` the optical radius."""
    oh = x["run_onehot"]
    th = x["theta"]
    R = x["radius_m"]
    A = oh @ p["runout_a_m"]
    B = oh @ p["runout_b_m"]
    v = fx.bearing_wobble_rad(th, x["alpha"], R, p["frequency_ratio"], A, B)
    arg = p["frequency_ratio"] * th[:, None] - x["alpha"][None, :]
    s, c = jnp.sin(arg), jnp.cos(arg)
    ta = th[:, None]  # d arg / d nu
    return v, {
        "frequency_ratio": (A[:, None] * (c * ta) + B[:, None] * -(s * ta)) / R,
        "runout_a_m": (oh[:, None, :] * s[:, :, None]) / R,
        "runout_b_m": (oh[:, None, :] * c[:, :, None]) / R,
    }


def eccentricity_shift_valjac(p, x):
    """``(value, Jacobian)`` of ``_es_fn``: ``step(tau) [dx sin(d) + dy cos(d)] / R``, ``d =
    theta - alpha_k``, ``step = (1 + tanh(u)) / 2``, ``u = (tau - t_s) / (2 w)``."""
    th, tau, R, w = x["theta"], x["tau"], x["radius_m"], x["step_width_s"]
    t0 = p["shift_time_s"]
    v = fx.eccentricity_shift_rad(th, tau, x["alpha"], R, t0, p["shift_x_m"], p["shift_y_m"], w)
    d = th[:, None] - x["alpha"][None, :]
    sd, cd = jnp.sin(d), jnp.cos(d)
    step = fx.smooth_step(tau, t0, w)
    ecc = (p["shift_x_m"] * sd + p["shift_y_m"] * cd) / R
    T = jnp.tanh(0.5 * (tau - t0) / w)
    g = -0.5 / w  # d u / d t_s
    dstep = 0.5 * ((g + g * T) * (1.0 - T))  # the tangent of tanh as jax.jvp forms it
    return v, {
        "shift_time_s": dstep[:, None] * ecc,
        "shift_x_m": step[:, None] * (sd / R),
        "shift_y_m": step[:, None] * (cd / R),
    }
